"""``jaxcal reproduce``.
"""

from __future__ import annotations

import pathlib
import time

from ._common import _Usage, _write_outputs

__all__ = ["QUICK", "ALL_EIGHT"]


#: ``--quick`` settings: few seeds and samples, two methods (LM and AdaModW: compilation, ~10-20 s
#: per method on 2 CPU cores, dominates a small run). The population methods keep their full
#: budgets (with 150 generations they ended "still improving"; a trial costs ~1 s at 400 samples).
QUICK = {
    "seeds": 3,
    "samples": 400,
    "methods": ("lm", "adamodw"),
    "hyperparameters": {
        "rbfnn": {"n_centres": 60},
    },
}


ALL_EIGHT = "ga ekf bso lm iwoa rbfnn adam adamodw"


def _staged_ok(name: str) -> bool:
    """Whether ``name`` is stages of registered methods (``ga>lm``)."""
    from ..methods._stages import check_method_name, is_staged_name

    try:
        return is_staged_name(name) and bool(check_method_name(name))
    except ValueError:
        return False


def _cmd_reproduce(args) -> int:
    from .._experiments._sweep import PAPER_METHODS, sweep
    from ..methods import METHODS

    quick = args.quick
    seeds = args.seeds if args.seeds is not None else (QUICK["seeds"] if quick else 20)
    samples = args.samples if args.samples is not None else (QUICK["samples"] if quick else 2000)
    # the defaults (the paper's M1-M8, or the quick pair) are all registered
    methods = [m.lower() for m in args.methods or (QUICK["methods"] if quick else PAPER_METHODS)]
    unknown = [m for m in methods if m not in METHODS and not _staged_ok(m)]
    if unknown:
        raise _Usage(f"unknown method(s) {unknown}; available: {', '.join(sorted(METHODS))}")
    if seeds < 1:
        raise _Usage(f"--seeds must be >= 1, got {seeds}")
    hyper = {m: h for m, h in QUICK["hyperparameters"].items() if m in methods} if quick else {}
    out = pathlib.Path(args.out)
    if quick and not args.methods and not args.quiet:
        print(f"jaxcal reproduce --quick: {' and '.join(methods)} only, {seeds} seeds × {samples} samples (a smoke "
              f"run). All eight methods at this scale: --quick --methods {ALL_EIGHT} (~3 min on 2 CPU cores, mostly "
              "compilation); the paper's scale: no --quick.")
    t0 = time.perf_counter()
    try:
        res = sweep(methods, seeds, seed=args.seed, n_samples=samples, noise_std=args.noise_std, hyperparameters=hyper,
                    chunk_size=args.chunk_size, batching=args.batching, out_dir=out / "sweep", progress=not args.quiet)
    except ValueError as e:
        if "other settings" not in str(e):
            raise
        raise _Usage(f"{out}/sweep holds chunks of a run with other settings (seeds, samples, methods, noise, ...); "
                     f"pass another --out DIR, or delete {out} to start over") from None
    t_sweep = time.perf_counter() - t0
    files = _write_outputs(res, out, figures=not args.no_figures)
    total = time.perf_counter() - t0
    print(f"\n{len(files)} files written to {out}/ (sweep {t_sweep:.1f} s, total {total:.1f} s; "
          f"chunks in {out / 'sweep'} resume an interrupted run)")
    return 0
