"""Self-contact: two tips of one robot touch each other, and the distance between their contact
points is known — a calibration with no sensor outside the robot.

A robot with several arms (a :class:`~jaxcal.KinematicTree`) puts a ball on each hand, or a ball
on one and a flat pad on the other, and brings them into contact at many postures; at contact
the distance between the two contact points is the sum of the radii (mm, the file's
``contact_distance_mm`` column, one value per row). The joint readings at contact are the data;
the residual of a row is

    r = ‖p_a(q) − p_b(q)‖ − d,

``p_a``, ``p_b`` the two tips' tool points in the base frame (mm; :func:`~jaxcal._models.
_kinematics.tool_point_soa` with ``tip=``), through both arms' chains and every joint they share.
What it sees: the two arms *relative to each other*. Nothing fixes where the pair is in the base
frame (the shared joints' absolute errors and a rigid motion of both tips together stay with the
prior), and only the known distance fixes the length scale — the identifiability report names
both. Contact data join planes, cameras or a tracker in a combined fit (:func:`jaxcal.calibrate_blocks`).

Self-contact as a calibration of humanoid and dual-arm robots: Roncone, Hoffmann, Pattacini,
Metta (2014), "Automatic kinematic chain calibration using artificial skin: self-touch in the
iCub humanoid robot", ICRA; Stepanova, Pajdla, Hoffmann (2019), "Robot self-calibration using
multiple kinematic chains — a simulation study on the iCub humanoid robot", IEEE RA-L 4(2).

Data files: the tree's joint columns (``q1_deg …``, every joint of the tree in its order), the
``contact_distance_mm`` column, and a ``# tips: left_tool,right_tool`` line naming the two tips.
:func:`simulate_self_contact` makes such data for a known truth.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._models._kinematics import check_joint_angles, tool_point_soa
from ._kind import SensorKind, register_kind
from ._measurement import MeasurementModel

__all__ = ["SelfContact", "SelfContactKind", "simulate_self_contact"]


def _two_tips(tips) -> tuple[str, str]:
    """``tips`` as two distinct names (a ``"a,b"`` text or a pair)."""
    if isinstance(tips, str):
        tips = [t.strip() for t in tips.replace(";", ",").split(",") if t.strip()]
    tips = tuple(str(t) for t in tips)
    if len(tips) != 2 or tips[0] == tips[1] or not all(tips):
        raise ValueError(f"self-contact needs two different tips that touch (a '# tips: A,B' line in the data file), "
                         f"got {list(tips)}")
    return tips  # type: ignore[return-value]


class SelfContact(MeasurementModel):
    """Two tips of the robot touching: the distance between their tool points (contact points, mm)
    is the reading ``y`` ``[n]`` (the sum of the radii of the balls, or a ball's radius against a
    flat pad, per row). Residual ``[n, 1]`` = ``‖p_a − p_b‖ − y`` (mm).

    Args:
        tips: the two tips (tip links of a :class:`~jaxcal.KinematicTree`), e.g.
            ``("left_tool", "right_tool")``; each tip's tool point is its contact point.
    """

    kind: ClassVar[str] = "self_contact"
    size: ClassVar[int] = 1
    sample_shape: ClassVar[tuple[int, ...]] = ()
    tips: tuple[str, str] = eqx.field(static=True)

    def __init__(self, tips):
        self.tips = _two_tips(tips)

    @property
    def jacobian_free_of_data(self) -> bool:
        return True

    def check_robot(self, robot) -> None:
        """Raises ValueError: a tip the robot does not have (the message lists its tips)."""
        have = tuple(robot.tip_names())
        missing = [t for t in self.tips if t not in have]
        if missing:
            raise ValueError(f"self-contact tip(s) {missing} are not tips of robot {robot.name!r}; its tips: "
                             f"{list(have)} (a URDF robot with several tips: --tip A,B on the command line, "
                             "load_urdf's tips argument in Python)")

    def predict(self, robot, deviations, q) -> Float[Array, " n"]:
        """The distances ``[n]`` (mm) between the two tips' tool points."""
        q = check_joint_angles(robot, q)
        pa = tool_point_soa(robot, deviations, q, tip=self.tips[0])
        pb = tool_point_soa(robot, deviations, q, tip=self.tips[1])
        return jnp.sqrt(sum((u - v) ** 2 for u, v in zip(pa, pb)))

    def residual(self, robot, deviations, q, y) -> Float[Array, "n 1"]:
        return (self.predict(robot, deviations, q) - y)[:, None]

    def check_measurements(self, y, n: int) -> None:
        y = np.asarray(y)
        if y.shape != (n,):
            raise ValueError(f"self-contact readings must be [{n}] distances (mm), got shape {list(y.shape)}")
        if n and not (np.isfinite(y).all() and (y >= 0).all()):
            raise ValueError("self-contact distances must be finite and >= 0 mm (the sum of the contact radii)")


