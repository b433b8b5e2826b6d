"""Calibration methods: one registry behind :func:`jaxcal.calibrate`.

Every method is an ``equinox.Module`` with a pure ``run(problem, key) -> RawRun``, so a whole
calibration can be ``jax.jit``-ed and ``jax.vmap``-ed over keys and datasets.
"""

from . import _gradient as _gradient  # noqa: F401  (registers adam, adamw, adamod, adamodw)
from . import _least_squares as _least_squares  # noqa: F401  (registers lm, gn)
from ._base import METHODS as METHODS
from ._base import Method as Method
from ._base import RawRun as RawRun
from ._base import ScaledProblem as ScaledProblem
from ._base import default_half_width as default_half_width
from ._base import make_method as make_method
from ._base import register_method as register_method
from ._gradient import DEFAULTS as GRADIENT_DEFAULTS
from ._gradient import OptaxMethod as OptaxMethod
from ._least_squares import GaussNewton as GaussNewton
from ._least_squares import LevenbergMarquardt as LevenbergMarquardt

__all__ = [
    "GRADIENT_DEFAULTS",
    "GaussNewton",
    "LevenbergMarquardt",
    "METHODS",
    "Method",
    "OptaxMethod",
    "RawRun",
    "ScaledProblem",
    "default_half_width",
    "make_method",
    "register_method",
]
