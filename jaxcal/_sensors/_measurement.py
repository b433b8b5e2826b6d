"""Measurement models: what a sensor reads for given joint angles and parameters.

Each model is a small pytree with ``predict`` (the sensor reading), ``residual``
(``prediction − measured``, ``[n, m]``) and ``sample_error`` (one error per sample for the
RMSE/MEAN/MAX metrics). :func:`residuals` flattens any of them to the ``[n·m]`` vector that
least-squares solvers and gradient methods work on.
"""

from __future__ import annotations

import abc
import copy
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._host_method import host_method
from .._core._params import Deviations, Group
from .._core._precision import to_device
from .._core._rotvec import matrix_to_rotvec
from .._core._rotvec import rotvec_to_matrix as rotvec_to_matrix_np
from .._models._abstract import AbstractRobot
from .._models._kinematics import _chain, _tool_offset, check_joint_angles, rotvec_to_matrix, tool_point_soa
from .._models._tree import tip_tool_group, tool_group_name
from ._kind import SensorKind, check_tip, register_kind, resolve_tip

__all__ = ["MeasurementModel", "CableLength", "Position", "Pose", "Markers", "residuals", "predict", "resolve_tip",
           "check_tip"]


#: :class:`Pose`'s orientation weight (mm/rad) where none is given: the start of its estimate
DEFAULT_ORIENTATION_SCALE = 1000.0
#: the range (mm/rad) of an estimated orientation weight ``σ̂_pos / σ̂_rot``: exact orientation
#: readings (a simulation without orientation noise) give σ̂_rot → 0; the upper end keeps the
#: whitened Jacobian well conditioned (a 1 mm lever then weighs like 1000 mm at the default)
ORIENTATION_SCALE_RANGE = (1e-3, 1e6)


def tip_groups(tip: str | None) -> tuple[Group, ...]:
    """``(tool@<tip>,)`` for a model that sees ``tip`` (not the default tip), else ``()``: the
    group its tool point moves with (:func:`~jaxcal._models._tree.tip_tool_group`)."""
    return () if tip is None else (tip_tool_group(tip),)


def xyz_entries(prefix: str, values, suffix: str = "") -> dict[str, float]:
    """``{prefix x suffix: v_x, ...}`` of a ``[3]`` position (mm): the entry names of a vector
    group (``anchor_x``, ``point_y@a0``)."""
    return {f"{prefix}{c}{suffix}": float(v) for c, v in zip("xyz", np.asarray(values, np.float64))}


