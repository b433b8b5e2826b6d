"""The data files ``jaxcal simulate`` writes: one file simulator per sensor kind.

A sensor kind that can be simulated names its file simulator (:attr:`SensorKind.simulator
<jaxcal._sensors._kind.SensorKind>`, ``"module:function"``); :func:`simulate_file` imports it and
calls it with the kind and a :class:`FileRequest`. That name is the hook by which the sensors
(floor 2) reach their simulation (this floor, 4) without importing upward: a new sensor adds its
simulator here (or in any module of this floor or below) and names it on its kind, and
``jaxcal simulate`` and ``--like`` take it from the registry. Each simulator refuses the options
that do not apply to its kind (:class:`ValueError`, in the command line's words), draws the rows
on the true robot of the request's seed (:func:`~jaxcal._simulation._truth.simulated_truth`: the
same robot, tool and sensor frame for every kind, so files of one seed can be combined) and writes
its set-up lines into the data's metadata (a draw wire's anchor, the labels, a camera's target,
intrinsics, mount and tips, the two tips of a self-contact).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

__all__ = ["FileRequest", "SimulatedFile", "simulate_file", "UNKNOWN_ANCHOR_STD_MM",
           "UNKNOWN_OFFSET_STD_MM", "CAMERA_TARGET", "CAMERA_INTRINSICS", "CAMERA_IMAGE_SIZE"]

#: ``--unknown-anchor``: σ per axis (mm) of the true anchor around the default one, and σ (mm) of
#: the wire's zero offset; neither is written where ``jaxcal calibrate`` reads a known anchor.
UNKNOWN_ANCHOR_STD_MM = 50.0
UNKNOWN_OFFSET_STD_MM = 20.0
#: The camera files' set-up: a 9×6 checkerboard of 20 mm squares, OpenCV intrinsics ``fx, fy, cx,
#: cy, k1, k2, p1, p2, k3`` (px), the image size (px).
CAMERA_TARGET = "checkerboard:9x6:20"
CAMERA_INTRINSICS = (1000.0, 1000.0, 640.0, 512.0, -0.05, 0.02, 0.0005, -0.0003, 0.0)
CAMERA_IMAGE_SIZE = (1280, 1024)


@dataclasses.dataclass(frozen=True)
class FileRequest:
    """What a simulated data file is to hold (``jaxcal simulate``'s options).

    Attributes:
        robot: the nominal robot (the true one is drawn from ``truth_seed``).
        seed: the poses and the noise (``jax.random.key(seed)``); the file's ``# seed:`` line.
        n_samples: rows (a camera's images).
        noise_std: the readings' noise σ in the kind's noise unit (mm; a camera's px).
        truth_seed: the true robot's seed (``None``: ``seed``).
        like_source: ``--like``: the words naming the result this file repeats (its ``# like:``
            line; ``None``: a new set-up).
        like_meta: ``--like``: the first file's metadata (its set-up lines), or ``None``.
        anchor: draw wire: the anchor ``"x,y,z"`` mm as typed (``--anchor``) or ``None``.
        unknown_anchor: draw wire: the anchor and the wire's zero offset drawn (not written).
        radius_mm: point: spheres of this radius (sphere + ball, mm), or ``None``.
        mount: camera: ``eye-in-hand``, ``eye-to-hand`` or ``tip-to-tip`` (``None``: the first
            file's, else eye-in-hand).
        missing_corners: camera: the fraction of corners left undetected (``None``: the first
            file's, else 0).
        orientation_noise_deg: pose: σ per axis of the orientation readings, deg.
    """

    robot: object
    seed: int
    n_samples: int
    noise_std: float
    truth_seed: int | None = None
    like_source: str | None = None
    like_meta: Mapping | None = None
    anchor: str | None = None
    unknown_anchor: bool = False
    radius_mm: float | None = None
    mount: str | None = None
    missing_corners: float | None = None
    orientation_noise_deg: float = 0.0

    @property
    def true_seed(self) -> int:
        """The seed of the true robot (:attr:`truth_seed`, else :attr:`seed`)."""
        return self.seed if self.truth_seed is None else self.truth_seed

    def seed_lines(self) -> dict:
        """The file's ``seed`` line and, for ``--like``, ``true_robot_seed`` and ``like``."""
        if self.like_source is None:
            return {"seed": self.seed}
        return {"seed": self.seed, "true_robot_seed": self.true_seed, "like": self.like_source}

    def like_words(self) -> str:
        return "" if self.like_source is None else f", the robot and set-up of {self.like_source}"


@dataclasses.dataclass(frozen=True)
class SimulatedFile:
    """A simulated data file: ``data`` (a :class:`~jaxcal.Dataset` whose metadata are the file's
    ``#`` lines) and ``summary``, the words that describe it (``"12 cable samples of robot ...
    (σ = ..., seed ...)"``)."""

    data: object
    summary: str


def simulate_file(kind, request: FileRequest) -> SimulatedFile:
    """A simulated data file of ``kind`` (a :class:`~jaxcal._sensors._kind.SensorKind` or its name)
    by the kind's own simulator (:attr:`SensorKind.simulator`).

    Raises:
        ValueError: a kind that is not simulated, an option that does not apply to it, or a set-up
            the robot cannot give (the message in the command line's words).
    """
    from .._sensors._kind import resolve_hook, sensor_kind, simulated_kind_names

    k = sensor_kind(kind) if isinstance(kind, str) else kind
    if k.simulator is None:
        raise ValueError(f"{k.name} data are not simulated; `jaxcal simulate` writes "
                         f"{', '.join(simulated_kind_names())} data")
    return resolve_hook(k.simulator)(k, request)


# -- checks shared by the simulators ---------------------------------------------------------------
def _refuse_unknown_anchor(request: FileRequest) -> None:
    if request.unknown_anchor:
        raise ValueError("--unknown-anchor applies to --measurement cable without --anchor (it draws the anchor)")


def _check_rows(request: FileRequest, least: int = 2) -> None:
    if request.n_samples < least:
        raise ValueError(f"--samples must be at least {least}, got {request.n_samples}")


def _refuse_orientation_noise(kind, request: FileRequest) -> None:
    if request.orientation_noise_deg:
        raise ValueError(f"--orientation-noise-deg applies to --measurement pose, not {kind.name}")


def _model(kind, request: FileRequest):
    """The kind's model at its default set-up (``--anchor``; ``--radius-mm``: spheres)."""
    from .._core._csvfile import number_list

    anchor = number_list(request.anchor, 3, "--anchor") if request.anchor else None
    measurement = kind.default_model(request.robot, anchor_mm=anchor, n_markers=None, data=None)
    if request.radius_mm is not None:
        measurement = kind.spheres(measurement, request.radius_mm, False)
    return measurement


# -- a tool sensor: draw wire, tracker, pose sensor ---------------------------------------------------
def cable_file(kind, request: FileRequest) -> SimulatedFile:
    """Draw-wire data: the true anchor in the model (``anchor_mm``), or with ``unknown_anchor`` an
    anchor ``N(0, UNKNOWN_ANCHOR_STD_MM²)`` per axis off the default and a zero offset
    ``N(0, UNKNOWN_OFFSET_STD_MM²)`` (mm) drawn from the true robot's key, written in full precision
    as ``true_anchor_mm`` / ``true_cable_offset_mm`` (which calibrate does not read; ``--like``
    simulates from these lines)."""
    import jax.numpy as jnp

    from .._core._csvfile import number_list
    from .._core._params import Deviations
    from .._sensors._measurement import CableLength

    if request.unknown_anchor and request.anchor:
        _refuse_unknown_anchor(request)
    _check_rows(request)
    _refuse_orientation_noise(kind, request)
    measurement = _model(kind, request)
    like = request.like_meta
    if like is not None and "true_anchor_mm" in like:  # the drawn anchor and offset, to the last bit
        measurement = CableLength(number_list(like["true_anchor_mm"], 3, "the first file's true_anchor_mm"))
        offset, unknown = float(like["true_cable_offset_mm"]), False
    else:
        offset, unknown = None, request.unknown_anchor
    truth = _truth(request.robot, request.true_seed, unknown)
    vals = dict(truth.values)  # the true anchor in the model; the deviation's anchor back to 0
    measurement = CableLength(measurement.anchor + vals["anchor"])
    vals["anchor"] = jnp.zeros_like(vals["anchor"])
    if offset is not None:
        vals["cable_offset"] = jnp.full_like(vals["cable_offset"], offset)
    truth = Deviations(vals, truth.layout)
    if not request.unknown_anchor:
        setup = kind.plan_lines(measurement)  # the anchor line a planned file has
    else:  # the truth to the last bit: --like simulates from these lines
        setup = {"true_anchor_mm": ",".join(repr(float(v)) for v in measurement.anchor),
                 "true_cable_offset_mm": repr(float(truth.cable_offset))}
    return _tool_sensor_file(kind, request, measurement, truth, setup, 0.0)


def experiment_file(kind, request: FileRequest) -> SimulatedFile:
    """Tool positions (a tracker) on the seed's true robot."""
    _refuse_unknown_anchor(request)
    _check_rows(request)
    _refuse_orientation_noise(kind, request)
    measurement = _model(kind, request)
    return _tool_sensor_file(kind, request, measurement, _truth(request.robot, request.true_seed, False), {}, 0.0)


def pose_file(kind, request: FileRequest) -> SimulatedFile:
    """Tool poses; ``orientation_noise_deg``: noise on the orientation readings too (a rotation
    about the tool frame's axes), written as ``orientation_noise_std_deg``."""
    _refuse_unknown_anchor(request)
    _check_rows(request)
    rot = request.orientation_noise_deg
    if not (math.isfinite(rot) and rot >= 0):
        raise ValueError(f"--orientation-noise-deg must be a σ ≥ 0 in degrees, got {rot}")
    measurement = _model(kind, request)
    return _tool_sensor_file(kind, request, measurement, _truth(request.robot, request.true_seed, False), {}, rot)


def _truth(robot, robot_seed: int, unknown_anchor: bool):
    """The seed's true set-up (:func:`~jaxcal._simulation._truth.simulated_truth`: the deviations
    :func:`jaxcal.simulate_experiment` draws from ``jax.random.key(robot_seed)``, the tool and sensor
    frame nominal, as for every kind); ``unknown_anchor``: an anchor and a wire offset drawn too."""
    import jax

    from ._truth import simulated_truth

    return simulated_truth(jax.random.key(robot_seed), robot,
                           anchor_std_mm=UNKNOWN_ANCHOR_STD_MM if unknown_anchor else 0.0,
                           cable_offset_std_mm=UNKNOWN_OFFSET_STD_MM if unknown_anchor else 0.0)


def _tool_sensor_file(kind, request: FileRequest, measurement, truth, setup: dict, rot: float) -> SimulatedFile:
    """:func:`jaxcal.simulate_experiment` of ``request.n_samples`` rows (train and test together)."""
    import jax
    import jax.numpy as jnp

    from .._datasets._dataset import Dataset, mm_joints_metadata
    from ._simulate import add_orientation_noise, simulate_experiment

    robot, noise = request.robot, request.noise_std
    ex = simulate_experiment(jax.random.key(request.seed), robot, n_samples=request.n_samples, noise_std=noise,
                             measurement=measurement, true_deviations=truth, test_fraction=0.5)
    q = jnp.concatenate([ex.train.q, ex.test.q])
    y = jnp.concatenate([ex.train.y, ex.test.y])
    meta = {"source": "jaxcal simulate", "robot": robot.name, **request.seed_lines(), "noise_std_mm": noise,
            **setup, **mm_joints_metadata(robot)}
    rot_text = ""
    if rot:
        y = add_orientation_noise(y, math.radians(rot), request.seed)
        meta["orientation_noise_std_deg"] = rot
        rot_text = f", {rot}° per axis on the orientation"
    return SimulatedFile(Dataset(q, y, kind.name, meta),
                         f"{request.n_samples} {kind.name} samples of robot {robot.name} (σ = {noise} mm{rot_text}, "
                         f"seed {request.seed}{request.like_words()})")


# -- contact: planes, points, a distance bar ------------------------------------------------------------
def _contact_meta(kind, request: FileRequest) -> dict:
    from .._datasets._dataset import mm_joints_metadata

    robot = request.robot
    return {"source": "jaxcal simulate", "robot": robot.name, "seed": request.seed, "noise_std_mm": request.noise_std,
            **mm_joints_metadata(robot)}


def plane_file(kind, request: FileRequest) -> SimulatedFile:
    """Plane contact: :func:`~jaxcal._simulation._simulate_sensors.simulate_contact` on the kind's
    default planes, written with their labels."""
    ex, meta, _, labels = _labelled_contact(kind, request)
    return _contact_file(kind, request, ex.train, meta, f"{len(labels)} {kind.name}s: {', '.join(labels)}")


def point_file(kind, request: FileRequest) -> SimulatedFile:
    """Point contact: :func:`~jaxcal._simulation._simulate_sensors.simulate_contact` on the kind's
    default points (``radius_mm``: spheres), written with their labels (and the spheres'
    ``radius_mm``)."""
    import numpy as np

    ex, meta, measurement, labels = _labelled_contact(kind, request)
    if not measurement.sphere:
        return _contact_file(kind, request, ex.train, meta, f"{len(labels)} {kind.name}s: {', '.join(labels)}")
    r = np.asarray(measurement.radii, np.float64)
    meta["radius_mm"] = ",".join(f"{v:g}" for v in r) if np.ptp(r) > 0 else f"{r[0]:g}"
    return _contact_file(kind, request, ex.train, meta,
                         f"{len(labels)} spheres of radius {meta['radius_mm']} mm: {', '.join(labels)}")


def _labelled_contact(kind, request: FileRequest):
    """``(experiment, meta, model, labels)`` of a labelled contact kind's file (planes, points)."""
    import jax

    from .._sensors._contact import label_metadata_key
    from ._simulate_sensors import simulate_contact
    from ._truth import simulated_truth

    _refuse_unknown_anchor(request)
    _check_rows(request)
    measurement = _model(kind, request)
    labels = tuple(measurement.labels)
    if request.like_meta is not None:
        want = request.like_meta.get(f"{kind.name}_labels")
        if want is not None and want != ",".join(labels):
            raise ValueError(f"--like: the first file's {kind.name}s are {want}, `jaxcal simulate` now writes "
                             f"{','.join(labels)}; the set-up is not known")
    robot, key = request.robot, jax.random.key(request.seed)
    truth = simulated_truth(jax.random.key(request.true_seed), robot, measurement)
    ex = simulate_contact(key, robot, measurement, n_samples=request.n_samples, noise_std=request.noise_std,
                          test_fraction=0.0, true_deviations=truth)
    meta = _contact_meta(kind, request)
    meta[label_metadata_key(kind.name)] = ",".join(labels)
    return ex, meta, measurement, labels


def distance_file(kind, request: FileRequest) -> SimulatedFile:
    """A distance bar of 150 and 300 mm: :func:`~jaxcal._simulation._simulate_sensors.simulate_distance`."""
    import jax

    from ._simulate_sensors import simulate_distance
    from ._truth import simulated_truth

    _refuse_unknown_anchor(request)
    _check_rows(request)
    measurement = _model(kind, request)
    robot, key = request.robot, jax.random.key(request.seed)
    truth = simulated_truth(jax.random.key(request.true_seed), robot, measurement)
    ex = simulate_distance(key, robot, n_samples=request.n_samples, noise_std=request.noise_std, test_fraction=0.0,
                           true_deviations=truth)
    return _contact_file(kind, request, ex.train, _contact_meta(kind, request), "bar lengths 150 and 300 mm")


def _contact_file(kind, request: FileRequest, data, meta: dict, what: str) -> SimulatedFile:
    from .._datasets._dataset import Dataset

    return SimulatedFile(Dataset(data.q, data.y, kind.name, {**meta, **request.seed_lines()}),
                         f"{request.n_samples} {kind.name} samples of robot {request.robot.name} "
                         f"(σ = {request.noise_std} mm, seed {request.seed}, {what}{request.like_words()})")


# -- a camera ------------------------------------------------------------------------------------------
def camera_file(kind, request: FileRequest) -> SimulatedFile:
    """:func:`jaxcal.simulate_camera` (a 9×6 checkerboard of 20 mm squares, 1280×1024 px, f = 1000 px;
    ``--like``: the first file's), written with the target, intrinsics, image size and mount lines
    (and ``missing_corners`` where corners were left out). Mount ``tip-to-tip`` (a robot with two
    tips or more): the camera on the first tip sees the target on the second (self-observation;
    ``--like``: the first file's tips), with ``# tip:`` and ``# target_tip:`` lines."""
    import jax
    import numpy as np

    from .._core._csvfile import number_list
    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._sensors._camera import Camera, load_target
    from .._sensors._kind import resolve_tip
    from ._simulate_sensors import simulate_camera
    from ._truth import simulated_truth

    _refuse_unknown_anchor(request)
    robot = request.robot
    lines = {} if request.like_meta is None else request.like_meta
    mount = (request.mount or lines.get("mount") or "eye-in-hand").replace("-", "_")
    missing = request.missing_corners if request.missing_corners is not None else float(lines.get("missing_corners", 0.0))
    if request.anchor:
        raise ValueError("--anchor applies to --measurement cable only")
    if request.n_samples < 3:
        raise ValueError(f"--samples (images) must be at least 3, got {request.n_samples}")
    if not 0.0 <= missing < 1.0:
        raise ValueError(f"--missing-corners must be in [0, 1), got {missing}")
    target = lines.get("target", CAMERA_TARGET)
    intr = [float(v) for v in number_list(lines["camera_intrinsics"], 9, "the first file's camera_intrinsics")] \
        if "camera_intrinsics" in lines else list(CAMERA_INTRINSICS)
    size = tuple(int(v) for v in number_list(lines["image_size_px"], 2, "the first file's image_size_px")) \
        if "image_size_px" in lines else CAMERA_IMAGE_SIZE
    tips = {}
    if mount == "tip_to_tip":  # self-observation: the camera on the first tip, the target on the second
        names = robot.tip_names()[:2] if request.like_meta is None else [lines.get("tip", ""), lines.get("target_tip", "")]
        if len(names) != 2 or not all(names):
            raise ValueError("--mount tip-to-tip needs a robot with two tips (--robot FILE.urdf --tip A,B: the camera "
                             f"on A, the target on B); robot {robot.name!r} has {len(robot.tip_names()) or 'one unnamed'} "
                             "tip(s)")
        tips = {"tip": names[0], "target_tip": names[1]}
    on = {k: resolve_tip(robot, v) for k, v in tips.items()}  # None: the robot's default tip
    cam = Camera(load_target(target), intr, mount, image_size=size, **on)
    key = jax.random.key(request.seed)  # the poses and noise; the seed's robot and tool, as every kind's
    truth = simulated_truth(jax.random.key(request.true_seed), robot)
    q, y, cam, truth = simulate_camera(key, robot, cam, n_views=request.n_samples, noise_px=request.noise_std,
                                       missing=missing, true_deviations=truth)
    n_masked = int(np.isnan(np.asarray(y)).any(axis=-1).sum())
    meta = {"source": "jaxcal simulate", "robot": robot.name, **request.seed_lines(),
            "noise_std_px": request.noise_std, "target": target, "camera_intrinsics": ",".join(repr(v) for v in intr),
            "mount": cam.mount, "image_size_px": ",".join(str(v) for v in size),
            **({"missing_corners": missing} if missing else {}), **tips, **mm_joints_metadata(robot)}
    where = f": camera on {tips['tip']}, target on {tips['target_tip']}" if tips else ""
    return SimulatedFile(Dataset(q, y, kind.name, meta),
                         f"{request.n_samples} camera images ({cam.mount}{where}, {cam.n_points} target points, "
                         f"{n_masked} corner(s) left undetected) of robot {robot.name} (σ = {request.noise_std} px, "
                         f"seed {request.seed}{request.like_words()})")


# -- self-contact -----------------------------------------------------------------------------------------
def self_contact_file(kind, request: FileRequest) -> SimulatedFile:
    """The robot's first two tips touch (:func:`jaxcal.simulate_self_contact`, 30 mm balls: 60 mm
    apart at contact) on the seed's robot, written with the ``# tips:`` line (``--like``: the first
    file's tips)."""
    import jax

    from .._datasets._dataset import Dataset, mm_joints_metadata
    from .._sensors._self_contact import simulate_self_contact
    from ._truth import simulated_truth

    _refuse_unknown_anchor(request)
    _check_rows(request)
    robot = request.robot
    tips = robot.tip_names()[:2] if request.like_meta is None else \
        [t.strip() for t in request.like_meta.get("tips", "").split(",")]
    if len(tips) != 2:
        raise ValueError("--measurement self_contact needs a robot with two tips: --robot FILE.urdf --tip A,B")
    if request.anchor:
        raise ValueError("--anchor applies to --measurement cable only")
    key = jax.random.key(request.seed)  # the poses and noise; the seed's robot, as every kind's (simulated_truth)
    truth = simulated_truth(jax.random.key(request.true_seed), robot)
    q, y = simulate_self_contact(key, robot, tips, n_samples=request.n_samples, noise_std=request.noise_std,
                                 true_deviations=truth)
    meta = {"source": "jaxcal simulate", "robot": robot.name, **request.seed_lines(), "noise_std_mm": request.noise_std,
            "tips": ",".join(tips), **mm_joints_metadata(robot)}
    return SimulatedFile(Dataset(q, y, kind.name, meta),
                         f"{len(y)} self-contact rows of {tips[0]} and {tips[1]} of robot {robot.name} "
                         f"(σ = {request.noise_std} mm contact scatter, seed {request.seed}{request.like_words()})")
