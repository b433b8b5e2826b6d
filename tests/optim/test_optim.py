"""Tests for jaxcal.optim: AdaMod / AdaModW as optax gradient transformations.

Two parts:

* Invariants of the paper's method: a plain NumPy transcription of eqs. 6–15 (written here,
  independent of the implementation), the reduction to Adam for ``b3=0, weight_decay=0``, the
  closed form of the first decayed step, the schedule's step convention, masks.
* A conformance suite every optimizer must pass (mirroring optax's
  ``contrib/_common_test.py``), parametrised over :data:`OPTIMIZERS`. Add an
  :class:`OptimizerCase` to extend it.

Dtype promotion: our transformations are tested under ``jax_numpy_dtype_promotion="strict"``.
optax's own ``adam``/``adamw``, its schedules and ``MultiSteps`` do not run under strict
promotion in optax 0.2.8 (``float ** int32`` in bias correction, float32 accumulators under
x64), so tests touching them run under ``"standard"`` (see :func:`_promotion`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402
import optimistix as optx  # noqa: E402
import pytest  # noqa: E402

from jaxcal.optim import ScaleByAdaModState, adamod, adamodw, scale_by_adamod  # noqa: E402


# ----------------------------------------------------------------------------------------------
# Helpers
# ----------------------------------------------------------------------------------------------
def _promotion(strict: bool):
    return jax.numpy_dtype_promotion("strict" if strict else "standard")


def _assert_trees_close(a, b, rtol=0.0, atol=0.0):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_allclose(np.asarray(x, np.float64), np.asarray(y, np.float64), rtol=rtol, atol=atol)


def _random_tree(key, dtype=jnp.float64, scale=1.0):
    """Nested pytree: dict with an array, a tuple of arrays and a nested dict."""
    k1, k2, k3, k4 = jax.random.split(key, 4)
    return {
        "w": scale * jax.random.normal(k1, (3, 4), dtype),
        "pair": (scale * jax.random.normal(k2, (5,), dtype), scale * jax.random.normal(k3, ())),
        "inner": {"b": scale * jax.random.normal(k4, (2, 1, 2), dtype)},
    }


def _cast_tree(tree, dtype):
    return jax.tree.map(lambda x: x.astype(dtype), tree)


def _run_steps(opt, params, grads_list, jit=True):
    """Apply ``opt`` for each gradient tree in ``grads_list``; returns params, state, updates."""
    update = jax.jit(opt.update) if jit else opt.update
    state = opt.init(params)
    all_updates = []
    for g in grads_list:
        updates, state = update(g, state, params)
        params = optax.apply_updates(params, updates)
        all_updates.append(updates)
    return params, state, all_updates


def _grads_list(n, like, seed=0, scale=1.0):
    keys = jax.random.split(jax.random.key(seed), n)
    leaves, treedef = jax.tree.flatten(like)
    out = []
    for k in keys:
        ks = jax.random.split(k, len(leaves))
        out.append(
            jax.tree.unflatten(
                treedef,
                [
                    (scale * jax.random.normal(kk, x.shape, jnp.float64)).astype(x.dtype)
                    for kk, x in zip(ks, leaves, strict=True)
                ],
            )
        )
    return out


# ----------------------------------------------------------------------------------------------
# NumPy transcription of the paper's eqs. 6–15 (independent of the implementation).
# ----------------------------------------------------------------------------------------------
def adamodw_numpy(params0, grads, lr, b1=0.9, b2=0.999, b3=0.999, eps=1e-8, wd=0.0, decay=None, record=None):
    """Run AdaModW on lists of float64 arrays.

    Args:
      params0: list of arrays g_0.
      grads: list (over steps t = 1..T) of lists of arrays U_t.
      lr: float, or callable of the 0-based step count (step t uses lr(t - 1)).
      decay: optional list of bools, which leaves get weight decay (default: all).
      record: optional list; gets, per step and leaf, the mask where the bound acts (b < kappa).

    Returns:
      (params after each step [T][leaves], updates [T][leaves], final (m, z, b)).
    """
    p = [np.array(x, np.float64) for x in params0]
    m = [np.zeros_like(x) for x in p]
    z = [np.zeros_like(x) for x in p]
    b = [np.zeros_like(x) for x in p]  # b_0 = 0, no bias correction (eq. 12)
    decay = [True] * len(p) if decay is None else decay
    params_hist, updates_hist = [], []
    for t, u_t in enumerate(grads, start=1):
        eta = float(lr(t - 1)) if callable(lr) else float(lr)
        step = []
        for i, u in enumerate(u_t):
            u = np.asarray(u, np.float64)
            m[i] = b1 * m[i] + (1 - b1) * u  # (6)
            z[i] = b2 * z[i] + (1 - b2) * u**2  # (7)
            m_hat = m[i] / (1 - b1**t)  # (8)
            z_hat = z[i] / (1 - b2**t)  # (8)
            kappa = eta / (np.sqrt(z_hat) + eps)  # (10)
            b[i] = b3 * b[i] + (1 - b3) * kappa  # (11)
            kappa_hat = np.minimum(kappa, b[i])  # (13)
            if record is not None:
                record.append(b[i] < kappa)
            xi = wd if decay[i] else 0.0
            step.append(-kappa_hat * (m_hat + xi * p[i]))  # (15): g_t = g_{t-1} + step
        p = [x + s for x, s in zip(p, step, strict=True)]
        params_hist.append(p)
        updates_hist.append(step)
    return params_hist, updates_hist, (m, z, b)


def _scan_run(opt, params0, grads_stacked):
    """Run ``opt`` in one jitted ``lax.scan``; returns per-step params, updates, final state."""

    @jax.jit
    def run(params0, grads_stacked):
        def body(carry, g):
            p, s = carry
            u, s = opt.update(g, s, p)
            p = optax.apply_updates(p, u)
            return (p, s), (p, u)

        (_, state), (ps, us) = jax.lax.scan(body, (params0, opt.init(params0)), grads_stacked)
        return ps, us, state

    return run(params0, grads_stacked)


def _lambda_schedule(count):
    # Strict-promotion safe python schedule (count is an int32 array in JAX, an int in NumPy).
    return 1e-2 / (1.0 + 0.05 * jnp.asarray(count).astype(jnp.float64))


_SCHEDULES = {
    "constant": (1e-2, True),
    "cosine": (optax.cosine_decay_schedule(3e-2, decay_steps=150, alpha=0.1), False),
    "lambda": (_lambda_schedule, True),
}


_TRANSCRIPTION_HPARAMS = dict(b1=0.9, b2=0.99, b3=0.95, eps=1e-8)


def _transcription_problem(steps=200):
    """Two leaves of different shapes; gradients of varied scales so that the bound
    min(kappa_t, b_t) of eq. 13 switches both ways."""
    rng = np.random.default_rng(0)
    params0 = [rng.normal(size=(3, 4)), rng.normal(size=(7,))]
    grads = [[rng.normal(size=(3, 4)) * 10.0 ** rng.uniform(-3, 1), rng.normal(size=(7,))] for _ in range(steps)]
    return params0, grads


@pytest.mark.parametrize("weight_decay", [0.0, 1e-2])
@pytest.mark.parametrize("schedule", list(_SCHEDULES))
def test_matches_numpy_transcription(schedule, weight_decay):
    """200 steps on random gradients, two leaves of different shapes, float64, to 1e-12."""
    lr, strict_ok = _SCHEDULES[schedule]
    params0, grads = _transcription_problem()
    hp = _TRANSCRIPTION_HPARAMS
    ref_params, ref_updates, (m, z, b) = adamodw_numpy(params0, grads, lr, wd=weight_decay, **hp)

    opt = adamodw(lr, weight_decay=weight_decay, **hp)
    tree0 = {"a": jnp.asarray(params0[0]), "b": jnp.asarray(params0[1])}
    stacked = {
        "a": jnp.asarray(np.stack([g[0] for g in grads])),
        "b": jnp.asarray(np.stack([g[1] for g in grads])),
    }
    with _promotion(strict_ok):
        ps, us, state = _scan_run(opt, tree0, stacked)

    assert isinstance(state, ScaleByAdaModState)
    assert int(state.count) == 200
    for i, name in enumerate(["a", "b"]):
        np.testing.assert_allclose(np.asarray(ps[name]), np.stack([p[i] for p in ref_params]), rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(np.asarray(us[name]), np.stack([u[i] for u in ref_updates]), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.asarray(state.mu[name]), m[i], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.asarray(state.nu[name]), z[i], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.asarray(state.step_bound[name]), b[i], rtol=1e-12)


def test_bound_is_active():
    """The transcription test's problem exercises both branches of min(kappa_t, b_t) (eq. 13)."""
    params0, grads = _transcription_problem()
    bounded = []
    adamodw_numpy(params0, grads, 1e-2, **_TRANSCRIPTION_HPARAMS, record=bounded)
    bounded = np.concatenate([np.ravel(x) for x in bounded])
    assert 0.05 < bounded.mean() < 0.95, bounded.mean()


