"""Variance components of a combined fit: each data block's redundancy and σ̂ (Förstner 1979;
Koch 1999, §3.6), from every block's information matrix at a solution in one compiled program.

:func:`block_sigmas` is what :func:`jaxcal.calibrate`'s rounds reweight a
:class:`~jaxcal.Combined` model by between its fits; :func:`~jaxcal._calibration._blocks.block_statistics`
reports the same estimates with the blocks' other statistics."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._core._buckets import LeanJit
from .._core._params import Deviations, ParameterSpace
from .._core._precision import to_device
from .._fit._diagnostics import variance_component
from .._fit._problem import Problem, value_and_jacfwd
from .._sensors._blocks import Combined

__all__ = ["block_sigmas"]


def _block_grams(problem: Problem, observed):
    """The whitened residual ``[N, m]`` and each block's information matrix ``J_bᵀJ_b``
    ``[B, p, p]`` (``J_b`` its rows of the whitened Jacobian, masked entries zeroed) at
    ``problem.x0()``, in one compiled program: the ``N×p`` Jacobian stays on the device."""
    r, J = value_and_jacfwd(problem.residual, problem.x0(), problem.q)
    model = problem.measurement
    n = problem.q.shape[0]
    J = problem.to_blocks(J) * observed[:, :, None].astype(J.dtype)
    grams = jnp.stack([jnp.einsum("imp,imq->pq", Jb, Jb) for Jb in model._rows(J, n)])
    return problem.to_blocks(r), grams


#: one program per combined model and row count: the space is every parameter of the layout, so
#: the variance-component rounds (whose free sets may differ) share it
_block_grams = LeanJit(_block_grams, maxsize=4)


def _information(robot, model: Combined, space: ParameterSpace, deviations: Deviations, q, y):
    """:func:`block_information` with ``every`` at ``deviations``: ``(r [N, m], grams [B, P, P])``
    over every parameter of ``space``'s layout (one compiled program for every free set)."""
    q = to_device(np.asarray(q, np.float64))
    y = np.asarray(y, np.float64)
    full = ParameterSpace.from_names(space.layout, space.layout.names)
    problem = Problem(robot, model, q, to_device(y), full, deviations.astype(q.dtype))
    obs = model.observed(y)
    obs = np.ones((q.shape[0], model.size), bool) if obs is None else obs
    r, grams = _block_grams(problem, to_device(obs))
    return np.asarray(r, np.float64), np.asarray(grams, np.float64)


def _variance_components(model: Combined, space: ParameterSpace, prior, r, every, y, prior_noise: float = 1.0):
    """Each block's redundancy and σ̂ by variance components at a combined fit (module
    docstring): ``(grams [B, p, p] over the free parameters, A⁻¹ [p, p], observed [N, m],
    redundancy [B], σ̂ [B] each block's unit)``; ``r``, ``every``: :func:`_information`'s."""
    idx = space.free_index
    grams = every[:, idx][:, :, idx]
    lam = np.zeros(grams.shape[1])
    if prior is not None:
        s = prior.std(space)
        lam = np.where(np.isfinite(s), (prior_noise / s) ** 2, 0.0)
    A_inv = np.linalg.pinv(grams.sum(0) + np.diag(lam))
    obs = model.observed(np.asarray(y))
    obs = np.ones(r.shape, bool) if obs is None else obs
    sigma = np.asarray(model.sigma, np.float64)
    red, sig_hat = [], []
    for b, (mod, rb, ob) in enumerate(zip(model.models, model._rows(r, r.shape[0]), model._rows(obs, r.shape[0]))):
        raw = rb[:, : mod.size] * sigma[b]  # its own unit
        s, rd = variance_component(float(np.sum(raw[ob[:, : mod.size]] ** 2)), ob.sum(), A_inv, grams[b])
        sig_hat.append(s)
        red.append(rd)
    return grams, A_inv, obs, np.asarray(red), np.asarray(sig_hat)


def block_sigmas(robot, model: Combined, space: ParameterSpace, deviations: Deviations, prior, q, y) -> np.ndarray:
    """``[B]`` the blocks' σ for the next fit of a combined model at ``deviations``: each
    estimated block's σ̂ by variance components (where finite and > 0), the others' as they are.
    What :func:`jaxcal.calibrate` reweights a :class:`~jaxcal.Combined` model by between its fits."""
    r, every = _information(robot, model, space, deviations, q, y)
    sig_hat = _variance_components(model, space, prior, r, every, y)[-1]
    sigma = np.asarray(model.sigma, np.float64)
    ok = np.asarray(model.estimated) & np.isfinite(sig_hat) & (sig_hat > 0)
    return np.where(ok, sig_hat, sigma)
