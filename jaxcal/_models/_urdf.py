"""URDF serial chains: loading (base link → tip link), DH tables as chains, and export.

Parser choice: the standard library's ``xml.etree.ElementTree``. A serial-chain loader needs
``<link>`` (name, ``<inertial>``) and ``<joint>`` (type, parent, child, origin, axis, limit,
mimic) only — about a hundred lines. The pure-Python parsers available were heavier than that:
``yourdfpy`` pulls ``trimesh`` and ``lxml`` (meshes we never use), ``urchin``/``urdfpy`` add
``networkx``, ``pycollada`` and ``trimesh``, and ``urdf_parser_py`` is a ROS package that is not
maintained on PyPI for current Pythons. jaxcal keeps its dependencies lean, so a
stdlib loader it is. ``xacro`` files must be expanded first (``xacro robot.urdf.xacro > robot.urdf``).

Units: URDF lengths are metres; jaxcal works in mm. The loader multiplies every length (joint
origins, prismatic limits, link centres of mass) by 1000 here, at the file edge, and
:func:`export_urdf` divides by 1000 on the way out. Angles stay in rad.

Joint types: ``revolute`` and ``prismatic`` joints move; ``continuous`` joints are treated as
revolute with limits ±π (joint limits only bound sampling and planning; a continuous joint's
reading is still used as given); ``fixed`` joints are folded into the neighbouring transforms.
``floating`` and ``planar`` joints, and ``mimic`` joints, between base and tip are refused with
an error naming the joint: a calibration chain needs one independent reading per joint.
"""

from __future__ import annotations

import os
import pathlib
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence

import numpy as np

from ._chain import SerialChain, _dev_get, align_z, matrix_rpy, rpy_matrix, snap
from ._tree import KinematicTree

__all__ = ["load_urdf", "chain_from_dh", "export_urdf", "urdf_chain_links", "chain_to_dict", "chain_from_dict",
           "tree_from_urdf", "tree_from_dict"]

_M_TO_MM = 1000.0


def _floats(text: str | None, default: Sequence[float], what: str) -> np.ndarray:
    if text is None:
        return np.asarray(default, dtype=np.float64)
    try:
        v = np.asarray([float(s) for s in text.split()], dtype=np.float64)
    except ValueError:
        raise ValueError(f"URDF: cannot read numbers {text!r} in {what}") from None
    if v.shape != (len(default),):
        raise ValueError(f"URDF: {what} needs {len(default)} numbers, got {text!r}")
    return v


def _origin(el, what: str) -> np.ndarray:
    """``<origin xyz rpy>`` of ``el`` as a ``[4, 4]`` transform (translation converted to mm)."""
    T = np.eye(4)
    o = el.find("origin")
    if o is not None:
        T[:3, :3] = rpy_matrix(_floats(o.get("rpy"), (0, 0, 0), f"{what} <origin rpy>"))
        T[:3, 3] = _floats(o.get("xyz"), (0, 0, 0), f"{what} <origin xyz>") * _M_TO_MM
    return T


def _parse_root(source) -> tuple[ET.Element, str]:
    """The ``<robot>`` element and the URDF text from a path or an XML string."""
    if isinstance(source, os.PathLike) or (isinstance(source, str) and not source.lstrip().startswith("<")):
        path = pathlib.Path(source)
        if not path.exists():
            raise FileNotFoundError(f"URDF file not found: {path}")
        text = path.read_text()
    else:
        text = str(source)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise ValueError(f"URDF: not well-formed XML ({e})") from None
    if root.tag != "robot":
        raise ValueError(f"URDF: the root element must be <robot>, got <{root.tag}>")
    return root, text


def urdf_chain_links(source) -> dict:
    """Summary of a URDF's tree: ``{"links": [...], "roots": [...], "leaves": [...]}`` (link
    names), to choose ``base`` and ``tip`` for :func:`load_urdf`."""
    root, _ = _parse_root(source)
    links = [el.get("name") for el in root.findall("link")]
    parents = {j.find("child").get("link"): j.find("parent").get("link") for j in root.findall("joint")}
    has_child = set(parents.values())
    return {
        "links": links,
        "roots": [name for name in links if name not in parents],
        "leaves": [name for name in links if name not in has_child],
    }


def _parse_tree(source):
    """The URDF's tree: ``(root element, text, {link: element}, {child link: joint element},
    root links)``; a link with two parent joints is refused."""
    root, text = _parse_root(source)
    links = {}
    for el in root.findall("link"):
        links[el.get("name")] = el
    joints_by_child: dict[str, ET.Element] = {}
    for j in root.findall("joint"):
        jname = j.get("name")
        p, c = j.find("parent"), j.find("child")
        if p is None or c is None:
            raise ValueError(f"URDF: joint {jname!r} needs <parent link> and <child link>")
        child = c.get("link")
        if child in joints_by_child:
            raise ValueError(
                f"URDF: link {child!r} has two parent joints ({joints_by_child[child].get('name')!r} and "
                f"{jname!r}); a kinematic loop is not a serial chain"
            )
        joints_by_child[child] = j
    roots = [n for n in links if n not in joints_by_child]
    return root, text, links, joints_by_child, roots