def test_schedule_evaluated_at_zero_based_count():
    """eta_t = schedule(t - 1): step t uses the count before the increment, as optax does."""
    sched = optax.piecewise_constant_schedule(1e-2, {1: 0.1, 2: 10.0, 3: 0.5})  # 1e-2,1e-3,...
    rng = np.random.default_rng(2)
    grads = [[rng.normal(size=(4,))] for _ in range(6)]
    with _promotion(False):  # optax schedules are not strict-promotion safe
        _, _, updates = _run_steps(
            adamodw(sched, b3=0.5, weight_decay=1e-3),
            [jnp.ones(4)],
            [[jnp.asarray(g[0])] for g in grads],
        )
        _, ref, _ = adamodw_numpy([np.ones(4)], grads, sched, b3=0.5, wd=1e-3)
        _, shifted, _ = adamodw_numpy([np.ones(4)], grads, lambda c: sched(c + 1), b3=0.5, wd=1e-3)
    got = np.stack([u[0] for u in updates])
    np.testing.assert_allclose(got, np.stack([u[0] for u in ref]), rtol=1e-12)
    assert not np.allclose(got, np.stack([u[0] for u in shifted]), rtol=1e-3)
    # First step closed form with b3 = 0.5: kappa_hat_1 = 0.5 * eta_0 / (|g| + eps), eta_0 = 1e-2.
    g0 = grads[0][0]
    expected = -0.5 * 1e-2 / (np.abs(g0) + 1e-8) * (g0 + 1e-3 * 1.0)
    np.testing.assert_allclose(got[0], expected, rtol=1e-12)


