"""A calibration problem: data + models + which parameters are free, as one pytree."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._host_method import host_method
from .._core._params import Deviations, ParameterSpace, layout_for
from .._core._xla import jit
from .._models._abstract import AbstractRobot
from .._models._kinematics import shared_joint_trig
from .._sensors._initialise import residual_rows
from .._sensors._measurement import MeasurementModel

__all__ = ["Problem", "entry_count", "value_and_jacfwd", "residual_blocks_numpy", "signed_residuals",
           "observed_entries",
           "sample_errors_at", "predict_jit"]


def entry_count(measurement: MeasurementModel, n: int) -> int:
    """Entries of a residual vector of ``n`` rows (:meth:`Problem.residual`): ``n·m``, or the
    model's own entries (:meth:`MeasurementModel.residual_entries`)."""
    e = measurement.residual_entries(n)
    return n * measurement.size if e is None else int(e.size)


def value_and_jacfwd(f, x: Float[Array, " p"], q: Float[Array, "n dof"]):
    """``(f(x), ∂f/∂x)`` from one ``jax.jacfwd`` pass (the value is its primal), for ``f`` a
    residual of the kinematics at the joint angles ``q``: evaluated inside a
    :func:`~jaxcal._models._kinematics.shared_joint_trig` block, so ``cos``/``sin`` of ``q`` are computed
    once, not per Jacobian column. A caller that uses ``J`` more than once passes it through
    :func:`~jaxcal._core._xla.computed_once` (XLA would differentiate the kinematics once per use);
    one with a single reduction of it (a gradient ``Jᵀr``) does not, so that XLA fuses the
    Jacobian into the reduction and never writes it out (the gradient methods' step: 0.17 vs
    0.40 ms with the Jacobian written out, 2-core CPU)."""
    with shared_joint_trig(q):
        J, r = jax.jacfwd(lambda x: (f(x),) * 2, has_aux=True)(x)
    return r, J