class MeasurementModel(eqx.Module):
    """Abstract base of measurement models (an ``eqx.Module``: a pytree)."""

    #: short name used in data files and on the command line.
    kind: ClassVar[str]
    #: extras :func:`~jaxcal._sensors._initial_extras.initial_extras` can start from the data
    #: (closed form), by group name; ``()``: none.
    initialisable: ClassVar[tuple[str, ...]] = ()
    #: how many leading entries of a residual row the sample error (mm) is made of and the
    #: evaluation's expectation counts (a pose's position part, ``3``); ``None``: every entry.
    error_entries: ClassVar[int | None] = None
    #: residual entries per measured point, for a reading of several points (a camera image's
    #: corners: 2 px each; a marker set's markers: 3 mm each), the entries of point ``k`` being
    #: ``[k·w, (k+1)·w)`` of a row; the outlier scan judges each point on its own
    #: (:func:`~jaxcal._fit._diagnostics.scan_rows`). ``None``: a row is one point.
    point_entries: ClassVar[int | None] = None
    #: what one point is called in messages (``"corner"``, ``"marker"``) where :attr:`point_entries` is set
    point_word: ClassVar[str] = "point"
    #: residual entries per sample (``m``).
    size: ClassVar[int]
    #: measurement shape per sample (``()`` for a scalar).
    sample_shape: ClassVar[tuple[int, ...]]
    #: the per-sample error of a prediction (:func:`jaxcal.predicted_accuracy`) is
    #: ``sqrt(Σ rows² / error_points)``: the RMS over a camera image's target points (its
    #: :meth:`sample_error`); ``1`` (the norm of a row) for the others.
    error_points: ClassVar[int] = 1

    #: residual components with a noise σ each, ``((name, unit, first, stop), ...)`` over a row's
    #: ``size`` entries (:class:`Pose`: position mm, orientation rad); empty: one σ for every entry.
    components: ClassVar[tuple[tuple[str, str, int, int], ...]] = ()
    #: whether the reading depends on the robot's tool point (a marker set or a camera target is
    #: its own tool: ``False``)
    sees_tool_point: ClassVar[bool] = True
    #: what the readings are in words, for a reading kind (:meth:`readings_mm`): ``"lengths"``,
    #: ``"positions"``; ``""`` for a kind whose readings are not mm entry by entry
    reading_words: ClassVar[str] = ""
    #: the set-up the fit takes as known unless estimated, for the hint of an implausible fit:
    #: ``(extras, words, flag)`` — the ``--estimate`` names that free it, what it is, the option that
    #: frees it; ``None``: nothing to suggest
    known_setup: ClassVar[tuple[tuple[str, ...], str, str] | None] = None
    #: what one row's error in the accuracy tables is, where it is not the reading's own error
    #: (a tracker's 3-D distance); ``""``: nothing to say
    row_error: ClassVar[str] = ""
    #: the model holds its data file's sessions row by row (:class:`~jaxcal.SessionMarkers`: each
    #: row's frame and placement): it describes those rows only, and other rows (a test split, a
    #: new file) get a model of their own sessions
    row_sessions: ClassVar[bool] = False

    def expected_points(self) -> int | None:
        """The number of points a reading of a new data file of this set-up must have
        (:func:`jaxcal.load_csv`'s ``n_markers``: a marker set's markers), or ``None``: not
        checked (the file's own)."""
        return None

    def readings_mm(self, y) -> np.ndarray | None:
        """The readings ``[n, m]`` (mm) entry by entry as the residual ``prediction − reading``
        compares them (a pose's position part), float64 on the host; ``None`` for a kind whose
        residual is not that (labels, pixels, a bar's second pose): the unit check of
        :func:`jaxcal._fit._diagnostics.likely_cause` skips it."""
        if not self.reading_words:
            return None
        y = np.asarray(y, np.float64)
        return y.reshape(y.shape[0], -1)

    @host_method
    def in_range(self, points_mm, reach_mm: float, range_mm: tuple[float, float] | None = None) -> np.ndarray:
        """Which tool points ``points_mm`` ``[n, 3]`` (nominal robot, base frame, mm) the sensor
        reads, a bool mask ``[n]`` (the sensor's filter in :func:`jaxcal.candidate_poses`): all of
        them unless the sensor has a range of its own. ``range_mm``: that range ``(min, max)`` as
        the user gave it (``None``: the sensor's default for a robot of reach ``reach_mm``)."""
        return np.ones(np.shape(points_mm)[0], bool)

    @host_method
    def estimates_weights(self) -> bool:
        """Whether :func:`jaxcal.calibrate` estimates a σ per :attr:`components` and refits with
        the residual whitened by them (:meth:`reweighted`). No by default."""
        return False

    #: the reweighting's rounds stop when no weight (:meth:`component_scales`) moves by more than
    #: this (relative), or after :attr:`weight_rounds` fits per selection (exact orientation readings
    #: push a pose's weight to the end of its range, a factor of a few per round)
    weights_rtol: ClassVar[float] = 0.02
    weight_rounds: ClassVar[int] = 10

    #: the ``(q, y)`` pairs of this model are several sensors' data stacked (:class:`~jaxcal.Combined`),
    #: each block's checked by its own model where they were combined: :func:`jaxcal.calibrate`
    #: takes them as they are.
    stacked_data: ClassVar[bool] = False

    @host_method
    def takes_extra(self, flag: str, name: str) -> bool:
        """Whether ``calibrate(extras=[name])`` adds parameters to estimate with this sensor's data
        (``flag``: the :meth:`~jaxcal.ParameterSpace.for_robot` flag ``name`` stands for:
        ``anchor``, ``cable_offset``, ``tool``, ``base``): yes by default; no where they are free
        anyway (:class:`~jaxcal.SessionMarkers`' session frames).

        Raises:
            ValueError: the extra does not apply to this sensor (by default a draw wire's
                ``anchor`` and ``cable_offset``).
        """
        if flag in ("anchor", "cable_offset"):
            raise ValueError(f"extra {name!r} applies to draw-wire (cable) data only, not {self.kind!r}")
        return True

    @host_method
    def sees_group(self, group: str) -> bool:
        """Whether this sensor's data see the extras group ``group`` (a group name of
        :func:`jaxcal.layout_for`), so that ``calibrate(free=...)`` may free it: every group but
        a draw wire's ``anchor`` and ``cable_offset`` by default."""
        return group not in ("anchor", "cable_offset")

    @property
    def tool_group(self) -> str:
        """The deviation group the seen tool point moves with: the standard ``tool`` for the
        robot's default tip (``tip=None``), ``tool@<tip>`` for another tip of a
        :class:`~jaxcal.KinematicTree`. ``calibrate(extras=["tool"])`` frees this group. A model
        that does not see the tool point (:attr:`sees_tool_point`) names the standard one."""
        tip = getattr(self, "tip", None)
        return "tool" if tip is None or not self.sees_tool_point else tool_group_name(tip)

    def tip_for(self, robot) -> str | None:
        """The model's ``tip`` checked against ``robot`` (:func:`check_tip`; host-side, also at
        trace time: the tip is static)."""
        return check_tip(robot, getattr(self, "tip", None))

    @host_method
    def at_tip(self, tip: str | None) -> MeasurementModel:
        """This model seeing ``tip`` instead (``None``: the robot's default tip; resolve a name
        that may be the default one with :func:`resolve_tip` first).

        Raises:
            ValueError: the model sees no tip of the robot (a marker set, a camera's target are
                on the tip its ``tip`` names; a model without a ``tip`` field has none).
        """
        if not hasattr(self, "tip"):
            raise ValueError(f"{self.kind} measurements do not name a tip")
        new = copy.copy(self)
        object.__setattr__(new, "tip", None if tip is None else str(tip))
        return new

    @abc.abstractmethod
    def predict(self, robot: AbstractRobot, deviations: Deviations | None, q: Float[Array, "n dof"]):
        """Predicted reading for joint angles ``q`` ``[n, dof]`` (rad)."""

    def residual(self, robot, deviations, q, y) -> Float[Array, "n m"]:
        """``prediction − measured`` as ``[n, m]`` (mm)."""
        return (self.predict(robot, deviations, q) - y).reshape(q.shape[0], self.size)

    @host_method
    def pad_rows(self, n: int, n_to: int) -> MeasurementModel:
        """The model for data of ``n`` rows padded to ``n_to`` rows that repeat row 0
        (shape buckets): itself, unless the model holds per-row arrays (e.g.
        :class:`~jaxcal.SessionMarkers`' frame and placement of every row)."""
        del n, n_to
        return self

    @property
    def jacobian_free_of_data(self) -> bool:
        """Whether ``∂residual/∂Δ`` does not depend on the measured ``y`` (the residual is
        ``prediction − measured``, as here; a pose's orientation residual is not): an
        identification Jacobian computed for other readings then serves these too."""
        return type(self).residual is MeasurementModel.residual

    @host_method
    def observed(self, y) -> np.ndarray | None:
        """``[n, m]`` bool on the host: the residual entries that are real readings, or ``None``
        (every entry is). A model that masks missing readings (:class:`~jaxcal.SessionMarkers`:
        a missing marker) says which here, so that every statistic (σ̂, the robust and outlier
        scales, the residual count) counts only real ones."""
        del y
        return None

    @host_method
    def residual_entries(self, n: int) -> np.ndarray | None:
        """The flat positions ``[k]`` (row-major, into the ``[n, size]`` residual of ``n`` rows)
        that this model can make non-zero, or ``None``: every entry. A model whose rows are
        narrower than ``size`` in places (:class:`~jaxcal.Combined`: a tracker's 3 entries beside a
        camera's 108) names the others, which are zero by construction; the solves, Jacobians and
        information matrices then run over these entries only (:meth:`jaxcal.Problem.residual`),
        and :meth:`jaxcal.Problem.to_blocks` puts a vector back into ``[n, size]``."""
        del n
        return None

    def entry_residual(self, robot, deviations, q, y) -> Float[Array, " k"]:
        """The residual at :meth:`residual_entries` ``[k]`` (row-major; all ``n·size`` entries
        where it is ``None``). A model that names its entries builds them directly."""
        r = self.residual(robot, deviations, q, y).reshape(-1)
        e = self.residual_entries(jnp.shape(q)[0])
        return r if e is None else r[e]

    def nominal_lengths(self) -> dict[str, float]:
        """``{entry: nominal value}`` (mm) of this model's extras that are lengths with a nominal
        value (an anchor, plane offsets, point centres, ...), under their names in
        :func:`jaxcal.layout_for`: where a uniform scaling of every length of the set-up starts
        (:func:`~jaxcal._calibration._blocks.length_scale_direction`). None by default."""
        return {}

    def sample_error(self, residual: Float[Array, "n m"]) -> Float[Array, " n"]:
        """One signed (m = 1) or non-negative (m > 1, Euclidean norm) error per sample (mm)."""
        if self.size == 1:
            return residual[:, 0]
        return jnp.linalg.norm(residual, axis=-1)

    @host_method
    def check_measurements(self, y, n: int) -> None:
        """Raise ``ValueError`` unless ``y`` has shape ``[n, *sample_shape]`` and is finite."""
        shape = tuple(np.shape(y))
        want = (n, *self.sample_shape)
        if shape != want:
            raise ValueError(
                f"{self.kind} measurements must have shape {list(want)} for {n} samples, got {list(shape)}"
            )
        if not np.all(np.isfinite(np.asarray(y))):
            bad = np.flatnonzero(~np.isfinite(np.asarray(y)).reshape(n, -1).all(axis=1))
            raise ValueError(f"{self.kind} measurements contain NaN/inf at samples {bad[:10].tolist()}")


