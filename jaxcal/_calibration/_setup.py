"""From a data file to what a calibration of measured data needs: the measurement model and the
sensor extras to estimate.

:func:`jaxcal.calibrate` estimates the extras it is given (``extras=``); a data file of a given
kind cannot do without some: a distance bar or contact data never fix the tool point, a
draw-wire file without a known anchor needs the anchor and the wire's zero offset, marker data
need the motion-capture frame. :func:`measured_extras` adds those to the ones asked for and says
why in one note each. :func:`measurement_for` builds the whole set-up of a loaded data file
(its kind, its ``#`` metadata lines as defaults: ``anchor_mm``, ``radius_mm``, ``target``,
``camera_intrinsics``, ``mount``, ``image_size_px``), exactly as ``jaxcal calibrate`` does, and
:func:`block_from_file` makes a data file a :class:`jaxcal.Block` the same way (``jaxcal plan
--with``). Their error messages name the command line's options, which the keywords stand for
(``estimate`` for ``--estimate``, ``target`` for ``--target``...).
"""

from __future__ import annotations

import dataclasses
import math
import pathlib

__all__ = ["MeasurementSetup", "block_from_file", "measured_extras", "measurement_for"]


def measured_extras(kind: str, estimate=(), *, anchor_known: bool = True, sessions: bool = False,
                    sphere: bool = False, estimate_radius: bool = False,
                    radius_mm: float | None = None) -> tuple[set[str], list[str]]:
    """``(extras, notes)``: the extras to estimate for ``kind`` data (``"cable"``, ``"position"``,
    ``"pose"``, ``"markers"``, ``"camera"``, ``"plane"``, ``"point"``, ``"distance"``) — those in
    ``estimate`` (names as ``jaxcal calibrate --estimate`` takes them: ``anchor``, ``offset``,
    ``tool``, ``base``) and the ones the data need — and one note per default added.

    Args:
        kind: the data's measurement kind.
        estimate: the extras asked for (already checked against ``kind``).
        anchor_known: cable data: the anchor is known (given, or the file's ``anchor_mm`` line);
            otherwise the anchor and the cable offset are estimated.
        sessions: marker data of several sessions (every session frame is estimated anyway).
        sphere, estimate_radius, radius_mm: point data as spheres (a ball touching fixed
            spheres): the radius estimated, or known (``radius_mm``); only for the notes.
    """
    from .._sensors._contact import length_reference_note

    estimate = set(estimate)
    notes: list[str] = []
    if kind == "distance" and "tool" not in estimate:
        estimate.add("tool")
        notes.append("distance data: the tool point is estimated (from its nominal value); distances never see "
                     "the robot's base frame (d_1, theta_1 and the base's position and orientation stay at "
                     "nominal or are set by the prior)")
    if sphere:
        notes.append("point data as spheres: residual = distance to the centre minus the radius, "
                     + ("radius unknown: estimated per point (sphere fit to the data, then the joint fit)"
                        if estimate_radius else f"radius {radius_mm:g} mm (known)"))
    if kind in ("plane", "point") and "tool" not in estimate:
        estimate.add("tool")
        notes.append(f"{kind} data: the {kind}s and the tool point are estimated "
                     "(closed-form start from the data, then the joint fit); "
                     + length_reference_note(kind, known_radius=sphere and not estimate_radius))
    if kind == "cable" and not anchor_known:
        # nothing known about the anchor: estimate it (and the cable offset) from the data
        estimate |= {"anchor", "offset"}
        notes.append("no --anchor given and none in the file: the anchor and the cable offset are estimated "
                     "from the data (multilateration on the nominal robot, then the joint fit)")
    if kind == "markers" and "base" not in estimate and not sessions:  # sessions: every frame is estimated
        estimate.add("base")
        notes.append("marker data: the motion-capture frame (base extras) and the marker positions on the flange "
                     "are estimated (closed-form Kabsch start from the data, then the joint fit)")
    return estimate, notes


