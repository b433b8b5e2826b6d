"""Camera measurement model: a calibrated pinhole camera sees a known target (issue 23, part 4).

Two set-ups (``mount``):

* ``"eye_in_hand"``: the camera is on the flange, the target is fixed in the robot's base frame.
  Hand-eye ``X = T_flange_camera`` (OpenCV's ``cam2gripper``), target pose ``B = T_base_target``;
  image ``i`` sees ``T_camera_target,i = X⁻¹ · F(q_i)⁻¹ · B`` with ``F(q) = T_base_flange``.
* ``"eye_to_hand"``: the camera is fixed, the target is on the flange. Hand-eye
  ``X = T_base_camera`` (OpenCV's ``cam2base``), target pose ``B = T_flange_target``;
  ``T_camera_target,i = X⁻¹ · F(q_i) · B``.
* ``"tip_to_tip"`` (self-observation, a :class:`~jaxcal.KinematicTree`): the camera is on one tip
  (``tip``: a head camera, a camera on one arm), the target on another (``target_tip``: a hand).
  Hand-eye ``X = T_A_camera`` (camera in tip A's link frame), target pose ``B = T_B_target``
  (target in tip B's link frame); ``T_camera_target,i = X⁻¹ · F_A(q_i)⁻¹ · F_B(q_i) · B``, through
  both chains and every joint they share (a shared joint cancels out of ``F_A⁻¹F_B``: what moves
  both tips together is not seen).

A target point ``b_k`` ``[3]`` (mm, target frame; checkerboard corners, ArUco/AprilTag corners)
lands at ``p = T_camera_target·b_k`` in the camera frame and is imaged by OpenCV's pinhole
model with radial-tangential distortion (``cv2.projectPoints``; Brown–Conrady):

``x = p_x/p_z``, ``y = p_y/p_z``, ``r² = x² + y²``,
``x' = x(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)``,
``y' = y(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y``,
``u = fx x' + cx``, ``v = fy y' + cy`` (px).

The residual is the reprojection error ``(û − u, v̂ − v)`` in px per target point, ``[n, 2N]``
per image. A corner that was not detected is ``NaN`` in the data (an empty CSV cell): its
residual is 0 (zero weight), it is counted and reported, never dropped silently. The per-image
error (``sample_error``) is the RMS over the image's *detected* corners of the 2-D reprojection
distance, ``sqrt(Σ_k ‖r_k‖² / N_detected)`` (px), so the RMSE over images is the RMS corner
distance error and the statistical floor is :func:`jaxcal.statistical_floor` with ``size = 2``
and ``n_train`` = the number of detected corners: ``σ√2·sqrt(1 − p/(2·N_det))`` on training data
(see :func:`camera_floor`).

Extras (``kind="extra"`` groups, free by default, like marker positions): ``handeye_rotation``
(``handeye_rx/ry/rz``, rad) and ``handeye_translation`` (``handeye_x/y/z``, mm), ``target_rotation``
and ``target_translation`` (``target_rx…``, ``target_x…``), parametrised like the sensor frame
(``R = exp(δr)·R₀``, ``t = t₀ + δt``); with ``calibrate_intrinsics=True`` also ``intrinsics``
(``cam_fx, cam_fy, cam_cx, cam_cy`` px, ``cam_k1, cam_k2, cam_p1, cam_p2, cam_k3``), additive.

Closed-form start (:func:`initial_camera_extras`): per image a PnP pose (homography DLT for a
planar target, 3-D DLT otherwise, on undistorted normalised coordinates, then Gauss–Newton on
the pixel reprojection error), the hand-eye transform by Park & Martin (1994) exactly as
``cv2.calibrateHandEye(..., method=cv2.CALIB_HAND_EYE_PARK)`` does it (all pairs ``i < j``), then
the target pose as the chordal mean over images. Tip to tip, the relative motion
``F_A⁻¹F_B`` (tip B in tip A's frame) plays the flange's role of eye-to-hand: ``X·C_i =
F_A⁻¹F_B·B``, so Park–Martin takes ``G_i = (F_A⁻¹F_B)⁻¹ = F_B⁻¹F_A``.

References: Z. Zhang, "A flexible new technique for camera calibration", IEEE TPAMI 22(11), 2000
(homography, closed-form pose); F. C. Park, B. J. Martin, "Robot sensor calibration: solving
AX = XB on the Euclidean group", IEEE T-RA 10(5):717–721, 1994; R. Hartley, A. Zisserman,
*Multiple View Geometry*, 2nd ed., §4.4 (normalised DLT); OpenCV ``calib3d`` documentation
(distortion model, ``calibrateHandEye`` conventions).
"""

from __future__ import annotations

import math
import pathlib
import re
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._host_method import host_method
from .._core._params import Deviations, Group, layout_for
from .._core._precision import to_device
from .._core._rotvec import rotvec_to_matrix as rotvec_to_matrix_np
from .._core._xla import filter_jit
from .._models._kinematics import _chain, check_joint_angles, fk_pose_jit, materialised, rotvec_to_matrix
from ._initialise import project_rotation
from ._kind import PointsKind, check_tip, register_kind, resolve_tip
from ._measurement import MeasurementModel, tip_to_dict, xyz_entries

__all__ = ["Camera", "MOUNTS", "INTRINSIC_NAMES", "project_points", "undistort_points", "solve_pnp",
    "hand_eye_park", "initial_camera_extras", "checkerboard", "load_target", "camera_floor",
    "masked_corners", "default_camera", "planning_camera", "target_in_view"]

#: the three set-ups: camera on the moving tip, camera fixed with the target on the moving tip,
#: camera on one tip with the target on another (self-observation)
MOUNTS = ("eye_in_hand", "eye_to_hand", "tip_to_tip")
#: intrinsic parameters in OpenCV's order: focal lengths and principal point (px), distortion
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")

HANDEYE_ROTATION = Group.vector("handeye_rotation", ("handeye_rx", "handeye_ry", "handeye_rz"), "rad")
HANDEYE_TRANSLATION = Group.vector("handeye_translation", ("handeye_x", "handeye_y", "handeye_z"), "mm")
TARGET_ROTATION = Group.vector("target_rotation", ("target_rx", "target_ry", "target_rz"), "rad")
TARGET_TRANSLATION = Group.vector("target_translation", ("target_x", "target_y", "target_z"), "mm")
INTRINSICS = Group("intrinsics", tuple(f"cam_{n}" for n in INTRINSIC_NAMES), ("px",) * 4 + ("1",) * 5, "extra",
                   (9,))
CAMERA_GROUPS = (HANDEYE_ROTATION, HANDEYE_TRANSLATION, TARGET_ROTATION, TARGET_TRANSLATION)


_COLUMN = re.compile(r"([uv])_(\d+)_px")


def _tip_text(tip: str | None) -> str:
    return "the robot's default tip (None)" if tip is None else repr(tip)


def _check_two_tips(tip: str | None, target_tip: str | None) -> None:
    """Tip to tip: the camera's and the target's tips differ (``None``: the default tip)."""
    if tip == target_tip:
        raise ValueError(f"mount='tip_to_tip' needs the camera and the target on two different tips; both are on "
                         f"{_tip_text(tip)} (tip=, target_tip=; None is the robot's default tip): the images would "
                         "not depend on the robot")


def _frame(R, t, what):
    # checked on the host and put on the device as is (jnp.asarray of NumPy runs a small program)
    R = np.eye(3) if R is None else np.asarray(R)
    t = np.zeros(3) if t is None else np.asarray(t)
    Rn = np.asarray(R, np.float64)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"{what}: rotation must be [3, 3] and translation [3] (mm), got {R.shape}, {t.shape}")
    if not (np.allclose(Rn.T @ Rn, np.eye(3), atol=1e-6) and np.linalg.det(Rn) > 0):
        raise ValueError(f"{what}: rotation must be a proper rotation matrix (RᵀR = I, det R = +1)")
    return to_device(R, float), to_device(t, float)


