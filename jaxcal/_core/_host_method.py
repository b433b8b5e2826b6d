"""Host-side methods of equinox modules, bound as plain Python callables.

``equinox.Module`` makes every method it hands out a pytree: ``module.method`` builds an
``equinox.BoundMethod`` (itself a module, with its own dataclass initialisation), so that a bound
method can be passed through ``jax.jit``. That costs ~16–21 µs per attribute access on the
project's 2-core CPU (equinox 0.13) — more than the work of the small host-side methods that
:func:`jaxcal.calibrate` calls a few dozen times per call (which readings are real, the residual
entries, the padding of the per-row arrays, the method's label): ~0.4 ms of a ~6 ms warm
calibrate. :class:`host_method` binds such a method with ``functools.partial`` instead (~0.3 µs).

Only for methods that are called on the host and never passed to a transformation as a pytree;
an override in a subclass keeps working without the decorator (it is then bound the equinox way).
"""

from __future__ import annotations

import functools

__all__ = ["host_method"]


class host_method:  # noqa: N801 — used as a decorator, like property
    """Decorator: the method is bound as ``functools.partial(function, instance)``, not as an
    ``equinox.BoundMethod`` (see the module docstring). On the class it is the plain function."""

    def __init__(self, fn):
        self.fn = fn
        functools.update_wrapper(self, fn)

    def __get__(self, obj, objtype=None):
        if obj is None:
            return self.fn
        return functools.partial(self.fn, obj)