@pytest.mark.parametrize("lr", [1e-2, "schedule"])
def test_reduces_to_adam(lr):
    """b3 = 0 and weight_decay = 0 is optax.adam (eps on the corrected sqrt, eps_root = 0)."""
    if lr == "schedule":
        lr = optax.exponential_decay(1e-2, transition_steps=10, decay_rate=0.5)
    params = _random_tree(jax.random.key(0))
    grads = _grads_list(60, params, seed=1)
    with _promotion(False):  # optax.adam is not strict-promotion safe
        p1, _, u1 = _run_steps(adamodw(lr, b3=0.0, weight_decay=0.0), params, grads)
        p2, _, u2 = _run_steps(optax.adam(lr), params, grads)
    for a, b in zip(u1, u2, strict=True):
        _assert_trees_close(a, b, rtol=1e-12, atol=1e-16)
    _assert_trees_close(p1, p2, rtol=1e-12, atol=1e-14)


def test_first_decayed_step_closed_form():
    """Zero gradients: step 1 shrinks params by exactly kappa_hat_1 * xi * g_0.

    With m = z = 0, kappa_1 = eta / eps and b_1 = (1 - b3) kappa_1, so
    kappa_hat_1 = (1 - b3) eta / eps: the decay is scaled by the bounded step, not by eta.
    """
    eta, b3, eps, xi = 1e-3, 0.9, 1e-8, 1e-5
    params = {"a": jnp.array([1.0, -2.0, 3.0]), "b": jnp.array([[0.5]])}
    zeros = jax.tree.map(jnp.zeros_like, params)
    opt = adamodw(eta, b3=b3, eps=eps, weight_decay=xi)
    with _promotion(True):
        updates, state = jax.jit(opt.update)(zeros, opt.init(params), params)
    kappa_hat = (1 - b3) * eta / eps  # = 1e4
    for k in params:
        np.testing.assert_allclose(np.asarray(updates[k]), -kappa_hat * xi * np.asarray(params[k]), rtol=1e-14)
        np.testing.assert_allclose(np.asarray(state.step_bound[k]), kappa_hat, rtol=1e-14)
    new = optax.apply_updates(params, updates)
    np.testing.assert_allclose(np.asarray(new["a"]), 0.9 * np.asarray(params["a"]), rtol=1e-14)
    # AdamW-style decay would have been eta * xi * g_0: here it is (1 - b3) / eps = 1e7 times that.
    np.testing.assert_allclose(
        np.asarray(updates["a"]) / (-eta * xi * np.asarray(params["a"])), (1 - b3) / eps, rtol=1e-12
    )