class Camera(MeasurementModel):
    """A calibrated pinhole camera (OpenCV radial-tangential distortion) seeing a known target.

    Readings ``[n, N, 2]`` px: the image coordinates ``(u, v)`` of the ``N`` target points in
    each of ``n`` images, ``NaN`` where a point was not detected (masked: zero weight, counted
    and reported).

    Frames: eye-in-hand, ``X = T_flange_camera`` (OpenCV's ``cam2gripper``), ``B = T_base_target``
    and image ``i`` sees ``T_camera_target = X⁻¹·F(q_i)⁻¹·B`` (``F(q) = T_base_flange``);
    eye-to-hand, ``X = T_base_camera`` (``cam2base``), ``B = T_flange_target`` and
    ``T_camera_target = X⁻¹·F(q_i)·B``; tip to tip (self-observation on a
    :class:`~jaxcal.KinematicTree`: a head camera seeing a target on a hand), ``X = T_A_camera``,
    ``B = T_B_target`` with ``F_A``, ``F_B`` the link frames of ``tip`` and ``target_tip``, and
    ``T_camera_target = X⁻¹·F_A(q_i)⁻¹·F_B(q_i)·B``. A target point ``b_k`` lands at ``p = T_camera_target·b_k``
    and is projected as by ``cv2.projectPoints``: ``x = p_x/p_z``, ``y = p_y/p_z``, ``r² = x² + y²``,
    ``x' = x(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)``,
    ``y' = y(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y``, ``u = fx x' + cx``,
    ``v = fy y' + cy``. The residual is the reprojection error ``(û − u, v̂ − v)`` px per point
    (``[n, 2N]``); ``sample_error`` is the RMS over an image's detected points of the 2-D
    reprojection distance (px).

    Extras (free by default): ``handeye_rotation`` (``handeye_rx/ry/rz``, rad),
    ``handeye_translation`` (``handeye_x/y/z``, mm), ``target_rotation``, ``target_translation``
    (``target_rx…``, ``target_x…``), as ``R = exp(δr)·R₀``, ``t = t₀ + δt``; with
    ``calibrate_intrinsics=True`` also ``intrinsics`` (``cam_fx, cam_fy, cam_cx, cam_cy`` px,
    ``cam_k1, cam_k2, cam_p1, cam_p2, cam_k3``), additive. :func:`jaxcal.calibrate` starts them in
    closed form (per-image PnP, then the hand-eye transform by Park & Martin 1994 as
    ``cv2.calibrateHandEye(..., method=cv2.CALIB_HAND_EYE_PARK)``).

    Args:
        points_mm: ``[N, 3]`` target points in the target frame (mm), in the order of the
            data columns ``u_k_px, v_k_px``.
        intrinsics: ``[9]`` ``fx, fy, cx, cy`` (px), ``k1, k2, p1, p2, k3`` (OpenCV order;
            four or five distortion entries may be left out: zeros).
        mount: ``"eye_in_hand"``, ``"eye_to_hand"`` or ``"tip_to_tip"``.
        handeye_rotation, handeye_translation: nominal ``X`` (``[3, 3]``, ``[3]`` mm):
            ``T_flange_camera`` eye-in-hand, ``T_base_camera`` eye-to-hand, ``T_A_camera`` tip
            to tip (default identity: unknown, started from the data).
        target_rotation, target_translation: nominal ``B``: ``T_base_target`` eye-in-hand,
            ``T_flange_target`` eye-to-hand, ``T_B_target`` tip to tip.
        image_size: ``(width, height)`` px, used to keep simulated targets in view (optional).
        calibrate_intrinsics: add the ``intrinsics`` group (free by default) — off by default:
            a camera calibrated beforehand (``cv2.calibrateCamera``) is usually better known.
        tip: the tip of a :class:`~jaxcal.KinematicTree` that moves: the one carrying the camera
            (eye-in-hand and tip to tip: a head camera) or the target (eye-to-hand); ``None``: the
            robot's default tip. ``F(q)`` (``F_A`` tip to tip) is then that tip's link frame.
        target_tip: tip to tip only: the tip that carries the target (tip B, a hand), in the
            convention of ``tip`` (``None``: the robot's default tip; :func:`jaxcal.resolve_tip`
            gives it for a tip's name); it must differ from ``tip``.

    Why a third mount and not only a ``target_tip=`` beside the two others: the mount already says
    what the robot moves and in which frames ``X`` and ``B`` are given (flange or base), and tip to
    tip both are tip frames; and ``None`` keeps meaning "the robot's default tip" for both tips, as
    for every model's ``tip`` — a ``target_tip`` on ``"eye_in_hand"`` whose ``None`` meant "fixed in
    the base" could not name the default tip. A camera fixed to the root (a chest camera) seeing a
    hand is ``"eye_to_hand"`` with ``tip`` the hand; a camera on a hand seeing a target fixed in
    the cell is ``"eye_in_hand"``.

    Raises:
        ValueError: ``target_tip`` given with another mount, or the camera and the target on one
            tip (the images then do not depend on the robot). A tip the robot lacks is named, with
            the robot's tips, where the model meets the robot (:meth:`tip_for`,
            :meth:`target_tip_for`).
    """

    points: Float[Array, "N 3"]
    intrinsics: Float[Array, " 9"]
    handeye_rotation: Float[Array, "3 3"]
    handeye_translation: Float[Array, " 3"]
    target_rotation: Float[Array, "3 3"]
    target_translation: Float[Array, " 3"]
    mount: str = eqx.field(static=True, default="eye_in_hand")
    image_size: tuple[int, int] | None = eqx.field(static=True, default=None)
    calibrate_intrinsics: bool = eqx.field(static=True, default=False)
    tip: str | None = eqx.field(static=True, default=None)
    target_tip: str | None = eqx.field(static=True, default=None)
    kind: ClassVar[str] = "camera"
    initialisable: ClassVar[tuple[str, ...]] = ("handeye", "target")
    sees_tool_point: ClassVar[bool] = False
    #: unit of the residual and of the per-sample errors
    unit: ClassVar[str] = "px"
    point_entries: ClassVar[int | None] = 2  # a corner's u, v: the outlier scan judges each corner
    point_word: ClassVar[str] = "corner"

    def __init__(self, points_mm, intrinsics, mount: str = "eye_in_hand", *, handeye_rotation=None,
                 handeye_translation=None, target_rotation=None, target_translation=None, image_size=None,
                 calibrate_intrinsics: bool = False, tip: str | None = None, target_tip: str | None = None):
        self.tip = None if tip is None else str(tip)
        self.target_tip = None if target_tip is None else str(target_tip)
        pts = jnp.asarray(points_mm, jnp.result_type(float))
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 4:
            raise ValueError(f"points_mm must be [N, 3] target points (mm), N >= 4; got shape {tuple(pts.shape)}")
        if not np.all(np.isfinite(np.asarray(pts))):
            raise ValueError("points_mm contain NaN/inf")
        k = np.asarray(intrinsics, np.float64).ravel()
        if k.size not in (4, 8, 9) or not np.all(np.isfinite(k)) or k[0] <= 0 or k[1] <= 0:
            raise ValueError("intrinsics must be fx, fy, cx, cy [, k1, k2, p1, p2 [, k3]] with fx, fy > 0 (px); "
                             f"got {k.tolist()}")
        k = np.concatenate([k, np.zeros(9 - k.size)])
        mount = mount.replace("-", "_").lower()
        if mount not in MOUNTS:
            raise ValueError(f"mount must be one of {MOUNTS}, got {mount!r}")
        if target_tip is not None and mount != "tip_to_tip":
            raise ValueError(f"target_tip={target_tip!r} applies to mount='tip_to_tip' (a camera on one tip seeing a "
                             f"target on another), not {mount!r}")
        if mount == "tip_to_tip":
            _check_two_tips(self.tip, self.target_tip)
        self.points = pts
        self.intrinsics = to_device(k, float)
        self.mount = mount
        self.handeye_rotation, self.handeye_translation = _frame(handeye_rotation, handeye_translation, "hand-eye")
        self.target_rotation, self.target_translation = _frame(target_rotation, target_translation, "target pose")
        self.image_size = None if image_size is None else (int(image_size[0]), int(image_size[1]))
        self.calibrate_intrinsics = bool(calibrate_intrinsics)

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def error_points(self) -> int:  # type: ignore[override]
        """The target points: a prediction's per-image error is the RMS over them."""
        return self.n_points

    def target_tip_for(self, robot) -> str | None:
        """Tip to tip: the model's ``target_tip`` checked against ``robot``
        (as :meth:`tip_for` checks ``tip``; host-side, also at trace time: the tip is static).

        Raises:
            ValueError: another mount (the target is on no tip of its own), or a tip the robot
                does not have (the message names it and lists the robot's tips).
        """
        if self.mount != "tip_to_tip":
            raise ValueError(f"a {self.mount} camera's target is on no tip of its own (mount='tip_to_tip' is)")
        try:
            return check_tip(robot, self.target_tip)
        except ValueError as e:
            raise ValueError(f"the camera's target_tip: {e}") from None

    @host_method
    def with_frames(self, X, B) -> Camera:
        """This camera with the nominal hand-eye transform ``X`` and target pose ``B`` (``[4, 4]``, mm)."""
        X, B = np.asarray(X, np.float64), np.asarray(B, np.float64)
        return Camera(self.points, self.intrinsics, self.mount, handeye_rotation=X[:3, :3], handeye_translation=X[:3, 3],
                      target_rotation=B[:3, :3], target_translation=B[:3, 3], image_size=self.image_size,
                      calibrate_intrinsics=self.calibrate_intrinsics, tip=self.tip, target_tip=self.target_tip)

    @host_method
    def tip_name(self, robot) -> str | None:
        """The name of the tip ``tip`` stands for on ``robot`` (the default tip's for ``None``)."""
        return self.tip_for(robot) or robot.default_tip()

    @host_method
    def target_tip_name(self, robot) -> str | None:
        """Tip to tip: the name of the target's tip on ``robot`` (the default tip's for ``None``)."""
        return self.target_tip_for(robot) or robot.default_tip()

    @host_method
    def at_tip(self, tip: str | None) -> Camera:
        """This camera with ``tip`` (the camera's tip tip to tip; the moving tip otherwise) instead
        (:meth:`jaxcal.MeasurementModel.at_tip`).

        Raises:
            ValueError: tip to tip, ``tip`` is the target's tip.
        """
        new = super().at_tip(tip)
        if new.mount == "tip_to_tip":
            _check_two_tips(new.tip, new.target_tip)
        return new

    @property
    def size(self) -> int:  # type: ignore[override]
        return 2 * self.n_points

    @property
    def sample_shape(self) -> tuple[int, ...]:  # type: ignore[override]
        return (self.n_points, 2)

    def extra_groups(self) -> tuple[Group, ...]:
        """Hand-eye and target pose (always), the intrinsics with ``calibrate_intrinsics``."""
        return CAMERA_GROUPS + ((INTRINSICS,) if self.calibrate_intrinsics else ())

    def nominal_lengths(self) -> dict[str, float]:
        return xyz_entries("handeye_", self.handeye_translation) | xyz_entries("target_", self.target_translation)

    # -- frames ---------------------------------------------------------------------------------
    def frames(self, deviations: Deviations | None, dtype=None):
        """``(R_X, t_X, R_B, t_B, k)``: the hand-eye and target transforms and the ``[9]``
        intrinsics, nominal corrected by the deviations (``R = exp(δr)·R₀``, ``t = t₀ + δt``)."""
        dtype = dtype or self.points.dtype
        RX, tX = self.handeye_rotation.astype(dtype), self.handeye_translation.astype(dtype)
        RB, tB = self.target_rotation.astype(dtype), self.target_translation.astype(dtype)
        k = self.intrinsics.astype(dtype)
        if deviations is not None:
            vals = deviations.values
            if "handeye_rotation" in vals:
                RX = rotvec_to_matrix(vals["handeye_rotation"].astype(dtype)) @ RX
                tX = tX + vals["handeye_translation"].astype(dtype)
                RB = rotvec_to_matrix(vals["target_rotation"].astype(dtype)) @ RB
                tB = tB + vals["target_translation"].astype(dtype)
            if "intrinsics" in vals:
                k = k + vals["intrinsics"].astype(dtype)
        return RX, tX, RB, tB, k

    def camera_map(self, robot, deviations, q):
        """The camera-frame points as one affine map per image of fixed points:
        ``p_ik = A_i·w_k + a_i`` (mm), returned as ``(Aa [12, n], w [N, 3], k [9])``: the rows of
        ``A_i`` (row-major, 9) and ``a_i`` (3) as structure-of-arrays ``[n]`` rows, the target
        points ``w`` in the frame the robot does not move (eye-in-hand: ``T_base_target·b``, base
        frame; eye-to-hand: ``T_flange_target·b``, flange frame; tip to tip: ``T_B_target·b``, tip
        B's link frame) and the intrinsics.

        Eye-in-hand ``p = R_Xᵀ(Fᵀ(w − P) − t_X)``: ``A = R_XᵀRᵀ``, ``a = −R_Xᵀ(RᵀP + t_X)``;
        eye-to-hand ``p = R_Xᵀ(P + R·w − t_X)``: ``A = R_XᵀR``, ``a = R_Xᵀ(P − t_X)``, with
        ``F = (R, P)`` the flange frame; tip to tip ``p = R_Xᵀ(R_Aᵀ(P_B + R_B·w − P_A) − t_X)``,
        eye-to-hand's form with the relative frame ``F_A⁻¹F_B = (R_AᵀR_B, R_Aᵀ(P_B − P_A))`` as
        ``F``: ``A = R_XᵀR_AᵀR_B``, ``a = R_Xᵀ(R_Aᵀ(P_B − P_A) − t_X)``, both tips' frames from the
        tree's frame kernel (:meth:`jaxcal.KinematicTree.frame_soa`). Every parameter of the robot
        and the hand-eye transform acts on the image only through ``(A, a)`` (12 numbers per
        image), and the target pose only through ``w``: :func:`_affine_project` uses this
        structure for its derivative."""
        q = check_joint_angles(robot, q)
        # the flange frames computed once and stored: XLA:CPU would otherwise fuse the whole
        # kinematic chain into every [n, N] consumer and recompute it per target point (and per
        # Jacobian column): 0.8 s instead of ~10 ms for a 2160 × 36 Jacobian (see materialised)
        tips = (self.tip_for(robot),) + ((self.target_tip_for(robot),) if self.mount == "tip_to_tip" else ())
        F = materialised(jnp.stack([c for tip in tips for v in _chain(robot, deviations, q, tip) for c in v]))  # [12·t, n]
        cols = tuple(tuple(F[3 * i + r] for r in range(3)) for i in range(3))  # R's columns
        P = tuple(F[9 + r] for r in range(3))
        if self.mount == "tip_to_tip":  # tip B in tip A's frame: (R_AᵀR_B, R_Aᵀ(P_B − P_A))
            cols_b = tuple(tuple(F[12 + 3 * i + r] for r in range(3)) for i in range(3))
            P_b = tuple(F[21 + r] for r in range(3))
            cols, P = (tuple(tuple(sum(cols[i][r] * cols_b[j][r] for r in range(3)) for i in range(3))
                             for j in range(3)),
                       tuple(sum(cols[i][r] * (P_b[r] - P[r]) for r in range(3)) for i in range(3)))
        RX, tX, RB, tB, k = self.frames(deviations, q.dtype)
        w = self.points.astype(q.dtype) @ RB.T + tB  # [N, 3]
        if self.mount == "eye_in_hand":
            A = [[sum(RX[c, i] * cols[c][j] for c in range(3)) for j in range(3)] for i in range(3)]
            RtP = [sum(cols[c][r] * P[r] for r in range(3)) for c in range(3)]
            a = [-sum(RX[c, i] * (RtP[c] + tX[c]) for c in range(3)) for i in range(3)]
        else:
            A = [[sum(RX[r, i] * cols[j][r] for r in range(3)) for j in range(3)] for i in range(3)]
            a = [sum(RX[r, i] * (P[r] - tX[r]) for r in range(3)) for i in range(3)]
        # stored once (see materialised): read per target point, it would be recomputed per point
        return materialised(jnp.stack([A[i][j] for i in range(3) for j in range(3)] + a)), w, k

    def camera_points(self, robot, deviations, q) -> tuple[Array, Array, Array]:
        """The target points in the camera frame: three ``[n, N]`` arrays (mm)."""
        Aa, w, _ = self.camera_map(robot, deviations, q)
        return _apply_affine(Aa, w)

    def predict(self, robot, deviations, q) -> Float[Array, "n N 2"]:
        """Image coordinates ``[n, N, 2]`` (px) of every target point (none masked)."""
        return _affine_project(*self.camera_map(robot, deviations, q))

    def residual(self, robot, deviations, q, y) -> Float[Array, "n 2N"]:
        """``predicted − measured`` (px) ``[n, 2N]``; 0 where ``y`` is NaN (not detected)."""
        y = jnp.asarray(y)
        ok = jnp.isfinite(y)
        r = self.predict(robot, deviations, q) - jnp.where(ok, y, 0.0)
        return jnp.where(ok, r, 0.0).reshape(q.shape[0], self.size)

    def sample_error(self, residual) -> Float[Array, " n"]:
        """RMS over an image's detected corners of the 2-D reprojection distance (px). Masked
        corners have an exactly zero residual and are left out of the mean (a detected corner
        whose residual is exactly 0.0 would be too: a measure-zero event with noisy data)."""
        r = residual.reshape(residual.shape[0], self.n_points, 2)
        sq = jnp.sum(r * r, axis=-1)
        count = jnp.sum(sq > 0, axis=-1).astype(sq.dtype)
        return jnp.sqrt(jnp.sum(sq, axis=-1) / jnp.maximum(count, 1.0))

    @host_method
    def observed(self, y) -> np.ndarray | None:
        """``[n, 2N]`` bool: the residual entries of detected corners (NaN = not detected), or
        ``None`` when every corner of every image was detected; so σ̂, the robust and outlier
        scales and the residual count leave the masked corners out."""
        seen = np.isfinite(np.asarray(y, np.float64)).reshape(np.shape(y)[0], -1)
        return None if seen.all() else seen

    @host_method
    def check_measurements(self, y, n: int) -> None:
        """``[n, N, 2]``, finite or NaN (not detected); ±inf is an error."""
        shape = tuple(np.shape(y))
        if shape != (n, *self.sample_shape):
            raise ValueError(f"camera measurements must have shape {[n, *self.sample_shape]} for {n} images "
                             f"({self.n_points} target points), got {list(shape)}")
        yn = np.asarray(y)
        if np.isinf(yn).any():
            raise ValueError("camera measurements contain ±inf (not-detected corners are NaN / empty cells)")


