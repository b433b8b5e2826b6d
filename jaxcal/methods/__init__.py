"""Calibration methods: one registry behind :func:`jaxcal.calibrate`.

Every method is an ``equinox.Module`` with a pure ``run(problem, key) -> RawRun``, so a whole
calibration can be ``jax.jit``-ed and ``jax.vmap``-ed over keys and datasets.
"""

from . import _bso as _bso  # noqa: F401  (registers bso)
from . import _ekf as _ekf  # noqa: F401  (registers ekf)
from . import _ga as _ga  # noqa: F401  (registers ga)
from . import _gradient as _gradient  # noqa: F401  (registers adam, adamw, adamod, adamodw)
from . import _iwoa as _iwoa  # noqa: F401  (registers iwoa)
from . import _least_squares as _least_squares  # noqa: F401  (registers lm, gn)
from . import _rbfnn as _rbfnn  # noqa: F401  (registers rbfnn)
from ._base import METHODS as METHODS
from ._base import Method as Method
from ._base import RawRun as RawRun
from ._base import ScaledProblem as ScaledProblem
from ._base import default_half_width as default_half_width
from ._base import make_method as make_method
from ._base import method_settings as method_settings
from ._base import register_method as register_method
from ._bso import BeetleSwarm as BeetleSwarm
from ._ekf import ExtendedKalmanFilter as ExtendedKalmanFilter
from ._ga import GeneticAlgorithm as GeneticAlgorithm
from ._gradient import DEFAULTS as GRADIENT_DEFAULTS
from ._gradient import OptaxMethod as OptaxMethod
from ._iwoa import ImprovedWhale as ImprovedWhale
from ._least_squares import GaussNewton as GaussNewton
from ._least_squares import LevenbergMarquardt as LevenbergMarquardt
from ._rbfnn import RBFNetwork as RBFNetwork
from ._rbfnn import RBFNetworkMethod as RBFNetworkMethod
from ._stages import Staged as Staged
from ._stages import StageInfo as StageInfo
from ._stages import stages as stages

__all__ = [
    "GRADIENT_DEFAULTS",
    "BeetleSwarm",
    "ExtendedKalmanFilter",
    "GaussNewton",
    "GeneticAlgorithm",
    "ImprovedWhale",
    "LevenbergMarquardt",
    "METHODS",
    "Method",
    "OptaxMethod",
    "RBFNetwork",
    "RBFNetworkMethod",
    "RawRun",
    "ScaledProblem",
    "StageInfo",
    "Staged",
    "default_half_width",
    "make_method",
    "method_settings",
    "register_method",
    "stages",
]