class CableLength(MeasurementModel):
    """Draw-wire (cable-extension) sensor: length from a fixed anchor to the tool point.

    ``L = ‖p_tool(q) − (anchor + Δanchor)‖ + cable_offset``: the paper's sensor. The anchor
    (wire exit point, base frame), the tool point where the wire attaches (flange frame) and
    the cable's zero offset can be estimated as extras through :class:`~jaxcal.Deviations`.

    Attributes:
        anchor: ``[3]`` nominal anchor position in the base frame (mm).
        tip: the tip of a :class:`~jaxcal.KinematicTree` the wire is attached to (static;
            ``None``: the robot's default tip); another tip's tool point is the ``tool@<tip>``
            group (:meth:`extra_groups`).
    """

    anchor: Float[Array, " 3"]
    tip: str | None = eqx.field(static=True, default=None)
    kind: ClassVar[str] = "cable"
    initialisable: ClassVar[tuple[str, ...]] = ("anchor", "cable_offset", "tool")
    known_setup: ClassVar[tuple[tuple[str, ...], str, str] | None] = (
        ("anchor", "cable_offset"), "the anchor and cable offset were", "--estimate anchor,offset")
    reading_words: ClassVar[str] = "lengths"
    size: ClassVar[int] = 1
    sample_shape: ClassVar[tuple[int, ...]] = ()

    @host_method
    def takes_extra(self, flag: str, name: str) -> bool:
        if flag == "base":
            raise ValueError("extra 'base' (sensor frame) applies to position/pose data; a draw-wire has an anchor")
        return True

    @host_method
    def sees_group(self, group: str) -> bool:
        return not group.startswith("base")  # a draw wire has an anchor, no sensor frame

    def __init__(self, anchor, tip: str | None = None):
        anchor = jnp.asarray(anchor)
        if anchor.shape != (3,):
            raise ValueError(f"anchor must be a [3] position in mm, got shape {anchor.shape}")
        self.anchor = anchor
        self.tip = tip

    def extra_groups(self) -> tuple[Group, ...]:
        """``tool@<tip>`` for a tip other than the default one, else none."""
        return tip_groups(self.tip)

    def nominal_lengths(self) -> dict[str, float]:
        return xyz_entries("anchor_", self.anchor)

    @host_method
    def in_range(self, points_mm, reach_mm: float, range_mm: tuple[float, float] | None = None) -> np.ndarray:
        """The tool points whose wire length ``‖p − anchor‖`` lies within ``range_mm`` (default
        ``(0.05, 1.2)·reach_mm``, as :func:`jaxcal.simulate_experiment` draws its poses)."""
        lo, hi = (0.05 * reach_mm, 1.2 * reach_mm) if range_mm is None else map(float, range_mm)
        dist = np.linalg.norm(np.asarray(points_mm, np.float64) - np.asarray(self.anchor, np.float64), axis=1)
        return (dist >= lo) & (dist <= hi)

    def predict(self, robot, deviations, q) -> Float[Array, " n"]:
        """Wire lengths ``[n]`` (mm)."""
        q = check_joint_angles(robot, q)
        p = tool_point_soa(robot, deviations, q, scalar_consumer=True, tip=self.tip_for(robot))
        anchor = self.anchor.astype(q.dtype)
        offset = jnp.zeros((), q.dtype)
        if deviations is not None:
            anchor = anchor + deviations.anchor.astype(q.dtype)
            offset = deviations.cable_offset.astype(q.dtype)
        sq = sum((p[k] - anchor[k]) ** 2 for k in range(3))
        return jnp.sqrt(sq) + offset


