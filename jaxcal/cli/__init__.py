"""The ``jaxcal`` command line: reproduce the paper, calibrate a robot from a CSV file, simulate data.

Subcommands (``jaxcal SUBCOMMAND --help`` explains units and file formats):

* ``jaxcal reproduce``: the paper's comparison (Tables III–V, Figs. 2–4) as a seed sweep.
* ``jaxcal calibrate DATA.csv``: calibrate from measured data; prints before/after accuracy on
  held-out data and the calibrated DH table; writes a JSON result.
* ``jaxcal simulate --out data.csv``: a simulated draw-wire (or position) data set to try
  ``calibrate`` on.
* ``jaxcal report SWEEP_DIR``: tables and figures again from a finished (or interrupted) sweep.
* ``jaxcal export RESULT.json --out calibrated.urdf``: the calibrated model as URDF (and the
  calibrated DH table with ``--dh-out`` where the model is a DH table).
* ``jaxcal plan --poses N --out poses.csv``: which poses to measure, their observability indices and
  the predicted accuracy, before measuring.
* ``jaxcal fleet-prior results/*.json --out model.prior.json``: a robot model's prior learned from
  its calibrated units, for ``jaxcal calibrate ... --prior model.prior.json``.
* ``jaxcal drift previous.json current.json``: which robot parameters of a unit moved between two
  calibrations, beyond their uncertainty.

Errors in the input (unknown robot or method, bad CSV, too few samples) print one line on
stderr and exit with status 2; a failed calibration exits with status 1.
"""

from __future__ import annotations

import sys

from ._common import _Usage
from ._parser import build_parser

__all__ = ["main", "build_parser"]

_EXIT_USAGE = 2


def _die(msg: str, code: int = _EXIT_USAGE) -> int:
    print(f"jaxcal: error: {msg}", file=sys.stderr)
    return code


# -- plan -------------------------------------------------------------------------------------------


#: commands that are one bounded job (seconds; one calibration or one fleet program, one file
#: written): Python's cyclic garbage collector stays off while they run (see :func:`main`)
_NO_GC_COMMANDS = ("calibrate", "evaluate", "export", "simulate")


def main(argv: list[str] | None = None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``); returns the exit status.

    Python's cyclic garbage collector is off during start-up (importing JAX and jaxcal) and while
    a one-job command (:data:`_NO_GC_COMMANDS`) runs, and as it was afterwards: importing and
    tracing create hundreds of thousands of long-lived objects, which its full collections
    traversed again and again — 0.25-0.3 s of a ``jaxcal calibrate`` start on 2 cores (466
    collections; the peak resident memory is the same without them, 344 MB)."""
    return _run(argv, exiting=False)


def console_main() -> int:
    """The ``jaxcal`` program (the console script and ``python -m jaxcal.cli``): :func:`main`, after
    which the process ends. The objects the command made are moved out of the garbage
    collector's sight (``gc.freeze()``) before it is switched on again: otherwise the first
    collection after the command and the interpreter's collection at exit traverse them all —
    0.5-0.75 s of a 2-3 s ``jaxcal calibrate`` on 2 cores, for memory the operating system takes
    back anyway. (:func:`main` itself, called inside a longer-lived process such as a test run,
    leaves them to the collector.)

    Its process is jaxcal's own, so it also runs the host linear algebra (NumPy's BLAS/LAPACK) on
    one thread unless ``OPENBLAS_NUM_THREADS`` / ``MKL_NUM_THREADS`` say otherwise
    (:func:`_one_blas_thread`)."""
    _one_blas_thread()
    return _run(None, exiting=True)


#: the BLAS libraries' thread-count variables the command line sets to 1 where the user set none
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _one_blas_thread() -> None:
    """One BLAS thread for the host's small linear algebra (p×p factorisations, least squares), set
    before NumPy loads its BLAS (the variables are read once, at load). XLA runs the solves on its
    own thread pool; OpenBLAS's worker threads busy-wait between calls and took the cores from it:
    a warm ``jaxcal calibrate --combine`` of the dual-arm robot (four files, 138 free parameters)
    took 18.0 s with OpenBLAS's default threads and 10.3 s with one on the 2-core CPU, its LM solves
    6.3 → 3.7 s, its parameter selection's 36 least-squares solves of a 138×138 factor 0.16 s →
    milliseconds each. A variable the user set is left as it is."""
    import os

    for var in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(var, "1")


def _run(argv: list[str] | None, exiting: bool) -> int:
    import gc

    gc_enabled = gc.isenabled()
    gc.disable()
    try:
        return _main(argv, gc_enabled)
    finally:
        if exiting:
            gc.freeze()
        if gc_enabled:
            gc.enable()


def _main(argv: list[str] | None, gc_enabled: bool) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help (0) or a usage error (2, message already printed)
        return int(e.code or 0)
    if not getattr(args, "command", None):
        parser.print_help()
        return _EXIT_USAGE
    from .._core._precision import enable_x64

    enable_x64()
    from .._core._cache import disable_compilation_cache, ensure_compilation_cache

    disable_compilation_cache() if args.no_cache else ensure_compilation_cache()
    from .._calibration._calibrate import CalibrationError

    if gc_enabled and args.command not in _NO_GC_COMMANDS:  # sweeps, reports, planning: collected as usual
        import gc

        gc.enable()
    try:
        return args.func(args)
    except _Usage as e:
        return _die(str(e))
    except (ValueError, TypeError, KeyError, FileNotFoundError, CalibrationError) as e:
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        return _die(msg.strip("'\""))
    except OSError as e:
        return _die(f"{e.strerror or e}: {getattr(e, 'filename', '') or ''}".rstrip(": "))
    except KeyboardInterrupt:
        print("jaxcal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(console_main())