def _distort_project(x, y, k):
    """OpenCV's distortion and camera matrix on normalised coordinates ``x, y`` → ``(u, v)`` px."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (k[i] for i in range(9))
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return fx * xd + cx, fy * yd + cy


def _apply_affine(Aa, w):
    """``p_ik = A_i·w_k + a_i``: three ``[n, N]`` arrays from ``Aa`` ``[12, n]`` and ``w`` ``[N, 3]``."""
    return tuple(sum(Aa[3 * i + j][:, None] * w[None, :, j] for j in range(3)) + Aa[9 + i][:, None] for i in range(3))


@jax.custom_jvp
def _affine_project(Aa, w, k):
    """Image coordinates ``[n, N, 2]`` (px) of the points ``p_ik = A_i·w_k + a_i``
    (:meth:`Camera.camera_map`), with a derivative rule that follows the structure.

    ``jax.jacfwd`` pushes one tangent per parameter through the whole per-point computation
    (``[n, N]`` arrays: the affine map, the division, the distortion polynomial), ~100 flops per
    point and parameter. Here the chain rule is taken once per point: with ``L_ik = ∂(u, v)/∂p``
    ``[2, 3]`` (closed form), ``d(u, v)_ik = L_ik·(dA_i·w_k + da_i) + (L_ik·A_i)·dw_k`` is the
    contraction of ``[n, N, 2, 12]`` per-point coefficients with the ``[12, n]`` tangent of
    ``(A, a)``, plus ``[n, N, 2, 3]`` with the ``[N, 3]`` tangent of ``w`` — dot products that
    XLA batches over the parameters. Intrinsics (with ``calibrate_intrinsics``) are
    differentiated by ``jax.jacfwd`` of the projection; tangents that are known zeros are
    skipped (``symbolic_zeros``). Exact: the Jacobian agrees with plain ``jax.jacfwd`` to
    round-off (``tests/sensors/test_camera.py``)."""
    px, py, pz = _apply_affine(Aa, w)
    u, v = _distort_project(px / pz, py / pz, k)
    return jnp.stack([u, v], -1)


def _affine_project_jvp(primals, tangents):
    from jax.custom_derivatives import SymbolicZero

    Aa, w, k = primals
    dAa, dw, dk = tangents
    px, py, pz = _apply_affine(Aa, w)
    iz = 1.0 / pz
    x, y = px * iz, py * iz
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (k[i] for i in range(9))
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    uv = jnp.stack([fx * xd + cx, fy * yd + cy], -1)
    drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r²
    dxx = radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x  # ∂xd/∂x
    dxy = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y  # ∂xd/∂y = ∂yd/∂x
    dyy = radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x  # ∂yd/∂y
    # L = diag(fx, fy)·∂(xd, yd)/∂(x, y)·∂(x, y)/∂p,  ∂(x, y)/∂p = [[1, 0, −x], [0, 1, −y]]/p_z
    L = jnp.stack([jnp.stack([fx * dxx * iz, fx * dxy * iz, -fx * (dxx * x + dxy * y) * iz], -1),
                   jnp.stack([fy * dxy * iz, fy * dyy * iz, -fy * (dxy * x + dyy * y) * iz], -1)], -2)  # [n, N, 2, 3]
    out = jnp.zeros_like(uv)
    if not isinstance(dAa, SymbolicZero):
        c = jnp.concatenate([(L[..., :, None] * w[None, :, None, None, :]).reshape(*L.shape[:3], 9), L], -1)
        out = out + jnp.einsum("nkaj,jn->nka", c, dAa)
    if not isinstance(dw, SymbolicZero):
        A = Aa[:9].T.reshape(-1, 3, 3)  # [n, 3, 3]
        out = out + jnp.einsum("nkaj,kj->nka", jnp.einsum("nkai,nij->nkaj", L, A), dw)
    if not isinstance(dk, SymbolicZero):
        Lk = jax.jacfwd(lambda kk: jnp.stack(_distort_project(x, y, kk), -1), argnums=0)(k)  # [n, N, 2, 9]
        out = out + jnp.einsum("nkaj,j->nka", Lk, dk)
    return uv, out


_affine_project.defjvp(_affine_project_jvp, symbolic_zeros=True)


# -- NumPy geometry ------------------------------------------------------------------------------
def _log(R) -> np.ndarray:
    """Rotation vectors ``[..., 3]`` of ``R`` ``[..., 3, 3]`` (rad), accurate near 0 and π (via the
    quaternion: Shepperd's branch on the trace or the largest diagonal entry, per matrix)."""
    R = np.asarray(R, np.float64)
    tr = np.trace(R, axis1=-2, axis2=-1)
    d = np.diagonal(R, axis1=-2, axis2=-1)
    with np.errstate(invalid="ignore", divide="ignore"):  # the branches not taken may divide by 0
        s = np.sqrt(tr + 1.0) * 2
        q = np.stack([0.25 * s, (R[..., 2, 1] - R[..., 1, 2]) / s, (R[..., 0, 2] - R[..., 2, 0]) / s,
                      (R[..., 1, 0] - R[..., 0, 1]) / s], -1)  # w, x, y, z
        big = np.argmax(d, axis=-1)
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            s = np.sqrt(1.0 + R[..., i, i] - R[..., j, j] - R[..., k, k]) * 2
            qi = np.empty_like(q)
            qi[..., 0] = (R[..., k, j] - R[..., j, k]) / s
            qi[..., 1 + i] = 0.25 * s
            qi[..., 1 + j] = (R[..., j, i] + R[..., i, j]) / s
            qi[..., 1 + k] = (R[..., k, i] + R[..., i, k]) / s
            q = np.where(((tr <= 0) & (big == i))[..., None], qi, q)
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    sv = np.linalg.norm(v, axis=-1)
    small = sv < 1e-15
    return np.where(small[..., None], 2 * v,
                    (2 * np.arctan2(sv, q[..., 0]))[..., None] * v / np.where(small, 1.0, sv)[..., None])


def _inv(T) -> np.ndarray:
    T = np.asarray(T, np.float64)
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def _T(R, t) -> np.ndarray:
    """Homogeneous transforms ``[..., 4, 4]`` of ``R`` ``[..., 3, 3]`` and ``t`` ``[..., 3]``."""
    R = np.asarray(R, np.float64)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3], T[..., :3, 3], T[..., 3, 3] = R, t, 1.0
    return T