def test_none_updates_pass_through():
    """Like optax's Adam, ``None`` leaves in the updates stay ``None`` and keep their state."""
    params = {"a": jnp.ones(2), "b": jnp.ones(3)}
    opt = adamodw(1e-2, weight_decay=1e-3)
    state = opt.init(params)
    updates, new_state = opt.update({"a": jnp.ones(2), "b": None}, state, params)
    assert updates["b"] is None and updates["a"].shape == (2,)
    _assert_trees_close(new_state.nu["b"], state.nu["b"])
    assert float(new_state.nu["a"][0]) > 0


def test_decay_of_zero_gradient_leaves_stability_bound():
    """For zero gradients kappa_hat -> eta / eps; decay is stable only if kappa_hat * xi < 2."""
    eta, eps = 1e-3, 1e-8
    params = jnp.ones(2)
    zeros = [jnp.zeros(2)] * 300
    with _promotion(True):
        stable, _, _ = _run_steps(adamodw(eta, b3=0.9, eps=eps, weight_decay=1e-6), params, zeros)
        unstable, _, _ = _run_steps(adamodw(eta, b3=0.9, eps=eps, weight_decay=1e-4), params, zeros)
    assert np.all(np.abs(np.asarray(stable)) < 1e-6)  # factor 1 - 0.1 per step eventually
    assert np.all(np.abs(np.asarray(unstable)) > 1e6)  # factor 1 - 10 per step: diverges


def test_mask_tree_prefix_and_callable():
    """Masked-out leaves take the plain AdaMod step; masked-in leaves the AdaModW step."""
    params = _random_tree(jax.random.key(3))
    grads = _grads_list(20, params, seed=4)
    kw = dict(learning_rate=1e-2, b3=0.9)
    # "pair" is a tuple subtree: a prefix mask covers both of its leaves.
    mask = {"w": True, "pair": False, "inner": {"b": True}}
    with _promotion(True):
        got, _, _ = _run_steps(adamodw(weight_decay=0.1, mask=mask, **kw), params, grads)
        got_fn, _, _ = _run_steps(
            adamodw(weight_decay=0.1, mask=lambda p: jax.tree.map(lambda x: x.ndim != 1, p), **kw),
            params,
            grads,
        )
        decayed, _, _ = _run_steps(adamodw(weight_decay=0.1, **kw), params, grads)
        plain, _, _ = _run_steps(adamod(**kw), params, grads)
    _assert_trees_close(got["w"], decayed["w"], rtol=1e-14)
    _assert_trees_close(got["inner"], decayed["inner"], rtol=1e-14)
    _assert_trees_close(got["pair"], plain["pair"], rtol=1e-14)
    assert not np.allclose(np.asarray(decayed["pair"][0]), np.asarray(plain["pair"][0]))
    # Callable: decays everything except the 1-d leaf pair[0] (pair[1] is a 0-d scalar).
    _assert_trees_close(got_fn["w"], decayed["w"], rtol=1e-14)
    _assert_trees_close(got_fn["pair"][0], plain["pair"][0], rtol=1e-14)
    _assert_trees_close(got_fn["pair"][1], decayed["pair"][1], rtol=1e-14)


def test_params_required_for_weight_decay():
    params = {"a": jnp.ones(3)}
    grads = {"a": jnp.full(3, 0.5)}
    opt = adamodw(1e-2, weight_decay=1e-3)
    with pytest.raises(ValueError, match="needs the current params"):
        opt.update(grads, opt.init(params))
    with pytest.raises(ValueError, match="needs the current params"):
        masked = adamodw(1e-2, weight_decay=1e-3, mask={"a": True})
        masked.update(grads, masked.init(params))
    # No params needed without decay (literal zero), or when the mask excludes every leaf.
    for opt in (
        adamod(1e-2),
        adamodw(1e-2, weight_decay=0.0),
        adamodw(1e-2, weight_decay=1e-3, mask={"a": False}),
    ):
        updates, _ = opt.update(grads, opt.init(params))
        np.testing.assert_allclose(np.asarray(updates["a"]), -1e-2 * 1e-3, rtol=1e-6)


