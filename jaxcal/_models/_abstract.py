"""The robot protocol: what every robot model (a DH table, a serial chain) tells the rest of jaxcal.

The rooms above the models (calibration, results, reports, the command line) ask a robot for
what they need through these methods and never which type it is: its joints and their units,
its calibratable groups, its length entries, its file form, its DH table where it has one. A new
robot type (a kinematic tree of several branches) implements this class and the kinematic
kernels (``frame_soa(dev, q)`` and ``point_in_base(dev, q, point, fused=...)``, the flange frame
and a flange point in the base frame as structure-of-arrays triples, which
:mod:`jaxcal._models._kinematics` calls).

Written as optimistix writes its abstract solvers: an abstract ``eqx.Module`` whose concrete
subclasses are final.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence

import equinox as eqx
import numpy as np

__all__ = ["AbstractRobot"]


class AbstractRobot(eqx.Module):
    """Abstract base of jaxcal's robot models (:class:`jaxcal.DHRobot`, :class:`jaxcal.SerialChain`).

    Lengths in mm, angles in rad (prismatic joint coordinates in mm). Every concrete robot has a
    ``name`` (static), a nominal ``tool`` point ``[3]`` mm in its flange (tip link) frame and a
    ``nongeometric`` field (joint compliance, transmission errors, or ``None``).
    """

    @property
    @abc.abstractmethod
    def dof(self) -> int:
        """Number of moving joints (the data files' joint columns)."""

    def joint_units(self) -> tuple[str, ...]:
        """Unit of each joint coordinate: ``"rad"`` (revolute) or ``"mm"`` (prismatic); every
        joint revolute unless a robot type says otherwise."""
        return ("rad",) * self.dof

    @abc.abstractmethod
    def error_groups(self) -> tuple:
        """The robot's calibratable parameter groups (:class:`jaxcal._core._params.Group`),
        geometric then non-geometric; a measurement model adds its sensor extras after these."""

    @abc.abstractmethod
    def reach_mm(self) -> float:
        """A generous bound on the distance from the base origin to the tool point (mm)."""

    @abc.abstractmethod
    def nominal_lengths(self) -> dict[str, float]:
        """``{entry: nominal value}`` (mm) of the robot's length entries: what a uniform scaling of
        every length of a set-up multiplies (the tool point is the layout's ``tool`` group)."""

    @abc.abstractmethod
    def with_tool(self, tool_mm: Sequence[float]) -> AbstractRobot:
        """A copy with another nominal tool point ``[3]`` mm in the flange (tip link) frame."""

    @abc.abstractmethod
    def geometry_dict(self) -> dict:
        """The robot's geometry as JSON-friendly data (its file form in result files), without the
        non-geometric models; :meth:`to_dict` adds them."""

    def to_dict(self) -> dict:
        """JSON-friendly robot for result files: :meth:`geometry_dict` plus the non-geometric
        models (``"nongeometric"``) where the robot has any; ``jaxcal._calibration._io.robot_from_dict``
        reads it back."""
        from ._nongeometric import nongeometric_to_dict

        out = self.geometry_dict()
        if (ng := nongeometric_to_dict(self)) is not None:
            out["nongeometric"] = ng
        return out

    def fingerprint(self) -> dict:
        """Plain data that is equal for equal robots (a stored sweep chunk is reused only for an
        equal robot): :meth:`to_dict` unless a robot type has a more compact form."""
        return self.to_dict()

    def tip_names(self) -> tuple[str, ...]:
        """The robot's named tips, for measurement models that name the tip they see (a
        :class:`~jaxcal.KinematicTree`'s tip links, the default tip first); ``()`` for a robot
        with one unnamed tool point (a DH table, a serial chain)."""
        return ()

    def entry_labels(self) -> dict[str, str]:
        """``{entry name: label}`` for tables where an entry's name alone does not say where it
        acts (a :class:`~jaxcal.KinematicTree`'s ``"left_tool / l_elbow"``, ``"tip left_tool"``);
        ``{}`` for a robot whose entries need none (a DH table, a serial chain)."""
        return {}

    def default_tip(self) -> str | None:
        """The name of the tip a measurement model sees when it names none (a serial chain's tip
        link, a tree's first tip), or ``None`` for a robot whose tip has no name (a DH table)."""
        names = self.tip_names()
        return names[0] if names else None

    def dh_rows_deg(self, deviations=None) -> np.ndarray | None:
        """The robot's DH table ``[dof, 4]`` (α/°, a/mm, d/mm, θ/° per joint, angles not wrapped)
        at ``deviations`` (``None``: the nominal table), where the robot is described by one;
        ``None`` for a robot that is not (a generic chain: its calibrated model is the per-joint
        corrections, exported as URDF)."""
        return None
