"""Building a method: :func:`make_method` (a registry name, stages joined by ``>``, a
:class:`~jaxcal.methods.Method` or an optax transformation) and :func:`stages`.

The two call each other (a staged name builds each stage by name; a stage may itself be given
by name), so they live together here, above the registry (:mod:`._base`) and the staged method
(:mod:`._stages`), which import neither.
"""

from __future__ import annotations

from .._core._buckets import BoundedCache
from ._base import METHODS, Method, method_settings
from ._stages import SEPARATOR, Staged, check_method_name, is_staged_name

__all__ = ["make_method", "stages"]


def make_method(method, **hyperparameters) -> Method:
    """A :class:`Method` from a registry name, stages of registry names joined by ``>``
    (``"ga>lm"``, settings as ``"lm.max_steps"``; :func:`stages`), a Method
    instance, or an ``optax.GradientTransformation`` (run as a full-batch gradient method)."""
    import sys

    if isinstance(method, Method):
        if hyperparameters:
            raise ValueError("pass hyperparameters to the method's constructor, not with a Method instance")
        return method
    optax = sys.modules.get("optax")  # an optax transformation implies optax is imported
    if optax is not None and isinstance(method, optax.GradientTransformation):
        from ._gradient import OptaxMethod

        return OptaxMethod.from_transformation(method, **hyperparameters)
    if not isinstance(method, str):
        raise TypeError(f"method must be a name, a jaxcal Method or an optax.GradientTransformation, got {type(method)}")
    key = method.lower()
    if ">" in key:  # stages, e.g. "ga>lm" (see ._stages)
        key = check_method_name(key)
    elif key not in METHODS:
        raise ValueError(f"unknown method {method!r}; available: {', '.join(sorted(METHODS))}")
    try:
        cache_key = (key, tuple(sorted(hyperparameters.items())))
        hash(cache_key)
    except TypeError:  # unhashable settings (e.g. arrays): build afresh
        cache_key = None
    if cache_key is not None and cache_key in _METHOD_CACHE:
        return _METHOD_CACHE[cache_key]
    valid = method_settings(key)
    unknown = sorted(set(hyperparameters) - set(valid)) if valid is not None else []
    if unknown:
        raise TypeError(f"unknown setting(s) {unknown} for method {method!r}; its settings: {', '.join(valid)}")
    try:
        if ">" in key:
            built = stages(key, **hyperparameters)
        else:
            built = METHODS[key](**hyperparameters)
    except TypeError as e:
        if ">" in key:
            raise
        raise TypeError(f"bad hyperparameters for method {method!r}: {e}") from None
    if cache_key is not None:
        # the same name and settings give the same object, so jit caches hit (an optax
        # transformation is a static field, compared by identity)
        _METHOD_CACHE[cache_key] = built
    return built


#: built methods by (name, settings), least recently used first out beyond 256 entries
_METHOD_CACHE = BoundedCache(256)


def _prefixes(names: list[str]) -> list[str]:
    """Registry name where it is unique among the stages, else the 1-based position."""
    return [n if n and names.count(n) == 1 else str(i + 1) for i, n in enumerate(names)]


def stages(*methods, **settings) -> Staged:
    """Compose methods into stages, each starting where the last ended.

    Args:
        *methods: registry names, :class:`Method` instances or optax transformations (at least
            two), or one string joined by ``>`` (``stages("ga>lm")``).
        **settings: ``"stage.setting": value`` where ``stage`` is a stage's registry name (when
            unique) or its 1-based position: ``stages("ga", "lm", **{"ga.generations": 100,
            "2.max_steps": 50})``. Method instances take no settings (configure them directly).

    Example: ``calibrate(robot, m, data, method=stages("adamodw", "lm", **{"adamodw.steps": 200}))``.
    """
    if len(methods) == 1 and is_staged_name(methods[0]):
        methods = tuple(methods[0].split(SEPARATOR))
    if len(methods) < 2:
        raise ValueError(f"stages needs at least two methods, got {len(methods)}")
    names = []
    for m in methods:
        if isinstance(m, str):
            names.append(check_method_name(m.strip()))
        elif isinstance(m, Method):
            names.append(type(m).name if type(m).name in METHODS else "")
        else:
            names.append("")  # an optax transformation: by position only
    prefixes = _prefixes(names)
    valid = sorted(set(prefixes) | {str(i + 1) for i in range(len(methods))}, key=lambda s: (s.isdigit(), s))
    per_stage: list[dict] = [{} for _ in methods]
    for k, v in settings.items():
        stage, dot, setting = str(k).partition(".")
        if not dot or not setting:
            raise ValueError(f"setting {k!r} of staged method {SEPARATOR.join(n or '?' for n in names)!r} must name "
                             f"its stage, as STAGE.SETTING with STAGE one of {valid} (e.g. {valid[0]}.{k})")
        stage = stage.strip().lower()
        if stage.isdigit() and 1 <= int(stage) <= len(methods):
            i = int(stage) - 1
        elif stage in names and names.count(stage) == 1:
            i = names.index(stage)
        else:
            hint = " (the name occurs more than once: use its position)" if names.count(stage) > 1 else ""
            raise ValueError(f"unknown stage {stage!r} in setting {k!r}{hint}; stages: {valid}")
        per_stage[i][setting.strip()] = v
    built = []
    for i, (m, hyper) in enumerate(zip(methods, per_stage)):
        if isinstance(m, str):
            try:
                built.append(make_method(names[i], **hyper))
            except TypeError as e:
                valid_settings = sorted(make_method(names[i]).hyperparameters())
                raise TypeError(f"bad setting for stage {i + 1} ({names[i]!r}): {e}; its settings include "
                                f"{valid_settings}") from None
        else:
            built.append(make_method(m, **hyper))
    return Staged(tuple(built), tuple(prefixes))