def _sensor_frame(model, deviations, dtype):
    """``(R [3,3], t [3])`` of ``T_sensor_base``: the nominal frame of ``model`` corrected by the
    ``base_rotation`` / ``base_translation`` deviations (``R = exp(δr)·R₀``, ``t = t₀ + δt``)."""
    R = jnp.asarray(model.rotation).astype(dtype)
    t = jnp.asarray(model.translation).astype(dtype)
    if deviations is not None:
        R = rotvec_to_matrix(jnp.asarray(deviations.base_rotation).astype(dtype)) @ R
        t = t + jnp.asarray(deviations.base_translation).astype(dtype)
    return R, t


def _check_frame(rotation, translation):
    # by device_put: jnp.eye / jnp.zeros, and jnp.asarray of a NumPy array, would each compile a
    # small program in a fresh process
    R = to_device(np.eye(3) if rotation is None else rotation)
    t = to_device(np.zeros(3) if translation is None else translation)
    if R.shape != (3, 3):
        raise ValueError(f"rotation must be a [3, 3] rotation matrix (sensor <- base), got shape {R.shape}")
    if t.shape != (3,):
        raise ValueError(f"translation must be a [3] vector in mm, got shape {t.shape}")
    if isinstance(R, jax.core.Tracer):  # built inside a traced function: its values are not known yet
        return R, t
    Rn = np.asarray(R, dtype=np.float64)
    if not (np.allclose(Rn.T @ Rn, np.eye(3), atol=1e-6) and np.linalg.det(Rn) > 0):
        raise ValueError("rotation must be a proper rotation matrix (RᵀR = I, det R = +1)")
    return R, t


class Position(MeasurementModel):
    """3-D position of the tool point measured in the sensor's frame (e.g. a laser tracker),
    ``[n, 3]`` mm: ``y = R·p_base(q) + t`` with ``(R, t) = T_sensor_base``.

    A tracker never measures in the robot's base frame: give the nominal sensor-to-base frame
    here (default: identity, i.e. data already in the base frame) and estimate its correction
    with the ``base`` extras (``base_rx…base_z``; :func:`jaxcal.initial_extras` finds a start
    by Kabsch/Horn on nominal FK).

    Attributes:
        rotation: ``[3, 3]`` nominal ``R_sensor_base``.
        translation: ``[3]`` nominal base origin in the sensor frame (mm).
        tip: the tip of a :class:`~jaxcal.KinematicTree` whose tool point is measured (static;
            ``None``: the robot's default tip); another tip's tool point is the ``tool@<tip>``
            group (:meth:`extra_groups`).
    """

    rotation: Float[Array, "3 3"]
    translation: Float[Array, " 3"]
    tip: str | None = eqx.field(static=True, default=None)
    kind: ClassVar[str] = "position"
    known_setup: ClassVar[tuple[tuple[str, ...], str, str] | None] = (("base",), "the sensor frame was", "--estimate base")
    row_error: ClassVar[str] = ("a row's error is the 3-D distance between the predicted and the measured point: "
                                "about √3·σ = 1.73·σ at the floor for a noise σ per axis")
    initialisable: ClassVar[tuple[str, ...]] = ("base", "tool")
    reading_words: ClassVar[str] = "positions"
    size: ClassVar[int] = 3
    sample_shape: ClassVar[tuple[int, ...]] = (3,)

    def __init__(self, rotation=None, translation=None, tip: str | None = None):
        self.rotation, self.translation = _check_frame(rotation, translation)
        self.tip = tip

    def extra_groups(self) -> tuple[Group, ...]:
        """``tool@<tip>`` for a tip other than the default one, else none."""
        return tip_groups(self.tip)

    def predict(self, robot, deviations, q) -> Float[Array, "n 3"]:
        q = check_joint_angles(robot, q)
        p = tool_point_soa(robot, deviations, q, tip=self.tip_for(robot))
        R, t = _sensor_frame(self, deviations, q.dtype)
        return jnp.stack([R[k, 0] * p[0] + R[k, 1] * p[1] + R[k, 2] * p[2] + t[k] for k in range(3)], axis=-1)


