"""Which parameters the data can identify: rank, singular values and an identifiable subset."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from ._measurement import MeasurementModel
from ._params import Deviations, ParameterSpace
from ._problem import Problem
from ._robot import DHRobot

__all__ = ["IdentifiabilityReport", "identifiability"]


@dataclasses.dataclass(frozen=True)
class IdentifiabilityReport:
    """Result of :func:`identifiability`.

    Attributes:
        names: the free parameters examined (length ``p``).
        rank: numerical rank of the column-scaled identification Jacobian.
        singular_values: ``[p]`` singular values of the column-scaled Jacobian, descending.
        identifiable: names of a maximal identifiable subset (chosen by QR with column pivoting).
        unidentifiable: the other names; each is (locally) a combination of identifiable ones.
        dependencies: for each unidentifiable name, ``[(coefficient, name), ...]`` such that a
            change ``δ`` of it has the same first-order effect as changing each listed
            parameter by ``coefficient·δ`` (physical units); empty if it has no effect at all.
        condition_number: condition number of the column-scaled Jacobian restricted to the
            identifiable subset.
        space: :class:`ParameterSpace` with only the identifiable subset free (the default mask
            of :func:`jaxcal.calibrate`).
        rtol: relative singular-value threshold used for the rank.
    """

    names: tuple[str, ...]
    rank: int
    singular_values: np.ndarray
    identifiable: tuple[str, ...]
    unidentifiable: tuple[str, ...]
    dependencies: dict
    condition_number: float
    space: ParameterSpace
    rtol: float

    def __str__(self) -> str:
        lines = [
            f"identification Jacobian rank {self.rank} of {len(self.names)} free parameters "
            f"(column-scaled, rtol={self.rtol:g}); condition number of the identifiable "
            f"subset {self.condition_number:.3g}",
            "identifiable: " + ", ".join(self.identifiable),
        ]
        if self.unidentifiable:
            lines.append("not identifiable (fixed at their current value):")
            for n in self.unidentifiable:
                deps = self.dependencies.get(n, [])
                if not deps:
                    lines.append(f"  {n}: has no effect on the measurements")
                else:
                    combo = " ".join(f"{c:+.4g}·{m}" for c, m in deps)
                    lines.append(f"  {n}: acts like {combo}")
        return "\n".join(lines)

    def equivalent(self, deviations, held=None) -> np.ndarray:
        """The values ``[p_identifiable]`` the identifiable parameters take when the unidentifiable
        ones are held at ``held`` (default zero; a calibration holds them at its start,
        ``result.start``) and ``deviations`` is the truth, to first order:
        ``x_k + Σ_j coefficient_jk·(x_j − held_j)`` over the dependencies. This is what a
        calibration of the identifiable subset estimates (compare estimates with it, not with the
        raw truth)."""
        names = list(self.space.names)
        flat = np.asarray(deviations.ravel(), np.float64)
        base = np.zeros_like(flat) if held is None else np.asarray(held.ravel(), np.float64)
        value = {n: flat[names.index(n)] for n in self.names}
        out = {n: value[n] for n in self.identifiable}
        for dropped, deps in self.dependencies.items():
            for coef, kept in deps:
                out[kept] += coef * (value[dropped] - base[names.index(dropped)])
        return np.asarray([out[n] for n in self.identifiable])

    def to_dict(self) -> dict:
        """JSON-friendly summary."""
        return {
            "rank": self.rank,
            "n_free": len(self.names),
            "singular_values": [float(s) for s in self.singular_values],
            "identifiable": list(self.identifiable),
            "unidentifiable": list(self.unidentifiable),
            "dependencies": {k: [[float(c), n] for c, n in v] for k, v in self.dependencies.items()},
            "condition_number": self.condition_number,
            "rtol": self.rtol,
        }


_pivoted_qr = jax.jit(functools.partial(jsl.qr, mode="economic", pivoting=True))


@jax.jit
def _start_jacobian(problem: Problem):
    return problem.jacobian(problem.x0())


def identifiability(
    robot: DHRobot,
    measurement: MeasurementModel,
    q,
    space: ParameterSpace | None = None,
    deviations: Deviations | None = None,
    *,
    rtol: float = 1e-9,
) -> IdentifiabilityReport:
    """Rank, singular values and an identifiable subset of the free parameters.

    The identification Jacobian ``J = ∂residual/∂Δ`` ``[n·m, p]`` (``jax.jacfwd``) is taken at
    ``deviations`` (nominal by default) for joint angles ``q`` ``[n, dof]``; its columns are
    scaled to unit norm so that mm and rad columns compare. The rank counts singular values
    above ``rtol·s_max``; QR with column pivoting picks a maximal well-conditioned subset;
    each left-out column is expressed in the kept ones by least squares.

    Run it in float64 (:func:`jaxcal.enable_x64`): in float32 the threshold must be ~1e-5.
    """
    q = jnp.asarray(q)
    space = ParameterSpace.for_robot(robot) if space is None else space
    if space.n_free == 0:
        raise ValueError("no free parameters to examine")
    sample = jnp.zeros((q.shape[0], *measurement.sample_shape), q.dtype)
    problem = Problem(robot, measurement, q, sample, space, deviations)
    J = np.asarray(_start_jacobian(problem), dtype=np.float64)
    if not np.all(np.isfinite(J)):
        raise ValueError("identification Jacobian contains NaN/inf (check joint angles and anchor)")
    norms = np.linalg.norm(J, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    Js = J / scale
    # Js[:, piv] = Q R with orthonormal Q: Js, J and their column subsets have the singular
    # values and least-squares solutions of the columns of the small triangular factor, so the
    # SVDs and least squares below run on R (p×p), not on the N×p Jacobian. NumPy's
    # multithreaded LAPACK on the tall matrices took 0.2–1 s per call on a busy 2-core machine.
    _, R, piv = _pivoted_qr(jnp.asarray(Js))
    piv = np.asarray(piv)
    Rs = np.zeros((R.shape[0], len(piv)))
    Rs[:, piv] = np.asarray(R, dtype=np.float64)  # Js = Q Rs
    s = np.linalg.svd(Rs, compute_uv=False)
    rank = int(np.sum(s > rtol * s[0])) if s[0] > 0 else 0
    Rj = Rs * scale  # J = Q Rj
    names = space.free_names
    keep_idx = np.sort(piv[:rank])
    drop_idx = [i for i in range(len(names)) if i not in set(keep_idx.tolist())]
    keep = np.zeros(len(names), dtype=bool)
    keep[keep_idx] = True
    deps = {}
    if drop_idx:
        A = Rj[:, keep_idx]
        for j in drop_idx:
            if norms[j] == 0:
                deps[names[j]] = []
                continue
            coef, *_ = np.linalg.lstsq(A, Rj[:, j], rcond=None)
            # significance judged on the scaled coefficients
            sig = np.abs(coef * norms[keep_idx] / norms[j]) > 1e-6
            order = np.argsort(-np.abs(coef * norms[keep_idx]))
            deps[names[j]] = [(float(coef[k]), names[keep_idx[k]]) for k in order if sig[k]][:6]
    sub = Rs[:, keep_idx]
    sv = np.linalg.svd(sub, compute_uv=False) if keep_idx.size else np.array([1.0])
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    return IdentifiabilityReport(
        names=names,
        rank=rank,
        singular_values=s,
        identifiable=tuple(names[i] for i in keep_idx),
        unidentifiable=tuple(names[i] for i in drop_idx),
        dependencies=deps,
        condition_number=cond,
        space=space.restrict(keep),
        rtol=rtol,
    )