class Problem(eqx.Module):
    """Everything a solver needs: ``residual(x)`` for the free-parameter vector ``x`` ``[p]``.

    A pytree (arrays are leaves, the parameter space is static), so a problem can be passed
    through ``jax.jit`` and ``jax.vmap`` (e.g. over datasets drawn from different keys).

    Attributes:
        robot: nominal robot.
        measurement: measurement model.
        q: ``[n, dof]`` joint angles (rad).
        y: measurements, ``[n, *measurement.sample_shape]`` (mm).
        space: free parameters (static).
        base: values of the deviations that are not free (zeros = nominal).
        weight: ``[n]`` row weights, 1 for a real sample and 0 for a padding row
            (shape buckets), or ``None`` (every row real). Padding rows contribute
            nothing: :meth:`residual` and :meth:`sample_errors` are 0 there, and every mean divides
            by :attr:`n_real` (a traced count), so a padded problem gives the unpadded one's
            values to round-off.
    """

    robot: AbstractRobot
    measurement: MeasurementModel
    q: Float[Array, "n dof"]
    y: Array
    base: Deviations
    space: ParameterSpace = eqx.field(static=True)
    weight: Array | None = None

    def __init__(self, robot, measurement, q, y, space=None, base=None, weight=None):
        self.robot = robot
        self.measurement = measurement
        self.q = jnp.asarray(q)
        self.y = jnp.asarray(y, dtype=self.q.dtype)
        self.space = ParameterSpace.for_robot(robot, measurement=measurement) if space is None else space
        layout = layout_for(robot, measurement)
        if self.space.layout != layout:
            raise ValueError(f"parameter space has groups {list(self.space.layout.group_names)} for {self.space.dof} "
                             f"joints, but robot {robot.name!r} with this measurement has {list(layout.group_names)} "
                             f"for {robot.dof} joints")
        self.base = Deviations.zeros(layout, self.q.dtype) if base is None else base.astype(self.q.dtype)
        self.weight = None if weight is None else jnp.asarray(weight, self.q.dtype)

    @property
    def n_samples(self) -> int:
        """Rows of the data (padding rows included)."""
        return int(self.q.shape[0])

    @property
    def n_residuals(self) -> int:
        """Residual entries of the data (padding rows included)."""
        return self.n_samples * self.measurement.size

    @property
    def entries(self) -> np.ndarray | None:
        """Flat positions ``[k]`` into ``[n, m]`` of the entries :meth:`residual` returns
        (:meth:`MeasurementModel.residual_entries`); ``None``: all ``n·m``."""
        return self.measurement.residual_entries(self.n_samples)

    @property
    def n_entries(self) -> int:
        """Length of :meth:`residual`'s vector (and rows of :meth:`jacobian`): :attr:`n_residuals`,
        or fewer where the model names its entries (a combined model's narrower blocks)."""
        return entry_count(self.measurement, self.n_samples)

    def to_blocks(self, v):
        """``[n_entries, ...]`` (a :meth:`residual` vector, a :meth:`jacobian`) → ``[n, m, ...]``,
        the entries the model leaves out set to zero (NumPy in, NumPy out)."""
        n, m, e = self.n_samples, self.measurement.size, self.entries
        if e is None:
            return v.reshape(n, m, *v.shape[1:])
        if isinstance(v, np.ndarray):
            full = np.zeros((n * m, *v.shape[1:]), v.dtype)
            full[e] = v
        else:
            full = jnp.zeros((n * m, *v.shape[1:]), v.dtype).at[e].set(v)
        return full.reshape(n, m, *v.shape[1:])

    def entry_rows(self) -> np.ndarray | None:
        """``[n_entries]`` the row of each entry of :meth:`residual` (``None``: all ``n·m``, row
        ``i`` holding entries ``i·m … i·m + m − 1``)."""
        e = self.entries
        return None if e is None else e // self.measurement.size

    @property
    def n_real(self):
        """Real samples: ``n_samples`` (a Python int) without weights, else ``Σ weight`` (an array)."""
        return self.n_samples if self.weight is None else jnp.sum(self.weight)

    @property
    def n_real_residuals(self):
        """Real residual entries (``n_real · m``), what the means divide by."""
        return self.n_residuals if self.weight is None else self.n_real * self.measurement.size

    @host_method
    def observed(self) -> np.ndarray | None:
        """``[n, m]`` bool: the real residual entries (:meth:`MeasurementModel.observed`; ``None``:
        every entry of the data is real)."""
        return self.measurement.observed(self.y)

    @property
    def n_observed_residuals(self) -> int:
        """Residual entries that are real readings (:attr:`n_residuals` less the masked ones)."""
        obs = self.observed()
        return self.n_residuals if obs is None else int(obs.sum())

    def mean_weights(self) -> Float[Array, " n"]:
        """``[n]`` weights of the per-sample mean: ``1/n`` each, or ``weight / n_real``."""
        if self.weight is None:
            n = self.n_samples
            return jnp.full((n,), 1.0 / n, self.dtype)
        return self.weight / self.n_real

    def weighted_blocks(self, r: Array) -> Array:
        """Residual blocks ``[n, ...]`` with the padding rows zeroed (``r`` itself without weights)."""
        if self.weight is None:
            return r
        return r * self.weight.reshape(-1, *([1] * (r.ndim - 1)))

    @property
    def dtype(self):
        return self.q.dtype

    def x0(self) -> Float[Array, " p"]:
        """The free entries of ``base`` (zeros for the nominal start)."""
        return self.space.to_vector(self.base)

    def deviations(self, x: Float[Array, " p"]) -> Deviations:
        """Full deviations for free-parameter vector ``x``."""
        return self.space.from_vector(x, self.base)

    def residual(self, x: Float[Array, " p"]) -> Float[Array, " N"]:
        """``prediction − measured`` flattened to ``[n·m]`` (mm), or to the model's own entries
        ``[n_entries]`` where it names them (:meth:`MeasurementModel.residual_entries`: the others
        are zero by construction); :meth:`to_blocks` is the inverse."""
        rows = self.entry_rows()
        if rows is None:
            return self.weighted_blocks(self.measurement.residual(self.robot, self.deviations(x), self.q, self.y)
                                        ).reshape(-1)
        r = self.measurement.entry_residual(self.robot, self.deviations(x), self.q, self.y)
        return r if self.weight is None else r * self.weight[rows]

    def sample_errors(self, x: Float[Array, " p"]) -> Float[Array, " n"]:
        """Per-sample errors for the metrics (mm; 0 on padding rows)."""
        r = self.measurement.residual(self.robot, self.deviations(x), self.q, self.y)
        return self.weighted_blocks(self.measurement.sample_error(r))

    def sample_errors_from_residual(self, r: Float[Array, " n*m"]) -> Float[Array, " n"]:
        """:meth:`sample_errors` from the flat residual :meth:`residual` gave (padding rows 0)."""
        return self.measurement.sample_error(self.to_blocks(r))

    def jacobian(self, x: Float[Array, " p"]) -> Float[Array, "n*m p"]:
        """Identification Jacobian ``∂residual/∂x`` ``[n_entries, p]`` (``[n·m, p]`` unless the model
        names its entries) by ``jax.jacfwd`` (paper eq. 5)."""
        return value_and_jacfwd(self.residual, x, self.q)[1]

    def with_data(self, q, y, weight=None) -> Problem:
        """Same models and parameters, other data (e.g. the test split)."""
        return Problem(self.robot, self.measurement, q, y, self.space, self.base, weight)

    def with_space(self, space: ParameterSpace) -> Problem:
        return Problem(self.robot, self.measurement, self.q, self.y, space, self.base, self.weight)