def test_mu_dtype():
    params = {"a": jnp.ones(3, jnp.float32)}
    opt = scale_by_adamod(1e-2, mu_dtype=jnp.bfloat16)
    state = opt.init(params)
    assert state.mu["a"].dtype == jnp.bfloat16 and state.nu["a"].dtype == jnp.float32
    with _promotion(True):
        updates, new_state = jax.jit(opt.update)(params, state, params)
    assert updates["a"].dtype == jnp.float32
    assert new_state.mu["a"].dtype == jnp.bfloat16


def test_accepts_extra_args():
    params = {"a": jnp.ones(3)}
    for opt in (adamod(1e-2), adamodw(1e-2)):
        updates, _ = opt.update(params, opt.init(params), params, value=jnp.ones(()), unused=1)
        assert updates["a"].shape == (3,)


# ----------------------------------------------------------------------------------------------
# Conformance suite (mirrors optax/contrib/_common_test.py). Extend OPTIMIZERS to add methods.
# ----------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class OptimizerCase:
    """One optimizer under test.

    Attributes:
      name: Test id.
      factory: ``**kwargs -> optax.GradientTransformation`` (must be ``inject_hyperparams``-able).
      kwargs: Construction arguments.
      new_hparams: Values injected at runtime by the ``inject_hyperparams`` test.
      strict_promotion: Whether it runs under ``jax_numpy_dtype_promotion="strict"``.
      convergence_steps: Steps for the parabola/Rosenbrock convergence test.
    """

    name: str
    factory: Callable[..., optax.GradientTransformation]
    kwargs: dict[str, Any]
    new_hparams: dict[str, Any]
    strict_promotion: bool = True
    convergence_steps: int = 20_000

    def make(self, **overrides) -> optax.GradientTransformation:
        return self.factory(**{**self.kwargs, **overrides})


OPTIMIZERS: list[OptimizerCase] = [
    # optax references (sanity checks of the suite itself).
    OptimizerCase(
        "adam",
        optax.adam,
        {"learning_rate": 1e-2},
        {"learning_rate": 3e-3},
        strict_promotion=False,
    ),
    OptimizerCase(
        "adamw",
        optax.adamw,
        {"learning_rate": 1e-2, "weight_decay": 1e-4},
        {"learning_rate": 3e-3, "weight_decay": 1e-2},
        strict_promotion=False,
    ),
    # jaxcal.optim
    OptimizerCase("adamod", adamod, {"learning_rate": 1e-2}, {"learning_rate": 3e-3, "b3": 0.9}),
    OptimizerCase(
        "adamodw",
        adamodw,
        {"learning_rate": 1e-2, "weight_decay": 1e-4},
        {"learning_rate": 3e-3, "weight_decay": 1e-2},
    ),
]
_IDS = [c.name for c in OPTIMIZERS]
suite = pytest.mark.parametrize("case", OPTIMIZERS, ids=_IDS)


def _setup_parabola(dtype):
    initial = jnp.array([-1.0, 10.0, 1.0], dtype=dtype)
    final = jnp.array([1.0, -1.0, 1.0], dtype=dtype)
    return initial, final, lambda p: jnp.sum((p - final) ** 2)


def _setup_rosenbrock(dtype):
    a, b = 1.0, 100.0
    initial = jnp.array([0.0, 0.0], dtype=dtype)
    final = jnp.array([a, a**2], dtype=dtype)
    return initial, final, lambda p: (a - p[0]) ** 2 + b * (p[1] - p[0] ** 2) ** 2


@suite
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64], ids=["float32", "float64"])
@pytest.mark.parametrize("target", [_setup_parabola, _setup_rosenbrock], ids=["parabola", "rosen"])
def test_suite_converges(case, target, dtype):
    initial, final, obj = target(dtype)
    opt = case.make()

    @jax.jit
    def run(params):
        def body(carry, _):
            p, s = carry
            g = jax.grad(obj)(p)
            u, s = opt.update(g, s, p)
            return (optax.apply_updates(p, u), s), None

        (p, _), _ = jax.lax.scan(body, (params, opt.init(params)), length=case.convergence_steps)
        return p

    with _promotion(case.strict_promotion):
        params = run(initial)
    np.testing.assert_allclose(np.asarray(params), np.asarray(final), rtol=3e-2, atol=3e-2)


