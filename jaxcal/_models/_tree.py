"""Kinematic trees: several tips on branches that share joints (a dual-arm robot on one torso axis,
a humanoid with a head camera).

A :class:`KinematicTree` is a root (the base link frame) and moving joints, each hanging from the
root or from another joint (``parents``), with named *tips* (tip links: ``"left_tool"``,
``"head_camera"``) at the end of the paths. A joint shared by several tips (a torso axis) is one
joint of the tree: one joint-angle column, moving every tip above it, with **one** set of error
parameters. Lengths in mm, angles in rad (prismatic joint coordinates in mm), as in the chains.

Kinematics. The path from the root to a tip is a serial chain, and the tree computes it as one:
:meth:`KinematicTree.path_chain` is the :class:`~jaxcal.SerialChain` of that path (the tree's
arrays of those joints and the tip's flange), and the tip kernels (:meth:`KinematicTree.frame_soa`,
:meth:`KinematicTree.point_in_base`, with ``tip=``) are the chain's kernels on it, with the tree's
deviations of those joints (:meth:`KinematicTree.path_deviations`). The per-joint transform, the
error model (``offset, dx, dy, dz, drx, dry, drz`` of each joint origin, the 6-parameter error of
each tip transform) and their structure-of-arrays code are the chain's (:mod:`jaxcal._models._chain`
documents them); nothing is written again here. Joint-space (non-geometric) corrections act on
the tree's joint readings before the paths are taken, so a harmonic error of the torso joint is
one group entry too.

Joint order (the ``q`` columns and the per-joint error entries): parents before children. A tree
loaded from URDF (:func:`jaxcal.load_urdf` with ``tips=``) numbers its joints in order of first
appearance along the tips' paths, tips in the given order, each path from the base outward: for
``tips=["left_tool", "right_tool", "head_camera"]`` the torso joint(s), the left arm, the right
arm, the head. ``joint_names`` holds the URDF names in that order.

Error groups (:meth:`KinematicTree.error_groups`): the chain's per-joint groups over *all* tree
joints (``offset_j`` … ``drz_j``, ``j`` the 1-based tree joint; :meth:`KinematicTree.entry_labels`
gives each entry's branch and joint name) — so a shared joint has one entry per group, and the
joint-indexed machinery of jaxcal (non-geometric groups, still-joint checks, the preference order
of the identifiability QR, the default-free rule) applies unchanged — then per tip the tip
transform's ``tip_translation@<tip>`` (``tip_dx@<tip>`` …) and ``tip_rotation@<tip>``: a tip's
errors are its own, named by it, and rank and select as their family (``tip_translation``) as
the per-session groups of the sensors do. A tree with one tip has exactly the chain's groups
(``tip_translation``, ``tip_rotation``): it *is* that chain.

Single-tip protocol. The rest of jaxcal calls ``frame_soa(dev, q)`` / ``point_in_base(dev, q,
point)`` and reads ``robot.tool`` without a tip: these use the **default tip**, ``tips[0]`` (the
first of ``load_urdf``'s ``tips``), whose tool point moves with the layout's standard ``tool``
group; another tip's tool point moves with a ``tool@<tip>`` group where the deviations have one
(:meth:`KinematicTree.tool_groups` makes them for a measurement model to add).

Branches (:attr:`KinematicTree.branches`, for display and tables): maximal runs of joints without
a split, each hanging from the root or from the last joint of another branch; a branch that ends
at one tip is named after the tip, one that splits after the child link of its last joint
(``"torso"``, ``"left_tool"``, ``"right_tool"``, ``"head_camera"``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core._host_method import host_method
from .._core._precision import to_device
from ._abstract import AbstractRobot
from ._chain import (
    GEOMETRIC_GROUPS,
    TIP_GROUPS,
    SerialChain,
    _dev_get,
    _pattern,
    joint_error_groups,
    joint_free_by_default,
    origin_lengths,
    snap,
    tip_error_groups,
)
from ._nongeometric import NonGeometric, NonGeometricMixin, nongeometric_groups

__all__ = ["KinematicTree", "tool_group_name"]


class KinematicTree(NonGeometricMixin, AbstractRobot):
    """A kinematic tree: moving joints hanging from a root or from each other, with named tips.

    Build it with :func:`jaxcal.load_urdf` (``tips=[...]``), :meth:`build` or :meth:`from_chain`.
    Axes are aligned to the joint frames' ``z`` as in :class:`~jaxcal.SerialChain` (the module
    docstring says what the kinematics, joint order, error groups and default tip are).

    Attributes:
        origin_R: ``[dof, 3, 3]`` rotation of each joint origin (parent joint frame, or the base
            frame for a joint on the root → joint frame).
        origin_t: ``[dof, 3]`` translation of each joint origin (mm, parent joint frame).
        align: ``[dof, 3, 3]`` ``R_a`` per joint (URDF child-link frame = joint frame · ``R_aᵀ``).
        q_min, q_max: ``[dof]`` joint limits (rad; mm for prismatic joints).
        flange_R, flange_t: ``[n_tips, 3, 3]``, ``[n_tips, 3]`` mm: nominal transform from each
            tip's last joint frame to its tip link frame.
        tools: ``[n_tips, 3]`` nominal tool point of each tip, in its tip link frame (mm).
        joint_types: ``"revolute"`` / ``"prismatic"`` per joint (static).
        parents: per joint the index of its parent joint, ``-1`` for a joint on the root (static;
            parents come before their children).
        tips: tip names = tip link names (static); ``tips[0]`` is the default tip.
        tip_parents: per tip the index of the last joint on its path (static).
        joint_names, link_names: URDF joint names and the child link of each joint (static).
        branches: ``(name, parent branch or None, joint indices)`` per branch (static, derived).
        base: base link name; name: display name; urdf: the URDF text the tree was loaded from
            (static).
        nongeometric: harmonic transmission-error models (:meth:`with_harmonics`) or ``None``.
    """

    origin_R: Float[Array, "dof 3 3"]
    origin_t: Float[Array, "dof 3"]
    align: Float[Array, "dof 3 3"]
    q_min: Float[Array, " dof"]
    q_max: Float[Array, " dof"]
    flange_R: Float[Array, "n_tips 3 3"]
    flange_t: Float[Array, "n_tips 3"]
    tools: Float[Array, "n_tips 3"]
    joint_types: tuple[str, ...] = eqx.field(static=True)
    patterns: tuple = eqx.field(static=True)
    parents: tuple[int, ...] = eqx.field(static=True)
    tips: tuple[str, ...] = eqx.field(static=True)
    tip_parents: tuple[int, ...] = eqx.field(static=True)
    flange_patterns: tuple = eqx.field(static=True)
    joint_names: tuple[str, ...] = eqx.field(static=True)
    link_names: tuple[str, ...] = eqx.field(static=True)
    branches: tuple = eqx.field(static=True)
    base: str = eqx.field(static=True, default="base")
    name: str = eqx.field(static=True, default="tree")
    urdf: str | None = eqx.field(static=True, default=None)
    nongeometric: NonGeometric | None = None

    @classmethod
    def build(
        cls,
        *,
        origin_R: Sequence,
        origin_t: Sequence,
        joint_types: Sequence[str],
        q_min: Sequence[float],
        q_max: Sequence[float],
        parents: Sequence[int],
        tips: Sequence[str],
        tip_parents: Sequence[int],
        flange_R=None,
        flange_t=None,
        align=None,
        tools=None,
        joint_names: Sequence[str] | None = None,
        link_names: Sequence[str] | None = None,
        base: str = "base",
        name: str = "tree",
        urdf: str | None = None,
    ) -> KinematicTree:
        """Build a tree from host arrays (axes already along each joint frame's ``z``).

        The per-joint arrays are checked and snapped as a chain's (:meth:`SerialChain.build`);
        ``flange_R`` ``[n_tips, 3, 3]`` (default identity), ``flange_t`` ``[n_tips, 3]`` mm
        (default 0), ``tools`` ``[n_tips, 3]`` mm (default 0).

        Raises:
            ValueError: a parent not before its child, a tip's joint out of range, repeated or
                empty tip names, a joint on no tip's path (its reading would move nothing
                measured), or what :meth:`SerialChain.build` refuses.
        """
        joints = SerialChain.build(origin_R=origin_R, origin_t=origin_t, joint_types=joint_types, q_min=q_min,
                                   q_max=q_max, align=align, joint_names=joint_names, link_names=link_names)
        dof = joints.dof
        parents = tuple(int(p) for p in parents)
        if len(parents) != dof or any(not -1 <= p < j for j, p in enumerate(parents)):
            raise ValueError(f"parents must give, for each of the {dof} joints, an earlier joint's index or -1 "
                             f"(the root), got {parents}")
        tips = tuple(str(t) for t in tips)
        tip_parents = tuple(int(p) for p in tip_parents)
        n = len(tips)
        if n < 1 or len(set(tips)) != n or not all(tips):
            raise ValueError(f"tips must be one or more different names, got {list(tips)}")
        if len(tip_parents) != n or any(not 0 <= p < dof for p in tip_parents):
            raise ValueError(f"tip_parents must give, for each of the {n} tips, a joint index in 0..{dof - 1}, "
                             f"got {tip_parents}")
        used = {j for p in tip_parents for j in _path_of(parents, p)}
        if len(used) != dof:
            idle = [joints.joint_names[j] for j in range(dof) if j not in used]
            raise ValueError(f"joints {idle} lead to no tip: every joint of a tree must move at least one tip")
        fR = np.broadcast_to(np.eye(3), (n, 3, 3)) if flange_R is None else np.asarray(flange_R, np.float64)
        fR = np.stack([snap(r) for r in fR.reshape(n, 3, 3)])
        ft = np.zeros((n, 3)) if flange_t is None else np.asarray(flange_t, np.float64).reshape(n, 3)
        tl = np.zeros((n, 3)) if tools is None else np.asarray(tools, np.float64).reshape(n, 3)
        if not np.all(np.isfinite(tl)):
            raise ValueError(f"tools must be finite numbers (mm), got {tl.tolist()}")
        for k, r in enumerate(fR):
            if not (np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0):
                raise ValueError(f"flange_R[{k}] (tip {tips[k]!r}) is not a rotation matrix")
        for t in tips:
            tip_error_groups(None if n == 1 else t)  # register the tip's group names (group_of works at once)
        return cls(
            origin_R=joints.origin_R, origin_t=joints.origin_t, align=joints.align, q_min=joints.q_min,
            q_max=joints.q_max, flange_R=to_device(fR), flange_t=to_device(ft), tools=to_device(tl),
            joint_types=joints.joint_types, patterns=joints.patterns, parents=parents, tips=tips,
            tip_parents=tip_parents, flange_patterns=tuple(_pattern(r) for r in fR),
            joint_names=joints.joint_names, link_names=joints.link_names,
            branches=_branches(parents, tip_parents, tips, joints.link_names), base=base, name=name, urdf=urdf,
        )

    @classmethod
    def from_chain(cls, chain: SerialChain) -> KinematicTree:
        """The one-tip tree of a serial chain (its tip named ``chain.tip``): the same kinematics
        and the same error groups."""
        f = lambda a: np.asarray(a, np.float64)  # noqa: E731
        return cls.build(
            origin_R=f(chain.origin_R), origin_t=f(chain.origin_t), joint_types=chain.joint_types, q_min=f(chain.q_min),
            q_max=f(chain.q_max), parents=range(-1, chain.dof - 1), tips=(chain.tip,), tip_parents=(chain.dof - 1,),
            flange_R=f(chain.flange_R)[None], flange_t=f(chain.flange_t)[None], align=f(chain.align),
            tools=f(chain.tool)[None], joint_names=chain.joint_names, link_names=chain.link_names, base=chain.base,
            name=chain.name, urdf=chain.urdf)

    # ------------------------------------------------------------------ structure
    @property
    def dof(self) -> int:
        """Number of moving joints of the whole tree (the data files' joint columns)."""
        return len(self.parents)

    @property
    def prismatic(self) -> tuple[bool, ...]:
        """Per joint: ``True`` for a prismatic joint (static)."""
        return tuple(s == "prismatic" for s in self.joint_types)

    @property
    def tool(self) -> Float[Array, " 3"]:
        """The default tip's nominal tool point ``[3]`` mm (what single-tip callers read)."""
        return self.tools[0]

    @property
    def tip(self) -> str:
        """The default tip's name (``tips[0]``)."""
        return self.tips[0]

    def tip_index(self, tip: str | int | None) -> int:
        """Index of ``tip`` (a name, an index, or ``None``: the default tip, 0)."""
        if tip is None:
            return 0
        if isinstance(tip, (int, np.integer)) and not isinstance(tip, bool):
            if not 0 <= tip < len(self.tips):
                raise ValueError(f"tip index {tip} out of range: the tree has {len(self.tips)} tips {list(self.tips)}")
            return int(tip)
        if tip not in self.tips:
            raise ValueError(f"unknown tip {tip!r}; tips of {self.name!r}: {list(self.tips)}")
        return self.tips.index(tip)

    def path(self, tip: str | int | None = None) -> tuple[int, ...]:
        """Indices of the joints from the root to ``tip`` (root first), into ``q``'s columns."""
        return _path_of(self.parents, self.tip_parents[self.tip_index(tip)])

    def path_chain(self, tip: str | int | None = None) -> SerialChain:
        """The :class:`~jaxcal.SerialChain` from the root to ``tip``: the tree's arrays of the
        path's joints (no copy when the path is every joint) and the tip's flange and tool; joint
        ``i`` of the chain is tree joint ``path(tip)[i]``. Works on traced trees (inside ``jit``)."""
        k = self.tip_index(tip)
        idx = self.path(k)
        take = (lambda a: a) if idx == tuple(range(self.dof)) else (lambda a: a[np.asarray(idx)])  # noqa: E731
        xp = np if isinstance(self.q_min, np.ndarray) else jnp  # a tree of NumPy arrays: a chain of them
        zeros = xp.zeros((len(idx),), self.q_min.dtype)
        return SerialChain(
            origin_R=take(self.origin_R), origin_t=take(self.origin_t), flange_R=self.flange_R[k],
            flange_t=self.flange_t[k], align=take(self.align), q_min=take(self.q_min), q_max=take(self.q_max),
            tool=self.tools[k], mass=zeros, com=xp.zeros((len(idx), 3), zeros.dtype),
            joint_types=tuple(self.joint_types[j] for j in idx), patterns=tuple(self.patterns[j] for j in idx),
            flange_pattern=self.flange_patterns[k], joint_names=tuple(self.joint_names[j] for j in idx),
            link_names=tuple(self.link_names[j] for j in idx), base=self.base, tip=self.tips[k], name=self.name,
            urdf=self.urdf)

    def tip_group_names(self, tip: str | int | None = None) -> tuple[str, str]:
        """Names of ``tip``'s translation and rotation error groups: the chain's
        ``("tip_translation", "tip_rotation")`` for a one-tip tree, else with ``@<tip>``."""
        k = self.tip_index(tip)
        return tuple(g.name for g in tip_error_groups(None if len(self.tips) == 1 else self.tips[k]))

    def path_deviations(self, dev, tip: str | int | None = None) -> dict | None:
        """The deviations of ``tip``'s path in the chain's names, for :meth:`path_chain`'s kernels:
        each per-joint group (``offset`` … ``drz``) at the path's joints and the tip's own
        ``tip_translation`` / ``tip_rotation``; ``None`` for ``None``. ``dev``: a
        :class:`~jaxcal.Deviations` or a mapping of group arrays."""
        if dev is None:
            return None
        k = self.tip_index(tip)
        idx = self.path(k)
        full = idx == tuple(range(self.dof))
        out = {}
        for g, _unit in GEOMETRIC_GROUPS:
            v = _dev_get(dev, g)
            if v is not None:
                out[g] = v if full else jnp.asarray(v)[np.asarray(idx)]
        for (g, _names, _unit), own in zip(TIP_GROUPS, self.tip_group_names(k)):
            v = _dev_get(dev, own)
            if v is not None:
                out[g] = v
        return out

    def _path_args(self, dev, q, tip):
        """``(path chain, its deviations, its joint readings [n, len(path)])`` of ``tip``, the
        joint-space corrections applied to the tree's readings first."""
        from ._kinematics import effective_joint_angles

        if dev is not None and not isinstance(dev, Mapping):
            q = effective_joint_angles(self, dev, q)
        k = self.tip_index(tip)
        idx = self.path(k)
        qk = q if idx == tuple(range(self.dof)) else q[:, np.asarray(idx)]
        return self.path_chain(k), self.path_deviations(dev, k), qk

    # ------------------------------------------------------------------ kinematics
    def point_in_base(self, dev, q: Float[Array, "n dof"], point, *, fused: bool = False,
                      tip: str | int | None = None):
        """A point ``[3]`` (mm) in ``tip``'s link frame (default: the default tip), in the base
        frame: three ``[n]`` arrays. ``q`` ``[n, dof]`` holds every tree joint (rad; mm at
        prismatic joints); the path's joints are used. :meth:`SerialChain.point_in_base` on
        :meth:`path_chain` (``fused`` as there): jittable, ``jax.jacfwd``-friendly in ``dev``."""
        chain, sub, qk = self._path_args(dev, q, tip)
        return chain.point_in_base(sub, qk, point, fused=fused)

    def frame_soa(self, dev, q: Float[Array, "n dof"], *, tip: str | int | None = None):
        """``tip``'s link frame (default: the default tip) in the base frame as SoA: columns X,
        Y, Z and origin P (mm), each a triple of ``[n]`` arrays; :meth:`SerialChain.frame_soa`
        on :meth:`path_chain`."""
        chain, sub, qk = self._path_args(dev, q, tip)
        return chain.frame_soa(sub, qk)

    def tool_of(self, tip: str | int | None = None) -> Float[Array, " 3"]:
        """``tip``'s nominal tool point ``[3]`` mm in its tip link frame."""
        return self.tools[self.tip_index(tip)]

    def tool_group(self, tip: str | int | None = None) -> str:
        """The deviation group that moves ``tip``'s tool point: the standard ``tool`` for the
        default tip, ``tool@<tip>`` for another (used where the deviations have it)."""
        k = self.tip_index(tip)
        return "tool" if k == 0 else tool_group_name(self.tips[k])

    def tool_groups(self) -> tuple:
        """``tool@<tip>`` ``[3]`` mm extra groups (``tool_x@<tip>`` …) of every tip but the
        default one (whose tool point is the layout's standard ``tool`` group): for a
        measurement model of several tool points to add to its ``extra_groups()``."""
        return tuple(tip_tool_group(self.tips[k]) for k in range(1, len(self.tips)))

    def tool_vector(self, dev, dtype, tip: str | int | None = None) -> Float[Array, " 3"]:
        """``tip``'s tool point ``[3]`` mm in its tip link frame: nominal + the deviation group of
        :meth:`tool_group` where ``dev`` has it."""
        t = jnp.asarray(self.tool_of(tip)).astype(dtype)
        dt = _dev_get(dev, self.tool_group(tip))
        return t if dt is None else t + jnp.asarray(dt).astype(dtype)

    # ------------------------------------------------------------------ robot protocol
    def tip_names(self) -> tuple[str, ...]:
        """The tip links, the default tip first."""
        return self.tips

    def joint_units(self) -> tuple[str, ...]:
        """Unit of each joint coordinate: ``"rad"`` or ``"mm"``."""
        return tuple("mm" if p else "rad" for p in self.prismatic)

    def error_groups(self):
        """The chain's per-joint geometric groups over every tree joint (``offset_j`` …
        ``drz_j``, ``j`` the 1-based tree joint), then per tip its ``tip_translation`` ``[3]`` mm
        and ``tip_rotation`` ``[3]`` rad (``@<tip>`` unless the tree has one tip), then the
        non-geometric groups."""
        tips = (None,) if len(self.tips) == 1 else self.tips
        return (tuple(joint_error_groups(self.joint_units()) + [g for t in tips for g in tip_error_groups(t)])
                + nongeometric_groups(self))

    def free_by_default(self, entry_name: str) -> bool:
        """As a chain: ``drz`` at a revolute joint is not free by default, every other entry is."""
        return joint_free_by_default(self.prismatic, entry_name)

    def entry_labels(self) -> dict[str, str]:
        """``{entry name: "branch / joint name"}`` of the per-joint entries and ``{entry name: "tip
        <tip>"}`` of the tip entries, for tables (``"offset_9": "left_tool / l_elbow"``)."""
        branch_of = {j: b for b, _parent, joints in self.branches for j in joints}
        out = {}
        for g in self.error_groups():
            for n in g.names:
                head, _, j = n.rpartition("_")
                if g.kind == "geometric" and j.isdigit():
                    out[n] = f"{branch_of[int(j) - 1]} / {self.joint_names[int(j) - 1]}"
                elif g.kind == "geometric":
                    out[n] = f"tip {n.partition('@')[2] or self.tips[0]}"
        return out

    def with_tips(self, tips: Sequence[str]) -> KinematicTree:
        """The tree of the same robot with only ``tips``, in that order (``tips[0]`` the default
        tip): the joints on their paths, numbered as :func:`jaxcal.load_urdf` numbers a tree's
        joints (first appearance along the tips' paths, each from the root) — the tree
        ``load_urdf(path, tips=tips)`` of this robot's URDF loads. One tip: a one-tip tree, which is
        the serial chain of that path (the chain's error groups). What ``--tip A[,B...]`` gives for
        a tree preset on the command line.

        Raises:
            ValueError: no tips, a repeated tip, a tip the tree does not have (the message lists
                its tips), or a tree with harmonic joint errors (whose joints would renumber).
        """
        tips = [tips] if isinstance(tips, str) else list(tips)
        if not tips or len(set(tips)) != len(tips):
            raise ValueError(f"tips must be one or more different tips of {self.name!r}, got {tips}; its tips: "
                             f"{list(self.tips)}")
        ks = [self.tip_index(t) for t in tips]
        if self.nongeometric is not None:
            raise ValueError("with_tips: take the tips first, then add the harmonic joint errors (with_harmonics)")
        order: list[int] = []
        for k in ks:
            order.extend(j for j in self.path(k) if j not in order)
        new = {j: i for i, j in enumerate(order)}
        f = lambda a, idx: np.asarray(a, np.float64)[np.asarray(idx)]  # noqa: E731
        return KinematicTree.build(
            origin_R=f(self.origin_R, order), origin_t=f(self.origin_t, order), align=f(self.align, order),
            joint_types=[self.joint_types[j] for j in order], q_min=f(self.q_min, order), q_max=f(self.q_max, order),
            parents=[new[self.parents[j]] if self.parents[j] >= 0 else -1 for j in order], tips=tips,
            tip_parents=[new[self.tip_parents[k]] for k in ks], flange_R=f(self.flange_R, ks),
            flange_t=f(self.flange_t, ks), tools=f(self.tools, ks), joint_names=[self.joint_names[j] for j in order],
            link_names=[self.link_names[j] for j in order], base=self.base, name=self.name, urdf=self.urdf)

    def with_tool(self, tool_mm: Sequence[float], tip: str | int | None = None) -> KinematicTree:
        """A copy with another nominal tool point ``[3]`` mm for ``tip`` (default: the default
        tip, the one the protocol's single-tip callers use), in its tip link frame."""
        tool = np.asarray(tool_mm, np.float64)
        if tool.shape != (3,) or not np.all(np.isfinite(tool)):
            raise ValueError(f"tool_mm must be 3 finite numbers (mm), got {tool_mm!r}")
        tools = np.array(self.tools, np.float64)
        tools[self.tip_index(tip)] = tool
        return eqx.tree_at(lambda r: r.tools, self, jnp.asarray(tools).astype(self.tools.dtype))

    def with_compliance(self, mass_model=None, joints=None):
        """Not available on a tree yet: a joint's gravity torque sums every branch above it,
        which the chain's mass model does not describe (harmonic errors are: :meth:`with_harmonics`)."""
        raise NotImplementedError("joint compliance is not modelled on a kinematic tree yet (the gravity torque of a "
                                  "shared joint sums every branch above it); harmonic errors are (--harmonics on the "
                                  "command line, with_harmonics in Python)")

    def geometry_dict(self) -> dict:
        """JSON-friendly tree that :func:`jaxcal._models._urdf.tree_from_dict` rebuilds exactly:
        base link, tips and their tool points (mm), joint names and types, and the geometry — the
        URDF text a tree was loaded from (``"urdf"``), or, for a tree built by hand, its arrays
        (``"origins"``: joint origins, parents, axis alignments, limits, tip joints and flanges,
        link names; mm / rad)."""
        f = lambda a: np.asarray(a, np.float64).tolist()  # noqa: E731
        out = {
            "type": "kinematic_tree",
            "name": self.name,
            "base": self.base,
            "tips": list(self.tips),
            "tools_mm": f(self.tools),
            "joint_names": list(self.joint_names),
            "joint_types": list(self.joint_types),
        }
        if self.urdf is not None:
            out["urdf"] = self.urdf
        else:
            out["origins"] = {"origin_R": f(self.origin_R), "origin_t_mm": f(self.origin_t), "align": f(self.align),
                              "q_min": f(self.q_min), "q_max": f(self.q_max), "parents": list(self.parents),
                              "tip_parents": list(self.tip_parents), "flange_R": f(self.flange_R),
                              "flange_t_mm": f(self.flange_t), "link_names": list(self.link_names)}
        return out

    @host_method
    def nominal_lengths(self) -> dict[str, float]:
        """``{entry: nominal value}`` (mm) of the tree's length entries: ``dx_j, dy_j, dz_j`` of
        every joint origin and each tip's flange translation (``tip_dx@<tip>`` …); what a uniform
        scaling of every length multiplies (the tool points are extras, not the robot's)."""
        out = origin_lengths(self.origin_t)
        ft = np.asarray(self.flange_t, np.float64)
        for k in range(len(self.tips)):
            names = next(g.names for g in tip_error_groups(None if len(self.tips) == 1 else self.tips[k]))
            out |= dict(zip(names, (float(v) for v in ft[k])))
        return out

    @host_method
    def reach_mm(self) -> float:
        """A generous bound on the distance from the base origin to any tip's tool point (mm):
        the largest of the path chains' bounds (:meth:`SerialChain.reach_mm`), on the host (a
        NumPy copy of the tree: slicing its JAX arrays would run a small program per slice)."""
        host = jax.tree_util.tree_map(np.asarray, self)
        return max(host.path_chain(k).reach_mm() for k in range(len(self.tips)))


def tool_group_name(tip: str) -> str:
    """``tool@<tip>``: the name of the group that moves the tool point of ``tip`` (a tree's tip
    other than its default one)."""
    return f"tool@{tip}"


def tip_tool_group(tip: str):
    """The extra group ``tool@<tip>`` (entries ``tool_x@<tip>``, ``tool_y@<tip>``, ``tool_z@<tip>``,
    mm): the deviation of the tool point of ``tip`` (not a tree's default tip, whose tool point is
    the standard ``tool`` group) from its nominal value, in its tip link frame."""
    from .._core._params import Group

    return Group.vector(tool_group_name(tip), tuple(f"tool_{c}@{tip}" for c in "xyz"), "mm")


def _path_of(parents: Sequence[int], last: int) -> tuple[int, ...]:
    """Joint indices from the root down to joint ``last``, root first."""
    out = []
    j = last
    while j >= 0:
        out.append(j)
        j = parents[j]
    return tuple(reversed(out))


def _branches(parents, tip_parents, tips, link_names) -> tuple:
    """``(name, parent branch name or None, joint indices)`` of each branch: a maximal run of
    joints in which every joint but the last has exactly one child joint and no tip. Named after
    its tip when it ends at one tip and nothing else, else after its last joint's child link."""
    kids: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        kids.setdefault(p, []).append(j)
    tips_at: dict[int, list[int]] = {}
    for k, p in enumerate(tip_parents):
        tips_at.setdefault(p, []).append(k)
    out: list = []
    names: set[str] = set()
    stack = [(j, None) for j in reversed(kids.get(-1, []))]
    while stack:
        first, parent = stack.pop()
        joints = [first]
        while len(kids.get(joints[-1], [])) == 1 and not tips_at.get(joints[-1]):
            joints.append(kids[joints[-1]][0])
        last = joints[-1]
        at = tips_at.get(last, [])
        name = tips[at[0]] if not kids.get(last) and len(at) == 1 else link_names[last]
        if name in names:
            name = f"{name}_{first + 1}"
        names.add(name)
        out.append((name, parent, tuple(joints)))
        stack.extend((j, name) for j in reversed(kids.get(last, [])))
    return tuple(out)