class Pose(MeasurementModel):
    """Full pose ``T_sensor_tool = T_sensor_base·T_base_tool`` ``[n, 4, 4]`` (flange orientation,
    origin at the tool point); ``T_sensor_base`` as in :class:`Position` (default identity).

    The residual per sample is ``[Δp (mm, 3), orientation_scale · δθ (3)]`` with
    ``δθ = ½ vee(R_mᵀR_p − R_pᵀR_m)`` the small-angle rotation error (rad): ``orientation_scale``
    (mm/rad) sets how many mm of position error one radian of orientation error is worth, i.e. it
    whitens the orientation entries to the position σ when it equals ``σ_pos / σ_rot``.
    Position and orientation are two :attr:`components` with a σ each. Not given (default),
    :func:`jaxcal.calibrate` estimates both σ from the data by variance components (Förstner 1979;
    the same estimate as a combined fit's per-block σ, :func:`jaxcal.calibrate_blocks`) and refits
    with ``orientation_scale = σ̂_pos / σ̂_rot`` until it settles (within
    :data:`ORIENTATION_SCALE_RANGE`; the result's measurement carries the final weight and
    ``uncertainty.component_std`` both σ̂). Given, the weight stays as it is.
    ``sample_error`` is the position error norm (mm).

    Attributes:
        orientation_scale: the weight (mm/rad), a run-time scalar: refits with another weight run
            the same compiled program.
        orientation_scale_given: whether the weight was given (static).
        tip: the tip of a :class:`~jaxcal.KinematicTree` whose pose is measured (static;
            ``None``: the robot's default tip): its link frame's orientation, origin at its tool
            point (the ``tool@<tip>`` group, :meth:`extra_groups`).
    """

    rotation: Float[Array, "3 3"]
    translation: Float[Array, " 3"]
    orientation_scale: Float[Array, ""]
    orientation_scale_given: bool = eqx.field(static=True, default=True)
    tip: str | None = eqx.field(static=True, default=None)
    kind: ClassVar[str] = "pose"
    known_setup: ClassVar[tuple[tuple[str, ...], str, str] | None] = (("base",), "the sensor frame was", "--estimate base")
    row_error: ClassVar[str] = ("a row's error is the 3-D distance of its position part: about √3·σ = 1.73·σ at the "
                                "floor for a noise σ per axis")
    error_entries: ClassVar[int | None] = 3
    reading_words: ClassVar[str] = "positions"
    initialisable: ClassVar[tuple[str, ...]] = ("base", "tool")
    size: ClassVar[int] = 6
    sample_shape: ClassVar[tuple[int, ...]] = (4, 4)
    components: ClassVar[tuple[tuple[str, str, int, int], ...]] = (("position", "mm", 0, 3),
                                                                  ("orientation", "rad", 3, 6))

    def readings_mm(self, y) -> np.ndarray:
        """The measured positions ``[n, 3]`` (mm) of the poses ``y`` ``[n, 4, 4]``."""
        return np.asarray(y, np.float64)[:, :3, 3]

    def __init__(self, orientation_scale: float | None = None, rotation=None, translation=None,
                 tip: str | None = None):
        self.tip = tip
        given = orientation_scale is not None
        scale = float(DEFAULT_ORIENTATION_SCALE if orientation_scale is None else orientation_scale)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"orientation_scale must be a positive weight in mm/rad, got {orientation_scale!r}")
        self.orientation_scale = to_device(np.asarray(scale, np.float64))
        self.orientation_scale_given = given
        self.rotation, self.translation = _check_frame(rotation, translation)

    def extra_groups(self) -> tuple[Group, ...]:
        """``tool@<tip>`` for a tip other than the default one, else none."""
        return tip_groups(self.tip)

    @host_method
    def component_scales(self) -> np.ndarray:
        """``[2]`` what each component's raw residual is multiplied by: 1 (mm) and the weight
        (mm/rad)."""
        return np.asarray([1.0, float(self.orientation_scale)])

    @host_method
    def estimates_weights(self) -> bool:
        """Whether :func:`jaxcal.calibrate` estimates the components' σ and reweights."""
        return not self.orientation_scale_given

    @host_method
    def reweighted(self, sigma) -> Pose:
        """This model with ``orientation_scale = σ_pos / σ_rot`` (``sigma``: ``[2]`` mm, rad),
        clipped to :data:`ORIENTATION_SCALE_RANGE`; the flag ``orientation_scale_given`` kept."""
        lo, hi = ORIENTATION_SCALE_RANGE
        w = float(np.clip(sigma[0] / sigma[1], lo, hi)) if sigma[1] > 0 else hi
        return eqx.tree_at(lambda m: m.orientation_scale, self, to_device(np.asarray(w, np.float64)))

    def predict(self, robot, deviations, q) -> Float[Array, "n 4 4"]:
        from .._models._kinematics import fk_pose

        q = check_joint_angles(robot, q)
        T = fk_pose(robot, q, deviations, tool=True, tip=self.tip_for(robot))
        R, t = _sensor_frame(self, deviations, T.dtype)
        top = jnp.concatenate([R @ T[..., :3, :3], (T[..., :3, 3] @ R.T + t)[..., None]], axis=-1)
        return jnp.concatenate([top, T[..., 3:, :]], axis=-2)

    def residual(self, robot, deviations, q, y) -> Float[Array, "n 6"]:
        q = check_joint_angles(robot, q)
        tip = self.tip_for(robot)
        frame = _chain(robot, deviations, q, tip)
        p = jnp.stack(_tool_offset(robot, deviations, frame, q.dtype, tip), axis=-1)
        Rp = jnp.stack([jnp.stack(c, -1) for c in frame[:3]], axis=-1)  # [n,3,3]
        R, t = _sensor_frame(self, deviations, q.dtype)
        # residual in the sensor frame: position R·p + t − p_m; orientation of R·R_p vs R_m
        p = p @ R.T + t
        Rp = jnp.einsum("ij,njk->nik", R, Rp)
        Rm, pm = y[:, :3, :3], y[:, :3, 3]
        E = jnp.einsum("nji,njk->nik", Rm, Rp)  # R_mᵀ R_p
        w = 0.5 * jnp.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]], -1)
        return jnp.concatenate([p - pm, self.orientation_scale.astype(w.dtype) * w], axis=-1)

    def sample_error(self, residual):
        return jnp.linalg.norm(residual[:, :3], axis=-1)