def _default_base(roots) -> str:
    if len(roots) != 1:
        raise ValueError(f"URDF: the file has several root links {roots}: name the chain's base link "
                         "(--base LINK on the command line, load_urdf's base argument in Python)")
    return roots[0]


def _leaves_below(joints_by_child, base: str) -> list[str]:
    """The leaf links of the subtree below link ``base``."""
    children: dict[str, list[str]] = {}
    for c, j in joints_by_child.items():
        children.setdefault(j.find("parent").get("link"), []).append(c)
    leaves, stack = [], [base]
    while stack:
        k = stack.pop()
        if children.get(k):
            stack.extend(children[k])
        else:
            leaves.append(k)
    return leaves


def _path(joints_by_child, base: str, tip: str) -> list[ET.Element]:
    """The joints from link ``base`` down to link ``tip``, base first."""
    path: list[ET.Element] = []
    link = tip
    while link != base:
        j = joints_by_child.get(link)
        if j is None:
            up = [tip]
            k = tip
            while k in joints_by_child:
                k = joints_by_child[k].find("parent").get("link")
                up.append(k)
            raise ValueError(
                f"URDF: tip link {tip!r} is not below base link {base!r} (its ancestors are {up[1:]}); "
                "a serial chain runs from a base link down to one of its descendants"
            )
        path.append(j)
        link = j.find("parent").get("link")
    path.reverse()
    return path


def load_urdf(source, *, base: str | None = None, tip: str | None = None, tips: Sequence[str] | None = None,
              tool=(0.0, 0.0, 0.0), name: str | None = None) -> SerialChain | KinematicTree:
    """Load the serial chain from link ``base`` to link ``tip`` of a URDF, or with ``tips`` the
    kinematic tree from ``base`` to several tip links.

    Args:
        source: a path to a ``.urdf`` file or the URDF XML text.
        base: base link name (default: the tree's root link).
        tip: tip link name (default: the single leaf below ``base`` if there is exactly one).
        tips: several tip link names (instead of ``tip``): returns a
            :class:`~jaxcal.KinematicTree` of the union of the paths from ``base`` to each tip
            (its joint order and error groups: :class:`~jaxcal.KinematicTree`); the first tip is
            the tree's default tip.
        tool: nominal tool point ``[3]`` in the tip link frame (**mm**); with ``tips``, one ``[3]``
            for every tip or a mapping ``{tip: [3]}`` (tips not named: the tip link origin).
        name: display name (default: the ``<robot name>``).

    Returns:
        A :class:`~jaxcal.SerialChain` in mm / rad whose base frame is the ``base`` link frame and
        whose flange frame is the ``tip`` link frame; joint ``i`` of ``q`` is the ``i``-th moving
        joint from base to tip (``chain.joint_names``). Per moving joint the mass [kg] and centre
        of mass [mm, joint frame] of its child link, merged with links fixed to it along the
        path, are kept in ``chain.mass`` / ``chain.com``. With ``tips``: a
        :class:`~jaxcal.KinematicTree` (:func:`tree_from_urdf`).

    Raises:
        ValueError: unknown link names (the message lists the valid ones); ``tip`` not below
            ``base``; a link with two parents; a ``mimic``, ``floating`` or ``planar`` joint on the
            path; a revolute/prismatic joint without ``<limit lower upper>``; no moving joint;
            with ``tips``: an unknown tip (the message lists the leaf links), two tips on one
            path, a repeated tip, or ``tip`` and ``tips`` both given.
    """
    if tips is not None:
        if tip is not None:
            raise ValueError("load_urdf: give either tip (a serial chain) or tips (a kinematic tree), not both")
        return tree_from_urdf(source, base=base, tips=tips, tool=tool, name=name)
    root, text, links, joints_by_child, roots = _parse_tree(source)
    if base is None:
        base = _default_base(roots)
    for label, link in (("base", base), ("tip", tip)):
        if link is not None and link not in links:
            raise ValueError(f"URDF: unknown {label} link {link!r}; links in this file: {sorted(links)}")
    if tip is None:
        leaves = _leaves_below(joints_by_child, base)
        if len(leaves) != 1:
            raise ValueError(f"URDF: the tree below {base!r} branches: name the chain's tip link among its leaf links "
                             f"{sorted(leaves)} (--tip LINK on the command line, load_urdf's tip argument in Python)")
        tip = leaves[0]
    rows = _path_rows(_path(joints_by_child, base, tip), links, base, tip)
    return SerialChain.build(**rows, tool=tool, base=base, tip=tip, name=name or root.get("name") or "urdf", urdf=text)


