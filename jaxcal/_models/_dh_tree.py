"""Kinematic trees from standard DH rows: each row regrouped into a joint origin and what follows
the joint's rotation, with shared joints opening each branch (the tree presets of
:mod:`jaxcal.robots` and the DH tree files of :func:`jaxcal._calibration._io.load_tree_csv`).

Standard DH ``A_i = Rz(θ_i + q_i)·Tz(d_i)·Tx(a_i)·Rx(α_i)`` (a, d mm; α, θ offset in degrees),
regrouped as :func:`jaxcal.chain_from_dh` regroups it: joint i's origin is the previous row's
``Tx(a)·Rx(α)`` times ``Tz(d_i)·Rz(θ_i)``, and the last row's ``Tx(a)·Rx(α)`` is the tip's flange.
A joint that several branches share keeps only what precedes its rotation; the rest of its row
(d, θ offset, a, α), which the sources give per branch, opens each branch (its first joint's
origin, or a tip's flange) — ``Tz(d)·Rz(θ)`` commutes with the joint's ``Rz(q)`` — so the shared
joint's reading and error parameters are one, as on the robot.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ._tree import KinematicTree

__all__ = ["TreeSpec", "dh_head", "dh_tail", "dh_row"]


def _tz(d):
    T = np.eye(4)
    T[2, 3] = d
    return T


def _tx(a):
    T = np.eye(4)
    T[0, 3] = a
    return T


def _rz(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def _rx(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    T = np.eye(4)
    T[1:3, 1:3] = [[c, -s], [s, c]]
    return T


def dh_head(d, theta):
    """``Tz(d)·Rz(θ)``: what a DH row puts before its joint's rotation (they commute)."""
    return _tz(d) @ _rz(theta)


def dh_tail(a, alpha):
    """``Tx(a)·Rx(α)``: what a DH row puts after its joint's rotation."""
    return _tx(a) @ _rx(alpha)


def dh_row(a, d, alpha, theta):
    """A whole standard DH row at zero joint reading (a fixed transform)."""
    return dh_head(d, theta) @ dh_tail(a, alpha)


class TreeSpec:
    """Joints and tips added branch by branch (parents first), then :meth:`build`: host-side
    bookkeeping (4×4 NumPy transforms, mm; limits given in degrees) for
    :meth:`~jaxcal.KinematicTree.build`."""

    def __init__(self):
        self.origins, self.parents, self.names, self.links, self.lo, self.hi = [], [], [], [], [], []
        self.tips, self.tip_parents, self.flanges, self.tools = [], [], [], []

    def joint(self, parent: int, origin, name: str, link: str, limits_deg) -> int:
        self.origins.append(np.asarray(origin, np.float64))
        self.parents.append(parent)
        self.names.append(name)
        self.links.append(link)
        self.lo.append(np.radians(limits_deg[0]))
        self.hi.append(np.radians(limits_deg[1]))
        return len(self.parents) - 1

    def branch(self, parent: int, mount, rows, names, links, limits_deg) -> tuple[int, np.ndarray]:
        """DH ``rows`` ``(a, d, α, θ)`` hanging from joint ``parent`` (``-1``: the base) after the
        fixed ``mount``: returns the last joint's index and the last row's tail (a tip's flange)."""
        prev = np.asarray(mount, np.float64)
        for (a, d, alpha, theta), name, link, lim in zip(rows, names, links, limits_deg, strict=True):
            parent = self.joint(parent, prev @ dh_head(d, theta), name, link, lim)
            prev = dh_tail(a, alpha)
        return parent, prev

    def tip(self, name: str, parent: int, flange, tool=(0.0, 0.0, 0.0)) -> None:
        self.tips.append(name)
        self.tip_parents.append(parent)
        self.flanges.append(np.asarray(flange, np.float64))
        self.tools.append(np.asarray(tool, np.float64))

    def build(self, name: str, base: str, tools: Mapping[str, Sequence[float]] | None) -> KinematicTree:
        tl = np.array(self.tools)
        for t, v in (tools or {}).items():
            if t not in self.tips:
                raise ValueError(f"tool points given for {t!r}, which is not a tip of {name} ({self.tips})")
            tl[self.tips.index(t)] = np.asarray(v, np.float64)
        O = np.array(self.origins)
        F = np.array(self.flanges)
        return KinematicTree.build(
            origin_R=O[:, :3, :3], origin_t=O[:, :3, 3], joint_types=["revolute"] * len(O), q_min=self.lo,
            q_max=self.hi, parents=self.parents, tips=self.tips, tip_parents=self.tip_parents,
            flange_R=F[:, :3, :3], flange_t=F[:, :3, 3], tools=tl, joint_names=self.names, link_names=self.links,
            base=base, name=name)