def marker_group(k: int) -> Group:
    """The extra group ``marker_k`` (``k`` = 1..N): the deviation of marker ``k``'s position from
    its nominal position in the flange frame, entries ``marker_k_x/y/z`` (mm)."""
    return Group.vector(f"marker_{k}", (f"marker_{k}_x", f"marker_{k}_y", f"marker_{k}_z"), "mm")


class MarkerModel(MeasurementModel):
    """Shared by the marker models (:class:`Markers`, :class:`~jaxcal.SessionMarkers`): ``N``
    markers per sample, readings ``[n, N, 3]`` mm, residual ``[n, 3N]``; the sample error is the
    RMS over the sample's markers of the 3-D distance error (mm)."""

    initialisable: ClassVar[tuple[str, ...]] = ("base", "markers")
    sees_tool_point: ClassVar[bool] = False
    reading_words: ClassVar[str] = "positions"
    point_entries: ClassVar[int | None] = 3  # a marker's x, y, z: the outlier scan judges each marker
    point_word: ClassVar[str] = "marker"

    @property
    @abc.abstractmethod
    def n_markers(self) -> int:
        """Markers per sample."""

    @property
    def size(self) -> int:  # type: ignore[override]
        return 3 * self.n_markers

    @property
    def sample_shape(self) -> tuple[int, ...]:  # type: ignore[override]
        return (self.n_markers, 3)

    def sample_error(self, residual) -> Float[Array, " n"]:
        r = residual.reshape(residual.shape[0], self.n_markers, 3)
        return jnp.sqrt(jnp.mean(jnp.sum(r * r, axis=-1), axis=-1))

    @host_method
    def takes_extra(self, flag: str, name: str) -> bool:
        if flag == "tool":
            raise ValueError("extra 'tool' does not apply to marker data: the marker positions (marker_k groups) "
                             "are the tool; Markers(known=False) calibrates them")
        return super().takes_extra(flag, name)