def _path_rows(path: list[ET.Element], links: dict, base: str, tip: str) -> dict:
    """The chain of the URDF joints ``path`` (base → tip) as :meth:`SerialChain.build` arguments:
    per moving joint its aligned origin, type, limits, names and body inertials, and the flange
    (fixed joints folded into the next origin or the flange). A joint's values depend only on the
    path above it, so paths sharing their first joints give those joints identical rows."""
    origin_R, origin_t, align, types, q_min, q_max, jnames, lnames = [], [], [], [], [], [], [], []
    mass, com = [], []
    pending = np.eye(4)  # fixed transforms since the last moving joint's frame (or the base)
    R_prev = np.eye(3)   # alignment of the last moving joint
    acc_mass, acc_mc = 0.0, np.zeros(3)  # mass and Σ m·c (in the last joint frame) of the current body
    for j in path:
        jname, jtype = j.get("name"), j.get("type")
        child = j.find("child").get("link")
        T = _origin(j, f"joint {jname!r}")
        if j.find("mimic") is not None:
            raise ValueError(
                f"URDF: joint {jname!r} between {base!r} and {tip!r} is a mimic joint; jaxcal chains need one "
                "independent joint reading per joint (mimic couplings are not supported)"
            )
        if jtype in ("floating", "planar"):
            raise ValueError(
                f"URDF: joint {jname!r} between {base!r} and {tip!r} is {jtype}; only revolute, continuous, "
                "prismatic and fixed joints are supported in a serial chain"
            )
        if jtype == "fixed":
            pending = pending @ T
            acc_mass, acc_mc = _add_inertial(links.get(child), R_prev, pending, acc_mass, acc_mc)
            continue
        if jtype not in ("revolute", "continuous", "prismatic"):
            raise ValueError(f"URDF: joint {jname!r} has unknown type {jtype!r}")
        axis = _floats(j.find("axis").get("xyz") if j.find("axis") is not None else None, (1, 0, 0),
                       f"joint {jname!r} <axis xyz>")
        if np.linalg.norm(axis) < 1e-12:
            raise ValueError(f"URDF: joint {jname!r} has a zero axis")
        if jtype == "continuous":
            lo, hi = -np.pi, np.pi
        else:
            lim = j.find("limit")
            if lim is None or lim.get("lower") is None or lim.get("upper") is None:
                raise ValueError(f"URDF: {jtype} joint {jname!r} needs <limit lower=... upper=...>")
            lo, hi = float(lim.get("lower")), float(lim.get("upper"))
            if jtype == "prismatic":
                lo, hi = lo * _M_TO_MM, hi * _M_TO_MM
            if not lo < hi:
                raise ValueError(f"URDF: joint {jname!r} has limits lower={lo} >= upper={hi}")
        if types:  # close the previous body
            mass.append(acc_mass)
            com.append(acc_mc / acc_mass if acc_mass > 0 else np.zeros(3))
        Ra = align_z(axis)
        O = pending @ T
        R_o = R_prev.T @ O[:3, :3] @ Ra
        t_o = R_prev.T @ O[:3, 3]
        origin_R.append(snap(R_o))
        origin_t.append(t_o)
        align.append(Ra)
        types.append("prismatic" if jtype == "prismatic" else "revolute")
        q_min.append(lo)
        q_max.append(hi)
        jnames.append(jname)
        lnames.append(child)
        R_prev, pending = Ra, np.eye(4)
        acc_mass, acc_mc = _add_inertial(links.get(child), R_prev, pending, 0.0, np.zeros(3))
    if not types:
        raise ValueError(f"URDF: no revolute, continuous or prismatic joint between {base!r} and {tip!r}")
    mass.append(acc_mass)
    com.append(acc_mc / acc_mass if acc_mass > 0 else np.zeros(3))
    flange_R = R_prev.T @ pending[:3, :3]
    flange_t = R_prev.T @ pending[:3, 3]
    return dict(origin_R=origin_R, origin_t=origin_t, joint_types=types, q_min=q_min, q_max=q_max,
                flange_R=flange_R, flange_t=flange_t, align=align, mass=mass, com=com,
                joint_names=jnames, link_names=lnames)