def project_points(points_cam, intrinsics) -> np.ndarray:
    """NumPy projection of camera-frame points ``[..., 3]`` (mm) → ``[..., 2]`` px (OpenCV model)."""
    p = np.asarray(points_cam, np.float64)
    k = np.concatenate([np.asarray(intrinsics, np.float64).ravel(), np.zeros(9)])[:9]
    u, v = _distort_project(p[..., 0] / p[..., 2], p[..., 1] / p[..., 2], k)
    return np.stack([u, v], axis=-1)


def undistort_points(uv, intrinsics, iterations: int = 20) -> np.ndarray:
    """Normalised coordinates ``[..., 2]`` of pixels ``uv`` ``[..., 2]``: the fixed-point
    inversion of the distortion that ``cv2.undistortPoints`` uses (exact for no distortion)."""
    k = np.concatenate([np.asarray(intrinsics, np.float64).ravel(), np.zeros(9)])[:9]
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = k
    uv = np.asarray(uv, np.float64)
    x0, y0 = (uv[..., 0] - cx) / fx, (uv[..., 1] - cy) / fy
    x, y = x0.copy(), y0.copy()
    for _ in range(iterations if np.any(k[4:]) else 0):
        r2 = x * x + y * y
        icdist = 1.0 / (1 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (x0 - dx) * icdist, (y0 - dy) * icdist
    return np.stack([x, y], axis=-1)


def _null_vector(A) -> np.ndarray:
    """Unit right singular vectors ``[m, p]`` of the smallest singular value of ``A`` ``[m, r, p]``
    (the DLT solution; rows of zeros, e.g. undetected points, change nothing). Fewer rows than
    unknowns are padded with zero rows, so the minimal case gets the null vector, not the
    smallest non-zero direction. A matrix with a non-finite entry gets NaN (alone)."""
    m, r, p = A.shape
    bad = ~np.isfinite(A).all(axis=(1, 2))
    A = np.where(bad[:, None, None], 0.0, A)
    if r < p:
        A = np.concatenate([A, np.zeros((m, p - r, p))], axis=1)
    v = np.linalg.svd(A, full_matrices=False)[2][:, -1]
    return np.where(bad[:, None], np.nan, v)


def _normalise_2d(p, w):
    """Hartley's normalising similarities ``[m, 3, 3]`` of points ``p`` ``[m, N, 2]`` over the
    points with weight ``w`` ``[m, N]`` = 1 (0: not detected): centroid to 0, mean distance √2."""
    n = w.sum(axis=1)
    c = np.sum(p * w[..., None], axis=1) / n[:, None]
    s = math.sqrt(2) / np.maximum(np.sum(w * np.linalg.norm(p - c[:, None], axis=-1), axis=1) / n, 1e-12)
    T = np.zeros((len(p), 3, 3))
    T[:, 0, 0], T[:, 1, 1], T[:, 2, 2] = s, s, 1.0
    T[:, :2, 2] = -s[:, None] * c
    return T


def _homography(src, dst, w) -> np.ndarray:
    """``H`` ``[m, 3, 3]`` with ``dst ~ H src`` (normalised DLT, Hartley & Zisserman Alg. 4.2) per
    image from ``src``, ``dst`` ``[m, N, 2]`` over the points with weight ``w`` ``[m, N]`` = 1."""
    Ts, Td = _normalise_2d(src, w), _normalise_2d(dst, w)
    one = np.ones(src.shape[:-1] + (1,))
    s = np.concatenate([src, one], axis=-1) @ np.swapaxes(Ts, 1, 2)
    d = np.concatenate([dst, one], axis=-1) @ np.swapaxes(Td, 1, 2)
    x, y, v_s, u, v, z = s[..., 0], s[..., 1], s[..., 2], d[..., 0], d[..., 1], d[..., 2]
    o = np.zeros_like(x)
    A = np.stack([np.stack([o, o, o, -z * x, -z * y, -z * v_s, v * x, v * y, v * v_s], axis=-1),
                  np.stack([z * x, z * y, z * v_s, o, o, o, -u * x, -u * y, -u * v_s], axis=-1)], axis=2)
    H = _null_vector((A * w[..., None, None]).reshape(len(src), -1, 9)).reshape(-1, 3, 3)
    return np.linalg.inv(Td) @ H @ Ts


def _pose_residuals(R, t, pts, uv, ok, k):
    """Reprojection errors ``[..., N, 2]`` (px) of the target points ``pts`` ``[N, 3]`` at poses
    ``R`` ``[..., 3, 3]``, ``t`` ``[..., 3]``; 0 where ``ok`` ``[..., N]`` is False (not detected)."""
    r = project_points(pts @ np.swapaxes(R, -1, -2) + t[..., None, :], k) - uv
    return np.where(ok[..., None], r, 0.0)


def _squares(r):
    """``Σ r²`` ``[m]`` of residuals ``[m, N, 2]`` (a BLAS dot product per image)."""
    f = r.reshape(len(r), 1, -1)
    return (f @ np.swapaxes(f, 1, 2))[:, 0, 0]


def _solve_each(A, b):
    """``np.linalg.solve`` of a stack ``A`` ``[m, 6, 6]``, ``b`` ``[m, 6]``; a singular matrix
    gives a NaN solution and its index in the second output, the others are solved."""
    try:
        return np.linalg.solve(A, b[..., None])[..., 0], np.zeros(len(A), bool)
    except np.linalg.LinAlgError:
        x, singular = np.full(b.shape, np.nan), np.zeros(len(A), bool)
        for i in range(len(A)):
            try:
                x[i] = np.linalg.solve(A[i], b[i])
            except np.linalg.LinAlgError:
                singular[i] = True
        return x, singular


#: central-difference steps of the pose fit: rotation vector (rad), translation (mm)
_PNP_STEPS = np.array([1e-7] * 3 + [1e-5] * 3)


def _refine_poses(R, t, pts, uv, ok, k, iterations: int = 30):
    """Levenberg–Marquardt on the pixel reprojection error of ``m`` images' poses side by side.

    Each image is its own problem (6 unknowns, central-difference Jacobian, the update
    ``R ← exp(δ)·R``, ``t ← t + δ``) with its own damping ``λ`` (÷10 on a decrease, ×10 on an
    increase; given up above 1e10) and its own stop (a relative decrease of the squared error
    below 1e-14, or ``iterations`` steps): a batched step runs the one-image iteration of every
    image that is still going, so one image that fails or converges late does not change another.

    Args:
        R, t: ``[m, 3, 3]``, ``[m, 3]`` starting poses ``T_camera_target``.
        pts: ``[N, 3]`` target points (mm); uv: ``[m, N, 2]`` px; ok: ``[m, N]`` detected.

    Returns:
        ``(R, t, r, singular)``: the poses, their residuals ``[m, N, 2]`` (0 where not detected)
        and ``[m]`` whether the damped normal equations of an image were singular (its pose is
        then the last one reached; :func:`solve_pnp` raises ``LinAlgError`` for it).
    """
    R, t = R.copy(), t.copy()
    m = len(R)
    e = np.diag(_PNP_STEPS)
    Dp, Dm = rotvec_to_matrix_np(e[:, :3]), rotvec_to_matrix_np(-e[:, :3])  # [6, 3, 3]; I for j ≥ 3
    r = _pose_residuals(R, t, pts, uv, ok, k)
    ss = _squares(r)
    lam = np.full(m, 1e-3)
    going, singular = np.ones(m, bool), np.zeros(m, bool)
    for _ in range(iterations):
        a = np.flatnonzero(going)
        if not a.size:
            break
        Rpm = np.stack([Dp @ R[a, None], Dm @ R[a, None]], axis=1)  # [ma, ±, 6, 3, 3]
        tpm = np.stack([t[a, None] + e[:, 3:], t[a, None] - e[:, 3:]], axis=1)
        rpm = _pose_residuals(Rpm, tpm, pts, uv[a, None, None], ok[a, None, None], k)
        J = ((rpm[:, 0] - rpm[:, 1]) / (2 * _PNP_STEPS)[:, None, None]).reshape(len(a), 6, -1)
        J = np.ascontiguousarray(np.swapaxes(J, 1, 2))  # [ma, 2N, 6]
        H, g = np.swapaxes(J, 1, 2) @ J, (np.swapaxes(J, 1, 2) @ r[a].reshape(len(a), -1, 1))[..., 0]
        dH = np.diagonal(H, axis1=1, axis2=2)
        pend = np.arange(len(a))  # the images of this step still looking for a decrease
        while pend.size:
            i = a[pend]
            step, sing = _solve_each(H[pend] + lam[i, None, None] * (np.eye(6) * (dH[pend] + 1e-12)[:, None, :]),
                                     g[pend])
            singular[i[sing]], going[i[sing]] = True, False
            Rn, tn = rotvec_to_matrix_np(-step[:, :3]) @ R[i], t[i] - step[:, 3:]
            rn = _pose_residuals(Rn, tn, pts, uv[i], ok[i], k)
            ssn = _squares(rn)
            acc = (ssn < ss[i]) & ~sing
            ia = i[acc]
            done = ss[ia] - ssn[acc] < 1e-14 * ss[ia] + 1e-24
            R[ia], t[ia], r[ia], ss[ia], lam[ia] = Rn[acc], tn[acc], rn[acc], ssn[acc], lam[ia] / 10
            going[ia[done]] = False
            rej = ~acc & ~sing
            lam[i[rej]] *= 10
            stuck = rej & (lam[i] > 1e10)
            going[i[stuck]] = False
            pend = pend[rej & ~stuck]
    return R, t, r, singular


def _solve_pnp_images(points_mm, uv, intrinsics):
    """:func:`solve_pnp` of ``n`` images of one target at once (NumPy over the images: each
    step one array program, no loop over images).

    Args:
        points_mm: ``[N, 3]`` target points (mm); uv: ``[n, N, 2]`` px (NaN: not detected);
        intrinsics: ``[9]`` (or ``[4]``/``[8]``).

    Returns:
        ``(R [n, 3, 3], t [n, 3], rms_px [n], errors)``: ``errors[i]`` is ``None`` or the
        exception :func:`solve_pnp` raises for image ``i`` (its pose and RMS are then NaN).
    """
    P = np.asarray(points_mm, np.float64)
    uv = np.asarray(uv, np.float64)
    n = uv.shape[0]
    k = np.concatenate([np.asarray(intrinsics, np.float64).ravel(), np.zeros(9)])[:9]
    ok = np.isfinite(uv).all(axis=-1)
    w = ok.astype(np.float64)
    n_ok = ok.sum(axis=1)
    errors: list = [None] * n
    R, t = np.full((n, 3, 3), np.nan), np.full((n, 3), np.nan)
    # each image's detected points: centroid, principal axes (undetected rows are zero rows)
    c = np.sum(np.where(ok[..., None], P, 0.0), axis=1) / np.maximum(n_ok, 1)[:, None]
    Pc = np.where(ok[..., None], P - c[:, None], 0.0)
    _, s, Vt = np.linalg.svd(Pc, full_matrices=False)
    planar = s[:, -1] <= 1e-9 * s[:, 0]
    need = np.where(planar, 4, 6)
    for i in np.flatnonzero(n_ok < need):
        errors[i] = ValueError(f"PnP needs at least {need[i]} detected points, got {n_ok[i]}")
    xn = np.where(ok[..., None], undistort_points(uv, k), 0.0)
    pl = np.flatnonzero(planar & (n_ok >= 4))
    if pl.size:  # plane frame: origin c, axes Vt[0], Vt[1], normal Vt[2] (a right-handed frame)
        E = Vt[pl].copy()
        E[np.linalg.det(E) < 0, 2] *= -1
        H = _homography(Pc[pl] @ np.swapaxes(E[:, :2], 1, 2), xn[pl], w[pl])
        h1, h2, h3 = H[..., 0], H[..., 1], H[..., 2]
        lam = 2.0 / (np.linalg.norm(h1, axis=-1) + np.linalg.norm(h2, axis=-1))
        lam = np.where(h3[:, 2] * lam < 0, -lam, lam)[:, None]  # the target in front of the camera
        r1, r2 = lam * h1, lam * h2
        Rp = project_rotation(np.stack([r1, r2, np.cross(r1, r2)], axis=-1))  # R_camera_plane
        R[pl] = Rp @ E  # target frame: x_plane = E (x − c)
        t[pl] = lam * h3 - (R[pl] @ c[pl, :, None])[..., 0]
    gen = np.flatnonzero(~planar & (n_ok >= 6))
    if gen.size:  # DLT of [R|t] on [X Y Z 1] (centred)
        Xh = np.concatenate([Pc[gen], w[gen, :, None]], axis=-1)
        x, y, o = xn[gen, :, :1], xn[gen, :, 1:], np.zeros_like(Xh)
        A = np.stack([np.concatenate([Xh, o, -x * Xh], -1), np.concatenate([o, Xh, -y * Xh], -1)], axis=2)
        M = _null_vector(A.reshape(len(gen), -1, 12)).reshape(-1, 3, 4)
        M = M / np.cbrt(np.linalg.det(M[:, :, :3]))[:, None, None]
        Rg = project_rotation(M[:, :, :3])
        tg = M[:, :, 3] - (Rg @ c[gen, :, None])[..., 0]
        z = np.sum(w[gen] * (P @ np.swapaxes(Rg, 1, 2) + tg[:, None])[..., 2], axis=1) / n_ok[gen]
        for i in gen[z < 0]:
            errors[i] = ValueError("PnP: degenerate view (target behind the camera)")
        R[gen[z >= 0]], t[gen[z >= 0]] = Rg[z >= 0], tg[z >= 0]
    for i in np.flatnonzero(~(np.isfinite(R).all(axis=(1, 2)) & np.isfinite(t).all(axis=1))):
        errors[i] = errors[i] or ValueError("PnP: degenerate view")
    run = np.array([i for i in range(n) if errors[i] is None], dtype=int)
    rms = np.full(n, np.nan)
    if run.size:
        R[run], t[run], r, singular = _refine_poses(R[run], t[run], P, uv[run], ok[run], k)
        rms[run] = np.sqrt(np.sum(np.sum(r * r, axis=-1), axis=-1) / n_ok[run])
        for i in run[singular]:
            errors[i] = np.linalg.LinAlgError("PnP: singular normal equations in the pose fit")
    bad = np.array([e is not None for e in errors], dtype=bool)
    R[bad], t[bad], rms[bad] = np.nan, np.nan, np.nan
    return R, t, rms, errors


def solve_pnp(points_mm, uv, intrinsics):
    """Pose ``T_camera_target`` (``R [3, 3]``, ``t [3]`` mm) of a target seen in one image.

    Args:
        points_mm: ``[N, 3]`` target points (mm, target frame).
        uv: ``[N, 2]`` detected image points (px); rows with NaN are left out.
        intrinsics: ``[9]`` (or ``[4]``/``[8]``) OpenCV intrinsics.

    Planar targets (the smallest singular value of the centred points below 1e-9 of the
    largest): homography DLT from the plane's 2-D coordinates to the undistorted normalised
    image points, ``H ∝ [r1 r2 t]`` (Zhang 2000, §3.1), the rotation projected onto SO(3).
    Other targets: DLT of the ``3×4`` matrix ``[R|t]`` (≥ 6 points). Then Levenberg–Marquardt on
    the pixel reprojection error with the distortion. Returns ``(R, t, rms_px)``. Many images
    of one target: :func:`initial_camera_extras` solves them together (the same computation
    per image, batched over the images in NumPy).

    Raises:
        ValueError: too few detected points (4 planar, 6 otherwise) or a degenerate view.
    """
    uv = np.asarray(uv, np.float64)
    R, t, rms, errors = _solve_pnp_images(points_mm, uv[None], intrinsics)
    if errors[0] is not None:
        raise errors[0]
    return R[0], t[0], float(rms[0])


def hand_eye_park(gripper2base, target2cam):
    """Hand-eye ``X`` ``[4, 4]`` solving ``A_ij X = X B_ij`` by Park & Martin (1994).

    Args:
        gripper2base: ``[n, 4, 4]`` ``T_base_flange,i`` (eye-to-hand: pass ``T_flange_base,i``).
        target2cam: ``[n, 4, 4]`` ``T_camera_target,i`` (e.g. :func:`solve_pnp`).

    Returns:
        ``T_flange_camera`` (eye-to-hand: ``T_base_camera``), as
        ``cv2.calibrateHandEye(..., method=cv2.CALIB_HAND_EYE_PARK)`` computes it: over every
        pair ``i < j``, ``A = G_j⁻¹G_i``, ``B = C_j C_i⁻¹``, ``M = Σ log(R_B) log(R_A)ᵀ``,
        ``R_X = (MᵀM)^(−1/2) Mᵀ``, then ``t_X`` as the least-squares solution of
        ``(I − R_A) t_X = t_A − R_X t_B`` stacked over the pairs.
    """
    G = np.asarray(gripper2base, np.float64)
    C = np.asarray(target2cam, np.float64)
    n = G.shape[0]
    if n < 3:
        raise ValueError(f"hand-eye calibration needs at least 3 poses (2 motions), got {n}")
    i, j = np.triu_indices(n, 1)  # the pairs i < j, in OpenCV's order
    A = _inv(G)[j] @ G[i]
    B = C[j] @ _inv(C)[i]
    M = _log(B[:, :3, :3]).T @ _log(A[:, :3, :3])
    w, V = np.linalg.eigh(M.T @ M)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        raise ValueError("hand-eye: the robot motions rotate about fewer than two distinct axes; "
                         "the rotation is not determined (vary the wrist orientation)")
    R = V @ np.diag(1 / np.sqrt(w)) @ V.T @ M.T
    Cm = (np.eye(3) - A[:, :3, :3]).reshape(-1, 3)
    d = (A[:, :3, 3] - np.einsum("ij,nj->ni", R, B[:, :3, 3])).reshape(-1)
    t = np.linalg.lstsq(Cm, d, rcond=None)[0]
    return _T(R, t)


# -- targets ---------------------------------------------------------------------------------------
def checkerboard(columns: int, rows: int, square_mm: float) -> np.ndarray:
    """``[columns·rows, 3]`` inner-corner positions of a checkerboard (mm, z = 0), row by row
    (``x`` fastest), as ``cv2.findChessboardCorners`` orders them for ``(columns, rows)``."""
    if columns < 2 or rows < 2 or not square_mm > 0:
        raise ValueError(f"checkerboard needs >= 2 columns and rows and a square > 0 mm, got {columns}, {rows}, "
                         f"{square_mm}")
    x, y = np.meshgrid(np.arange(columns) * float(square_mm), np.arange(rows) * float(square_mm))
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def load_target(spec: str, base_dir=None) -> np.ndarray:
    """Target points ``[N, 3]`` (mm) from ``"checkerboard:COLSxROWS:SQUARE_MM"`` or a CSV file
    with columns ``x_mm, y_mm, z_mm`` (one row per point, in the order of the ``u_k/v_k`` data
    columns; ``#`` comment lines allowed). A relative file path is taken relative to ``base_dir``
    when it does not exist as given."""
    from .._core._csvfile import read_table

    spec = spec.strip()
    m = re.fullmatch(r"checkerboard:(\d+)x(\d+):([0-9.eE+-]+)", spec, flags=re.I)
    if m:
        return checkerboard(int(m[1]), int(m[2]), float(m[3]))
    p = pathlib.Path(spec)
    if not p.exists() and base_dir is not None and (pathlib.Path(base_dir) / p).exists():
        p = pathlib.Path(base_dir) / p
    t = read_table(p, what="target layout file", row_name="target point")
    missing = [c for c in ("x_mm", "y_mm", "z_mm") if c not in t.header]
    if missing:
        raise ValueError(f"{p}: target layout needs columns x_mm, y_mm, z_mm (missing {missing}); "
                         "or give checkerboard:COLSxROWS:SQUARE_MM")
    return t.floats(["x_mm", "y_mm", "z_mm"])


# -- closed-form start -----------------------------------------------------------------------------
def masked_corners(y) -> tuple[int, int, int]:
    """``(masked, total, images_with_masked)`` corner readings of camera data ``[n, N, 2]``."""
    bad = ~np.isfinite(np.asarray(y, np.float64)).all(axis=-1)
    return int(bad.sum()), int(bad.size), int(bad.any(axis=1).sum())


def initial_camera_extras(robot, measurement: Camera, q, y, *, estimate=None, start: Deviations | None = None):
    """Closed-form start of the hand-eye transform and the target pose from the images.

    1. Per image, :func:`solve_pnp` → ``C_i = T_camera_target,i`` (images with too few detected
       points or a degenerate view are skipped); all images in one batched NumPy computation,
       each image the computation of its own :func:`solve_pnp` call.
    2. The flange frames ``F_i`` of the robot at ``start`` (nominal DH part).
    3. :func:`hand_eye_park` with ``G_i = F_i`` (eye-in-hand) or ``F_i⁻¹`` (eye-to-hand) → ``X``;
       tip to tip, the relative motion ``F_A,i⁻¹F_B,i`` (tip B in tip A's frame, both from the
       tree's frame kernel) plays eye-to-hand's flange: ``G_i = F_B,i⁻¹F_A,i``.
    4. The target pose ``B``: the chordal mean rotation and the mean translation of
       ``G_i X C_i``: ``T_base_target`` (eye-in-hand), ``T_flange_target`` (eye-to-hand),
       ``T_B_target`` (tip to tip).

    Tip to tip, Park–Martin needs relative motions of the two tips that rotate about at least two
    distinct axes (``ValueError`` otherwise, saying so): a camera on the head that only pans seeing
    a hand that only translates does not determine ``X``.

    Args:
        estimate: ``"handeye"`` and/or ``"target"`` (default both); the other stays at ``start``.

    Returns:
        :class:`~jaxcal.ExtrasEstimate` (RMS values in px: RMS reprojection distance per corner).
    """
    from ._initialise import ExtrasEstimate, tip_frames

    est = {"handeye", "target"} if estimate is None else set(estimate)
    bad = est - {"handeye", "target"}
    if bad:
        raise ValueError(f"cannot initialise {sorted(bad)} for camera data; possible: handeye, target")
    q = to_device(q)
    Y = np.asarray(y, np.float64)
    dtype = q.dtype
    start = Deviations.zeros(layout_for(robot, measurement), dtype) if start is None else start.astype(dtype)
    RX0, tX0, RB0, tB0, k = (np.asarray(a, np.float64) for a in _frames_jit(measurement, start, dtype))
    pts = np.asarray(measurement.points, np.float64)
    T = tip_frames(robot, measurement, q, start)
    R, t, pnp_rms, errors = _solve_pnp_images(pts, Y, k)  # every image at once
    used = np.array([i for i, e in enumerate(errors) if e is None], dtype=int)
    if len(used) < 3:
        raise ValueError(f"camera start: only {len(used)} image(s) with enough detected target points (need 3)")
    C = _T(R[used], t[used])
    F = T[used]
    if measurement.mount == "tip_to_tip":  # the target's tip seen from the camera's: F_A⁻¹F_B
        F = _inv(F) @ np.asarray(fk_pose_jit(robot, q, start, tip=measurement.target_tip_for(robot)), np.float64)[used]
    G = F if measurement.mount == "eye_in_hand" else _inv(F)
    if "handeye" in est:
        try:
            X = hand_eye_park(G, C)
        except ValueError as e:
            if measurement.mount != "tip_to_tip":
                raise
            raise ValueError(f"camera start (tip to tip: the motion of tip {measurement.target_tip_name(robot)} "
                             f"relative to tip {measurement.tip_name(robot)} plays the flange's role): {e}") from None
    else:
        X = _T(RX0, tX0)
    if "target" in est:
        Bs = np.einsum("nij,jk,nkl->nil", G, X, C)
        B = _T(project_rotation(Bs[:, :3, :3].sum(axis=0)), Bs[:, :3, 3].mean(axis=0))
    else:
        B = _T(RB0, tB0)
    RX_nom = np.asarray(measurement.handeye_rotation, np.float64)
    RB_nom = np.asarray(measurement.target_rotation, np.float64)
    dev = start.replace(handeye_rotation=to_device(_log(X[:3, :3] @ RX_nom.T), dtype),
                        handeye_translation=to_device(X[:3, 3] - np.asarray(measurement.handeye_translation), dtype),
                        target_rotation=to_device(_log(B[:3, :3] @ RB_nom.T), dtype),
                        target_translation=to_device(B[:3, 3] - np.asarray(measurement.target_translation), dtype))

    def rms(d):
        r = np.asarray(_residual_jit(measurement, robot, d, q, to_device(Y, dtype)), np.float64)
        n_det = max(int(np.isfinite(Y).all(axis=-1).sum()), 1)
        return float(np.sqrt(np.sum(r * r) / n_det))

    before, after = rms(start), rms(dev)
    if measurement.mount == "tip_to_tip":
        what = (f"camera on tip {measurement.tip_name(robot)} (T_A_camera)",
                f"target on tip {measurement.target_tip_name(robot)}")
    else:
        what = {"eye_in_hand": ("camera on the flange (T_flange_camera)", "target in the base frame"),
                "eye_to_hand": ("camera in the base frame (T_base_camera)", "target on the flange")}[measurement.mount]
    msg = (f"extras from the data: per-image PnP on {len(used)} of {Y.shape[0]} images (median reprojection "
           f"{np.median(pnp_rms[used]):.3f} px), hand-eye by Park–Martin: {what[0]} at "
           f"({', '.join(f'{v:.1f}' for v in X[:3, 3])}) mm, {what[1]} at "
           f"({', '.join(f'{v:.1f}' for v in B[:3, 3])}) mm (RMS reprojection error of the nominal robot "
           f"{before:.3g} → {after:.3g} px)")
    return ExtrasEstimate(dev, before, after, Y.shape[0] - len(used), msg)


#: the residual and the camera-frame points, compiled once per shape (host-side callers)
_residual_jit = filter_jit(lambda m, robot, d, q, y: m.residual(robot, d, q, y))
_predict_jit = filter_jit(lambda m, robot, d, q: (m.predict(robot, d, q), m.camera_points(robot, d, q)[2]))
#: the camera's frames at some deviations (:meth:`Camera.frames`) for the start, as one program
_frames_jit = filter_jit(lambda m, d, dtype: m.frames(d, dtype))


def camera_floor(noise_px: float, n_params: int, y):
    """:func:`jaxcal.statistical_floor` of camera data ``y`` ``[n, N, 2]`` with masked corners:
    ``n_train`` = the number of detected corners, ``size = 2`` (each a 2-D reading), so the
    floor is the RMS 2-D reprojection distance per detected corner, i.e. what the RMSE of
    :meth:`Camera.sample_error` over images estimates when every image has about as many
    detected corners."""
    from .._core._metrics import statistical_floor

    n_det = int(np.isfinite(np.asarray(y, np.float64)).all(axis=-1).sum())
    return statistical_floor(noise_px, n_params, n_det, size=2)


# -- simulation ------------------------------------------------------------------------------------
def _look_at(view_dir_cam_z, up=(0.0, 0.0, 1.0)):
    z = view_dir_cam_z / np.linalg.norm(view_dir_cam_z)
    x = np.cross(np.asarray(up, np.float64), z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    return np.c_[x, np.cross(z, x), z]


def default_camera(mount: str = "eye_in_hand") -> Camera:
    """The simulation's camera (``jaxcal simulate --measurement camera``): a 9×6 checkerboard of
    20 mm squares, 1280×1024 px, f = 1000 px, mild distortion, identity nominal frames."""
    return Camera(checkerboard(9, 6, 20.0), [1000.0, 1000.0, 640.0, 512.0, -0.05, 0.02, 0.0005, -0.0003, 0.0],
                  mount, image_size=(1280, 1024))


#: :func:`simulate_camera`'s tip-to-tip set-up: the camera's optical centre in tip A's link frame
#: and the target's centre in tip B's link frame (mm)
TIP_TO_TIP_CAMERA_MM = (20.0, -10.0, 15.0)
TIP_TO_TIP_TARGET_MM = (10.0, 15.0, 40.0)


def _setup_frames(robot, camera: Camera, deviations, home, distance_mm: float):
    """``(X, B)`` ``[4, 4]`` of :func:`simulate_camera`'s set-up for the robot at ``deviations`` and
    the joint angles ``home`` (rad): the target ``distance_mm`` in front of the camera; tip to tip,
    the camera :data:`TIP_TO_TIP_CAMERA_MM` off tip A, the target's centre
    :data:`TIP_TO_TIP_TARGET_MM` off tip B, camera and target facing each other at ``home`` (their
    distance is the robot's: ``distance_mm`` is not used)."""
    dtype = jnp.result_type(float)
    Fh = np.asarray(fk_pose_jit(robot, jnp.asarray(home[None], dtype), deviations, tool=False,
                                tip=camera.tip_for(robot)), np.float64)[0]
    pts = np.asarray(camera.points, np.float64)
    centre = pts.mean(axis=0)
    if camera.mount == "tip_to_tip":
        Fb = np.asarray(fk_pose_jit(robot, jnp.asarray(home[None], dtype), deviations, tool=False,
                                    tip=camera.target_tip_for(robot)), np.float64)[0]
        cam_pos = Fh[:3, :3] @ TIP_TO_TIP_CAMERA_MM + Fh[:3, 3]
        c_world = Fb[:3, :3] @ TIP_TO_TIP_TARGET_MM + Fb[:3, 3]
        view = c_world - cam_pos
        if np.linalg.norm(view) < 50.0:
            raise ValueError(f"tip-to-tip camera set-up: at home the target on tip {camera.target_tip_name(robot)} is "
                             f"{np.linalg.norm(view):.0f} mm from the camera on tip {camera.tip_name(robot)}; choose "
                             "a home posture with the target in front of the camera")
        R = _look_at(view) @ rotvec_to_matrix_np([0.0, 0.0, 0.2])  # camera and target facing each other
        X = _inv(Fh) @ _T(R, cam_pos)  # T_A_camera
        B = _inv(Fb) @ _T(R, c_world - R @ centre)  # T_B_target, its +z along the line of sight
    elif camera.mount == "eye_in_hand":
        X = _T(rotvec_to_matrix_np([0.03, -0.02, 0.4]), np.array([60.0, 0.0, 40.0]))  # T_flange_camera
        Ch = _T(rotvec_to_matrix_np([0.05, 0.04, 0.1]), -rotvec_to_matrix_np([0.05, 0.04, 0.1]) @ centre + [0, 0, distance_mm])
        B = Fh @ X @ Ch  # T_base_target
    else:
        B = _T(rotvec_to_matrix_np([0.02, 0.03, 0.3]), np.array([60.0, -20.0, 30.0]))  # T_flange_target
        tgt_world = Fh @ B
        c_world = tgt_world[:3, :3] @ centre + tgt_world[:3, 3]
        n_world = tgt_world[:3, :3] @ np.array([0.0, 0.0, 1.0])
        cam_pos = c_world - distance_mm * n_world  # looking along the target normal (+z into the board)
        X = _T(_look_at(n_world), cam_pos)  # T_base_camera
    return X, B


def planning_camera(robot, camera: Camera | None = None, *, mount: str = "eye_in_hand", home=None,
                    distance_mm: float = 450.0) -> Camera:
    """A camera model with :func:`simulate_camera`'s set-up as its *nominal* frames, for planning
    before any image exists (``jaxcal plan --measurement camera``): ``camera`` (default
    :func:`default_camera` with ``mount``) with the hand-eye and target frames of the nominal
    robot at ``home`` (default the middle of the joint ranges), the target ``distance_mm`` in
    front of the camera. With a real set-up, build the :class:`Camera` with its nominal frames
    (e.g. from a CAD model or an earlier calibration) instead."""
    camera = default_camera(mount) if camera is None else camera
    lo, hi = np.asarray(robot.q_min, np.float64), np.asarray(robot.q_max, np.float64)
    home = (lo + hi) / 2 if home is None else np.asarray(home, np.float64)
    X, B = _setup_frames(robot, camera, None, home, distance_mm)
    return camera.with_frames(X, B)


def target_in_view(robot, camera: Camera, q, deviations: Deviations | None = None, *,
                   min_depth_mm: float = 1.0) -> np.ndarray:
    """``[n, N]`` bool: target point ``k`` lies in front of the camera (depth > ``min_depth_mm``)
    and projects inside the image (``0 ≤ u ≤ width``, ``0 ≤ v ≤ height``) at joint angles
    ``q`` ``[n, dof]`` (rad), robot and frames at ``deviations`` (nominal by default). Needs
    the camera's ``image_size``."""
    if camera.image_size is None:
        raise ValueError("the camera model has no image_size (width, height px): cannot tell what is in view")
    q = jnp.asarray(q, jnp.result_type(float))
    uv, pz = (np.asarray(a, np.float64) for a in _predict_jit(camera, robot, deviations, q))
    w, h = camera.image_size
    return (pz > min_depth_mm) & (uv[..., 0] >= 0) & (uv[..., 0] <= w) & (uv[..., 1] >= 0) & (uv[..., 1] <= h)


# -- the data-file form of camera data -----------------------------------------------------------
def camera_columns(n_points: int) -> list[str]:
    """CSV columns of ``n_points`` target points' image coordinates: ``u_1_px, v_1_px, u_2_px…``."""
    return [f"{c}_{k}_px" for k in range(1, n_points + 1) for c in "uv"]


@register_kind
class CameraKind(PointsKind):
    """Camera data (:class:`Camera`): columns ``u_k_px, v_k_px`` for the k = 1..N target points
    (N from the file; empty cells: a corner not detected, masked), readings ``[n, N, 2]`` px."""

    name = "camera"
    noise_unit = "px"
    simulator = "jaxcal._simulation._simulate_files:camera_file"
    planner = "jaxcal._experiments._plan:camera_candidates"
    plan_compressed = True
    plan_next = ("take an image at each pose and fill in the detected target points' u_k_px, v_k_px (empty where not "
                 "detected)")
    pattern = re.compile(r"([uv])_(\d+)_px")
    number_group, width = 2, 2
    columns_word, count_word = "image-point", "target point(s)"
    expected_hint = "u_1_px, v_1_px, u_2_px, ..."

    def point_columns(self, n_points):
        return camera_columns(n_points)

    def planning_model(self, robot, *, anchor_mm=None, mount="eye_in_hand"):
        """:func:`planning_camera` (the simulation's set-up as the nominal frames) with ``mount``."""
        self.refuse_anchor(anchor_mm)
        return planning_camera(robot, mount=mount)

    def plan_lines(self, model):
        """The target (:func:`planning_camera`'s default 9×6 board of 20 mm squares), intrinsics,
        mount and image size."""
        return {"target": "checkerboard:9x6:20", "camera_intrinsics": ",".join(repr(float(v)) for v in model.intrinsics),
                "mount": model.mount, "image_size_px": ",".join(str(v) for v in model.image_size)}

    def plan_readings(self, model, n):
        return np.full((n, model.n_points, 2), np.nan)

    def check_options(self, estimate, options):
        if estimate - {"intrinsics"}:
            raise ValueError(f"--estimate for camera data takes intrinsics only (the hand-eye transform and the "
                             f"target pose are always estimated); got {sorted(estimate - {'intrinsics'})}")
        self.refuse_point_options(options)
        self.refuse_anchor(options.anchor_mm)

    def model_to_dict(self, model):
        f = lambda a: np.asarray(a, np.float64).tolist()  # noqa: E731
        return {"kind": "camera", "points_mm": f(model.points), "intrinsics": f(model.intrinsics), "mount": model.mount,
                "handeye_rotation": f(model.handeye_rotation), "handeye_translation_mm": f(model.handeye_translation),
                "target_rotation": f(model.target_rotation), "target_translation_mm": f(model.target_translation),
                "image_size": None if model.image_size is None else list(model.image_size),
                "calibrate_intrinsics": bool(model.calibrate_intrinsics)} | tip_to_dict(model) | (
                    {"target_tip": model.target_tip} if model.mount == "tip_to_tip" else {})

    def model_from_dict(self, d):
        return Camera(d["points_mm"], d["intrinsics"], d["mount"], handeye_rotation=d["handeye_rotation"],
                      handeye_translation=d["handeye_translation_mm"], target_rotation=d["target_rotation"],
                      target_translation=d["target_translation_mm"], image_size=d.get("image_size"),
                      calibrate_intrinsics=bool(d.get("calibrate_intrinsics", False)), tip=d.get("tip"),
                      target_tip=d.get("target_tip"))

    def setup(self, data, robot, estimate, options):
        """The :class:`Camera` of camera data from ``options.target``, ``options.camera_intrinsics``,
        ``options.mount`` (or the file's ``# target:``, ``# camera_intrinsics:``, ``# mount:`` lines;
        ``# image_size_px:`` always), hand-eye and target pose unknown (started from the data).
        No extra to estimate: the intrinsics (``--estimate intrinsics``) are a group of the model.
        Tip to tip (``# mount: tip_to_tip``, the mount a file with a ``# target_tip:`` line and no
        mount has), the file's ``# target_tip: NAME`` line names the tip carrying the target
        (:func:`jaxcal.resolve_tip`: ``None`` for the robot's default tip) and its ``# tip:`` line
        the camera's (:meth:`SensorKind.at_file_tip`, after this).

        Raises:
            ValueError: also a ``# target_tip:`` the robot lacks (named, with the robot's tips), a
                tip-to-tip file without that line, the line with another mount."""
        from .._core._csvfile import number_list

        self.check_options(estimate, options)
        meta, path = data.meta, options.path
        target = _given(options.target, meta.get("target"))
        if target is None:
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
        spec = _given(options.camera_intrinsics, meta.get("camera_intrinsics"))
        if spec is None:
            raise ValueError("--measurement camera needs the camera's intrinsics: --camera fx,fy,cx,cy[,k1,k2,p1,p2[,k3]] "
                             "(px; OpenCV's camera matrix and distortion) or a '# camera_intrinsics: …' line")
        if isinstance(spec, str):
            parts = [p for p in spec.replace(";", ",").split(",") if p.strip()]
            if len(parts) not in (4, 8, 9):
                raise ValueError(f"--camera takes 4, 8 or 9 numbers fx,fy,cx,cy[,k1,k2,p1,p2[,k3]], got {spec!r}")
            spec = number_list(spec, len(parts), "--camera")
        target_tip = str(meta.get("target_tip", "")).strip()
        mount = (_given(_given(options.mount, meta.get("mount")), "tip_to_tip" if target_tip else "eye_in_hand")
                 ).replace("-", "_").lower()
        size = meta.get("image_size_px")
        size = tuple(int(v) for v in number_list(size, 2, "the file's image_size_px")) if size else None
        if mount == "tip_to_tip":
            if not target_tip:
                raise ValueError("tip-to-tip camera data (mount tip_to_tip) need a '# target_tip: NAME' line naming the "
                                 "tip that carries the target (and a '# tip: NAME' line for the camera's tip)")
            try:
                target_tip = resolve_tip(robot, target_tip)
            except ValueError as e:
                raise ValueError(f"the data file's '# target_tip: {target_tip}' line: {e}") from None
            # the camera's tip: the file's '# tip:' line (at_file_tip), checked here too so that the
            # start never meets a camera and a target on one tip
            cam_tip = str(meta.get("tip", "")).strip()
            try:
                cam_tip = None if not cam_tip else resolve_tip(robot, cam_tip)
            except ValueError as e:
                raise ValueError(f"the data file's '# tip: {cam_tip}' line: {e}") from None
            model = Camera(points, spec, mount, image_size=size, calibrate_intrinsics="intrinsics" in estimate,
                           tip=cam_tip, target_tip=target_tip)
        elif target_tip:
            raise ValueError(f"the data file's '# target_tip: {target_tip}' line applies to mount tip_to_tip (a camera "
                             f"on one tip seeing a target on another), not {mount}")
        else:
            model = Camera(points, spec, mount, image_size=size, calibrate_intrinsics="intrinsics" in estimate)
        n_mask, n_all, n_img = masked_corners(data.y)
        where = "" if mount != "tip_to_tip" else (
            f", camera on tip {model.tip_name(robot)}, target on tip {model.target_tip_name(robot)}")
        note = (f"camera ({model.mount}{where}): hand-eye transform and target pose estimated (per-image PnP, "
                "Park–Martin hand-eye, then the joint fit)"
                f"{'; intrinsics estimated' if model.calibrate_intrinsics else ''}; "
                f"{n_mask} of {n_all} corner readings not detected (empty cells) in {n_img} image(s): masked "
                "(zero weight), not dropped")
        return model, set(), [note]

    def checked_readings(self, y, n, dof):
        if y.ndim != 3 or y.shape[0] != n or y.shape[2] != 2 or y.shape[1] < 1:
            raise ValueError(f"camera measurements must have shape [{n}, N, 2] (u, v px of N target points), "
                             f"got {list(y.shape)}")
        if np.isinf(y).any():
            raise ValueError("camera measurements contain ±inf; a corner that was not detected is NaN (an empty "
                             "CSV cell)")
        return np.where(np.isnan(y), 0.0, y)  # NaN = not detected: masked by the camera model, not an error


def _given(value, default):
    """``value``, or ``default`` where ``value`` is ``None`` or an empty text (an option not given)."""
    return default if value is None or (isinstance(value, str) and not value) else value