def signed_residuals(problem: Problem, x) -> np.ndarray:
    """Residual entries as NumPy ``[n, m]`` (mm; the position part ``[n, 3]`` of a pose), for
    robust scales and outlier scans.

    Evaluated at the full deviations — the free entries ``x`` put into the problem's ``base`` on
    the host — by :func:`~jaxcal._sensors._initialise.residual_rows`, a program with no free set:
    one compiled program per (models, row bucket) serves every free set (the robust/MAP rounds,
    identifiability's re-selection, an evaluation's registration and its outlier scan, the
    closed-form starts), not one per set."""
    x = np.asarray(x)
    dev = problem.space.from_vector(x.astype(problem.dtype, copy=False), problem.base)
    # rows with weights are padded already (shape buckets): as given
    r = residual_rows(problem.measurement, problem.robot, dev, problem.q, problem.y, pad=problem.weight is None)
    return residual_blocks_numpy(problem, r)


def observed_entries(problem: Problem, r) -> np.ndarray:
    """The residual entries of ``r`` (:func:`signed_residuals` blocks ``[n, m]``) that are real
    readings (:meth:`Problem.observed`), flat; ``r`` itself when every entry is."""
    obs = problem.observed()
    return r if obs is None else np.asarray(r)[obs[:, : np.shape(r)[1]]]


def residual_blocks_numpy(problem: Problem, r) -> np.ndarray:
    """Residual blocks ``[n, m]`` as the NumPy entries :func:`signed_residuals` returns (float64;
    the position part ``[n, 3]`` of a pose)."""
    r = np.asarray(r, np.float64)
    k = problem.measurement.error_entries
    return r if k is None else r[:, :k]


@jit
def sample_errors_at(problem: Problem, x: Float[Array, " p"]) -> Float[Array, " n"]:
    """Per-sample errors (mm) at free parameters ``x``, jitted (compiled once per shape)."""
    return problem.sample_errors(x)


@jit
def prediction_variance_at(problem: Problem, x: Float[Array, " p"], covariance: Float[Array, "p p"]
                           ) -> Float[Array, " n"]:
    """Per-sample variance (mm²) of the predicted reading at free parameters ``x`` with parameter
    covariance ``covariance`` ``[p, p]``: ``diag(J·Cov·Jᵀ)`` summed over the sample's coordinates
    (the position part of a pose), jitted (one program per shape; the N×p Jacobian stays in XLA)."""
    J = problem.to_blocks(problem.jacobian(x))
    if (k := problem.measurement.error_entries) is not None:
        J = J[:, :k]
    return jnp.einsum("nmp,pk,nmk->n", J, covariance, J)


@jit
def predict_jit(measurement, robot, deviations, q):
    """``measurement.predict(robot, deviations, q)``, jitted for host-side callers (compiled once
    per shape; executed op by op, the kinematics run as hundreds of small XLA programs, each
    compiled once per process)."""
    return measurement.predict(robot, deviations, q)