def tree_from_urdf(source, *, base: str | None = None, tips: Sequence[str], tool=(0.0, 0.0, 0.0),
                   name: str | None = None) -> KinematicTree:
    """The :class:`~jaxcal.KinematicTree` of a URDF from link ``base`` to the links ``tips``
    (``load_urdf(source, tips=...)``): the union of the base → tip paths, each computed as
    :func:`load_urdf` computes the chain to that tip (fixed, continuous and prismatic joints as
    there), a joint on several paths kept once. Joints in order of first appearance along the
    tips' paths (tips in the given order, each path from the base outward); ``tips[0]`` is the
    default tip. ``tool``: one ``[3]`` mm for every tip or ``{tip: [3]}``. Inertials are not
    kept (compliance is not modelled on trees).

    Raises:
        ValueError: no tips, a repeated tip, a tip that is not a link of the file (the message
            lists the leaf links below ``base``), a tip not below ``base``, two tips on one path
            (one above the other), an unknown ``tool`` key, and the chain loader's errors.
    """
    root, text, links, joints_by_child, roots = _parse_tree(source)
    if base is None:
        base = _default_base(roots)
    if base not in links:
        raise ValueError(f"URDF: unknown base link {base!r}; links in this file: {sorted(links)}")
    tips = [tips] if isinstance(tips, str) else list(tips)
    leaves = sorted(_leaves_below(joints_by_child, base))
    if not tips or len(set(tips)) != len(tips):
        raise ValueError(f"URDF: tips must be one or more different links, got {tips}; leaf links below {base!r}: "
                         f"{leaves}")
    for t in tips:
        if t not in links:
            raise ValueError(f"URDF: unknown tip link {t!r}; leaf links below {base!r}: {leaves} "
                             f"(every link of the file: {sorted(links)})")
    paths = {t: _path(joints_by_child, base, t) for t in tips}
    for a in tips:
        for b in tips:
            if a != b and any(j.find("child").get("link") == a for j in paths[b]):
                raise ValueError(f"URDF: tips {a!r} and {b!r} lie on one path ({a!r} is above {b!r}): the tips of a "
                                 "tree end different branches; keep one of them")
    if isinstance(tool, Mapping):
        unknown = sorted(set(tool) - set(tips))
        if unknown:
            raise ValueError(f"tool points given for {unknown}, which are not among the tips {tips}")
        tools = [tool.get(t, (0.0, 0.0, 0.0)) for t in tips]
    else:
        tools = [tool] * len(tips)
    index: dict[str, int] = {}
    cols: dict[str, list] = {}
    parents, tip_parents, flange_R, flange_t = [], [], [], []
    for t in tips:
        rows = _path_rows(paths[t], links, base, t)
        prev = -1
        for i, jname in enumerate(rows["joint_names"]):
            if jname not in index:
                index[jname] = len(parents)
                parents.append(prev)
                for key in ("origin_R", "origin_t", "align", "joint_types", "q_min", "q_max", "joint_names",
                            "link_names"):
                    cols.setdefault(key, []).append(rows[key][i])
            prev = index[jname]
        tip_parents.append(prev)
        flange_R.append(rows["flange_R"])
        flange_t.append(rows["flange_t"])
    return KinematicTree.build(**cols, parents=parents, tips=tips, tip_parents=tip_parents, flange_R=flange_R,
                               flange_t=flange_t, tools=tools, base=base, name=name or root.get("name") or "urdf",
                               urdf=text)


def _add_inertial(link_el, R_align, T_link, m_acc, mc_acc):
    """Add a link's ``<inertial>`` mass [kg] and centre of mass (converted to mm, expressed in the
    current joint frame: ``R_alignᵀ·(T_link · c)``) to the running body sums."""
    if link_el is None:
        return m_acc, mc_acc
    inertial = link_el.find("inertial")
    if inertial is None or inertial.find("mass") is None:
        return m_acc, mc_acc
    m = float(inertial.find("mass").get("value", 0.0))
    c_link = _origin(inertial, f"link {link_el.get('name')!r} <inertial>")[:3, 3]
    c = R_align.T @ (T_link[:3, :3] @ c_link + T_link[:3, 3])
    return m_acc + m, mc_acc + m * c


# ---------------------------------------------------------------------------- DH tables


def _dh_values(robot, deviations=None):
    """(alpha, a, d, theta, beta) of a DH robot as host arrays, deviated when given."""
    vals = []
    for g in ("alpha", "a", "d", "theta", "beta"):
        v = np.asarray(getattr(robot, g), dtype=np.float64).copy()
        dv = _dev_get(deviations, g)
        if dv is not None:
            v = v + np.asarray(dv, dtype=np.float64)
        vals.append(v)
    return vals


def chain_from_dh(robot, deviations=None) -> SerialChain:
    """The :class:`~jaxcal.SerialChain` equal to a :class:`~jaxcal.DHRobot` (standard, modified
    or Hayati), optionally with DH deviations applied (``alpha, a, d, theta, beta`` groups).

    Standard DH ``A_i = Rz(θ_i + q_i)·Tz(d_i)·Tx(a_i)·Rx(α_i)·Ry(β_i)`` regroups (``Tz`` commutes
    with ``Rz``) into origins ``O_1 = Tz(d_1)·Rz(θ_1)``, ``O_i = Tx(a_{i-1})·Rx(α_{i-1})·Ry(β_{i-1})·
    Tz(d_i)·Rz(θ_i)`` and the flange ``Tx(a_n)·Rx(α_n)·Ry(β_n)``; modified DH
    ``A_i = Rx(α_i)·Ry(β_i)·Tx(a_i)·Rz(θ_i + q_i)·Tz(d_i)`` gives ``O_i = Tz(d_{i-1})·Rx(α_i)·Ry(β_i)·
    Tx(a_i)·Rz(θ_i)`` with ``d_0 = 0`` and the flange ``Tz(d_n)``. FK is identical to round-off;
    the chain remembers its DH table (``chain.dh``) so that exports can write it again.
    """
    alpha, a, d, theta, beta = _dh_values(robot, deviations)
    dof = robot.dof
    hay = set(robot.beta_joints)

    def tr(x=0.0, y=0.0, z=0.0):
        T = np.eye(4)
        T[:3, 3] = (x, y, z)
        return T

    def rot(R):
        T = np.eye(4)
        T[:3, :3] = R
        return T

    from ._chain import _rx, _ry, _rz

    def tail(i):  # Tx(a_i)·Rx(α_i)·[Ry(β_i)] (standard)
        T = tr(x=a[i]) @ rot(_rx(alpha[i]))
        if (i + 1) in hay:
            T = T @ rot(_ry(beta[i]))
        return T

    origins = []
    if robot.convention == "standard":
        prev = np.eye(4)
        for i in range(dof):
            origins.append(prev @ tr(z=d[i]) @ rot(_rz(theta[i])))
            prev = tail(i)
        flange = prev
    else:
        prev_d = 0.0
        for i in range(dof):
            T = tr(z=prev_d) @ rot(_rx(alpha[i]))
            if (i + 1) in hay:
                T = T @ rot(_ry(beta[i]))
            origins.append(T @ tr(x=a[i]) @ rot(_rz(theta[i])))
            prev_d = d[i]
        flange = tr(z=prev_d)
    fl = lambda v: tuple(float(x) for x in v)  # noqa: E731
    dh = (robot.convention, fl(alpha), fl(a), fl(d), fl(theta), fl(beta), tuple(int(j) for j in robot.beta_joints))
    return SerialChain.build(
        origin_R=[O[:3, :3] for O in origins], origin_t=[O[:3, 3] for O in origins],
        joint_types=["revolute"] * dof, q_min=np.asarray(robot.q_min), q_max=np.asarray(robot.q_max),
        flange_R=flange[:3, :3], flange_t=flange[:3, 3], tool=np.asarray(robot.tool),
        joint_names=[f"joint_{i + 1}" for i in range(dof)], link_names=[f"link_{i + 1}" for i in range(dof)],
        base="base_link", tip="flange", name=robot.name, dh=dh,
    )


