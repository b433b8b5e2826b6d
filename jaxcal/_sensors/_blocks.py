"""Several data blocks in one fit, and known relations between their extras (issue 34).

A real cell combines sensors: plane contact and a distance bar, a tracker and a camera, pivot
points and a known socket distance. :class:`Combined` is one measurement model over named
**blocks**, each a measurement model with its own rows, so that :func:`jaxcal.calibrate` and
everything behind it (identifiability, priors, robust losses, buckets, uncertainty) see one
problem:

* ``q`` is the blocks' joint angles stacked ``[N, dof]`` (``N = Σ n_b``), block after block;
* ``y`` is ``[N, W]``: each row holds its block's reading flattened (a label index, a wire
  length, a 4×4 pose's 16 entries, a camera image's ``2N`` pixel values...), padded with zeros to
  the widest block's ``W`` entries;
* the residual is ``[N, m]`` with ``m`` the largest residual size of the blocks; each block's
  residual is divided by its noise σ_b (mm, px...: the block's own unit), so the combined
  residual is **whitened** (unitless, ~N(0, 1) per entry at the truth), and padded with zeros;
  :meth:`Combined.observed` marks the real entries, so every statistic (σ̂, robust scales, the
  residual count) counts only those; the residual vector of a fit, its Jacobian and the solves
  hold each row's own entries only (:meth:`Combined.residual_entries`), not the padding.

The robot's parameters are shared. Extras (see :func:`combine`): a labelled group (``plane@K``,
``point@K``, ``radius@K``, session groups) names one physical object and is shared by every
block with that label; the tool point ``tool`` is shared (one probe/ball/SMR on the flange)
unless a block says ``own_tool``, and so is the tool point of another tip of a kinematic tree
(``tool@<tip>``: every block that sees that tip, self-contact included); the sensor-frame groups (``anchor``, ``cable_offset``,
``base_rotation``, ``base_translation``) and a measurement's own unlabelled groups (``marker_k``,
the camera's ``handeye_*``/``target_*``) are per sensor: used by one block they keep their name,
used by several they are renamed per block, ``base_rotation@tracker`` (entries ``base_rx@tracker``...).

**Relations** (:class:`KnownDistance`, :class:`PlaneDistance`, :class:`PlaneAngle`,
:class:`PointOnPlane`) are geometric facts a user writes down about the labelled extras (two
sockets 50.00 mm apart, a gauge block's faces): one more block, kind ``"relations"``, one row per
relation, residual ``(value(extras) − known)/std`` (already whitened, σ fixed to 1). Its rows'
joint angles are unused (the middle of the joint ranges). With a known length, plane and point
data see the robot's length scale (:mod:`jaxcal._sensors._contact`).

References: Förstner, W. (1979), "Ein Verfahren zur Schätzung von Varianz- und
Kovarianzkomponenten", Allgemeine Vermessungs-Nachrichten 86; Koch, K.-R. (1999), *Parameter
Estimation and Hypothesis Testing in Linear Models*, 2nd ed., Springer, §3.6 (variance
components by the blocks' redundancy numbers, used by :func:`jaxcal.calibrate_blocks`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._host_method import host_method
from .._core._params import STANDARD_EXTRAS, Deviations, Group, layout_for
from .._core._precision import to_device
from .._models._tree import tool_group_name
from ._contact import FixedPoint, PlaneContact, _per_label
from ._kind import check_label
from ._measurement import MeasurementModel

__all__ = ["Block", "Combined", "Relations", "KnownDistance", "PlaneDistance", "PlaneAngle", "PointOnPlane",
           "combine", "SENSOR_GROUPS", "load_relations", "parse_relation"]

#: the standard extras that belong to one sensor (renamed per block when several blocks use them)
SENSOR_GROUPS = ("anchor", "cable_offset", "base_rotation", "base_translation")
#: the standard extras each measurement kind reads (the others of a block's layout stay unused)
_USES = {"cable": {"anchor", "cable_offset", "tool"}, "position": {"base_rotation", "base_translation", "tool"},
         "pose": {"base_rotation", "base_translation", "tool"}, "markers": {"base_rotation", "base_translation"},
         "camera": set(), "plane": {"tool"}, "point": {"tool"}, "distance": {"tool"}}


# -- relations ------------------------------------------------------------------------------------
class _Relation:
    """What every relation shares: the labelled extras it reads (``_labels``: ``(kind, field)``
    pairs, e.g. ``("point", "point_a")``), its known value and σ (the fields ``_target`` and
    ``_std``, in mm; ``_angle``: degrees there, radians inside)."""

    _labels: ClassVar[tuple[tuple[str, str], ...]]
    _target: ClassVar[str]
    _std: ClassVar[str] = "std_mm"
    _angle: ClassVar[bool] = False
    #: whether the known value may be 0 (a point on a plane), else it must be > 0
    _allow_zero: ClassVar[bool] = False

    def __post_init__(self):
        _check_relation(self, tuple(getattr(self, f) for _, f in self._labels), getattr(self, self._target),
                        getattr(self, self._std), allow_zero=self._allow_zero)

    @property
    def labels(self) -> tuple[tuple[str, str], ...]:
        return tuple((kind, getattr(self, field)) for kind, field in self._labels)

    @property
    def target(self) -> float:
        v = float(getattr(self, self._target))
        return math.radians(v) if self._angle else v

    @property
    def std(self) -> float:
        v = float(getattr(self, self._std))
        return math.radians(v) if self._angle else v


@dataclasses.dataclass(frozen=True)
class KnownDistance(_Relation):
    """The distance between two labelled fixed points (:class:`~jaxcal.FixedPoint` labels: two
    sockets of a plate, two spheres of an artefact) is ``distance_mm`` ± ``std_mm``.

    Residual ``(‖c_a − c_b‖ − distance_mm)/std_mm`` (unitless), ``c`` the calibrated centres
    (nominal + ``point@label``, base frame, mm)."""

    point_a: str
    point_b: str
    distance_mm: float
    std_mm: float = 0.005
    kind: ClassVar[str] = "point_distance"
    _labels = (("point", "point_a"), ("point", "point_b"))
    _target = "distance_mm"

    def value(self, geo) -> Array:
        ca, cb = geo[("point", self.point_a)], geo[("point", self.point_b)]
        return jnp.sqrt(jnp.sum((ca - cb) ** 2))

    def describe(self) -> str:
        return f"distance {self.point_a}–{self.point_b} = {self.distance_mm:g} ± {self.std_mm:g} mm"


@dataclasses.dataclass(frozen=True)
class PlaneDistance(_Relation):
    """Two (nearly) parallel labelled planes (:class:`~jaxcal.PlaneContact` labels: a gauge
    block's faces, a step) are ``distance_mm`` ± ``std_mm`` apart.

    Value ``|s·d_b − d_a|`` with ``s = n_a·n_b`` (≈ ±1: the normals may point the same way or
    against each other, e.g. a block's outward faces), ``d`` the planes' offsets (mm): the
    distance along ``n_a`` between the planes at the point of plane *b* nearest the origin."""

    plane_a: str
    plane_b: str
    distance_mm: float
    std_mm: float = 0.005
    kind: ClassVar[str] = "plane_distance"
    _labels = (("plane", "plane_a"), ("plane", "plane_b"))
    _target = "distance_mm"

    def value(self, geo) -> Array:
        (na, da), (nb, db) = geo[("plane", self.plane_a)], geo[("plane", self.plane_b)]
        return jnp.abs(jnp.dot(na, nb) * db - da)

    def describe(self) -> str:
        return f"planes {self.plane_a}–{self.plane_b} {self.distance_mm:g} ± {self.std_mm:g} mm apart"


@dataclasses.dataclass(frozen=True)
class PlaneAngle(_Relation):
    """The angle between two labelled planes' normals is ``angle_deg`` ± ``std_deg`` (a cube's
    faces: 90°). Value ``atan2(‖n_a × n_b‖, n_a·n_b)`` (rad inside; degrees only here, at the
    edge)."""

    plane_a: str
    plane_b: str
    angle_deg: float
    std_deg: float = 0.005
    kind: ClassVar[str] = "plane_angle"
    _labels = (("plane", "plane_a"), ("plane", "plane_b"))
    _target, _std, _angle = "angle_deg", "std_deg", True

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 < self.angle_deg < 180.0:
            raise ValueError(f"PlaneAngle: angle_deg must be strictly between 0 and 180 (the angle is not "
                             f"differentiable at 0/180°; parallel planes: PlaneDistance), got {self.angle_deg}")


    def value(self, geo) -> Array:
        na, nb = geo[("plane", self.plane_a)][0], geo[("plane", self.plane_b)][0]
        return jnp.arctan2(jnp.linalg.norm(jnp.cross(na, nb)), jnp.dot(na, nb))

    def describe(self) -> str:
        return f"angle {self.plane_a}–{self.plane_b} = {self.angle_deg:g} ± {self.std_deg:g}°"


@dataclasses.dataclass(frozen=True)
class PointOnPlane(_Relation):
    """A labelled fixed point lies on a labelled plane (± ``std_mm``): residual
    ``(n·c − d)/std_mm``; ``offset_mm`` for a point a known distance above the plane (a ball's
    centre: its radius)."""

    point: str
    plane: str
    std_mm: float = 0.005
    offset_mm: float = 0.0
    kind: ClassVar[str] = "point_on_plane"
    _labels = (("point", "point"), ("plane", "plane"))
    _target = "offset_mm"
    _allow_zero = True

    def value(self, geo) -> Array:
        c = geo[("point", self.point)]
        n, d = geo[("plane", self.plane)]
        return jnp.dot(n, c) - d

    def describe(self) -> str:
        return f"point {self.point} on plane {self.plane}" + (f" + {self.offset_mm:g} mm" if self.offset_mm else "")


RELATIONS = (KnownDistance, PlaneDistance, PlaneAngle, PointOnPlane)
#: the relation file's keywords → (class, number of labels, number of numbers required, allowed)
_KEYWORDS = {"distance": (KnownDistance, 2, (1, 2)), "plane_distance": (PlaneDistance, 2, (1, 2)),
             "plane_angle": (PlaneAngle, 2, (1, 2)), "point_on_plane": (PointOnPlane, 2, (0, 2))}


def parse_relation(line: str, where: str = "relation"):
    """One relation from a line of a relations file (see :func:`load_relations`)."""
    parts = line.replace(",", " ").split()
    if not parts or parts[0].lower() not in _KEYWORDS:
        raise ValueError(f"{where}: expected one of {', '.join(_KEYWORDS)} followed by two labels and numbers, "
                         f"got {line.strip()!r}")
    cls, n_labels, (lo, hi) = _KEYWORDS[parts[0].lower()]
    labels, nums = parts[1:1 + n_labels], parts[1 + n_labels:]
    if len(labels) != n_labels or not lo <= len(nums) <= hi:
        raise ValueError(f"{where}: {parts[0]} takes {n_labels} labels and {lo}–{hi} numbers, got {line.strip()!r}")
    try:
        values = [float(v) for v in nums]
    except ValueError:
        raise ValueError(f"{where}: not a number in {line.strip()!r}") from None
    return cls(*labels, *values)  # point_on_plane POINT PLANE [std_mm [offset_mm]]; the others A B value [std]


def load_relations(path) -> list:
    """Relations from a small text file, one per line (``#`` starts a comment; commas or spaces):

    ``distance A B L_mm [std_mm]`` — :class:`KnownDistance` between fixed points ``A`` and ``B``;
    ``plane_distance A B L_mm [std_mm]`` — :class:`PlaneDistance`;
    ``plane_angle A B angle_deg [std_deg]`` — :class:`PlaneAngle`;
    ``point_on_plane POINT PLANE [std_mm [offset_mm]]`` — :class:`PointOnPlane`.

    The labels are the point / plane labels of the data files (their ``point`` / ``plane`` column)."""
    out = []
    with open(path, encoding="utf-8") as f:
        for i, raw in enumerate(f, 1):
            line = raw.split("#", 1)[0].strip()
            if line:
                out.append(parse_relation(line, f"{path}, line {i}"))
    if not out:
        raise ValueError(f"{path}: no relations found")
    return out


def _check_relation(rel, labels, value, std, allow_zero: bool = False) -> None:
    for s in labels:
        check_label(s)
    if labels[0] == labels[1]:
        raise ValueError(f"{type(rel).__name__}: the two labels must differ, got {labels[0]!r} twice")
    if not (isinstance(value, (int, float)) and math.isfinite(value) and (allow_zero or value > 0)):
        raise ValueError(f"{type(rel).__name__}: the known value must be a finite number"
                         f"{'' if allow_zero else ' > 0'}, got {value!r}")
    if not (isinstance(std, (int, float)) and math.isfinite(std) and std > 0):
        raise ValueError(f"{type(rel).__name__}: std must be a finite number > 0, got {std!r}")


class Relations(MeasurementModel):
    """Known relations between labelled extras as a measurement model: one row per relation,
    reading ``y`` ``[n]`` the known values (mm, rad), residual ``[n, 1]``
    ``(value − known)/std`` (unitless). The relations' joint angles are not used.

    Attributes:
        sources: the :class:`~jaxcal.FixedPoint` / :class:`~jaxcal.PlaneContact` models that hold
            the labels' nominal geometry (one per label kind and block, in block order).
        relations: the relation objects (static).
    """

    sources: tuple
    relations: tuple = eqx.field(static=True)
    kind: ClassVar[str] = "relations"
    size: ClassVar[int] = 1
    sample_shape: ClassVar[tuple[int, ...]] = ()

    def __init__(self, relations: Sequence, sources: Sequence[MeasurementModel]):
        self.relations = tuple(relations)
        self.sources = tuple(sources)
        have = self._owner()
        for r in self.relations:
            if not isinstance(r, RELATIONS):
                raise TypeError(f"a relation must be one of {[c.__name__ for c in RELATIONS]}, got {type(r).__name__}")
            for what, label in r.labels:
                if (what, label) not in have:
                    known = sorted(lab for w, lab in have if w == what)
                    raise ValueError(f"relation '{r.describe()}' names {what} {label!r}, which no block has; "
                                     f"{what} labels of the blocks: {known or 'none'}")

    def _owner(self) -> dict:
        out = {}
        for i, m in enumerate(self.sources):
            what = "plane" if isinstance(m, PlaneContact) else "point"
            for k, s in enumerate(m.labels):
                out.setdefault((what, s), (i, k))
        return out

    def geometry(self, deviations: Deviations | None, dtype) -> dict:
        """``{("point", label): c [3]}`` and ``{("plane", label): (n [3], d [])}`` of the labels the
        relations name (base frame, mm), nominal + deviations."""
        owner = self._owner()
        geo = {}
        for r in self.relations:
            for key in r.labels:
                if key in geo:
                    continue
                i, k = owner[key]
                m = self.sources[i]
                if key[0] == "point":
                    c = m.centres.astype(dtype)[k]
                    if deviations is not None:
                        c = c + _per_label(deviations, "point", (key[1],), dtype)[0]
                    geo[key] = c
                else:
                    n, d = m.planes(deviations, dtype)
                    geo[key] = (n[k], d[k])
        return geo

    def values(self, deviations: Deviations | None, dtype=None) -> Float[Array, " n"]:
        """The relations' current values ``[n]`` (mm; rad for angles)."""
        dtype = jnp.result_type(float) if dtype is None else dtype
        geo = self.geometry(deviations, dtype)
        return jnp.stack([r.value(geo) for r in self.relations])

    def stds(self, dtype=None) -> Float[Array, " n"]:
        return jnp.asarray([r.std for r in self.relations], jnp.result_type(float) if dtype is None else dtype)

    def targets(self) -> np.ndarray:
        """``[n]`` the known values (mm; rad for angles): the reading ``y``."""
        return np.asarray([r.target for r in self.relations], np.float64)

    def predict(self, robot, deviations, q) -> Float[Array, " n"]:
        return self.values(deviations, jnp.asarray(q).dtype)

    def residual(self, robot, deviations, q, y) -> Float[Array, "n 1"]:
        dtype = jnp.asarray(q).dtype
        v = self.values(deviations, dtype)
        return ((v - jnp.asarray(y, dtype).reshape(-1)) / self.stds(dtype))[:, None]

    @host_method
    def check_measurements(self, y, n: int) -> None:
        super().check_measurements(y, n)
        if n != len(self.relations):
            raise ValueError(f"{len(self.relations)} relations but {n} rows")


# -- blocks ---------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True, eq=False)
class Block:
    """One data block of a combined fit.

    Attributes:
        name: the block's name (a label: letters, digits, ``_``, ``-``, ``.``), used for its
            statistics and for its renamed extras (``base_rotation@name``).
        measurement: its measurement model.
        data: a :class:`~jaxcal.Dataset` of that kind or a ``(q [n, dof] rad, y)`` pair.
        sigma: its noise σ per residual entry in the block's unit (mm; px for a camera), or
            ``None``: estimated from the data (variance components, :func:`jaxcal.calibrate_blocks`).
        extras: the standard extras this block estimates (``"tool"``, ``"base"``, ``"anchor"``,
            ``"cable_offset"``), as :func:`jaxcal.calibrate`'s ``extras``; a measurement's own
            groups (planes, points, markers, hand-eye) are free as they are alone.
        own_tool: this block's tool point is not the shared one (another probe): its own
            ``tool@name`` group.
    """

    name: str
    measurement: MeasurementModel
    data: object
    sigma: float | None = None
    extras: tuple = ()
    own_tool: bool = False

    def __post_init__(self):
        check_label(self.name)
        if not isinstance(self.measurement, MeasurementModel) or isinstance(self.measurement, (Combined, Relations)):
            raise TypeError(f"block {self.name!r}: measurement must be a sensor's measurement model, "
                            f"got {type(self.measurement).__name__}")
        if self.sigma is not None and not (math.isfinite(self.sigma) and self.sigma > 0):
            raise ValueError(f"block {self.name!r}: sigma must be a finite number > 0 or None, got {self.sigma!r}")
        extras = self.extras
        if isinstance(extras, str):
            extras = tuple(e.strip() for e in extras.split(",") if e.strip())
        object.__setattr__(self, "extras", tuple(extras))

    def arrays(self):
        """``(q [n, dof], y)`` host arrays of the block's data."""
        data = self.data
        if hasattr(data, "q"):
            if getattr(data, "kind", self.measurement.kind) != self.measurement.kind:
                raise ValueError(f"block {self.name!r}: data are {data.kind!r} readings but the measurement model is "
                                 f"{self.measurement.kind!r}")
            return np.asarray(data.q, np.float64), np.asarray(data.y, np.float64)
        if isinstance(data, (tuple, list)) and len(data) == 2:
            return np.asarray(data[0], np.float64), np.asarray(data[1], np.float64)
        raise TypeError(f"block {self.name!r}: data must be a jaxcal.Dataset or a (q, y) pair")


def _renamed(g: Group, block: str) -> Group:
    return Group(f"{g.name}@{block}", tuple(f"{n}@{block}" for n in g.names), g.units, g.kind, g.shape, g.prior_std)


class Combined(MeasurementModel):
    """Several measurement models over stacked rows, one whitened residual (kind ``"blocks"``).
    Build it with :func:`combine`.

    ``q`` is the blocks' joint angles stacked ``[N, dof]`` block after block; ``y`` is ``[N, W]``,
    each row its block's reading flattened (a label index, a wire length, a pose's 16 entries, a
    camera image's pixels...) and padded with zeros to the widest block's ``W``. The residual is
    ``[N, m]`` (``m`` the largest block residual size): each block's residual divided by its noise
    σ_b (in the block's own unit), so the whole is unitless and ~N(0, 1) per entry at the truth,
    zero-padded; :meth:`observed` marks the real entries, and every statistic counts only those. The
    padding never enters a solve: :meth:`residual_entries` names each row's own entries, and
    :meth:`jaxcal.Problem.residual` and its Jacobian hold those only.
    The robot's parameters are shared; a labelled extra (``plane@K``, ``point@K``...) is shared by
    every block with that label, the tool point by all blocks unless one says ``own_tool``, and a
    sensor's own groups (``anchor``, ``base_rotation``, ``handeye_*``...) are renamed per block
    when several blocks have them (``base_rotation@tracker``). Relations (:class:`KnownDistance`
    ...) are one more block, kind ``"relations"``, already whitened (σ = 1).

    Attributes:
        models: the blocks' measurement models (the relations last, if any).
        sigma: ``[B]`` each block's noise σ in its own unit (1 for the relations: whitened there).
        names: the block names (static); counts: their rows; widths: their flattened reading sizes.
        views: per block, ``(its own layout, ((its group, the combined group), ...))`` (static).
        groups: the extra groups the blocks add to the layout (static).
        pad: padding rows at the end (copies of row 0, a block-0 row: shape buckets).
        estimated: per block, whether its σ is estimated from the fit (variance components: a
            :class:`Block` with ``sigma=None``) (static); :func:`jaxcal.calibrate` then refits with
            each such σ re-estimated (:meth:`estimates_weights`) until none moves by more than
            ``sigma_rtol``, at most ``max_rounds`` fits (static).
    """

    models: tuple
    sigma: Float[Array, " B"]
    names: tuple[str, ...] = eqx.field(static=True)
    counts: tuple[int, ...] = eqx.field(static=True)
    widths: tuple[int, ...] = eqx.field(static=True)
    views: tuple = eqx.field(static=True)
    groups: tuple = eqx.field(static=True)
    pad: int = eqx.field(static=True, default=0)
    estimated: tuple[bool, ...] = eqx.field(static=True, default=())
    sigma_rtol: float = eqx.field(static=True, default=0.01)
    max_rounds: int = eqx.field(static=True, default=10)
    kind: ClassVar[str] = "blocks"
    unit: ClassVar[str] = "σ"
    stacked_data: ClassVar[bool] = True  # each block checked by its own model (combine)

    def __init__(self, models, sigma, names, counts, widths, views, groups, pad: int = 0, estimated=(),
                 sigma_rtol: float = 0.01, max_rounds: int = 10):
        self.models, self.names, self.counts = tuple(models), tuple(names), tuple(int(c) for c in counts)
        self.widths, self.views, self.groups, self.pad = tuple(widths), tuple(views), tuple(groups), int(pad)
        # from the host by jax.device_put (jnp.asarray of NumPy runs a small program); a JAX array as it is
        sigma = jnp.asarray(sigma, jnp.result_type(float)) if isinstance(sigma, jax.Array) else to_device(sigma, float)
        self.sigma = sigma.reshape(len(self.models))
        self.estimated = tuple(bool(e) for e in estimated) or (False,) * len(self.models)
        if len(self.estimated) != len(self.models):
            raise ValueError(f"estimated: one flag per block ({len(self.models)}), got {len(self.estimated)}")
        if not (sigma_rtol > 0 and max_rounds >= 1):
            raise ValueError(f"sigma_rtol must be > 0 and max_rounds >= 1, got {sigma_rtol!r}, {max_rounds!r}")
        self.sigma_rtol, self.max_rounds = float(sigma_rtol), int(max_rounds)

    def estimating(self, sigma_rtol: float, max_rounds: int) -> Combined:
        """The same model with other stopping rules of its σ's rounds (:attr:`sigma_rtol`,
        :attr:`max_rounds`)."""
        return Combined(self.models, self.sigma, self.names, self.counts, self.widths, self.views, self.groups,
                        self.pad, self.estimated, sigma_rtol, max_rounds)

    @host_method
    def estimates_weights(self) -> bool:
        """Whether :func:`jaxcal.calibrate` re-estimates block σ between its fits (some block's σ
        was not given)."""
        return any(self.estimated)

    @host_method
    def component_scales(self) -> np.ndarray:
        """``[B]`` what each block's raw residual is multiplied by: ``1/σ_b``."""
        return 1.0 / np.asarray(self.sigma, np.float64)

    @property
    def weights_rtol(self) -> float:  # type: ignore[override]
        return self.sigma_rtol

    @property
    def weight_rounds(self) -> int:  # type: ignore[override]
        return self.max_rounds

    @host_method
    def takes_extra(self, flag: str, name: str) -> bool:
        return True  # several sensors: each block checked its own (jaxcal.Block)

    @host_method
    def sees_group(self, group: str) -> bool:
        return True

    # -- shapes ---------------------------------------------------------------------------------

    @property
    def size(self) -> int:  # type: ignore[override]
        return max(m.size for m in self.models)

    @property
    def sample_shape(self) -> tuple[int, ...]:  # type: ignore[override]
        return (max(self.widths),)

    @property
    def n_rows(self) -> int:
        return sum(self.counts)

    @property
    def fixed_rows(self) -> int:
        """Rows :meth:`sample_error` and :meth:`residual` read (each row its block's): statistics
        that draw residuals (:func:`~jaxcal._fit._diagnostics.robust_consistency`) draw whole copies."""
        return self.n_rows + self.pad

    def extra_groups(self) -> tuple[Group, ...]:
        return self.groups

    def with_sigma(self, sigma) -> Combined:
        """The same blocks with other noise σ ``[B]`` (no recompilation: σ is an array leaf)."""
        return eqx.tree_at(lambda c: c.sigma, self, to_device(np.asarray(sigma, np.float64)))

    def block_index(self, name: str) -> int:
        if name not in self.names:
            raise KeyError(f"no block {name!r}; blocks: {list(self.names)}")
        return self.names.index(name)

    @property
    def relations(self) -> Relations | None:
        return self.models[-1] if isinstance(self.models[-1], Relations) else None

    # -- rows -----------------------------------------------------------------------------------
    def _rows(self, a, total: int):
        """Per block its rows of ``a`` (``[N, ...]``), block 0 with the padding rows at its end."""
        out, s = [], 0
        for b, n in enumerate(self.counts):
            part = a[s:s + n]
            if b == 0 and self.pad:
                part = jnp.concatenate([part, a[total - self.pad:]]) if not isinstance(a, np.ndarray) else \
                    np.concatenate([part, a[total - self.pad:]])
            out.append(part)
            s += n
        return out

    def _join(self, parts, xp=jnp):
        """Inverse of :meth:`_rows`."""
        if self.pad:
            n0 = self.counts[0]
            head, tail = parts[0][:n0], parts[0][n0:]
            return xp.concatenate([head, *parts[1:], tail])
        return xp.concatenate(parts)

    def _y(self, b: int, yb):
        m = self.models[b]
        return yb[:, : self.widths[b]].reshape(yb.shape[0], *m.sample_shape)

    def names_in(self, b: int, layout) -> dict[str, str]:
        """Block ``b``'s parameter names (its own layout) → their names in the combined ``layout``
        (:func:`jaxcal.layout_for` of the robot and this model: a block's renamed extras, e.g. its
        plane offset under the block's label)."""
        own, mapping = self.views[b]
        return {bn: cn for g, c in mapping for bn, cn in zip(own.group(g).names, layout.group(c).names)}

    def view(self, b: int, deviations: Deviations | None) -> Deviations | None:
        """Block ``b``'s deviations in its own layout (its renamed groups under their own names);
        the relations block reads the combined deviations themselves."""
        if deviations is None or self.views[b] is None:
            return deviations
        layout, mapping = self.views[b]
        vals = deviations.values
        return Deviations({g: vals[c] for g, c in mapping}, layout)

    # -- model ----------------------------------------------------------------------------------
    def block_residuals(self, robot, deviations, q, y) -> list:
        """Per block its residual ``[n_b, m_b]`` in its own unit (mm, px; relations: whitened)."""
        q, y = jnp.asarray(q), jnp.asarray(y)
        total = q.shape[0]
        qs, ys = self._rows(q, total), self._rows(y, total)
        return [m.residual(robot, self.view(b, deviations), qs[b], self._y(b, ys[b]))
                for b, m in enumerate(self.models)]

    def _whitened(self, robot, deviations, q, y) -> list:
        """Per block its residual over its σ ``[n_b, m_b]`` (block 0 with the padding rows)."""
        return [r / self.sigma[b].astype(r.dtype) for b, r in enumerate(self.block_residuals(robot, deviations, q, y))]

    def residual(self, robot, deviations, q, y) -> Float[Array, "N m"]:
        """Whitened residual ``[N, m]``: each block's residual over its σ, zero-padded."""
        m = self.size
        return self._join([jnp.pad(r, ((0, 0), (0, m - r.shape[1]))) if r.shape[1] < m else r
                           for r in self._whitened(robot, deviations, q, y)])

    def entry_residual(self, robot, deviations, q, y) -> Float[Array, " k"]:
        """The whitened residual at :meth:`residual_entries`, built from the blocks' own rows (no
        padding made and dropped again)."""
        if self.residual_entries(jnp.shape(q)[0]) is None:
            return self.residual(robot, deviations, q, y).reshape(-1)
        parts = self._whitened(robot, deviations, q, y)
        n0 = self.counts[0]  # block 0's padding rows come last (see _rows)
        return jnp.concatenate([parts[0][:n0].reshape(-1), *(r.reshape(-1) for r in parts[1:]),
                                parts[0][n0:].reshape(-1)])

    def sample_error(self, residual) -> Float[Array, " N"]:
        """Per row its block's sample error of the whitened residual (unitless)."""
        total = residual.shape[0]
        parts = [mod.sample_error(r[:, : mod.size]) for mod, r in zip(self.models, self._rows(residual, total))]
        return self._join(parts)

    def predict(self, robot, deviations, q) -> Float[Array, "N W"]:
        """Per row its block's predicted reading, flattened and zero-padded to ``W``."""
        q = jnp.asarray(q)
        W = self.sample_shape[0]
        parts = []
        for b, (mod, qb) in enumerate(zip(self.models, self._rows(q, q.shape[0]))):
            p = jnp.asarray(mod.predict(robot, self.view(b, deviations), qb)).astype(q.dtype).reshape(qb.shape[0], -1)
            parts.append(jnp.pad(p, ((0, 0), (0, W - p.shape[1]))))
        return self._join(parts)

    @host_method
    def outlier_parts(self) -> list[tuple[str, int, int, int, float, str, int | None, str]]:
        """The data blocks' rows for an outlier scan in each block's own unit
        (:func:`~jaxcal._fit._diagnostics.scan_outliers`): per block ``(name, first row, end row,
        entries, σ, unit, point entries, point word)``: its rows among the stacked ones, the
        residual entries an outlier scan reads (a pose's position part), the σ that turns its
        whitened residual back into its unit, and how its rows split into points (a camera's
        corners: ``2, "corner"``; ``None`` where a row is one point). The relations block is left
        out (its few rows are already whitened)."""
        out, s = [], 0
        for name, mod, n, sigma in zip(self.names, self.models, self.counts, np.asarray(self.sigma, np.float64)):
            if not isinstance(mod, Relations):
                entries = mod.size if mod.error_entries is None else int(mod.error_entries)
                out.append((name, s, s + n, entries, float(sigma), getattr(mod, "unit", "mm"), mod.point_entries,
                            mod.point_word))
            s += n
        return out

    @host_method
    def observed(self, y) -> np.ndarray | None:
        """``[N, m]`` bool: each block's real residual entries (its own mask), the padding columns
        of narrower blocks left out."""
        y = np.asarray(y, np.float64)
        m = self.size
        parts = []
        for b, (mod, yb) in enumerate(zip(self.models, self._rows(y, y.shape[0]))):
            own = mod.observed(self._y(b, yb))
            own = np.ones((yb.shape[0], mod.size), bool) if own is None else np.asarray(own, bool)
            parts.append(np.pad(own, ((0, 0), (0, m - mod.size))))
        out = self._join(parts, np)
        return None if out.all() else out

    @host_method
    def residual_entries(self, n: int) -> np.ndarray | None:
        """Each row's own block entries (its first ``m_b`` of ``m``; the padding rows are block-0
        rows), flat; ``None`` when every block has ``m`` entries. 30 camera images (108 entries)
        beside 500 tracker rows (3): 4 740 entries instead of 57 240."""
        sizes = [mod.size for mod in self.models]
        m = max(sizes)
        if min(sizes) == m:
            return None
        per_row = np.repeat(np.asarray(sizes + [sizes[0]]), np.asarray([*self.counts, self.pad]))
        if per_row.size != n:
            raise ValueError(f"combined model of {per_row.size} rows (padding included) evaluated on {n}")
        return np.flatnonzero(np.arange(m)[None, :] < per_row[:, None])

    @host_method
    def check_measurements(self, y, n: int) -> None:
        shape = tuple(np.shape(y))
        if shape != (n, *self.sample_shape) or n != self.n_rows + self.pad:
            raise ValueError(f"combined readings must have shape [{self.n_rows}, {self.sample_shape[0]}] "
                             f"(blocks {dict(zip(self.names, self.counts))}), got {list(shape)}")
        y = np.asarray(y)
        for b, (mod, yb) in enumerate(zip(self.models, self._rows(y, n))):
            try:
                mod.check_measurements(self._y(b, yb), yb.shape[0])
            except ValueError as e:
                raise ValueError(f"block {self.names[b]!r}: {e}") from None

    @host_method
    def pad_rows(self, n: int, n_to: int) -> Combined:
        """Padding rows repeat row 0 (a block-0 row): block 0's model padded to match."""
        if n_to == n:
            return self
        extra = n_to - n
        n0 = self.counts[0] + self.pad
        models = (self.models[0].pad_rows(n0, n0 + extra), *self.models[1:])
        return Combined(models, self.sigma, self.names, self.counts, self.widths, self.views, self.groups,
                        self.pad + extra, self.estimated, self.sigma_rtol, self.max_rounds)

    @property
    def jacobian_free_of_data(self) -> bool:
        return all(m.jacobian_free_of_data for m in self.models)


def check_shared_labels(blocks: Sequence[Block], sources: Mapping[str, str] | None = None) -> None:
    """A label shared by two blocks is one object: its nominal geometry must agree (it shares one
    deviation group, ``plane@K`` / ``point@K``).

    Raises:
        ValueError: two blocks giving one label different nominal values, naming the object, both
            blocks (``sources``: ``{block name: what to call it}``, e.g. its data file; default
            ``block 'NAME'``) and both values.
    """
    seen: dict = {}
    call = (lambda b: f"block {b!r}") if sources is None else (lambda b: str(sources.get(b, f"block {b!r}")))  # noqa: E731
    for b in blocks:
        m = b.measurement
        if isinstance(m, PlaneContact):
            n, d = np.asarray(m.normals), np.asarray(m.offsets)  # sliced on the host, not op by op
            geo = {s: np.concatenate([n[k], d[k][None]]) for k, s in enumerate(m.labels)}
            show = lambda v: f"normal {_fmt(v[:3])}, offset {v[3]:g} mm"  # noqa: E731
        elif isinstance(m, FixedPoint):
            c, r = np.asarray(m.centres), np.asarray(m.radii)
            geo = {s: np.concatenate([c[k], r[k][None]]) for k, s in enumerate(m.labels)}
            show = lambda v: f"centre {_fmt(v[:3])} mm, radius {v[3]:g} mm"  # noqa: E731
        else:
            continue
        for s, v in geo.items():
            key = (m.kind, s)
            if key in seen and not np.allclose(seen[key][1], v):
                first, v0 = seen[key]
                raise ValueError(f"{m.kind} {s!r} is in {call(first)} and {call(b.name)} with different nominal "
                                 f"values ({show(v0)} vs {show(v)}); a label names one object: give them the same "
                                 "nominal values or other labels")
            seen.setdefault(key, (b.name, v))


def _fmt(v) -> str:
    return "[" + ", ".join(f"{float(x):g}" for x in v) + "]"


def combine(robot, blocks: Sequence[Block], relations: Sequence = ()) -> tuple[Combined, np.ndarray, np.ndarray]:
    """The :class:`Combined` model of ``blocks`` (and ``relations``) and its stacked data
    ``(model, q [N, dof] rad, y [N, W])``; σ of each block its given ``sigma`` or 1.

    Raises ``ValueError`` naming the problem: two blocks with one name, a block whose data do not
    fit its model, a relation naming a point or plane no block has, a labelled group defined
    differently by two blocks (e.g. a point as a sphere in one block and a pivot in another)."""
    blocks = tuple(blocks)
    if not blocks:
        raise ValueError("combine needs at least one block")
    names = [b.name for b in blocks]
    dup = sorted({s for s in names if names.count(s) > 1})
    if dup:
        raise ValueError(f"block names must differ; repeated: {dup}")
    if "relations" in names and relations:
        raise ValueError("'relations' is the name of the relations block; name the data block otherwise")
    # which standard sensor groups are used by several blocks (renamed per block then)
    uses = {b.name: _USES.get(b.measurement.kind, {g.name for g in STANDARD_EXTRAS}) for b in blocks}
    sensor_shared = {g: sum(g in uses[b.name] for b in blocks) for g in SENSOR_GROUPS}
    own_counts: dict[str, int] = {}
    for b in blocks:
        for g in b.measurement.extra_groups() if hasattr(b.measurement, "extra_groups") else ():
            if "@" not in g.name:
                own_counts[g.name] = own_counts.get(g.name, 0) + 1
    check_shared_labels(blocks)
    # a tip's tool point (``tool@<tip>``, a kinematic tree's tip other than the default one) is one
    # object: every block's view has it, so a model that reads that tip's tool point by name
    # (self-contact) sees the one the other blocks estimate
    tip_tool_names = {tool_group_name(t) for t in robot.tip_names()}
    tip_tools = {g.name: g for b in blocks for g in layout_for(robot, b.measurement).groups if g.name in tip_tool_names}
    groups: dict[str, Group] = {}
    views, qs, ys, models, counts, widths, sigma = [], [], [], [], [], [], []
    for b in blocks:
        layout = layout_for(robot, b.measurement)
        missing = [g for name, g in tip_tools.items() if name not in layout.group_names]
        if missing:
            layout = layout.extend(missing)
        mapping = []
        for g in layout.groups:
            rename = ((g.name in SENSOR_GROUPS and sensor_shared[g.name] > 1)
                      or (g.name == "tool" and b.own_tool)
                      or (g.kind == "extra" and "@" not in g.name and own_counts.get(g.name, 0) > 1))
            target = _renamed(g, b.name) if rename else g
            if rename or g.name not in {s.name for s in layout_for(robot).groups}:
                have = groups.get(target.name)
                if have is not None and have != target:
                    raise ValueError(f"group {target.name!r} is defined differently by two blocks ({have.names} vs "
                                     f"{target.names}); give the objects different labels")
                groups[target.name] = target
            mapping.append((g.name, target.name))
        q, y = b.arrays()
        n = q.shape[0]
        if q.ndim != 2 or q.shape[1] != robot.dof:
            raise ValueError(f"block {b.name!r}: joint angles must be [n, {robot.dof}], got {list(q.shape)}")
        try:
            b.measurement.check_measurements(y, n)
        except ValueError as e:
            raise ValueError(f"block {b.name!r}: {e}") from None
        views.append((layout, tuple(mapping)))
        qs.append(q)
        ys.append(y.reshape(n, -1))
        models.append(b.measurement)
        counts.append(n)
        widths.append(int(np.prod(b.measurement.sample_shape, dtype=int)))
        sigma.append(1.0 if b.sigma is None else float(b.sigma))
    if relations:
        sources = [m for m in models if isinstance(m, (FixedPoint, PlaneContact))]
        rel = Relations(relations, sources)
        mid = 0.5 * (np.asarray(robot.q_min, np.float64) + np.asarray(robot.q_max, np.float64))
        qs.append(np.tile(mid, (len(rel.relations), 1)))
        ys.append(rel.targets()[:, None])
        models.append(rel)
        names.append("relations")
        counts.append(len(rel.relations))
        widths.append(1)
        sigma.append(1.0)
        views.append(None)
    W = max(widths)
    y = np.concatenate([np.pad(v, ((0, 0), (0, W - v.shape[1]))) for v in ys])
    estimated = [b.sigma is None for b in blocks] + [False] * (len(models) - len(blocks))  # the relations: σ = 1
    model = Combined(models, sigma, names, counts, widths, views, tuple(groups.values()), estimated=estimated)
    return model, np.concatenate(qs), y

