"""Robot presets: nominal geometry with joint limits, each with its source.

Serial arms (``DH_PRESETS``) return a fresh :class:`~jaxcal.DHRobot`: ``hsr_jr680``, ``puma560``,
``ur5``, ``abb_irb120``. Robots with several arms and eyes (``TREE_PRESETS``) return a fresh
:class:`~jaxcal.KinematicTree`: ``dual_arm_ma1400`` (two Yaskawa Motoman MA1400 arms on one torso
axis, two cameras riding on the torso: the CTU dual-arm robot) and ``icub`` (the iCub humanoid:
a three-joint torso shared by two seven-joint arms and the head, whose two eyes are cameras).
Lengths in mm, angles in rad. Use ``PRESETS`` (both) / :func:`get_robot` to look one up by name
(``jaxcal calibrate --robot NAME``; for a tree ``--tip A[,B...]`` keeps those tips,
:meth:`~jaxcal.KinematicTree.with_tips`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from ._models._abstract import AbstractRobot
from ._models._dh_tree import TreeSpec as _TreeSpec
from ._models._dh_tree import dh_head as _head
from ._models._dh_tree import dh_row as _row
from ._models._dh_tree import dh_tail as _tail
from ._models._robot import DHRobot
from ._models._tree import KinematicTree

__all__ = ["hsr_jr680", "puma560", "ur5", "abb_irb120", "dual_arm_ma1400", "icub", "DH_PRESETS", "TREE_PRESETS",
           "PRESETS", "get_robot"]


def hsr_jr680(tool_mm=(0.0, 0.0, 0.0)) -> DHRobot:
    """HSR-JR680 (Huashu Robot), standard DH exactly as Table I of Chen & Li (the paper).

    ====  =====  =======  =======  =====
    i     α/°    a/mm     d/mm     θ/°
    ====  =====  =======  =======  =====
    1     -90    250      653.5    0
    2     0      900      0        -90
    3     -90    -205     0        180
    4     90     0        1030.2   0
    5     -90    0        0        90
    6     0      0        200.6    0
    ====  =====  =======  =======  =====

    The paper gives no joint limits; the limits here (±170°, ±110°, ±140°, ±180°, ±120°,
    ±360°) are assumed, typical of 20 kg-class six-axis arms. The paper does not say where
    the draw-wire attaches; by default it is the flange centre (``tool_mm = 0``), which makes
    α6 and θ6 invisible to the wire (the identifiability report says so). Pass an off-axis
    ``tool_mm`` (flange frame) to make them observable.
    """
    return DHRobot.from_degrees(
        alpha_deg=[-90, 0, -90, 90, -90, 0],
        a_mm=[250, 900, -205, 0, 0, 0],
        d_mm=[653.5, 0, 0, 1030.2, 0, 200.6],
        theta_deg=[0, -90, 180, 0, 90, 0],
        q_min_deg=[-170, -110, -140, -180, -120, -360],
        q_max_deg=[170, 110, 140, 180, 120, 360],
        tool_mm=tool_mm,
        name="hsr_jr680",
    )


def puma560(tool_mm=(0.0, 0.0, 100.0)) -> DHRobot:
    """Unimation PUMA 560, standard DH and joint limits from P. Corke's Robotics Toolbox
    (``mdl_puma560``; Corke, *Robotics, Vision and Control*, 2nd ed., 2017), lengths in mm.

    α = (90, 0, −90, 90, −90, 0)°, a = (0, 431.8, 20.32, 0, 0, 0) mm,
    d = (0, 0, 150.05, 431.8, 0, 0) mm, θ offsets 0; limits (−160..160, −45..225, −225..45,
    −110..170, −100..100, −266..266)°. The base frame is at the shoulder height.
    """
    return DHRobot.from_degrees(
        alpha_deg=[90, 0, -90, 90, -90, 0],
        a_mm=[0, 431.8, 20.32, 0, 0, 0],
        d_mm=[0, 0, 150.05, 431.8, 0, 0],
        theta_deg=[0, 0, 0, 0, 0, 0],
        q_min_deg=[-160, -45, -225, -110, -100, -266],
        q_max_deg=[160, 225, 45, 170, 100, 266],
        tool_mm=tool_mm,
        name="puma560",
    )


def ur5(tool_mm=(0.0, 50.0, 80.0)) -> DHRobot:
    """Universal Robots UR5 (CB3), standard DH from Universal Robots' published
    "DH parameters for calculations of kinematics and dynamics" (mm):
    d1 = 89.159, a2 = −425, a3 = −392.25, d4 = 109.15, d5 = 94.65, d6 = 82.3,
    α = (90, 0, 0, 90, −90, 0)°; every joint ±360° (UR5 user manual).
    Joints 2, 3 and 4 are parallel.
    """
    return DHRobot.from_degrees(
        alpha_deg=[90, 0, 0, 90, -90, 0],
        a_mm=[0, -425.0, -392.25, 0, 0, 0],
        d_mm=[89.159, 0, 0, 109.15, 94.65, 82.3],
        theta_deg=[0, 0, 0, 0, 0, 0],
        q_min_deg=[-360] * 6,
        q_max_deg=[360] * 6,
        tool_mm=tool_mm,
        name="ur5",
    )


def abb_irb120(tool_mm=(30.0, 0.0, 60.0)) -> DHRobot:
    """ABB IRB 120, standard DH from its product specification dimensions (mm):
    d1 = 290, a2 = 270, a3 = 70, d4 = 302, d6 = 72, α = (−90, 0, −90, 90, −90, 0)°,
    θ offset −90° at joint 2 (as in the common DH model of the IRB 120, e.g. the ABB
    IRB 120 kinematics used in the Robotics Toolbox examples); joint limits from the product
    specification: ±165, ±110, −110..+70, ±160, ±120, ±400°.
    """
    return DHRobot.from_degrees(
        alpha_deg=[-90, 0, -90, 90, -90, 0],
        a_mm=[0, 270, 70, 0, 0, 0],
        d_mm=[290, 0, 0, 302, 0, 72],
        theta_deg=[0, -90, 0, 0, 0, 0],
        q_min_deg=[-165, -110, -110, -160, -120, -400],
        q_max_deg=[165, 110, 70, 160, 120, 400],
        tool_mm=tool_mm,
        name="abb_irb120",
    )


# ---------------------------------------------------------------------------- kinematic trees
#
# A tree preset is written as the standard DH rows of its source, regrouped into joint origins by
# jaxcal._models._dh_tree (a shared joint keeps what precedes its rotation; the rest of its row opens
# each branch) — the same code that reads DH tree files (jaxcal._calibration._io.load_tree_csv).

#: The dual-arm robot's DH rows (a mm, d mm, α°, θ°): Rozlivek et al.'s toolbox, ``loadMotoman.m``
#: (metres and radians there). The torso row is each arm's first row; α is −15° for the left arm and
#: +15° for the right, the rest of the row is the same.
_MA1400_TORSO_ROW = {"left": (0.0, -263.0, -15.0, -90.0), "right": (0.0, -263.0, 15.0, -90.0)}
_MA1400_ARM_ROWS = ((150.0, 1415.9, -90.0, 0.0),   # S
                   (614.0, 0.0, 180.0, -90.0),    # L
                   (200.0, 0.0, -90.0, 0.0),      # U
                   (0.0, -640.0, 90.0, 0.0),      # R
                   (30.0, 0.0, 90.0, -90.0),      # B
                   (0.0, 200.0, 0.0, 0.0))        # T (to the flange, force/torque sensor included)
#: The end effector's row (0, 354 mm, 0, 0): the tool point of each arm, in its flange frame.
_MA1400_EFFECTOR_MM = (0.0, 0.0, 354.0)
#: The cameras' two DH rows each (``rightEye`` / ``leftEye`` "after camera calibration" in
#: ``loadMotoman.m``; radians there, degrees here), the first turned by the torso joint.
_MA1400_CAMERA_ROWS = {
    "left": ((231.5, 1860.2, np.degrees(2.5486), np.degrees(0.0860)), (0.0, -498.2, 0.0, np.degrees(-3.0618))),
    "right": ((74.1, 1803.4, np.degrees(-2.5086), np.degrees(-2.7753)), (0.0, -567.0, 0.0, np.degrees(0.2863))),
}
#: Assumed joint limits (deg) of the torso and of each arm's S, L, U, R, B, T joints (DH zero).
_MA1400_LIMITS_DEG = {"torso": (-170.0, 170.0),
                     "arm": ((-170.0, 170.0), (-90.0, 120.0), (-85.0, 95.0), (-150.0, 150.0), (-45.0, 180.0),
                             (-200.0, 200.0))}


def dual_arm_ma1400(tools: Mapping[str, Sequence[float]] | None = None) -> KinematicTree:
    """The CTU dual-arm robot: two Yaskawa Motoman MA1400 six-axis arms on one rotating torso
    axis, with two cameras on the robot (Stepanova, Rozlivek, Puciow, Krsek, Pajdla & Hoffmann,
    "Automatic self-contained calibration of an industrial dual-arm robot with cameras using
    self-contact, planar constraints, and self-observation", *Robotics and Computer-Integrated
    Manufacturing* 73, 102250, 2022), with the nominal DH parameters its authors published in
    their toolbox (Rozlivek, Rustler, Stepanova & Hoffmann, "Multisensorial robot calibration
    framework and toolbox", IEEE-RAS Humanoids 2021; github.com/ctu-vras/multirobot-calibration,
    ``UserData/Robots/Motoman/loadMotoman.m``). Standard DH, ``A = Rz(θ + q)·Tz(d)·Tx(a)·Rx(α)``:

    ======  ======  ========  =======  ======
    joint   a/mm    d/mm      α/°      θ/°
    ======  ======  ========  =======  ======
    torso   0       −263      ∓15      −90     (−15° left arm, +15° right arm)
    S       150     1415.9    −90      0
    L       614     0         180      −90
    U       200     0         −90      0
    R       0       −640      90       0
    B       30      0         90       −90
    T       0       200       0        0
    ======  ======  ========  =======  ======

    These are the toolbox's nominal values as published (150 mm shoulder offset, 614 mm lower arm,
    200 mm elbow offset, 640 mm upper arm, 200 mm from the B axis to the flange frame, where the
    paper's arms carry a force/torque sensor); they were not checked against Yaskawa's MA1400
    datasheet, which was not at hand. The torso is **one** joint (joint 1, ``torso_joint``: one
    joint column, one set of error parameters) turning about the base ``z``; what its row holds
    after the rotation (d, θ offset, and α, which differs) opens each arm. Tips: ``left_tool`` and
    ``right_tool`` (each arm's flange frame, tool point 354 mm along its ``z``: the centre of the
    toolbox's custom end effector, its ``EE`` row), then ``left_camera`` and ``right_camera``: the
    camera frames (``z`` the optical axis, OpenCV's convention), fixed to the torso link at the
    poses of the toolbox's calibrated eye chains (``leftEye`` / ``rightEye``, "kinematics after
    camera calibration"), whose first row turns with the torso reading in the toolbox's data loader
    (``loadDatasetMotoman.m``; the paper calls them attached to the robot base, and its published
    data keep the torso at 0, so they do not tell the two apart). Joint order (the data
    files' ``q1 … q13``): torso, left S…T, right S…T. The base frame is the toolbox's ``base``
    (``z`` the torso axis; the arms work towards −``y``).

    Checked against the toolbox's published self-touch data (``no_leica_self_upper1``): the two
    tool points of the 124 touch poses lie 116.0 ± 1.3 mm apart (the end effectors touching), and
    the cameras (the toolbox's intrinsics, distortion left out) project the end effectors' centres
    within a marker's offset from them (≤ 52 mm) of the detected markers.

    **Assumed**: the joint limits — neither the paper nor the toolbox gives them. Here torso ±170°,
    S ±170°, L −90…+120°, U −85…+95°, R ±150°, B −45…+180°, T ±200° (in the DH zero above, not
    Yaskawa's pulse zero); every joint reading of the toolbox's published data sets lies within
    them. ``tools``: ``{tip: [3] mm}`` to replace the nominal tool points.
    """
    spec = _TreeSpec()
    torso = spec.joint(-1, np.eye(4), "torso_joint", "torso", _MA1400_LIMITS_DEG["torso"])
    names = "slurbt"
    arm_ends = {}
    for side in ("left", "right"):
        a, d, alpha, theta = _MA1400_TORSO_ROW[side]
        last, flange = spec.branch(
            torso, _head(d, theta) @ _tail(a, alpha), _MA1400_ARM_ROWS, [f"{side}_joint_{c}" for c in names],
            [f"{side}_link_{c}" for c in names], _MA1400_LIMITS_DEG["arm"])
        arm_ends[side] = (last, flange)
    for side in ("left", "right"):
        spec.tip(f"{side}_tool", *arm_ends[side], tool=_MA1400_EFFECTOR_MM)
    for side in ("left", "right"):
        first, second = _MA1400_CAMERA_ROWS[side]
        spec.tip(f"{side}_camera", torso, _row(*first) @ _row(*second))
    return spec.build("dual_arm_ma1400", "base", tools)


#: iCub v1 (iKin, ``iKinFwd.cpp``): the fixed ``H0`` from the root frame to the torso's first
#: DH frame, then rows (a mm, d mm, α°, θ°) with joint limits (min°, max°).
_ICUB_H0 = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
_ICUB_TORSO_ROWS = (((32.0, 0.0, 90.0, 0.0), (-22.0, 84.0)),      # torso pitch
                   ((0.0, -5.5, 90.0, -90.0), (-39.0, 39.0)))    # torso roll
#: Torso yaw (limits −59…59°): the row differs per branch after the rotation.
_ICUB_TORSO_YAW_DEG = (-59.0, 59.0)
_ICUB_YAW_ROW = {"left_arm": (23.3647, -143.3, -90.0, 105.0), "right_arm": (-23.3647, -143.3, 90.0, -105.0),
                "head": (2.31, -193.3, -90.0, -90.0)}
_ICUB_ARM_ROWS = {
    "left": (((0.0, 107.74, -90.0, 90.0), (-95.5, 5.0)),        # shoulder pitch
             ((0.0, 0.0, 90.0, -90.0), (0.0, 160.8)),           # shoulder roll
             ((15.0, 152.28, -90.0, 75.0), (-37.0, 100.0)),     # shoulder yaw
             ((-15.0, 0.0, 90.0, 0.0), (5.5, 106.0)),           # elbow
             ((0.0, 137.3, 90.0, -90.0), (-50.0, 50.0)),        # wrist prosupination
             ((0.0, 0.0, 90.0, 90.0), (-65.0, 10.0)),           # wrist pitch
             ((62.5, -16.0, 0.0, 0.0), (-25.0, 25.0))),         # wrist yaw
    "right": (((0.0, -107.74, 90.0, -90.0), (-95.5, 5.0)),
              ((0.0, 0.0, -90.0, -90.0), (0.0, 160.8)),
              ((-15.0, -152.28, -90.0, -105.0), (-37.0, 100.0)),
              ((15.0, 0.0, 90.0, 0.0), (5.5, 106.0)),
              ((0.0, -137.3, 90.0, -90.0), (-50.0, 50.0)),
              ((0.0, 0.0, 90.0, 90.0), (-65.0, 10.0)),
              ((62.5, 16.0, 0.0, 180.0), (-25.0, 25.0))),
}
_ICUB_ARM_JOINTS = ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_prosup", "wrist_pitch",
                   "wrist_yaw")
_ICUB_NECK_ROWS = (((33.0, 0.0, 90.0, 90.0), (-40.0, 30.0)),      # neck pitch
                  ((0.0, 1.0, -90.0, -90.0), (-70.0, 60.0)),     # neck roll
                  ((-54.0, 82.5, -90.0, 90.0), (-55.0, 55.0)))   # neck yaw
#: Eyes tilt (limits −35…15°), shared by both eyes; its row differs per eye after the rotation.
_ICUB_EYES_TILT_DEG = (-35.0, 15.0)
_ICUB_TILT_ROW = {"left": (0.0, -34.0, -90.0, 0.0), "right": (0.0, 34.0, -90.0, 0.0)}
#: Each eye's pan (iKin's last eye link: version ± vergence/2), limits −50…50°.
_ICUB_PAN_ROW = ((0.0, 0.0, 90.0, -90.0), (-50.0, 50.0))


def icub(tools: Mapping[str, Sequence[float]] | None = None) -> KinematicTree:
    """The iCub humanoid (version 1 kinematics): a three-joint torso shared by two seven-joint
    arms and the head, whose two eyes are cameras on a shared tilt joint — dimensions **and**
    joint limits from the iCub's own kinematics library, iKin (robotology/icub-main,
    ``src/libraries/iKin/src/iKinFwd.cpp``: ``iCubArm`` "left"/"right" and ``iCubEye``
    "left"/"right", version 1.0) — the robot of Stepanova, Pajdla & Hoffmann's multi-chain
    self-calibration study ("Robot self-calibration using multiple kinematic chains — a simulation
    study on the iCub humanoid robot", *IEEE RA-L* 4(2), 2019).

    Standard DH, ``A = Rz(θ + q)·Tz(d)·Tx(a)·Rx(α)`` (a, d mm; α, θ, limits °), after the fixed
    ``H0`` from the root frame (x back, y right, z up):

    ====================  ========  ========  =====  ======  =============
    joint                 a         d         α      θ       limits
    ====================  ========  ========  =====  ======  =============
    torso pitch           32        0         90     0       −22 … 84
    torso roll            0         −5.5      90     −90     −39 … 39
    torso yaw (l. arm)    23.3647   −143.3    −90    105     −59 … 59
    torso yaw (r. arm)    −23.3647  −143.3    90     −105
    torso yaw (head)      2.31      −193.3    −90    −90
    l. shoulder pitch     0         107.74    −90    90      −95.5 … 5
    l. shoulder roll      0         0         90     −90     0 … 160.8
    l. shoulder yaw       15        152.28    −90    75      −37 … 100
    l. elbow              −15       0         90     0       5.5 … 106
    l. wrist prosup.      0         137.3     90     −90     −50 … 50
    l. wrist pitch        0         0         90     90      −65 … 10
    l. wrist yaw          62.5      −16       0      0       −25 … 25
    neck pitch            33        0         90     90      −40 … 30
    neck roll             0         1         −90    −90     −70 … 60
    neck yaw              −54       82.5      −90    90      −55 … 55
    eyes tilt (l. / r.)   0         ∓34       −90    0       −35 … 15
    eye pan               0         0         90     −90     −50 … 50
    ====================  ========  ========  =====  ======  =============

    The right arm's rows are iKin's "right" ones, the left's mirror image: a 0, 0, −15, 15, 0, 0,
    62.5; d −107.74, 0, −152.28, 0, −137.3, 0, 16; α 90, −90, −90, 90, 90, 90, 0; θ −90, −90, −105,
    0, −90, 90, 180; the same limits. Torso yaw and eyes tilt are each **one** joint, shared
    by the branches above them (one joint column, one set of error parameters); what their rows
    hold after the rotation, which iKin gives per chain, opens each branch. Each eye's pan is its
    own joint: the iCub's head drives version and vergence, and each eye turns by version ±
    vergence/2 (+ left, − right, as iKin's gaze controller sets them).

    Tips: ``left_hand``, ``right_hand`` (the end frames of iKin's arm chains, the palm), then
    ``left_eye``, ``right_eye`` (the end frames of iKin's eye chains: the cameras, ``z`` the optical
    axis). Joint order (the data files' ``q1 … q23``): torso pitch, roll, yaw; the left arm's
    seven; the right arm's seven; neck pitch, roll, yaw; eyes tilt; left eye pan; right eye pan.
    The root is iKin's root frame (the waist). **Assumed**: nothing in the geometry or limits;
    the tool points are the tip frames' origins (``tools``: ``{tip: [3] mm}`` to move them: a
    fingertip, a marker).
    """
    spec = _TreeSpec()
    (r0, lim0), (r1, lim1) = _ICUB_TORSO_ROWS
    pitch = spec.joint(-1, _ICUB_H0 @ _head(r0[1], r0[3]), "torso_pitch", "torso_1", lim0)
    roll = spec.joint(pitch, _tail(r0[0], r0[2]) @ _head(r1[1], r1[3]), "torso_roll", "torso_2", lim1)
    yaw = spec.joint(roll, _tail(r1[0], r1[2]), "torso_yaw", "chest", _ICUB_TORSO_YAW_DEG)
    hands = {}
    for side in ("left", "right"):
        a, d, alpha, theta = _ICUB_YAW_ROW[f"{side}_arm"]
        rows, lims = zip(*_ICUB_ARM_ROWS[side], strict=True)
        hands[side] = spec.branch(yaw, _head(d, theta) @ _tail(a, alpha), rows,
                                  [f"{side[0]}_{j}" for j in _ICUB_ARM_JOINTS],
                                  [f"{side[0]}_{j}_link" for j in _ICUB_ARM_JOINTS], lims)
    a, d, alpha, theta = _ICUB_YAW_ROW["head"]
    rows, lims = zip(*_ICUB_NECK_ROWS, strict=True)
    neck, tail = spec.branch(yaw, _head(d, theta) @ _tail(a, alpha), rows, ["neck_pitch", "neck_roll", "neck_yaw"],
                             ["neck_1", "neck_2", "neck_3"], lims)
    tilt = spec.joint(neck, tail, "eyes_tilt", "head", _ICUB_EYES_TILT_DEG)
    eyes = {}
    for side in ("left", "right"):
        a, d, alpha, theta = _ICUB_TILT_ROW[side]
        (pa, pd, palpha, ptheta), plim = _ICUB_PAN_ROW
        eyes[side] = spec.branch(tilt, _head(d, theta) @ _tail(a, alpha), [(pa, pd, palpha, ptheta)],
                                 [f"{side}_eye_pan"], [f"{side}_eye_link"], [plim])
    for side in ("left", "right"):
        spec.tip(f"{side}_hand", *hands[side])
    for side in ("left", "right"):
        spec.tip(f"{side}_eye", *eyes[side])
    return spec.build("icub", "root_link", tools)


DH_PRESETS: dict[str, Callable[[], DHRobot]] = {
    "hsr_jr680": hsr_jr680,
    "puma560": puma560,
    "ur5": ur5,
    "abb_irb120": abb_irb120,
}
TREE_PRESETS: dict[str, Callable[[], KinematicTree]] = {
    "dual_arm_ma1400": dual_arm_ma1400,
    "icub": icub,
}
PRESETS: dict[str, Callable[[], AbstractRobot]] = {**DH_PRESETS, **TREE_PRESETS}


def get_robot(name: str) -> AbstractRobot:
    """A preset by name (a :class:`~jaxcal.DHRobot` of ``DH_PRESETS`` or a
    :class:`~jaxcal.KinematicTree` of ``TREE_PRESETS``); unknown names raise ``ValueError``
    listing the presets."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ValueError(f"unknown robot {name!r}; presets: {', '.join(PRESETS)}") from None