@suite
def test_suite_jit_and_nested_pytree(case):
    """jit == eager on a nested dict/tuple pytree; updates keep its structure and shapes."""
    params = _random_tree(jax.random.key(5))
    grads = _grads_list(5, params, seed=6)
    opt = case.make()
    with _promotion(case.strict_promotion):
        # A no-op optax.tree.map_params must work on the state (used for sharding specs).
        assert jax.tree.structure(optax.tree.map_params(opt, lambda v: v, opt.init(params))) == (
            jax.tree.structure(opt.init(params))
        )
        p_jit, s_jit, u_jit = _run_steps(opt, params, grads, jit=True)
        p_eager, s_eager, u_eager = _run_steps(opt, params, grads, jit=False)
    _assert_trees_close(p_jit, p_eager, rtol=1e-13, atol=1e-15)
    _assert_trees_close(s_jit, s_eager, rtol=1e-13, atol=1e-15)
    for u in u_jit:
        assert jax.tree.structure(u) == jax.tree.structure(params)
        assert jax.tree.map(jnp.shape, u) == jax.tree.map(jnp.shape, params)


_DTYPES = [jnp.float32, jnp.float64, jnp.bfloat16]


@suite
@pytest.mark.parametrize("dtype", _DTYPES, ids=lambda d: jnp.dtype(d).name)
def test_suite_preserves_dtype_and_state_is_stable(case, dtype):
    """Updates have the params' dtype; the state keeps its tree structure, shapes and dtypes.

    Run inside ``lax.scan`` and ``lax.cond`` (like optax's state-stability test), which fail
    if the state after an update differs from the init state in structure or dtype.
    """
    initial, _, obj = _setup_parabola(dtype)
    opt = case.make()

    @jax.jit
    def run(params):
        state0 = opt.init(params)

        def body(carry, _):
            p, s = carry
            g = jax.grad(obj)(p)
            u, new_s = opt.update(g, s, p)
            assert u.dtype == p.dtype, (u.dtype, p.dtype)
            cond = jax.random.randint(jax.random.key(0), (), 0, 2) == 0
            s = jax.lax.cond(cond, lambda: s, lambda: new_s)
            return (optax.apply_updates(p, u), s), None

        (p, s), _ = jax.lax.scan(body, (params, state0), length=3)
        return p, s, state0

    with _promotion(case.strict_promotion):
        params, state, state0 = run(initial)
    assert params.dtype == dtype
    assert jax.tree.structure(state) == jax.tree.structure(state0)
    assert jax.tree.map(lambda x: (x.shape, x.dtype), state) == jax.tree.map(lambda x: (x.shape, x.dtype), state0)


@suite
def test_suite_bfloat16_tracks_float32(case):
    """bfloat16 updates stay close to float32 ones (hyperparameters not rounded to bf16).

    Params barely move in bfloat16 (AdaMod's first steps are ~1e-3 of Adam's, below bf16's
    resolution near 1), so compare the updates of the first steps on the same inputs.
    """
    params = jnp.array([1.0, -2.0, 0.5, 3.0], jnp.float32)
    grads = [g.astype(jnp.bfloat16) for g in _grads_list(3, params, seed=15)]
    opt = case.make()
    with _promotion(case.strict_promotion):
        s32, s16 = opt.init(params), opt.init(params.astype(jnp.bfloat16))
        for g in grads:
            u32, s32 = opt.update(g.astype(jnp.float32), s32, params)
            u16, s16 = opt.update(g, s16, params.astype(jnp.bfloat16))
            assert u16.dtype == jnp.bfloat16
            assert np.all(np.abs(np.asarray(u32)) > 0)
            np.testing.assert_allclose(np.asarray(u16, np.float64), np.asarray(u32, np.float64), rtol=3e-2)


@suite
def test_suite_inject_hyperparams(case):
    """Changing injected hyperparameters at runtime does not recompile and matches rebuilding."""
    params = _random_tree(jax.random.key(7))
    grads = _grads_list(6, params, seed=8)
    opt = optax.inject_hyperparams(case.factory)(**case.kwargs)
    traces = []

    @jax.jit
    def step(p, s, g):
        traces.append(1)
        u, s = opt.update(g, s, p)
        return optax.apply_updates(p, u), s

    with _promotion(case.strict_promotion):
        p, s = params, opt.init(params)
        for i, g in enumerate(grads):
            if i == 3:
                for k, v in case.new_hparams.items():
                    s.hyperparams[k] = jnp.asarray(v, s.hyperparams[k].dtype)
            p, s = step(p, s, g)

        # Reference: the plain factory with the old values for 3 steps, then the new values.
        ref_p, ref_s, _ = _run_steps(case.make(), params, grads[:3])
        ref_opt = case.make(**case.new_hparams)
        for g in grads[3:]:
            u, ref_s = ref_opt.update(g, ref_s, ref_p)
            ref_p = optax.apply_updates(ref_p, u)
    assert len(traces) == 1, "inject_hyperparams step recompiled"
    _assert_trees_close(p, ref_p, rtol=1e-12, atol=1e-14)
    _assert_trees_close(s.inner_state, ref_s, rtol=1e-12, atol=1e-14)