@dataclasses.dataclass(frozen=True)
class MeasurementSetup:
    """What :func:`measurement_for` builds from a data file: the model to calibrate with and the
    extras to estimate.

    Attributes:
        measurement: the measurement model (:class:`~jaxcal.CableLength`, :class:`~jaxcal.Position`,
            :class:`~jaxcal.Pose`, :class:`~jaxcal.Markers`, :class:`~jaxcal.SessionMarkers`,
            :class:`~jaxcal.Camera`, :class:`~jaxcal.PlaneContact`, :class:`~jaxcal.FixedPoint`
            or :class:`~jaxcal.DistanceBar`).
        estimate: the extras to estimate as ``jaxcal calibrate --estimate`` names them
            (``anchor``, ``offset``, ``tool``, ``base``): those asked for and those the data need.
        notes: one sentence per default chosen and per fact worth knowing about the data (masked
            readings, sessions), as ``jaxcal calibrate`` prints them.
    """

    measurement: object
    estimate: frozenset = frozenset()
    notes: tuple = ()

    @property
    def extras(self) -> list[str]:
        """:attr:`estimate` as :func:`jaxcal.calibrate`'s ``extras`` (``offset`` → ``cable_offset``), sorted."""
        return sorted({"offset": "cable_offset"}.get(e, e) for e in self.estimate)