class Markers(MarkerModel):
    """Positions of ``N`` markers fixed on the end effector, seen by a motion-capture system or a
    laser tracker, ``[n, N, 3]`` mm in the sensor's frame:
    ``y_ik = R·(P_i + F_i·m_k) + t`` with ``(P_i, F_i)`` the flange origin and orientation in the
    base frame, ``m_k`` marker ``k``'s position in the flange frame and ``(R, t) = T_sensor_base``
    (as in :class:`Position`; its correction is the ``base`` extras).

    With ``known=False`` (default) every marker position is calibrated: the model adds the extra
    groups ``marker_1 … marker_N`` (``marker_k_x/y/z``, mm, deviations from ``positions_mm``),
    free by default; :func:`jaxcal.initial_extras` starts them (and the sensor frame) in closed
    form. With ``known=True`` the layout is taken as exact and the model adds no groups. The
    robot's tool point (``tool`` extras) is not used: the markers are the tool.

    The residual per sample is ``[n, 3N]`` (marker 1's x, y, z, marker 2's ...) mm;
    ``sample_error`` is the RMS over the sample's markers of the per-marker distance error,
    ``sqrt(mean_k ‖ŷ_ik − y_ik‖²)`` (mm), so the RMSE over samples is the RMS distance error
    over every marker reading.

    Attributes:
        positions: ``[N, 3]`` nominal marker positions in the flange (tool) frame (mm).
        rotation: ``[3, 3]`` nominal ``R_sensor_base``; translation: ``[3]`` mm.
        known: whether the marker positions are exact (static).
        tip: the tip of a :class:`~jaxcal.KinematicTree` that carries the markers (static;
            ``None``: the robot's default tip); the positions are in its tip link frame.
    """

    positions: Float[Array, "N 3"]
    rotation: Float[Array, "3 3"]
    translation: Float[Array, " 3"]
    known: bool = eqx.field(static=True, default=False)
    tip: str | None = eqx.field(static=True, default=None)
    kind: ClassVar[str] = "markers"

    def __init__(self, positions_mm, known: bool = False, rotation=None, translation=None, tip: str | None = None):
        self.tip = tip
        pos = jnp.asarray(positions_mm)
        if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] < 1:
            raise ValueError(f"positions_mm must be [N, 3] marker positions in the flange frame (mm), N >= 1; "
                             f"got shape {tuple(pos.shape)}")
        if not np.all(np.isfinite(np.asarray(pos))):
            raise ValueError("positions_mm contain NaN/inf")
        if not jnp.issubdtype(pos.dtype, jnp.floating):
            pos = pos.astype(jnp.result_type(float))
        self.positions = pos
        self.known = bool(known)
        self.rotation, self.translation = _check_frame(rotation, translation)

    @property
    def n_markers(self) -> int:
        return int(self.positions.shape[0])

    def expected_points(self) -> int | None:
        return self.n_markers

    @host_method
    def check_measurements(self, y, n: int) -> None:
        """``[n, N, 3]`` and finite: a missing marker (NaN) is masked by
        :class:`~jaxcal.SessionMarkers` (data with session labels), not by this model."""
        if np.shape(y) == (n, *self.sample_shape) and np.isnan(np.asarray(y)).any():
            rows = np.flatnonzero(np.isnan(np.asarray(y)).reshape(n, -1).any(axis=1))
            raise ValueError(f"markers measurements have missing markers (NaN) at samples {rows[:10].tolist()}: "
                             "Markers needs every marker in every row; SessionMarkers (data with a session/"
                             "placement label) masks missing markers")
        super().check_measurements(y, n)

    def extra_groups(self) -> tuple[Group, ...]:
        """``marker_1 … marker_N`` unless the positions are known."""
        return () if self.known else tuple(marker_group(k + 1) for k in range(self.n_markers))

    def nominal_lengths(self) -> dict[str, float]:
        return {n: v for k, row in enumerate(np.asarray(self.positions, np.float64))
                for n, v in xyz_entries(f"marker_{k + 1}_", row).items()}

    def marker_points(self, deviations: Deviations | None, dtype=None) -> Float[Array, "N 3"]:
        """Marker positions in the flange frame, nominal + the ``marker_k`` deviations (mm)."""
        m = self.positions if dtype is None else self.positions.astype(dtype)
        if deviations is None or self.known:
            return m
        vals = deviations.values
        rows = [m[k] + jnp.asarray(vals[f"marker_{k + 1}"]).astype(m.dtype) if f"marker_{k + 1}" in vals else m[k]
                for k in range(self.n_markers)]
        return jnp.stack(rows)

    def predict(self, robot, deviations, q) -> Float[Array, "n N 3"]:
        """Marker positions ``[n, N, 3]`` in the sensor frame (mm)."""
        q = check_joint_angles(robot, q)
        X, Y, Z, P = _chain(robot, deviations, q, self.tip_for(robot))
        m = self.marker_points(deviations, q.dtype)
        R, t = _sensor_frame(self, deviations, q.dtype)
        base = [jnp.stack([P[c] + m[k, 0] * X[c] + m[k, 1] * Y[c] + m[k, 2] * Z[c] for c in range(3)], -1)
                for k in range(self.n_markers)]  # N × [n, 3], base frame
        return jnp.stack([p @ R.T + t for p in base], axis=1)


def predict(measurement: MeasurementModel, robot: AbstractRobot, deviations: Deviations | None, q):
    """The sensor reading ``measurement`` predicts (same as ``measurement.predict``)."""
    return measurement.predict(robot, deviations, q)


def residuals(
    measurement: MeasurementModel,
    robot: AbstractRobot,
    deviations: Deviations | None,
    q: Float[Array, "n dof"],
    y,
) -> Float[Array, " n*m"]:
    """Flat residual vector ``prediction − measured``, ``[n·m]`` (mm).

    Pure and jittable; ``jax.jacfwd`` of this w.r.t. the free parameters is the
    identification Jacobian (the paper's ``U`` in eq. 5).
    """
    return measurement.residual(robot, deviations, q, y).reshape(-1)


def default_anchor(robot: AbstractRobot) -> Array:
    """A draw-wire anchor on the base plane in front of the robot: ``(reach/2, 0, 0)`` mm (the
    start of an anchor estimated from the data, and the simulations' anchor)."""
    return to_device([0.5 * robot.reach_mm(), 0.0, 0.0], np.float64)


def tip_to_dict(model) -> dict:
    """``{"tip": name}`` of a model that sees a tip other than the robot's default one, else ``{}``
    (a serial robot's result files are as before)."""
    return {} if getattr(model, "tip", None) is None else {"tip": str(model.tip)}


def frame_to_dict(model) -> dict:
    """A sensor frame as plain data: ``{"rotation": R [3, 3], "translation_mm": t [3]}`` (the
    nominal sensor-from-base transform of :class:`Position`, :class:`Pose`, :class:`Markers`)."""
    return {"rotation": np.asarray(model.rotation, np.float64).tolist(),
            "translation_mm": np.asarray(model.translation, np.float64).tolist()}