@suite
def test_suite_chain_after_clipping(case):
    params = _random_tree(jax.random.key(9))
    grads = _grads_list(5, params, seed=10, scale=10.0)  # global norm >> 1: clipping acts
    clipped = []
    for g in grads:
        norm = optax.tree.norm(g)
        clipped.append(jax.tree.map(lambda x, n=norm: x / jnp.maximum(n, 1.0), g))
    with _promotion(case.strict_promotion):
        got, _, _ = _run_steps(optax.chain(optax.clip_by_global_norm(1.0), case.make()), params, grads)
        ref, _, _ = _run_steps(case.make(), params, clipped)
    _assert_trees_close(got, ref, rtol=1e-12, atol=1e-14)


@suite
def test_suite_masked(case):
    """optax.masked: masked-in leaves are optimised as alone, masked-out updates pass through."""
    params = _random_tree(jax.random.key(11))
    grads = _grads_list(5, params, seed=12)
    mask = {"w": True, "pair": False, "inner": {"b": True}}
    opt = optax.masked(case.make(), mask)
    sub = {"w": params["w"], "inner": params["inner"]}
    with _promotion(case.strict_promotion):
        _, _, updates = _run_steps(opt, params, grads)
        # Alone on the masked-in subtree (same params trajectory as the masked run).
        sub_grads = [{"w": g["w"], "inner": g["inner"]} for g in grads]
        _, _, sub_updates = _run_steps(case.make(), sub, sub_grads)
    for u, su, g in zip(updates, sub_updates, grads, strict=True):
        _assert_trees_close(u["w"], su["w"], rtol=1e-13)
        _assert_trees_close(u["inner"], su["inner"], rtol=1e-13)
        _assert_trees_close(u["pair"], g["pair"])


@suite
def test_suite_multisteps(case):
    """optax.MultiSteps(k=3): zero updates until the k-th, which equals one step on the mean."""
    params = _random_tree(jax.random.key(13))
    grads = _grads_list(6, params, seed=14)
    # MultiSteps divides float by int32 (not strict-promotion safe) and accumulates in float32
    # unless told otherwise.
    with _promotion(False):
        ms = optax.MultiSteps(case.make(), every_k_schedule=3, accumulator_dtype=jnp.float64)
        _, _, updates = _run_steps(ms, params, grads)
        mean = [
            jax.tree.map(lambda *xs: sum(xs) / 3.0, *grads[0:3]),
            jax.tree.map(lambda *xs: sum(xs) / 3.0, *grads[3:6]),
        ]
        _, _, ref = _run_steps(case.make(), params, mean)
    for i in (0, 1, 3, 4):
        _assert_trees_close(updates[i], jax.tree.map(jnp.zeros_like, params))
    _assert_trees_close(updates[2], ref[0], rtol=1e-12, atol=1e-15)
    _assert_trees_close(updates[5], ref[1], rtol=1e-12, atol=1e-15)


@suite
def test_suite_optimistix(case):
    """optimistix.minimise with OptaxMinimiser on a quadratic with a pytree argument."""
    target = {"x": jnp.array([1.0, -2.0, 0.5]), "y": jnp.array(3.0)}
    scales = {"x": jnp.array([1.0, 4.0, 0.25]), "y": jnp.array(2.0)}

    def fn(y, args):
        return sum(
            jnp.sum(s * (a - t) ** 2)
            for a, t, s in zip(jax.tree.leaves(y), jax.tree.leaves(target), jax.tree.leaves(scales), strict=True)
        )

    y0 = jax.tree.map(jnp.zeros_like, target)
    solver = optx.OptaxMinimiser(case.make(learning_rate=5e-2), rtol=1e-7, atol=1e-7)
    with _promotion(case.strict_promotion):
        sol = optx.minimise(fn, solver, y0, max_steps=20_000, throw=False)
    assert sol.result == optx.RESULTS.successful
    _assert_trees_close(sol.value, target, rtol=1e-3, atol=1e-3)