def measurement_for(data, robot, *, anchor_mm=None, radius_mm: float | None = None, estimate=(), target=None,
                    camera_intrinsics=None, mount: str | None = None, path=None) -> MeasurementSetup:
    """The measurement model of a loaded data file and the extras its calibration estimates, as
    ``jaxcal calibrate`` builds them: the kind is the data's; a keyword left ``None`` takes the
    file's metadata line (``# anchor_mm:``, ``# radius_mm:``, ``# target:``,
    ``# camera_intrinsics:``, ``# mount:``; ``# image_size_px:`` always).

    * cable: the anchor given or the file's; neither: the default anchor as the start, and the
      anchor and the cable offset are estimated.
    * point: spheres (:class:`~jaxcal.FixedPoint` with radii) when ``radius_mm`` is given, the
      radius is estimated, or the file has a ``radius_mm`` line.
    * markers with session labels: a :class:`~jaxcal.SessionMarkers`; without: a
      :class:`~jaxcal.Markers` whose positions start from the data.
    * camera: a :class:`~jaxcal.Camera` with the hand-eye transform and the target pose unknown
      (started from the images).
    * plane, point: the planes / points from the data's labels, unknown (started from the data).

    Args:
        data: a :class:`~jaxcal.Dataset` (:func:`jaxcal.load_csv`), its metadata lines in
            ``data.meta``.
        robot: the robot model (:class:`~jaxcal.DHRobot` or :class:`~jaxcal.SerialChain`).
        anchor_mm: cable data: the draw-wire anchor ``(x, y, z)`` in the base frame, mm.
        radius_mm: point data as spheres: sphere radius plus ball radius, mm (with ``"radius"``
            in ``estimate``: the value the estimate starts from).
        estimate: extras asked for, as ``jaxcal calibrate --estimate`` names them: ``anchor``,
            ``offset`` (cable), ``tool``, ``base`` (position, pose, markers), ``radius`` (point),
            ``intrinsics`` (camera); a list or a comma-separated string.
        target: camera data: ``"checkerboard:COLSxROWS:SQUARE_MM"``, a CSV file of the target
            points (columns ``x_mm, y_mm, z_mm``) or the points themselves ``[N, 3]`` mm.
        camera_intrinsics: camera data: ``fx, fy, cx, cy[, k1, k2, p1, p2[, k3]]`` (px; OpenCV's
            camera matrix and distortion), numbers or a comma-separated string.
        mount: camera data: ``"eye_in_hand"`` (default) or ``"eye_to_hand"``.
        path: the file ``data`` came from: a relative target file is looked for next to it, and
            messages name it.

    Returns:
        :class:`MeasurementSetup`: the model, the extras to estimate, the notes.

    Raises:
        ValueError: an extra that does not apply to the data's kind, an option of another kind
            (an anchor for position data, a radius for plane data), a camera file without its
            target or intrinsics, a malformed metadata line. The messages name the ``jaxcal
            calibrate`` options the keywords stand for (``--anchor`` for ``anchor_mm``,
            ``--radius-mm``, ``--estimate``, ``--target``, ``--camera`` for ``camera_intrinsics``).
    """
    import numpy as np

    from .._datasets._csvfile import number_list

    kind, meta = data.kind, data.meta
    if isinstance(estimate, str):
        estimate = estimate.split(",")
    estimate = {str(e).strip().lower() for e in estimate if str(e).strip()}
    intrinsics = "intrinsics" in estimate
    if anchor_mm is not None:
        anchor_mm = [float(v) for v in np.asarray(anchor_mm, np.float64).ravel()]
        if len(anchor_mm) != 3 or not all(math.isfinite(v) for v in anchor_mm):
            raise ValueError(f"anchor_mm must be 3 finite numbers (x, y, z in mm), got {anchor_mm}")
    # the extras asked for are checked here; measured_extras adds the ones the kind of data needs
    if kind == "camera":
        if estimate - {"intrinsics"}:
            raise ValueError(f"--estimate for camera data takes intrinsics only (the hand-eye transform and the "
                             f"target pose are always estimated); got {sorted(estimate - {'intrinsics'})}")
        estimate = set()  # intrinsics: a group of the camera model
    if kind == "distance" and "base" in estimate:
        raise ValueError("--estimate base does not apply to distance data: distances never see the base frame")
    sphere = kind == "point" and (radius_mm is not None or "radius" in estimate or "radius_mm" in meta)
    radius = radius_mm
    if sphere and radius is None and "radius_mm" in meta:
        radius = number_list(meta["radius_mm"], 1, "the file's radius_mm")[0]
    estimate_radius = "radius" in estimate
    estimate.discard("radius")
    if (radius_mm is not None or estimate_radius) and kind != "point":
        raise ValueError("--radius-mm and --estimate radius apply to --measurement point only")
    if kind in ("plane", "point") and "base" in estimate:
        raise ValueError(f"--estimate base does not apply to {kind} data: the {kind}s are "
                         "in the robot base frame and carry any base-frame error")
    bad = estimate - {"anchor", "tool", "offset", "cable_offset", "base"}
    if bad:
        raise ValueError(f"--estimate takes anchor, offset, tool (cable) or base, tool (position); got {sorted(bad)}")
    if kind != "cable" and estimate & {"anchor", "offset", "cable_offset"}:
        raise ValueError("--estimate anchor/offset apply to --measurement cable only")
    if kind == "cable" and "base" in estimate:
        raise ValueError("--estimate base applies to --measurement position only")
    if anchor_mm is None and kind == "cable" and "anchor_mm" in meta:
        anchor_mm = number_list(meta["anchor_mm"], 3, "the file's anchor_mm")
    if kind == "markers" and "tool" in estimate:
        raise ValueError("--estimate tool does not apply to marker data: the marker positions are the tool")
    estimate, notes = measured_extras(kind, estimate, anchor_known=anchor_mm is not None, sessions=bool(data.labels),
                                      sphere=sphere, estimate_radius=estimate_radius, radius_mm=radius)
    if kind == "camera":
        from .._sensors._camera import masked_corners

        measurement = _camera(data, target, camera_intrinsics, mount, intrinsics, path)
        n_mask, n_all, n_img = masked_corners(data.y)
        notes.append(f"camera ({measurement.mount}): hand-eye transform and target pose estimated (per-image PnP, "
                     "Park–Martin hand-eye, then the joint fit)"
                     f"{'; intrinsics estimated' if measurement.calibrate_intrinsics else ''}; "
                     f"{n_mask} of {n_all} corner readings not detected (empty cells) in {n_img} image(s): masked "
                     "(zero weight), not dropped")
    elif data.labels:  # marker data of several sessions: SessionMarkers (one frame / placement per label)
        from .._sensors._sessions import SessionMarkers, masked_markers

        measurement = SessionMarkers.from_dataset(data)
        n_miss, n_all, n_rows = masked_markers(data.y)
        places = ", ".join(f"{p} ({len(k)})" for p, k in zip(measurement.placements, measurement.markers))
        notes.append(f"{len(dict.fromkeys(s for s, _, _ in data.labels))} recording sessions: frames "
                     f"{', '.join(measurement.frames)}; placements (markers) {places}; shared robot errors"
                     + (f"; {n_miss} of {n_all} marker readings missing (empty cells) in {n_rows} row(s): masked "
                        "(zero weight), not dropped" if n_miss else ""))
    else:
        measurement = measurement_of_kind(kind, robot, anchor_mm=anchor_mm, data=data,
                                          n_markers=data.y.shape[1] if kind == "markers" else None)
        if sphere:
            measurement = as_spheres(kind, measurement, radius, estimate_radius)
    return MeasurementSetup(measurement, frozenset(estimate), tuple(notes))