def frame_from_dict(d: dict) -> dict:
    """``{"rotation", "translation"}`` keywords of :func:`frame_to_dict`'s plain data (identity where absent)."""
    return {"rotation": to_device(np.asarray(d.get("rotation", np.eye(3)), np.float64)),
            "translation": to_device(np.asarray(d.get("translation_mm", np.zeros(3)), np.float64))}


# -- the data-file form of the draw wire, the tracker and the pose sensor ------------------------
@register_kind
class CableKind(SensorKind):
    """Draw-wire data (:class:`CableLength`): column ``length_mm``, readings ``[n]`` mm."""

    name = "cable"
    columns = ("length_mm",)
    fleet = True
    simulator = "jaxcal._simulation._simulate_files:cable_file"
    messy = "jaxcal._simulation._messy:CABLE_SESSION"

    def check_options(self, estimate, options):
        self.refuse_point_options(options)
        self.check_estimate_names(estimate - {"anchor", "offset", "cable_offset"})
        if "base" in estimate:
            raise ValueError("--estimate base applies to --measurement position only")

    def required_extras(self, estimate, *, anchor_known=True, **_):
        estimate = set(estimate)
        if anchor_known:
            return estimate, []
        # nothing known about the anchor: estimate it (and the cable offset) from the data
        return estimate | {"anchor", "offset"}, [
            "no --anchor given and none in the file: the anchor and the cable offset are estimated from the data "
            "(multilateration on the nominal robot, then the joint fit)"]

    def model_to_dict(self, model):
        return {"kind": "cable", "anchor_mm": np.asarray(model.anchor, np.float64).tolist()} | tip_to_dict(model)

    def plan_lines(self, model):
        return {"anchor_mm": ",".join(f"{float(v):.6g}" for v in model.anchor)}

    def model_from_dict(self, d):
        return CableLength(to_device(np.asarray(d["anchor_mm"], np.float64)), tip=d.get("tip"))

    def default_model(self, robot, *, data=None, anchor_mm=None, n_markers=None):
        if anchor_mm is None:
            return CableLength(default_anchor(robot))
        return CableLength(to_device(anchor_mm))  # as jnp.asarray, without a compiled conversion program

    def setup(self, data, robot, estimate, options):
        from .._core._csvfile import number_list

        self.check_options(estimate, options)
        anchor = options.anchor_mm
        if anchor is None and "anchor_mm" in data.meta:
            anchor = number_list(data.meta["anchor_mm"], 3, "the file's anchor_mm")
        estimate, notes = self.required_extras(estimate, anchor_known=anchor is not None)
        return self.default_model(robot, anchor_mm=anchor), estimate, notes


@register_kind
class PositionKind(SensorKind):
    """Tool positions (:class:`Position`, a laser tracker): columns ``x_mm, y_mm, z_mm``,
    readings ``[n, 3]`` mm in the sensor frame."""

    name = "position"
    columns = ("x_mm", "y_mm", "z_mm")
    fleet = True
    simulator = "jaxcal._simulation._simulate_files:experiment_file"
    messy = "jaxcal._simulation._messy:TRACKER_SESSION"

    def model_to_dict(self, model):
        return {"kind": "position"} | frame_to_dict(model) | tip_to_dict(model)

    def model_from_dict(self, d):
        return Position(**frame_from_dict(d), tip=d.get("tip"))

    def default_model(self, robot, *, data=None, anchor_mm=None, n_markers=None):
        self.refuse_anchor(anchor_mm)
        return Position()


@register_kind
class PoseKind(SensorKind):
    """Tool poses (:class:`Pose`): columns ``x_mm, y_mm, z_mm`` and a rotation vector
    ``rx_deg, ry_deg, rz_deg`` (degrees at the file's edge), readings ``[n, 4, 4]`` homogeneous
    transforms (mm, rad inside)."""

    name = "pose"
    columns = ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")
    fleet = True
    simulator = "jaxcal._simulation._simulate_files:pose_file"

    def model_to_dict(self, model):
        # the weight the fit used (estimated unless given: read back, it is taken as given)
        return {"kind": "pose", "orientation_scale": float(model.orientation_scale),
                "orientation_scale_estimated": not model.orientation_scale_given} | frame_to_dict(model) | tip_to_dict(model)

    def model_from_dict(self, d):
        return Pose(orientation_scale=float(d.get("orientation_scale", 1000.0)), **frame_from_dict(d), tip=d.get("tip"))

    def default_model(self, robot, *, data=None, anchor_mm=None, n_markers=None):
        self.refuse_anchor(anchor_mm)
        return Pose()

    def readings(self, values, path, table, meta):
        y = np.zeros((values.shape[0], 4, 4))
        y[:, :3, :3] = rotvec_to_matrix_np(np.deg2rad(values[:, 3:6]))
        y[:, :3, 3] = values[:, :3]
        y[:, 3, 3] = 1.0
        return y, meta, ()

    def write_values(self, data):
        y = np.asarray(data.y, np.float64)
        vals = np.concatenate([y[:, :3, 3], np.rad2deg(matrix_to_rotvec(y[:, :3, :3]))], axis=1)
        return list(self.columns), vals, [], [[] for _ in range(y.shape[0])]

    def sample_shape(self, dof):
        return (4, 4)

