"""Robot presets: nominal DH tables with joint limits, each with its source.

Every preset returns a fresh :class:`~jaxcal.DHRobot` (lengths in mm, angles in rad). Use
``PRESETS`` / :func:`get_robot` to look one up by name (``jaxcal calibrate --robot NAME``).
"""

from __future__ import annotations

from collections.abc import Callable

from ._models._robot import DHRobot

__all__ = ["hsr_jr680", "puma560", "ur5", "abb_irb120", "PRESETS", "get_robot"]


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


PRESETS: dict[str, Callable[[], DHRobot]] = {
    "hsr_jr680": hsr_jr680,
    "puma560": puma560,
    "ur5": ur5,
    "abb_irb120": abb_irb120,
}


def get_robot(name: str) -> DHRobot:
    """A preset by name; unknown names raise ``ValueError`` listing the presets."""
    try:
        return PRESETS[name]()
    except KeyError:
        raise ValueError(f"unknown robot {name!r}; presets: {', '.join(PRESETS)}") from None