# ---------------------------------------------------------------------------- export


def _fmt(v) -> str:
    return " ".join(repr(float(x)) if x != 0 else "0" for x in v)


def _origin_attrs(T) -> dict:
    """URDF ``<origin>`` attributes of a ``[4, 4]`` transform in mm (written in metres)."""
    return {"xyz": _fmt(np.asarray(T[:3, 3]) / _M_TO_MM), "rpy": _fmt(matrix_rpy(T[:3, :3]))}


def _urdf_origins(chain: SerialChain, deviations=None) -> list[np.ndarray]:
    """Per moving joint, the corrected transform in URDF frames: ``R_a(prev)·O_i'·R_a(i)ᵀ`` where
    ``O_i'`` is the deviated joint-frame origin (errors and joint offset folded in)."""
    al = np.asarray(chain.align)
    out = []
    for i, O in enumerate(chain.origins_numpy(deviations)):
        A_prev = np.eye(4)
        if i > 0:
            A_prev[:3, :3] = al[i - 1]
        A = np.eye(4)
        A[:3, :3] = al[i]
        out.append(A_prev @ O @ A.T)
    return out


def _flange_urdf(chain: SerialChain, deviations=None) -> np.ndarray:
    """The (deviated) tip transform in URDF frames ``[4, 4]`` mm: the last moving joint's child
    link frame → tip link frame, ``R_a(last)·F`` (:meth:`SerialChain.tip_numpy`)."""
    A = np.eye(4)
    A[:3, :3] = np.asarray(chain.align)[-1]
    return A @ chain.tip_numpy(deviations)


def _has_tip_error(deviations) -> bool:
    return any(_dev_get(deviations, g) is not None and np.any(np.asarray(_dev_get(deviations, g)) != 0)
               for g in ("tip_translation", "tip_rotation"))


