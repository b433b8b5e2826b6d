"""``jaxcal fleet-prior`` and ``jaxcal drift``: priors and changes learned from calibration result files.
"""

from __future__ import annotations

import datetime
import json
import pathlib

from ._common import _Usage


def _load(paths, what: str):
    from .._calibration._io import load_result

    out = []
    for p in paths:
        if not pathlib.Path(p).is_file():
            raise _Usage(f"{what}: result file {p!r} not found")
        out.append(load_result(p))
    return out


def _cmd_fleet_prior(args) -> int:
    from .._fit._objective import Prior

    results = _load(args.results, "fleet-prior")
    prior = Prior.from_fleet(results, noise_std=args.noise_std)
    prior.save(args.out)
    print(prior.population)
    print(f"\nwrote {args.out} ({prior.describe()}); use it as `jaxcal calibrate ... --prior {args.out}`")
    return 0


def _file_date(path) -> str:
    """A result file's ``calibrated_at`` entry (``jaxcal calibrate --out`` writes it), else its
    modification date (``YYYY-MM-DD``, UTC)."""
    try:
        d = json.loads(pathlib.Path(path).read_text(encoding="utf-8"))
        if isinstance(d, dict) and d.get("calibrated_at"):
            return str(d["calibrated_at"])
    except (OSError, ValueError):
        pass
    return datetime.datetime.fromtimestamp(pathlib.Path(path).stat().st_mtime, datetime.timezone.utc).date().isoformat()


def _cmd_drift(args) -> int:
    from .._fit._drift import drift

    previous, current = _load([args.previous, args.current], "drift")
    since = args.since if args.since is not None else f"{_file_date(args.previous)} ({pathlib.Path(args.previous).name})"
    report = drift(previous, current, since=since, alpha=args.alpha)
    print(report)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(report.to_dict(), indent=1) + "\n", encoding="utf-8")
        print(f"\nwrote {args.json}")
    return 1 if report.moved else 0