def measurement_of_kind(kind: str, robot, *, anchor_mm=None, n_markers: int | None = None, data=None):
    """The measurement model of ``kind`` data with its set-up unknown or at a default: cable with
    ``anchor_mm`` (mm; default :func:`~jaxcal._simulation._simulate.default_anchor`), position and
    pose in the base frame, ``n_markers`` markers at the flange (started from the data), the
    planes / points of ``data``'s labels (without data: the simulation's set-up), a distance bar.

    Raises:
        ValueError: ``anchor_mm`` given for data other than cable.
    """
    from .._sensors._measurement import CableLength, Markers, Pose, Position

    if kind in ("plane", "point", "distance"):  # contact data: planes/points from the data's labels
        if anchor_mm is not None:
            raise ValueError("--anchor applies to --measurement cable only")
        from .._sensors._contact import contact_model

        return contact_model(kind, robot, data)
    if kind == "cable":
        if anchor_mm is None:
            from .._simulation._simulate import default_anchor

            return CableLength(default_anchor(robot))
        from .._core._precision import to_device

        return CableLength(to_device(anchor_mm))  # as jnp.asarray, without a compiled conversion program
    if anchor_mm is not None:
        raise ValueError("--anchor applies to --measurement cable only")
    if kind == "markers":
        # marker positions on the flange unknown: they start from the data (closed form) and are calibrated
        import numpy as np

        return Markers(np.zeros((int(n_markers), 3)))
    return Pose() if kind == "pose" else Position()


def as_spheres(kind: str, measurement, radius_mm: float | None, estimate_radius: bool):
    """A point model (:class:`~jaxcal.FixedPoint`) as spheres of radius ``radius_mm`` (mm; the
    start where ``estimate_radius``).

    Raises:
        ValueError: ``kind`` is not ``"point"``; the radius is negative or not finite.
    """
    if kind != "point":
        raise ValueError("--radius-mm and --estimate radius apply to --measurement point only")
    r = 0.0 if radius_mm is None else float(radius_mm)
    if not (math.isfinite(r) and r >= 0):
        raise ValueError(f"--radius-mm must be a finite number >= 0 (mm), got {radius_mm}")
    from .._sensors._contact import FixedPoint

    return FixedPoint(measurement.labels, measurement.centres, radii_mm=r, estimate_radius=estimate_radius)


def _camera(data, target, intrinsics, mount, calibrate_intrinsics: bool, path):
    """The :class:`~jaxcal.Camera` of camera data from ``target``, ``intrinsics``, ``mount`` (or
    the file's ``# target:``, ``# camera_intrinsics:``, ``# mount:`` lines), hand-eye and target
    pose unknown (started from the data)."""
    import numpy as np

    from .._datasets._csvfile import number_list
    from .._sensors._camera import Camera, load_target

    meta = data.meta
    target = _or(target, meta.get("target"))
    if _or(target, None) is None:
        raise ValueError("--measurement camera needs the target layout: --target checkerboard:COLSxROWS:SQUARE_MM or "
                         "--target FILE.csv (x_mm,y_mm,z_mm per point), or a '# target: …' line in the data file")
    if isinstance(target, str):
        try:
            points = load_target(target, base_dir=None if path is None else pathlib.Path(path).parent)
        except (ValueError, OSError) as e:
            raise ValueError(f"--target: {e}") from None
    else:
        points = np.asarray(target, np.float64)
    if points.shape[0] != data.y.shape[1]:
        raise ValueError(f"the target has {points.shape[0]} points but {'the data' if path is None else path} "
                         f"{'have' if path is None else 'has'} image columns for {data.y.shape[1]} (u_k_px, v_k_px)")
    spec = _or(intrinsics, meta.get("camera_intrinsics"))
    if _or(spec, None) is None:
        raise ValueError("--measurement camera needs the camera's intrinsics: --camera fx,fy,cx,cy[,k1,k2,p1,p2[,k3]] "
                         "(px; OpenCV's camera matrix and distortion) or a '# camera_intrinsics: …' line")
    if isinstance(spec, str):
        parts = [p for p in spec.replace(";", ",").split(",") if p.strip()]
        if len(parts) not in (4, 8, 9):
            raise ValueError(f"--camera takes 4, 8 or 9 numbers fx,fy,cx,cy[,k1,k2,p1,p2[,k3]], got {spec!r}")
        spec = number_list(spec, len(parts), "--camera")
    mount = _or(_or(mount, meta.get("mount")), "eye_in_hand").replace("-", "_").lower()
    size = meta.get("image_size_px")
    size = tuple(int(v) for v in number_list(size, 2, "the file's image_size_px")) if size else None
    return Camera(points, spec, mount, image_size=size, calibrate_intrinsics=calibrate_intrinsics)