def export_urdf(model, deviations=None, path=None, *, tool_link: str = "jaxcal_tool_point",
                tip_link: str = "jaxcal_calibrated_tip") -> str:
    """Write a calibrated model as URDF; returns the text (and writes it to ``path`` if given).

    Args:
        model: a :class:`~jaxcal.SerialChain`, a :class:`~jaxcal.DHRobot` or a
            :class:`~jaxcal.KinematicTree` (every tip's path written as a chain's, each tip's
            tool point moved by its ``tree.tool_group(tip)``; added links named
            ``<tip_link>_<tip>``, ``<tool_link>_<tip>``: :func:`_export_tree`).
        deviations: calibrated deviations (chain groups ``offset, dx … drz`` and the tip errors
            ``tip_translation``, ``tip_rotation``, or DH groups for a DH robot; a ``tool`` group
            moves the tool point), or ``None`` for the nominal model.
        path: output file (optional).
        tool_link: name of a link fixed to the tip link at the (calibrated) tool point, added when
            the tool point is not the tip link origin (URDF has no other place for it).
        tip_link: name of a link added at the calibrated tip frame when the tip errors are not
            zero and the loaded URDF has no fixed joint between the last moving joint and the tip
            (the tip link is then the last joint's child, whose frame URDF ties to the joint);
            the tool link hangs from it, and FK to it is the calibrated FK.

    For a chain loaded from a URDF, the original file is kept (meshes, inertials, other
    branches) and only the ``<origin>`` of each moving joint between base and tip is replaced by
    the corrected one: the fixed transforms before it (folded into the chain) are taken out
    again, and the error rotations and the joint offset are folded into the origin, so the
    exported URDF gives the calibrated FK with the same raw joint readings. The offsets also
    appear in a comment. The calibrated tip transform goes into the ``<origin>`` of the first
    fixed joint after the last moving joint (the one on the last moving link), the later fixed
    joints kept, so every link fixed below it moves with the correction; without such a joint,
    see ``tip_link``. A chain built from DH (or a DH robot) is written as a minimal URDF
    ``base_link → link_1 … → flange`` with a comment holding the calibrated DH table.
    """
    from ._robot import DHRobot

    if isinstance(model, KinematicTree):
        return _export_tree(model, deviations, path, tool_link=tool_link, tip_link=tip_link)
    dh_table = None
    tool = np.asarray(model.tool, np.float64)
    if _dev_get(deviations, "tool") is not None:
        tool = tool + np.asarray(_dev_get(deviations, "tool"), np.float64)
    if isinstance(model, DHRobot):
        alpha, a, d, theta, beta = _dh_values(model, deviations)
        dh_table = (model.convention, alpha, a, d, theta, beta, model.beta_joints)
        chain = chain_from_dh(model, deviations)
        deviations = None
    else:
        chain = model
        if chain.dh is not None and deviations is None:
            dh_table = chain.dh
    origins = _urdf_origins(chain, deviations)
    offsets = _dev_get(deviations, "offset")
    note = "jaxcal calibrated model: moving joint origins corrected"
    if offsets is not None:
        note += "; joint offsets folded into the origins: " + ", ".join(
            f"{n}={float(v):.9g} {u}" for n, v, u in zip(chain.joint_names, np.asarray(offsets), chain.joint_units()))
    if chain.urdf is not None:
        root = ET.fromstring(chain.urdf)
        children = {j.find("child").get("link"): j for j in root.findall("joint")}
        _replace_origins(root, chain, origins, children)
        tool_parent = chain.tip
        if _has_tip_error(deviations):
            tool_parent = _write_tip(root, chain, children, _flange_urdf(chain, deviations), tip_link)
            note += f"; tip transform ({chain.link_names[-1]} → {chain.tip}) corrected"
            if tool_parent != chain.tip:
                note += f" in the added link {tool_parent!r}"
        root.insert(0, ET.Comment(" " + note + " "))
        _add_tool_link(root, tool_parent, tool, tool_link)
        text = ET.tostring(root, encoding="unicode")
        text = '<?xml version="1.0"?>\n' + text + "\n"
    else:
        root = ET.Element("robot", name=chain.name)
        root.append(ET.Comment(" " + note + " "))
        if dh_table is not None:
            from .._core._trig import wrap_angle_deg  # angles as everywhere: (−180°, 180°]

            conv, alpha, a, d, theta, beta, bj = dh_table
            alpha, theta, beta = (wrap_angle_deg(np.rad2deg(np.asarray(v, np.float64))) for v in (alpha, theta, beta))
            rows = "\n".join(
                f"  {i + 1}: alpha={alpha[i]:.9g} deg, a={a[i]:.9g} mm, d={d[i]:.9g} mm, "
                f"theta={theta[i]:.9g} deg" + (f", beta={beta[i]:.9g} deg" if (i + 1) in bj else "")
                for i in range(len(alpha)))
            root.append(ET.Comment(f" DH table ({conv} convention):\n{rows}\n "))
        ET.SubElement(root, "link", name=chain.base)
        parent = chain.base
        al = np.asarray(chain.align)
        for i in range(chain.dof):
            child = chain.link_names[i]
            link = ET.SubElement(root, "link", name=child)
            m = float(np.asarray(chain.mass)[i])
            if m > 0:
                inertial = ET.SubElement(link, "inertial")
                c = al[i] @ np.asarray(chain.com)[i] / _M_TO_MM
                ET.SubElement(inertial, "origin", xyz=_fmt(c), rpy="0 0 0")
                ET.SubElement(inertial, "mass", value=repr(m))
            typ = chain.joint_types[i]
            j = ET.SubElement(root, "joint", name=chain.joint_names[i], type=typ)
            ET.SubElement(j, "origin", **_origin_attrs(origins[i]))
            ET.SubElement(j, "parent", link=parent)
            ET.SubElement(j, "child", link=child)
            ET.SubElement(j, "axis", xyz=_fmt(snap(al[i][:, 2])))
            scale = _M_TO_MM if typ == "prismatic" else 1.0
            ET.SubElement(j, "limit", lower=repr(float(chain.q_min[i]) / scale),
                          upper=repr(float(chain.q_max[i]) / scale), effort="0", velocity="0")
            parent = child
        ET.SubElement(root, "link", name=chain.tip)
        j = ET.SubElement(root, "joint", name=f"{chain.tip}_joint", type="fixed")
        ET.SubElement(j, "origin", **_origin_attrs(_flange_urdf(chain, deviations)))
        ET.SubElement(j, "parent", link=parent)
        ET.SubElement(j, "child", link=chain.tip)
        _add_tool_link(root, chain.tip, tool, tool_link)
        ET.indent(root)
        text = '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
    if path is not None:
        pathlib.Path(path).write_text(text)
    return text


def _replace_origins(root, chain: SerialChain, origins: list[np.ndarray], children: dict) -> None:
    """Write the corrected URDF-frame origins ``origins`` (``[4, 4]`` mm per moving joint of
    ``chain``, :func:`_urdf_origins`) into the loaded URDF ``root``: the fixed transforms between
    the previous moving joint's child link (or the base) and the joint are taken out again."""
    joints = {j.get("name"): j for j in root.findall("joint")}
    for i, jname in enumerate(chain.joint_names):
        j = joints[jname]
        # fixed transforms from the previous moving joint's child link to this joint's parent
        pending = np.eye(4)
        link = j.find("parent").get("link")
        stop = chain.link_names[i - 1] if i > 0 else chain.base
        while link != stop:
            fj = children[link]
            pending = _origin(fj, "") @ pending
            link = fj.find("parent").get("link")
        T = np.linalg.solve(pending, origins[i])
        o = j.find("origin")
        if o is None:
            o = ET.SubElement(j, "origin")
        for k, v in _origin_attrs(T).items():
            o.set(k, v)