@register_kind
class SelfContactKind(SensorKind):
    """Self-contact data (:class:`SelfContact`): the robot's joint columns, ``contact_distance_mm``
    per row, and a ``# tips: A,B`` line."""

    name = "self_contact"
    columns = ("contact_distance_mm",)
    plannable = False  # no planning candidates of contact postures yet
    simulator = "jaxcal._simulation._simulate_files:self_contact_file"

    def setup(self, data, robot, estimate, options):
        """The model of the file's ``# tips:`` line, checked against ``robot``'s tips. The tips'
        errors are the robot's own groups (``tip_translation@<tip>``, ...): nothing to add."""
        self.check_options(estimate, options)
        if "base" in estimate:
            raise ValueError("--estimate base does not apply to self-contact data: the base frame is not seen")
        if "tips" not in data.meta:
            raise ValueError("self-contact data need a '# tips: A,B' line naming the two tips that touch")
        model = SelfContact(data.meta["tips"])
        model.check_robot(robot)
        return model, set(estimate), [f"self-contact of {model.tips[0]} and {model.tips[1]}: the two arms are seen "
                                      "relative to each other; where the pair is in the base frame stays with "
                                      "the prior"]

    def model_to_dict(self, model) -> dict:
        return {"kind": self.name, "tips": list(model.tips)}

    def model_from_dict(self, d: dict):
        return SelfContact(d["tips"])


def simulate_self_contact(key, robot, tips, *, n_samples: int = 300, distance_mm: float = 60.0,
                          noise_std: float = 0.1, true_deviations=None):
    """Self-contact data of ``robot`` with deviations ``true_deviations``: joint readings at which
    the two ``tips``' tool points are ``distance_mm`` + N(0, ``noise_std``²) apart (the contact's
    own scatter), the reading the known ``distance_mm``.

    Postures: random joint angles within the limits, brought to contact by 50 Gauss–Newton steps
    on the joint angles (the minimum-norm step of the one constraint, clipped to the joint limits),
    on the true robot; self-collision is not checked.

    Returns:
        ``(q [n, dof] rad, y [n] mm)``; rows that did not reach contact within 1e-6 mm are
        replaced by others (at most 20 rounds of candidates).

    Raises:
        ValueError: the tips rarely reach each other (fewer than ``n_samples`` contacts in 20
            rounds of ``4·n_samples`` candidates).
    """
    model = SelfContact(tips)
    model.check_robot(robot)
    lo, hi = np.asarray(robot.q_min, np.float64), np.asarray(robot.q_max, np.float64)

    def gap(q, target):
        return model.predict(robot, true_deviations, q[None])[0] - target

    @jax.jit
    def contact(q, target):
        """50 minimum-norm Gauss–Newton steps of every row toward its target gap, within the limits."""
        def body(_, q):
            f, g = jax.vmap(lambda qi, ti: (gap(qi, ti), jax.grad(gap)(qi, ti)))(q, target)
            return jnp.clip(q - (f / jnp.maximum((g * g).sum(axis=1), 1e-12))[:, None] * g, lo, hi)

        q = jax.lax.fori_loop(0, 50, body, q)
        return q, jax.vmap(gap)(q, target)

    out_q = []
    m = 4 * n_samples  # candidates per round: one compiled program for every round
    for _ in range(20):
        key, k_q, k_e = jax.random.split(key, 3)
        q = jax.random.uniform(k_q, (m, lo.size), minval=lo, maxval=hi)
        target = distance_mm + noise_std * jax.random.normal(k_e, (m,))
        q, f = (np.asarray(v, np.float64) for v in contact(q, target))
        ok = np.abs(f) < 1e-6
        out_q.append(q[ok])
        if sum(len(v) for v in out_q) >= n_samples:
            break
    q = np.concatenate(out_q)[:n_samples]
    y = np.full(len(q), float(distance_mm))
    if len(y) < n_samples:
        raise ValueError(f"only {len(y)} of {n_samples} self-contact postures found: tips {list(model.tips)} rarely "
                         "reach each other within the joint limits")
    return q, y
