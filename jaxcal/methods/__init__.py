"""Calibration methods: one registry behind :func:`jaxcal.calibrate`.

Every method is an ``equinox.Module`` with a pure ``run(problem, key) -> RawRun``, so a whole
calibration can be ``jax.jit``-ed and ``jax.vmap``-ed over keys and datasets.
"""

from ._base import METHODS as METHODS
from ._base import Method as Method
from ._base import RawRun as RawRun
from ._base import ScaledProblem as ScaledProblem
from ._base import default_half_width as default_half_width
from ._base import method_settings as method_settings
from ._base import register_builtin as _register_builtin
from ._base import register_method as register_method
from ._make import make_method as make_method

#: the built-in methods, registered by name and imported on first use (a command that runs
#: ``lm`` does not import optax or the population methods): ``name: module``
_BUILTIN = {
    "bso": "_bso", "ekf": "_ekf", "ga": "_ga", "adam": "_gradient", "adamw": "_gradient",
    "adamod": "_gradient", "adamodw": "_gradient", "iwoa": "_iwoa", "lm": "_least_squares",
    "gn": "_least_squares", "rbfnn": "_rbfnn",
}
for _name, _module in _BUILTIN.items():
    _register_builtin(_name, f"{__name__}.{_module}")

#: public names imported on first use (PEP 562): ``name: (module, attribute)``
_LAZY = {
    "BeetleSwarm": ("_bso", "BeetleSwarm"),
    "ExtendedKalmanFilter": ("_ekf", "ExtendedKalmanFilter"),
    "GeneticAlgorithm": ("_ga", "GeneticAlgorithm"),
    "GRADIENT_DEFAULTS": ("_gradient", "DEFAULTS"),
    "OptaxMethod": ("_gradient", "OptaxMethod"),
    "ImprovedWhale": ("_iwoa", "ImprovedWhale"),
    "GaussNewton": ("_least_squares", "GaussNewton"),
    "LevenbergMarquardt": ("_least_squares", "LevenbergMarquardt"),
    "RBFNetwork": ("_rbfnn", "RBFNetwork"),
    "RBFNetworkMethod": ("_rbfnn", "RBFNetworkMethod"),
    "Staged": ("_stages", "Staged"),
    "StageInfo": ("_stages", "StageInfo"),
    "stages": ("_make", "stages"),
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(f".{module}", __name__), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))


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