def _write_tip(root, chain: SerialChain, children: dict, T_tip: np.ndarray, name: str,
               shared: frozenset = frozenset()) -> str:
    """Write the calibrated tip transform ``T_tip`` (URDF frames, mm) into the loaded URDF
    ``root``: into the first fixed joint below the last moving link that is not in ``shared``
    (joint names other tips of a tree pass through), solved so that the product of the fixed
    joints down to the tip is ``T_tip``; returns the tip link's name. Without such a fixed joint,
    add link ``name`` fixed to the tip at ``T_tip`` and return ``name``."""
    path = []  # fixed joints from the last moving link down to the tip, top first
    link = chain.tip
    while link != chain.link_names[-1]:
        fj = children[link]
        path.insert(0, fj)
        link = fj.find("parent").get("link")
    above = np.eye(4)  # the shared fixed joints on top stay as they are
    while path and path[0].get("name") in shared:
        above = above @ _origin(path.pop(0), "")
    T_tip = np.linalg.solve(above, T_tip)
    if not path:
        if not name:
            raise ValueError(f"the tip errors need a link to carry them: {chain.tip!r} is the last moving "
                             "joint's child; give export_urdf's tip_link argument (the name of a link to add)")
        ET.SubElement(root, "link", name=name)
        j = ET.SubElement(root, "joint", name=f"{name}_joint", type="fixed")
        ET.SubElement(j, "origin", **_origin_attrs(T_tip))
        ET.SubElement(j, "parent", link=chain.tip)
        ET.SubElement(j, "child", link=name)
        return name
    below = np.eye(4)
    for fj in path[1:]:
        below = below @ _origin(fj, "")
    T = T_tip @ np.linalg.inv(below)
    o = path[0].find("origin")
    if o is None:
        o = ET.SubElement(path[0], "origin")
    for k, v in _origin_attrs(T).items():
        o.set(k, v)
    return chain.tip


def _export_tree(tree: KinematicTree, deviations, path, *, tool_link: str, tip_link: str) -> str:
    """:func:`export_urdf` of a :class:`~jaxcal.KinematicTree`: each tip's path written as a
    chain's (:func:`_replace_origins`, :func:`_write_tip`, per tip through
    :meth:`~jaxcal.KinematicTree.path_chain` and its deviations; a shared joint gets the same
    corrected origin from every path). A tip's correction goes into the first fixed joint below
    its last moving link that no other tip's path passes through; added links are named
    ``<tip_link>_<tip>`` and ``<tool_link>_<tip>``. A tree built by hand is written as a minimal
    URDF: ``base``, one link per joint (``link_names``), each tip fixed to its last joint's link."""
    note = "jaxcal calibrated kinematic tree: moving joint origins corrected"
    offsets = _dev_get(deviations, "offset")
    if offsets is not None:
        note += "; joint offsets folded into the origins: " + ", ".join(
            f"{n}={float(v):.9g} {u}" for n, v, u in zip(tree.joint_names, np.asarray(offsets), tree.joint_units()))
    n_tips = len(tree.tips)
    views = [(tree.path_chain(k), tree.path_deviations(deviations, k)) for k in range(n_tips)]
    tools = []
    for k in range(n_tips):
        dt = _dev_get(deviations, tree.tool_group(k))
        tools.append(np.asarray(tree.tools[k], np.float64) + (0.0 if dt is None else np.asarray(dt, np.float64)))
    suffixed = lambda base_name, k: base_name and f"{base_name}_{tree.tips[k]}"  # noqa: E731
    if tree.urdf is not None:
        root = ET.fromstring(tree.urdf)
        children = {j.find("child").get("link"): j for j in root.findall("joint")}
        on_path = []  # URDF joint names from the base to each tip
        for view, sub in views:
            _replace_origins(root, view, _urdf_origins(view, sub), children)
            on_path.append({j.get("name") for j in _path(children, view.base, view.tip)})
        for k, (view, sub) in enumerate(views):
            tool_parent = view.tip
            if _has_tip_error(sub):
                shared = frozenset().union(*(on_path[m] for m in range(n_tips) if m != k))
                tool_parent = _write_tip(root, view, children, _flange_urdf(view, sub), suffixed(tip_link, k), shared)
                note += f"; tip transform ({view.link_names[-1]} → {view.tip}) corrected"
                if tool_parent != view.tip:
                    note += f" in the added link {tool_parent!r}"
            _add_tool_link(root, tool_parent, tools[k], suffixed(tool_link, k))
        root.insert(0, ET.Comment(" " + note + " "))
    else:
        root = ET.Element("robot", name=tree.name)
        root.append(ET.Comment(" " + note + " "))
        ET.SubElement(root, "link", name=tree.base)
        origins = {}
        for k, (view, sub) in enumerate(views):
            origins.update(zip(tree.path(k), _urdf_origins(view, sub)))
        al = np.asarray(tree.align)
        for j in range(tree.dof):
            typ = tree.joint_types[j]
            ET.SubElement(root, "link", name=tree.link_names[j])
            el = ET.SubElement(root, "joint", name=tree.joint_names[j], type=typ)
            ET.SubElement(el, "origin", **_origin_attrs(origins[j]))
            ET.SubElement(el, "parent", link=tree.base if tree.parents[j] < 0 else tree.link_names[tree.parents[j]])
            ET.SubElement(el, "child", link=tree.link_names[j])
            ET.SubElement(el, "axis", xyz=_fmt(snap(al[j][:, 2])))
            scale = _M_TO_MM if typ == "prismatic" else 1.0
            ET.SubElement(el, "limit", lower=repr(float(tree.q_min[j]) / scale),
                          upper=repr(float(tree.q_max[j]) / scale), effort="0", velocity="0")
        for k, (view, sub) in enumerate(views):
            ET.SubElement(root, "link", name=view.tip)
            el = ET.SubElement(root, "joint", name=f"{view.tip}_joint", type="fixed")
            ET.SubElement(el, "origin", **_origin_attrs(_flange_urdf(view, sub)))
            ET.SubElement(el, "parent", link=view.link_names[-1])
            ET.SubElement(el, "child", link=view.tip)
            _add_tool_link(root, view.tip, tools[k], suffixed(tool_link, k))
        ET.indent(root)
    text = '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
    if path is not None:
        pathlib.Path(path).write_text(text)
    return text


