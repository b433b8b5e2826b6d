"""``jaxcal report``.
"""

from __future__ import annotations

import pathlib

from ._common import _Usage, _write_outputs


def _cmd_report(args) -> int:
    from .._experiments._sweep_results import load_sweep

    src = pathlib.Path(args.sweep_dir)
    if src.suffix.lower() == ".json" or args.html:
        if not src.is_file():
            raise _Usage(f"{args.sweep_dir}: no such file (--html takes a RESULT.json, a combined.json or an EVAL.json)")
        if not args.html:
            raise _Usage("a result, combined result or evaluation file needs --html PAGE.html (tables and figures for sweeps: "
                         "the sweep directory)")
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise _Usage("the HTML report needs matplotlib (pip install 'jaxcal[plot]')") from None
        from .._experiments._html import write_html

        out = write_html(src, args.html)
        print(f"wrote {out} (one self-contained page: figures inline, no network needed)")
        return 0
    if not (src / "sweep.json").exists() and (src / "sweep" / "sweep.json").exists():
        src = src / "sweep"
    if not (src / "sweep.json").exists():
        raise _Usage(f"{args.sweep_dir} holds no sweep (no sweep.json)")
    res = load_sweep(src, partial=args.partial)
    out = pathlib.Path(args.out) if args.out else src.parent
    files = _write_outputs(res, out, figures=not args.no_figures)
    print(f"\n{len(files)} files written to {out}/")
    return 0
