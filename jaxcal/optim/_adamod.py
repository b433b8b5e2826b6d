"""AdaMod and AdaModW (adaptive and momental bounds, decoupled weight decay) for optax.

The building block is :func:`scale_by_adamod`; :func:`adamodw` (the paper's full update, eq. 15)
and :func:`adamod` (no weight decay, eq. 14) are the convenience aliases. All three return
optax gradient transformations, so they compose with ``optax.chain``, ``optax.masked``,
``optax.MultiSteps``, ``optax.inject_hyperparams`` and ``optimistix.OptaxMinimiser``.

Unlike most optax ``scale_by_*`` transformations, :func:`scale_by_adamod` takes the learning
rate and returns the *full negative step*: the learning rate ``η_t`` enters the exponential
moving average of step sizes (eq. 11), so it cannot be applied afterwards by
``optax.scale_by_learning_rate`` (compare optax's ``contrib.dadapt_adamw``, which also keeps
its learning rate inside).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

__all__ = ["ScaleByAdaModState", "scale_by_adamod", "adamodw", "adamod"]

MaskOrFn = Any | Callable[[optax.Params], Any] | None


class ScaleByAdaModState(NamedTuple):
    """State of :func:`scale_by_adamod`.

    Attributes:
      count: Number of updates done so far, ``t - 1`` while computing step ``t``
        (shape ``()``, dtype ``int32``, like ``optax.ScaleByAdamState.count``).
      mu: First moment ``m_t`` (eq. 6); same tree structure and shapes as the params, dtype
        ``mu_dtype`` if given, else the params' dtype.
      nu: Second moment ``z_t`` (eq. 7); same structure, shapes and dtypes as the params.
      step_bound: Momental bound ``b_t`` on the step size (eq. 11, ``b_0 = 0``); same
        structure, shapes and dtypes as the params.
    """

    count: jax.Array  # shape=(), dtype=jnp.int32.
    mu: optax.Updates
    nu: optax.Updates
    step_bound: optax.Updates


def _is_zero_constant(x: Any) -> bool:
    """True only for a Python/NumPy number equal to 0 (never for arrays or tracers).

    Used to skip the decay term (and the need for ``params``) structurally, like
    ``optax.add_decayed_weights`` does. It never changes the result for finite params.
    """
    return isinstance(x, (int, float, np.number)) and not isinstance(x, bool) and x == 0


def _decay_flags(mask: MaskOrFn, params: Any, treedef: Any) -> list[bool]:
    """One Python bool per leaf of ``treedef``: whether that leaf is weight-decayed."""
    n = treedef.num_leaves
    if mask is None:
        return [True] * n
    mask_tree = mask(params) if callable(mask) else mask
    # ``mask_tree`` has the params' structure or a prefix of it: broadcast each mask leaf
    # over its subtree of params.
    full = jax.tree.map(lambda m, sub: jax.tree.map(lambda _: bool(m), sub), mask_tree, params)
    return [bool(f) for f in treedef.flatten_up_to(full)]


def _compute_dtype(*dtypes: Any) -> np.dtype:
    """Standard JAX promotion of the given dtypes, also under ``strict`` promotion mode."""
    with jax.numpy_dtype_promotion("standard"):
        out = dtypes[0]
        for d in dtypes[1:]:
            out = jnp.promote_types(out, d)
    return np.dtype(out)


def scale_by_adamod(
    learning_rate: optax.ScalarOrSchedule,
    b1: jax.typing.ArrayLike = 0.9,
    b2: jax.typing.ArrayLike = 0.999,
    b3: jax.typing.ArrayLike = 0.999,
    eps: jax.typing.ArrayLike = 1e-8,
    weight_decay: optax.ScalarOrSchedule = 0.0,
    mu_dtype: jax.typing.DTypeLike | None = None,
    *,
    mask: MaskOrFn = None,
) -> optax.GradientTransformation:
    r"""AdaMod step with optional decoupled weight decay (Chen & Li, eqs. 6–15).

    Let :math:`u_t` be the incoming update (the gradient), :math:`g_{t-1}` the current
    parameters, :math:`\eta_t` the learning rate, :math:`\xi` the weight decay and
    :math:`\beta_1, \beta_2, \beta_3, \sigma` the arguments ``b1``, ``b2``, ``b3``, ``eps``.
    The state starts at :math:`m_0 = z_0 = b_0 = 0` and every call to ``update`` computes,
    elementwise on every leaf, for :math:`t = 1, 2, \dots`:

    .. math::

      \begin{align*}
        m_t &= \beta_1 m_{t-1} + (1-\beta_1)\, u_t &&(6)\\
        z_t &= \beta_2 z_{t-1} + (1-\beta_2)\, u_t^2 &&(7)\\
        \hat m_t &= m_t / (1-\beta_1^t), \quad \hat z_t = z_t / (1-\beta_2^t) &&(8)\\
        \kappa_t &= \eta_t / (\sqrt{\hat z_t} + \sigma) &&(10)\\
        b_t &= \beta_3 b_{t-1} + (1-\beta_3)\, \kappa_t,\quad b_0 = 0 &&(11)\\
        \hat\kappa_t &= \min(\kappa_t, b_t) &&(13)\\
        \text{update}_t &= -\hat\kappa_t \odot (\hat m_t + \xi\, g_{t-1}) &&(14),(15)
      \end{align*}

    so ``optax.apply_updates(params, update)`` gives the paper's
    :math:`g_t = g_{t-1} - \hat\kappa_t (\hat m_t + \xi g_{t-1})`.

    The returned update is the whole step, learning rate included: :math:`\eta_t` enters the
    moving average (11), so it lives inside this transformation and must **not** be followed
    by ``optax.scale_by_learning_rate``.

    Notes:
      * **Schedules.** If ``learning_rate`` (or ``weight_decay``) is a callable, it is
        evaluated at the 0-based count *before* the increment: step :math:`t` (1-based) uses
        ``learning_rate(t - 1)``, the convention of ``optax.scale_by_schedule`` and
        ``optax.scale_by_learning_rate``.
      * **Warm-up.** Because :math:`b_0 = 0` and :math:`b_t` is not bias-corrected (eq. 12),
        :math:`\hat\kappa_1 = (1-\beta_3)\kappa_1`: the first steps are about
        :math:`1-\beta_3` times Adam's, an implicit warm-up of about :math:`1/(1-\beta_3)`
        steps (1000 for the default ``b3=0.999``) that shows in iteration counts.
      * **Relation to Adam.** With ``b3=0`` and ``weight_decay=0``, :math:`\hat\kappa_t =
        \kappa_t` and this is exactly ``optax.scale_by_adam(b1, b2, eps, eps_root=0)``
        followed by ``optax.scale_by_learning_rate(learning_rate)``.
      * **eps placement.** As in the paper (eq. 10), ``eps`` is added to the bias-corrected
        :math:`\sqrt{\hat z_t}` (optax's Adam placement). The reference AdaMod code
        (lancopku/AdaMod, also torch-optimizer's ``AdaMod``) instead adds ``eps`` to the
        *uncorrected* :math:`\sqrt{z_t}` and folds both bias corrections into the step size,
        :math:`\kappa_t = \eta\sqrt{1-\beta_2^t}/(1-\beta_1^t) / (\sqrt{z_t}+\sigma)`, and
        applies weight decay AdamW-style as :math:`\eta\,\xi\,g_{t-1}`. The two agree up to the
        size of ``eps`` relative to :math:`\sqrt{z_t}` (early steps differ most).
      * **Weight decay is scaled by the bounded step** :math:`\hat\kappa_t`, not by
        :math:`\eta_t` as in ``optax.adamw``. For a parameter whose gradient is (nearly)
        zero, :math:`\hat\kappa_t \to \eta/\sigma` after the warm-up, so one step multiplies it
        by :math:`1 - \hat\kappa_t\xi`; the decay is only stable while
        :math:`\hat\kappa_t \xi < 2`, i.e. roughly :math:`\xi < 2\sigma/\eta`. Keep ``eps``,
        ``learning_rate`` and ``weight_decay`` consistent, or mask such leaves out.
      * **Dtypes.** Each leaf is computed in the promotion of its gradient and state dtypes
        and at least float32 (so ``b2=0.999`` is not rounded to 1 for bfloat16 params), then
        the update is cast to the gradient's dtype and the moments to the state's dtypes
        (``mu_dtype`` or the params' dtype). Works under ``jax_numpy_dtype_promotion="strict"``.
      * Real-valued parameters only. The learning rate is assumed non-negative. ``None``
        leaves in the updates are returned as ``None`` (their state is left unchanged).

    Args:
      learning_rate: :math:`\eta_t`, a scalar or an optax schedule ``count -> scalar``.
      b1: :math:`\beta_1`, decay rate of the first moment (eq. 6). Default 0.9.
      b2: :math:`\beta_2`, decay rate of the second moment (eq. 7). Default 0.999.
      b3: :math:`\beta_3`, decay rate of the momental bound (eq. 11); memory of about
        :math:`1/(1-\beta_3)` steps. Default 0.999 (AdaMod's default).
      eps: :math:`\sigma`, added to :math:`\sqrt{\hat z_t}` in eq. 10. Default 1e-8.
      weight_decay: :math:`\xi`, decoupled weight decay coefficient (eq. 15), a scalar or a
        schedule. Default 0 (pure AdaMod). When it is not the literal number 0, ``update``
        needs ``params``.
      mu_dtype: Optional dtype of the first moment ``mu``; ``None`` uses the params' dtype.
      mask: Optional tree with the params' structure (or a prefix of it) of Python bools, or
        a callable ``params -> such a tree``; ``True`` leaves are weight-decayed, ``False``
        leaves take the same AdaMod step with :math:`\xi = 0`. ``None`` decays every leaf.

    Returns:
      An ``optax.GradientTransformation`` whose state is a :class:`ScaleByAdaModState` and
      whose updates have the structure, shapes and dtypes of the incoming updates.

    References:
      Ding, Ren, Luo, Sun, `An Adaptive and Momental Bound Method for Stochastic Learning
      <https://arxiv.org/abs/1910.12249>`_, arXiv:1910.12249, 2019.

      Chen & Li, Highly Accurate Robot Calibration Using Adaptive and Momental Bound with
      Decoupled Weight Decay (AdaModW), Section III, eqs. 6–15.

      Loshchilov & Hutter, `Decoupled Weight Decay Regularization
      <https://arxiv.org/abs/1711.05101>`_, ICLR 2019.
    """
    if mu_dtype is not None:
        mu_dtype = jax.dtypes.canonicalize_dtype(mu_dtype)
    decay_is_zero = _is_zero_constant(weight_decay)

    def init_fn(params):
        return ScaleByAdaModState(
            count=jnp.zeros([], jnp.int32),
            mu=optax.tree.zeros_like(params, dtype=mu_dtype),
            nu=optax.tree.zeros_like(params),
            step_bound=optax.tree.zeros_like(params),
        )

    def update_fn(updates, state, params=None):
        # ``None`` updates (as optax's Adam allows) are passed through, their state untouched.
        treedef = jax.tree.structure(updates, is_leaf=lambda x: x is None)
        g_leaves = treedef.flatten_up_to(updates)
        m_leaves = treedef.flatten_up_to(state.mu)
        v_leaves = treedef.flatten_up_to(state.nu)
        s_leaves = treedef.flatten_up_to(state.step_bound)
        n = len(g_leaves)

        if decay_is_zero:
            flags = [False] * n
        elif params is None:
            if mask is None or callable(mask):
                raise ValueError(
                    "scale_by_adamod/adamodw with nonzero weight_decay needs the current "
                    "params: call update(grads, state, params). Pass weight_decay=0.0 (or use "
                    "jaxcal.optim.adamod) to run without params."
                )
            flags = _decay_flags(mask, updates, treedef)
            if any(flags):
                raise ValueError(
                    "scale_by_adamod/adamodw with nonzero weight_decay needs the current "
                    "params for the decayed leaves: call update(grads, state, params)."
                )
        else:
            flags = _decay_flags(mask, params, treedef)
        p_leaves = treedef.flatten_up_to(params) if params is not None else [None] * n

        count = state.count
        count_inc = optax.safe_increment(count)
        eta = learning_rate(count) if callable(learning_rate) else learning_rate
        xi = weight_decay(count) if callable(weight_decay) else weight_decay

        def leaf(g, m, v, s, p, decay):
            if g is None:
                return None, m, v, s
            # Compute in at least float32 (in bfloat16, 0.999 rounds to 1 and b_t would never
            # move); results are cast back to the dtypes of the updates and of the state.
            cdt = _compute_dtype(g.dtype, m.dtype, v.dtype, s.dtype, jnp.float32)
            t = count_inc.astype(cdt)

            def c(x):
                return jnp.asarray(x).astype(cdt)

            b1c, b2c, b3c = c(b1), c(b2), c(b3)
            bc1 = 1 - b1c**t
            bc2 = 1 - b2c**t
            gc = g.astype(cdt)
            m_new = b1c * m.astype(cdt) + (1 - b1c) * gc  # (6)
            v_new = b2c * v.astype(cdt) + (1 - b2c) * (gc * gc)  # (7)
            m_hat = m_new / bc1  # (8)
            v_hat = v_new / bc2  # (8)
            kappa = c(eta) / (jnp.sqrt(v_hat) + c(eps))  # (10)
            s_new = b3c * s.astype(cdt) + (1 - b3c) * kappa  # (11)
            kappa_hat = jnp.minimum(kappa, s_new)  # (13)
            direction = m_hat + c(xi) * p.astype(cdt) if decay else m_hat  # (15) / (14)
            u = -kappa_hat * direction
            return (
                u.astype(g.dtype),
                m_new.astype(m.dtype),
                v_new.astype(v.dtype),
                s_new.astype(s.dtype),
            )

        outs = [leaf(*args) for args in zip(g_leaves, m_leaves, v_leaves, s_leaves, p_leaves, flags, strict=True)]
        new_updates, mu, nu, step_bound = (jax.tree.unflatten(treedef, [o[i] for o in outs]) for i in range(4))
        return new_updates, ScaleByAdaModState(count=count_inc, mu=mu, nu=nu, step_bound=step_bound)

    return optax.GradientTransformation(init_fn, update_fn)


def adamodw(
    learning_rate: optax.ScalarOrSchedule,
    b1: jax.typing.ArrayLike = 0.9,
    b2: jax.typing.ArrayLike = 0.999,
    b3: jax.typing.ArrayLike = 0.999,
    eps: jax.typing.ArrayLike = 1e-8,
    weight_decay: optax.ScalarOrSchedule = 1e-4,
    mask: MaskOrFn = None,
) -> optax.GradientTransformationExtraArgs:
    r"""AdaModW: AdaMod with decoupled weight decay (Chen & Li, eq. 15).

    Per leaf, with :math:`\hat m_t, \hat\kappa_t` from eqs. 6–13 (see
    :func:`scale_by_adamod` for the full list of equations),

    .. math::

      g_t = g_{t-1} - \hat\kappa_t \odot (\hat m_t + \xi\, g_{t-1}), \qquad (15)

    i.e. the weight decay is multiplied by the bounded adaptive step :math:`\hat\kappa_t`
    (not by the learning rate as in ``optax.adamw``). In calibration the params are the
    deviations from the nominal robot, so the decay shrinks toward the nominal model.

    Read the notes of :func:`scale_by_adamod`: the implicit warm-up of about
    :math:`1/(1-\beta_3)` steps, the eps placement (paper vs. the AdaMod reference code),
    and the stability bound :math:`\hat\kappa_t \xi < 2` for parameters with (near-)zero
    gradient, where :math:`\hat\kappa_t` grows toward :math:`\eta/\sigma`.

    **Defaults: the paper's, not jaxcal's tuned ones.** ``b1, b2, b3 = 0.9, 0.999, 0.999`` are
    AdaMod's published values (the paper's AdaModW uses them; it gives no learning rate or
    weight decay). ``b3 = 0.999`` means a ~1000-step warm-up: in a 500-step calibration it has
    not finished. The registered method ``calibrate(..., "adamodw")`` instead uses settings tuned
    on the simulated experiment (``jaxcal.methods.GRADIENT_DEFAULTS["adamodw"]``: ``learning_rate=0.1,
    b3=0.9, weight_decay=1e-4, steps=500``; ``benchmarks/results/tune_gradient.md``), in
    ``calibrate``'s scaled coordinates. For your own chain with the tuned behaviour, use
    ``adamodw(0.1, b3=0.9)``; ``adamodw(1e-2)`` with the paper's ``b3`` is still descending after
    500 steps (``calibrate`` then reports ``Status.STILL_IMPROVING``).

    Args:
      learning_rate: :math:`\eta_t`, a scalar or an optax schedule (evaluated at the 0-based
        count before the increment: step ``t`` uses ``learning_rate(t - 1)``). No default (the
        paper gives none; 0.1 is jaxcal's tuned value for calibration).
      b1: :math:`\beta_1`, first-moment decay (eq. 6). Default 0.9.
      b2: :math:`\beta_2`, second-moment decay (eq. 7). Default 0.999.
      b3: :math:`\beta_3`, step-bound decay (eq. 11). Default 0.999 (the paper's / AdaMod's;
        the registered ``"adamodw"`` method uses the tuned 0.9).
      eps: :math:`\sigma` of eq. 10. Default 1e-8.
      weight_decay: :math:`\xi` of eq. 15, a scalar or a schedule. Default 1e-4, optax.adamw's
        default (the paper gives no value); as the decay is scaled by :math:`\hat\kappa_t`,
        its effective strength depends on the gradient scale, so tune it per problem.
      mask: Which leaves are decayed: a tree of Python bools with the params' structure (or a
        prefix), or a callable ``params -> tree``, as in ``optax.adamw``. Leaves marked
        ``False`` take the plain AdaMod step (:math:`\xi = 0`). With
        ``optax.inject_hyperparams``, pass a callable mask via ``static_args=("mask",)``.

    Returns:
      An ``optax.GradientTransformationExtraArgs``; ``update(grads, state, params)`` needs
      ``params`` unless ``weight_decay`` is the literal number 0. The state is a
      :class:`ScaleByAdaModState`.

    Examples:
      >>> import jax.numpy as jnp, optax
      >>> from jaxcal.optim import adamodw
      >>> opt = adamodw(learning_rate=1e-2, weight_decay=1e-4)
      >>> params = {"delta": jnp.zeros(3)}
      >>> state = opt.init(params)
      >>> grads = {"delta": jnp.array([1.0, -2.0, 0.5])}
      >>> updates, state = opt.update(grads, state, params)
      >>> params = optax.apply_updates(params, updates)

    References:
      Chen & Li, Highly Accurate Robot Calibration Using Adaptive and Momental Bound with
      Decoupled Weight Decay (AdaModW), Section III.

      Ding, Ren, Luo, Sun, `An Adaptive and Momental Bound Method for Stochastic Learning
      <https://arxiv.org/abs/1910.12249>`_, arXiv:1910.12249, 2019.

      Loshchilov & Hutter, `Decoupled Weight Decay Regularization
      <https://arxiv.org/abs/1711.05101>`_, ICLR 2019.
    """
    return optax.with_extra_args_support(
        scale_by_adamod(
            learning_rate,
            b1=b1,
            b2=b2,
            b3=b3,
            eps=eps,
            weight_decay=weight_decay,
            mask=mask,
        )
    )


def adamod(
    learning_rate: optax.ScalarOrSchedule,
    b1: jax.typing.ArrayLike = 0.9,
    b2: jax.typing.ArrayLike = 0.999,
    b3: jax.typing.ArrayLike = 0.999,
    eps: jax.typing.ArrayLike = 1e-8,
) -> optax.GradientTransformationExtraArgs:
    r"""AdaMod: Adam with a momental bound on the adaptive step (eqs. 6–14, :math:`\xi=0`).

    .. math::

      g_t = g_{t-1} - \hat\kappa_t \odot \hat m_t, \qquad
      \hat\kappa_t = \min\!\big(\kappa_t,\ \beta_3 b_{t-1} + (1-\beta_3)\kappa_t\big). \qquad (14)

    See :func:`scale_by_adamod` for all equations and notes (implicit warm-up of about
    :math:`1/(1-\beta_3)` steps; eps on the bias-corrected :math:`\sqrt{\hat z_t}`, unlike the
    AdaMod reference code; with ``b3=0`` this is ``optax.adam``). ``params`` are not needed.

    Args:
      learning_rate: :math:`\eta_t`, a scalar or an optax schedule (step ``t`` uses
        ``learning_rate(t - 1)``).
      b1: :math:`\beta_1` (eq. 6). Default 0.9.
      b2: :math:`\beta_2` (eq. 7). Default 0.999.
      b3: :math:`\beta_3` (eq. 11). Default 0.999.
      eps: :math:`\sigma` (eq. 10). Default 1e-8.

    Returns:
      An ``optax.GradientTransformationExtraArgs`` with a :class:`ScaleByAdaModState` state.

    References:
      Ding, Ren, Luo, Sun, `An Adaptive and Momental Bound Method for Stochastic Learning
      <https://arxiv.org/abs/1910.12249>`_, arXiv:1910.12249, 2019.
    """
    return optax.with_extra_args_support(scale_by_adamod(learning_rate, b1=b1, b2=b2, b3=b3, eps=eps, weight_decay=0.0))