def _add_tool_link(root, tip: str, tool, name: str) -> None:
    if not np.any(np.asarray(tool) != 0) or not name:
        return
    ET.SubElement(root, "link", name=name)
    j = ET.SubElement(root, "joint", name=f"{name}_joint", type="fixed")
    ET.SubElement(j, "origin", xyz=_fmt(np.asarray(tool) / _M_TO_MM), rpy="0 0 0")
    ET.SubElement(j, "parent", link=tip)
    ET.SubElement(j, "child", link=name)


# ---------------------------------------------------------------------------- result files


def chain_to_dict(chain: SerialChain) -> dict:
    """JSON-friendly chain that :func:`chain_from_dict` rebuilds exactly
    (:meth:`SerialChain.geometry_dict`)."""
    return chain.geometry_dict()


def chain_from_dict(d: dict) -> SerialChain:
    """Inverse of :func:`chain_to_dict`: a chain from its ``"dh"`` table, its ``"origins"`` arrays
    or its ``"urdf"`` text (result files before the ``"origins"`` form held a hand-built chain as
    URDF text, which still loads)."""
    if "origins" in d:
        o = d["origins"]
        return SerialChain.build(
            origin_R=o["origin_R"], origin_t=o["origin_t_mm"], joint_types=d["joint_types"], q_min=o["q_min"],
            q_max=o["q_max"], flange_R=o["flange_R"], flange_t=o["flange_t_mm"], align=o["align"], tool=d["tool_mm"],
            mass=o["mass_kg"], com=o["com_mm"], joint_names=d["joint_names"], link_names=o["link_names"],
            base=d["base"], tip=d["tip"], name=d.get("name", "chain"))
    if "dh" in d:
        import jax.numpy as jnp

        from ._robot import DHRobot

        t = d["dh"]
        robot = DHRobot(
            jnp.asarray(t["alpha_rad"]), jnp.asarray(t["a_mm"]), jnp.asarray(t["d_mm"]), jnp.asarray(t["theta_rad"]),
            jnp.asarray(t["beta_rad"]), jnp.asarray(t["q_min"]), jnp.asarray(t["q_max"]), jnp.asarray(d["tool_mm"]),
            convention=t["convention"], beta_joints=tuple(t["beta_joints"]), name=d.get("name", "robot"),
        )
        return chain_from_dh(robot)
    return load_urdf(d["urdf"], base=d["base"], tip=d["tip"], tool=d["tool_mm"], name=d.get("name"))


def tree_from_dict(d: dict) -> KinematicTree:
    """Inverse of :meth:`KinematicTree.geometry_dict <jaxcal.KinematicTree.geometry_dict>`: a tree
    from its ``"urdf"`` text (base, tips, tool points) or its ``"origins"`` arrays (the
    non-geometric models of ``to_dict`` are ``nongeometric_from_dict``'s, as for chains)."""
    if "origins" in d:
        o = d["origins"]
        return KinematicTree.build(
            origin_R=o["origin_R"], origin_t=o["origin_t_mm"], joint_types=d["joint_types"], q_min=o["q_min"],
            q_max=o["q_max"], parents=o["parents"], tips=d["tips"], tip_parents=o["tip_parents"],
            flange_R=o["flange_R"], flange_t=o["flange_t_mm"], align=o["align"], tools=d["tools_mm"],
            joint_names=d["joint_names"], link_names=o["link_names"], base=d["base"], name=d.get("name", "tree"))
    return tree_from_urdf(d["urdf"], base=d["base"], tips=d["tips"], tool=dict(zip(d["tips"], d["tools_mm"])),
                          name=d.get("name"))