def _or(value, default):
    """``value``, or ``default`` where ``value`` is ``None`` or an empty text (an option not given)."""
    return default if value is None or (isinstance(value, str) and not value) else value


def block_from_file(data, robot, *, sigma: float | None = None, name: str | None = None):
    """A data file in hand as a :class:`jaxcal.Block` of a combined fit or plan
    (:func:`jaxcal.calibrate_blocks`, :func:`jaxcal.plan_blocks`): its kind from the file, its
    model and extras as :func:`measurement_for` builds them from the file's metadata lines.

    Args:
        data: a data file's path, or a loaded :class:`~jaxcal.Dataset`.
        robot: the robot model.
        sigma: the readings' noise σ (mm; px for camera data), or ``None``: the file's
            ``# noise_std_mm:`` (``# noise_std_px:``) line.
        name: the block's name (default: the file's name without its suffix; for a Dataset its kind).

    Returns:
        :class:`jaxcal.Block` with ``sigma`` set.

    Raises:
        ValueError: the file does not load, has another number of joints than ``robot``, holds
            marker data (their frames and positions are no block to plan with), has no σ, or its
            model cannot be built (:func:`measurement_for`); the file's own faults are prefixed
            with its path (a Dataset's: the block's name); a missing σ is asked for as
            ``jaxcal plan --with-sigma``, the keyword ``sigma``.
    """
    from .._datasets._csvfile import number_list
    from .._datasets._dataset import load_csv
    from .._sensors._blocks import Block
    from ._blocks import block_extras

    path = None
    if isinstance(data, (str, pathlib.Path)):
        path = data
        where = str(data)
        try:
            data = load_csv(path)
        except ValueError as e:
            raise ValueError(f"{where}: {e}") from None
        name = pathlib.Path(path).stem if name is None else name
    else:
        name = data.kind if name is None else name
        where = name
    kind = data.kind
    if data.dof != robot.dof:
        raise ValueError(f"{where}: {data.dof} joint columns but robot {robot.name!r} has {robot.dof} joints")
    if kind == "markers" or data.labels:
        raise ValueError(f"{where}: {kind} data of several sessions or markers cannot be planned with; give "
                         "cable, position, pose, plane, point, distance or camera files")
    unit = "px" if kind == "camera" else "mm"
    if sigma is None:
        text = data.meta.get(f"noise_std_{unit}")
        if text is None:
            raise ValueError(f"{where}: give its noise σ ({unit}) with --with-sigma, or a '# noise_std_{unit}: …' "
                             "line in the file")
        sigma = number_list(str(text), 1, f"the file's noise_std_{unit}")[0]
    if not (sigma > 0 and math.isfinite(sigma)):
        raise ValueError(f"{where}: σ must be a finite number > 0, got {sigma}")
    setup = measurement_for(data, robot, path=None if path is None else pathlib.Path(path))
    return Block(name, setup.measurement, data, sigma=float(sigma), extras=block_extras(setup.estimate))
