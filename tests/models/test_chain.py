"""Generic serial chains (issue 11): URDF loading, FK against an independent NumPy product of 4×4
transforms, the error model's Jacobian, DH tables as chains, export round trips, clear errors."""

import pathlib
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_differences

import jaxcal
from jaxcal import SerialChain, chain_from_dh, export_urdf, load_urdf, robots
from jaxcal._models._chain import GEOMETRIC_GROUPS

DATA = pathlib.Path(__file__).parents[1] / "data" / "urdf"
#: FIGAROH's examples (github.com/thanhndv212/figaroh-examples) as a git mirror, if present: its TIAGo URDF
#: (PAL Robotics, CC BY-NC-ND 3.0, so not copied into this repository) is loaded from there.
FIGAROH_GIT = pathlib.Path("/work/.mirror/thanhndv212+figaroh-examples/repo")


def _tiago_urdf():
    import subprocess

    try:
        return subprocess.run(["git", "--git-dir", str(FIGAROH_GIT), "show", "HEAD:examples/tiago/urdf/tiago_no_hand.urdf"],
                              capture_output=True, text=True, check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return None

#: (file, base, tip): a 6R industrial arm, a 7-DoF arm, a prismatic torso + 7-DoF arm
URDFS = {
    "ur10e": (DATA / "ur10e.urdf", "base_link", "tool0"),
    "panda": (DATA / "panda_arm.urdf", "panda_link0", "panda_link8"),
    "fetch": (DATA / "fetch.urdf", "base_link", "gripper_link"),
}


# ---------------------------------------------------------------- independent NumPy reference


def _rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _axis_angle(axis, t):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K


def numpy_urdf_fk(text, base, tip, q):
    """``T_base_tip`` [4, 4] in mm for one configuration ``q`` (rad / m→mm for prismatic):
    a plain product of the URDF's 4×4 joint transforms, read with its own minimal parser."""
    root = ET.fromstring(text)
    by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
    path, link = [], tip
    while link != base:
        j = by_child[link]
        path.append(j)
        link = j.find("parent").get("link")
    T = np.eye(4)
    k = 0
    for j in reversed(path):
        o = j.find("origin")
        xyz = [float(v) for v in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()]
        rpy = [float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
        A = np.eye(4)
        A[:3, :3] = _rpy(*rpy)
        A[:3, 3] = np.asarray(xyz) * 1000.0
        T = T @ A
        typ = j.get("type")
        if typ == "fixed":
            continue
        axis = [float(v) for v in j.find("axis").get("xyz").split()] if j.find("axis") is not None else [1, 0, 0]
        M = np.eye(4)
        if typ == "prismatic":
            M[:3, 3] = np.asarray(axis) / np.linalg.norm(axis) * q[k]
        else:
            M[:3, :3] = _axis_angle(axis, q[k])
        T = T @ M
        k += 1
    assert k == len(q)
    return T


def _random_q(chain, n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(np.asarray(chain.q_min), np.asarray(chain.q_max), size=(n, chain.dof))


def _chain_T(chain, dev, q):
    X, Y, Z, P = chain.frame_soa(dev, jnp.asarray(q))
    R = np.stack([np.stack(X, -1), np.stack(Y, -1), np.stack(Z, -1)], -1)
    T = np.zeros((q.shape[0], 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = np.stack(P, -1)
    T[:, 3, 3] = 1
    return T


def _random_dev(chain, seed=1, scale=1.0):
    rng = np.random.default_rng(seed)
    out = {}
    for g, unit in GEOMETRIC_GROUPS:
        s = 0.5 if unit in ("mm", "rad|mm") else 0.003
        out[g] = jnp.asarray(rng.normal(0, s * scale, chain.dof))
    return out


def _cases():
    out = [pytest.param(*v, id=k) for k, v in URDFS.items()]
    tiago = _tiago_urdf()
    out.append(pytest.param(tiago, "base_footprint", "wrist_ft_tool_link", id="tiago",
                            marks=pytest.mark.skipif(tiago is None, reason="FIGAROH examples not fetched")))
    return out


# ---------------------------------------------------------------- FK


@pytest.mark.parametrize("path,base,tip", _cases())
def test_fk_equals_numpy_product_of_urdf_transforms(path, base, tip):
    chain = load_urdf(path, base=base, tip=tip)
    text = chain.urdf
    q = _random_q(chain, 50)
    ref = np.stack([numpy_urdf_fk(text, base, tip, qi) for qi in q])
    T = _chain_T(chain, None, q)
    np.testing.assert_allclose(T[:, :3, 3], ref[:, :3, 3], rtol=0, atol=1e-9)  # mm
    np.testing.assert_allclose(T[:, :3, :3], ref[:, :3, :3], rtol=0, atol=1e-12)
    tool = np.array([12.0, -30.0, 85.0])
    p = np.stack(chain.point_in_base(None, jnp.asarray(q), jnp.asarray(tool)), -1)
    np.testing.assert_allclose(p, ref[:, :3, :3] @ tool + ref[:, :3, 3], rtol=0, atol=1e-9)


def test_loader_facts():
    fetch = load_urdf(DATA / "fetch.urdf", base="base_link", tip="gripper_link")
    assert fetch.dof == 8 and fetch.joint_types[0] == "prismatic"
    assert fetch.joint_names[0] == "torso_lift_joint" and fetch.joint_names[-1] == "wrist_roll_joint"
    assert fetch.joint_units()[:2] == ("mm", "rad")
    np.testing.assert_allclose([fetch.q_min[0], fetch.q_max[0]], [0.0, 386.15])  # m → mm
    np.testing.assert_allclose([fetch.q_min[3], fetch.q_max[3]], [-np.pi, np.pi])  # continuous
    # masses (kg): the gripper link, fixed to wrist_roll_link, is merged into the last body
    np.testing.assert_allclose(fetch.mass, [10.7796, 2.5587, 2.6615, 2.3311, 2.1299, 1.6563, 1.725, 0.1354 + 1.5175])
    # centre of mass of the torso link in the base frame at q = 0, from the joint frame data
    X, Y, Z, P = fetch.frame_soa(None, jnp.zeros((1, 8)))  # not the torso frame: rebuild it
    torso = load_urdf(DATA / "fetch.urdf", base="base_link", tip="torso_lift_link")
    Xt, Yt, Zt, Pt = (np.array([c[0] for c in v]) for v in torso.frame_soa(None, jnp.zeros((1, 1))))
    c_base = Pt + np.stack([Xt, Yt, Zt], 1) @ np.asarray(torso.flange_R).T @ np.zeros(3)
    com_base = np.asarray(torso.origin_R[0]) @ np.asarray(torso.com[0]) + np.asarray(torso.origin_t[0])
    np.testing.assert_allclose(com_base, [-86.875 - 1.3, -0.9, 377.43 + 293.5], atol=1e-9)
    assert c_base.shape == (3,)
    panda = load_urdf(DATA / "panda_arm.urdf")  # root and single leaf found by default
    assert (panda.base, panda.tip, panda.dof) == ("panda_link0", "panda_link8", 7)
    # URDF origins with ±π/2 are signed permutations after alignment: the kernel skips them
    assert all(all(c in (-1, 0, 1) for row in p for c in row) for p in panda.patterns)


# ---------------------------------------------------------------- error model


@pytest.mark.parametrize("key", ["ur10e", "fetch"])
def test_deviated_fk_equals_numpy_product_of_exported_urdf(key, tmp_path):
    """The error model with random deviations equals plain URDF FK of the exported file."""
    path, base, tip = URDFS[key]
    chain = load_urdf(path, base=base, tip=tip)
    dev = _random_dev(chain)
    text = export_urdf(chain, dev, tmp_path / "cal.urdf")
    q = _random_q(chain, 30, seed=3)
    ref = np.stack([numpy_urdf_fk(text, base, tip, qi) for qi in q])
    T = _chain_T(chain, dev, q)
    np.testing.assert_allclose(T[:, :3, 3], ref[:, :3, 3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(T[:, :3, :3], ref[:, :3, :3], rtol=0, atol=1e-12)
    p = np.stack(chain.point_in_base(dev, jnp.asarray(q), jnp.asarray([5.0, 6.0, 7.0])), -1)
    np.testing.assert_allclose(p, ref[:, :3, :3] @ [5.0, 6.0, 7.0] + ref[:, :3, 3], rtol=0, atol=1e-9)
    # the calibrated file keeps everything else (a branch off the chain, inertials)
    again = load_urdf(tmp_path / "cal.urdf", base=base, tip=tip)
    np.testing.assert_allclose(np.stack(again.point_in_base(None, jnp.asarray(q), jnp.zeros(3)), -1),
                               ref[:, :3, 3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(again.mass, chain.mass)


@pytest.mark.parametrize("key", ["ur10e", "fetch"])
def test_jacobian_matches_finite_differences(key):
    path, base, tip = URDFS[key]
    chain = load_urdf(path, base=base, tip=tip)
    q = jnp.asarray(_random_q(chain, 20, seed=5))
    dev0 = _random_dev(chain, seed=2, scale=0.1)
    names = [g for g, _ in GEOMETRIC_GROUPS]

    def f(x):
        dev = {g: x[i * chain.dof:(i + 1) * chain.dof] for i, g in enumerate(names)}
        p = chain.point_in_base(dev, q, jnp.asarray([10.0, 20.0, 30.0]))
        pf = chain.point_in_base(dev, q, jnp.asarray([10.0, 20.0, 30.0]), fused=True)  # the draw-wire kernel
        X, Y, Z, P = chain.frame_soa(dev, q)
        return jnp.concatenate([jnp.concatenate(p), jnp.concatenate(pf), jnp.concatenate(P), jnp.concatenate(Z)])

    x0 = jnp.concatenate([dev0[g] for g in names])
    n3 = 3 * q.shape[0]
    np.testing.assert_allclose(f(x0)[n3:2 * n3], f(x0)[:n3], rtol=0, atol=1e-9)  # both kernels: one FK
    J = jax.jacfwd(f)(x0)
    h = 1e-6
    Jfd = central_differences(f, x0, h)
    np.testing.assert_allclose(J, Jfd, rtol=1e-6, atol=1e-5)
    # drz has no effect at revolute joints (merged into the offset), and is not free by default
    drz = names.index("drz")
    for j, prism in enumerate(chain.prismatic):
        col = np.asarray(J[:, drz * chain.dof + j])
        assert (np.abs(col).max() > 0) == prism
        assert chain.free_by_default(f"drz_{j + 1}") == prism


# ---------------------------------------------------------------- DH tables as chains


def _dh_variants():
    out = []
    for name in sorted(robots.DH_PRESETS):
        out.append(pytest.param(robots.get_robot(name), id=name))
    hsr = robots.hsr_jr680(tool_mm=(50.0, -20.0, 120.0))
    out.append(pytest.param(hsr.with_hayati(2, 3), id="hsr_hayati"))
    out.append(pytest.param(jaxcal.DHRobot.from_degrees(
        alpha_deg=[0, -90, 0, -90, 90, -90], a_mm=[0, 30, 400, 25, 0, 0], d_mm=[350, 0, 0, 420, 0, 80],
        theta_deg=[0, -90, 10, 0, 0, 180], beta_deg=[0, 0, 0.3, 0, 0, 0], convention="modified",
        beta_joints=[3], tool_mm=[1, 2, 3]), id="modified_hayati"))
    return out


@pytest.mark.parametrize("robot", _dh_variants())
def test_dh_robot_and_its_chain_give_identical_fk(robot, tmp_path):
    chain = chain_from_dh(robot)
    q = jnp.asarray(_random_q(chain, 100, seed=7))
    ref = jaxcal.fk_pose(robot, q, tool=True)
    p = np.stack(chain.point_in_base(None, q, robot.tool), -1)
    np.testing.assert_allclose(p, ref[:, :3, 3], rtol=0, atol=1e-9)
    T = _chain_T(chain, None, np.asarray(q))
    np.testing.assert_allclose(T[:, :3, :3], ref[:, :3, :3], rtol=0, atol=1e-12)
    # DH deviations applied to the table give the deviated DH robot's FK
    rng = np.random.default_rng(0)
    ctor = getattr(jaxcal.Deviations, "from_dh", jaxcal.Deviations)
    dh_dev = ctor(*(jnp.asarray(rng.normal(0, 0.01, robot.dof)) for _ in range(5)), jnp.zeros(3), jnp.zeros(3),
                  jnp.zeros(()))
    chain_dev = chain_from_dh(robot, dh_dev)
    np.testing.assert_allclose(np.stack(chain_dev.point_in_base(None, q, robot.tool), -1),
                               jaxcal.fk_position(robot, q, dh_dev), rtol=0, atol=1e-9)
    # DH robot → URDF → chain: identical FK, and the DH table is written into the file
    text = export_urdf(robot, None, tmp_path / "dh.urdf")
    assert "DH table" in text
    back = load_urdf(tmp_path / "dh.urdf", base="base_link", tip="flange")
    np.testing.assert_allclose(np.stack(back.point_in_base(None, q, robot.tool), -1), ref[:, :3, 3], rtol=0, atol=1e-9)
    if np.any(np.asarray(robot.tool) != 0):  # the tool point is written as a fixed link
        tp = load_urdf(tmp_path / "dh.urdf", base="base_link", tip="jaxcal_tool_point")
        np.testing.assert_allclose(np.stack(tp.point_in_base(None, q, jnp.zeros(3)), -1), ref[:, :3, 3],
                                   rtol=0, atol=1e-9)


# ---------------------------------------------------------------- round trip and errors


@pytest.mark.parametrize("key", list(URDFS))
def test_urdf_round_trip(key, tmp_path):
    path, base, tip = URDFS[key]
    chain = load_urdf(path, base=base, tip=tip)
    export_urdf(chain, None, tmp_path / "x.urdf")
    again = load_urdf(tmp_path / "x.urdf", base=base, tip=tip)
    assert again.joint_names == chain.joint_names and again.joint_types == chain.joint_types
    for field in ("origin_R", "origin_t", "flange_R", "flange_t", "q_min", "q_max", "mass", "com"):
        np.testing.assert_allclose(getattr(again, field), getattr(chain, field), rtol=0, atol=1e-9, err_msg=field)


_MINI = """<robot name="mini">
  <link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <joint name="j1" type="{t1}"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>{lim}{mimic}</joint>
  <joint name="j2" type="revolute"><parent link="b"/><child link="c"/><origin xyz="0.1 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-1" upper="1"/></joint>
  <joint name="j3" type="revolute"><parent link="b"/><child link="d"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1"/></joint>
</robot>"""


def _mini(t1="revolute", lim='<limit lower="-1" upper="1"/>', mimic=""):
    return _MINI.format(t1=t1, lim=lim, mimic=mimic)


@pytest.mark.parametrize("kwargs,match", [
    (dict(base="a", tip="nope"), r"unknown tip link 'nope'; links in this file: \['a', 'b', 'c', 'd'\]"),
    (dict(base="zz", tip="c"), "unknown base link 'zz'"),
    (dict(base="c", tip="d"), "tip link 'd' is not below base link 'c'"),
    (dict(base="a"), r"branches: name the chain's tip link among its leaf links \['c', 'd'\] \(--tip LINK"),
])
def test_clear_errors_for_links(kwargs, match):
    with pytest.raises(ValueError, match=match):
        load_urdf(_mini(), **kwargs)


@pytest.mark.parametrize("text,match", [
    (_mini(mimic='<mimic joint="j3"/>'), "joint 'j1' between 'a' and 'c' is a mimic joint"),
    (_mini(t1="floating"), "joint 'j1' between 'a' and 'c' is floating"),
    (_mini(t1="planar"), "is planar"),
    (_mini(lim=""), "revolute joint 'j1' needs <limit lower=... upper=...>"),
    (_mini(t1="prismatic", lim='<limit upper="1"/>'), "prismatic joint 'j1' needs <limit"),
    ("<robot><link name='a'/>", "not well-formed XML"),
    ("<model/>", "root element must be <robot>"),
])
def test_clear_errors_for_joints(text, match):
    with pytest.raises(ValueError, match=match):
        load_urdf(text, base="a", tip="c")


def test_continuous_fixed_and_string_input():
    chain = load_urdf(_mini(t1="continuous", lim=""), base="a", tip="c")
    np.testing.assert_allclose([chain.q_min[0], chain.q_max[0]], [-np.pi, np.pi])
    assert isinstance(chain, SerialChain) and chain.urdf.startswith("<robot")
    with pytest.raises(ValueError, match="no revolute, continuous or prismatic joint"):
        load_urdf(_mini(t1="fixed", lim=""), base="a", tip="b")
    with pytest.raises(FileNotFoundError):
        load_urdf("no/such/file.urdf")


def _links_below(text, base):
    """Every link below ``base`` with at least one moving joint on its path from ``base``."""
    root = ET.fromstring(text)
    children: dict[str, list] = {}
    for j in root.findall("joint"):
        children.setdefault(j.find("parent").get("link"), []).append(j)
    out, todo = [], [(base, False)]
    while todo:
        link, moved = todo.pop()
        if moved:
            out.append(link)
        for j in children.get(link, []):
            todo.append((j.find("child").get("link"), moved or j.get("type") != "fixed"))
    return sorted(out)


@pytest.mark.parametrize("path,base,_tip", _cases())
def test_pinocchio_agrees_if_installed(path, base, _tip, request):
    """FK and the position Jacobian of every link below the base (every leaf: the tips, Fetch's
    head and fingers; and every link between) equal pinocchio's (``framesForwardKinematics`` /
    ``oMf``, ``computeFrameJacobian`` in ``LOCAL_WORLD_ALIGNED``, linear rows) at random joint
    configurations. Pinocchio is not a dependency: skipped without it
    (``benchmarks/results/pinocchio_check.md`` records a run with it)."""
    pin = pytest.importorskip("pinocchio")
    text = load_urdf(path, base=base, tip=_tip).urdf
    model = pin.buildModelFromXML(text)
    data = model.createData()
    worst = np.zeros(3)
    links = _links_below(text, base)
    assert _tip in links
    for link in links:
        chain = load_urdf(text, base=base, tip=link)
        q = _random_q(chain, 20, seed=11)
        T = _chain_T(chain, None, q)

        def tip_position(qi, chain=chain):  # [dof] -> [3] mm
            return jnp.stack(chain.frame_soa(None, qi[None])[3])[:, 0]

        J = np.asarray(jax.vmap(jax.jacfwd(tip_position))(jnp.asarray(q)))  # [n, 3, dof]: mm/rad, mm/mm
        fid, bid = model.getFrameId(link), model.getFrameId(base)
        assert fid < model.nframes and bid < model.nframes
        for k in range(q.shape[0]):
            qp = pin.neutral(model)  # joints off the chain stay neutral
            scale = np.ones(chain.dof)
            cols = []
            for i, name in enumerate(chain.joint_names):
                jm = model.joints[model.getJointId(name)]
                if jm.nq == 2:  # continuous joint: (cos, sin) in pinocchio's q
                    qp[jm.idx_q:jm.idx_q + 2] = np.cos(q[k, i]), np.sin(q[k, i])
                elif chain.prismatic[i]:
                    qp[jm.idx_q] = q[k, i] / 1000.0  # mm -> m
                else:
                    qp[jm.idx_q] = q[k, i]
                scale[i] = 1.0 if chain.prismatic[i] else 1000.0  # m/m = mm/mm; m/rad -> mm/rad
                cols.append(jm.idx_v)
            pin.framesForwardKinematics(model, data, qp)
            oMb, oMf = data.oMf[bid], data.oMf[fid]
            bMf = oMb.actInv(oMf)
            Jp = pin.computeFrameJacobian(model, data, qp, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            Jb = oMb.rotation.T @ Jp[:3, cols] * scale  # world-aligned -> base frame (the base does not move with q)
            errs = (np.abs(T[k, :3, 3] - bMf.translation * 1000.0).max(),
                    np.abs(T[k, :3, :3] - bMf.rotation).max(), np.abs(J[k] - Jb).max())
            worst = np.maximum(worst, errs)
    print(f"\npinocchio {pin.__version__}, {request.node.callspec.id}: "
          f"{len(links)} links; max |p - p_pin| = {worst[0]:.2e} mm, max |R - R_pin| = {worst[1]:.2e}, "
          f"max |J - J_pin| = {worst[2]:.2e} (mm/rad, mm/mm)")
    assert worst[0] < 1e-9 and worst[1] < 1e-12 and worst[2] < 1e-9, worst


@pytest.mark.parametrize("make", ["fetch", "dh", "built"])
def test_chain_dict_round_trip(make):
    import json

    from jaxcal._models._urdf import chain_from_dict, chain_to_dict

    if make == "fetch":
        chain = load_urdf(URDFS["fetch"][0], base="base_link", tip="gripper_link", tool=(1.0, 2.0, 3.0))
    elif make == "dh":
        chain = chain_from_dh(robots.hsr_jr680().with_hayati(2))
    else:
        chain = SerialChain.build(origin_R=[np.eye(3), np.eye(3)], origin_t=[[0, 0, 100.0], [300.0, 0, 0]],
                                  joint_types=["prismatic", "revolute"], q_min=[0, -3], q_max=[500, 3])
    back = chain_from_dict(json.loads(json.dumps(chain_to_dict(chain))))
    assert back.dh == chain.dh and back.joint_types == chain.joint_types
    q = jnp.asarray(_random_q(chain, 20))
    np.testing.assert_allclose(np.stack(back.point_in_base(None, q, back.tool), -1),
                               np.stack(chain.point_in_base(None, q, chain.tool), -1), rtol=0, atol=1e-9)


# ---------------------------------------------------------------- calibration through the layout


def _dh_experiment(n=300):
    robot = robots.hsr_jr680(tool_mm=(40.0, -30.0, 120.0))
    meas = jaxcal.Position()
    ex = jaxcal.simulate_experiment(jax.random.key(3), robot, measurement=meas, n_samples=n, noise_std=0.05)
    return robot, meas, ex


@pytest.mark.slow  # default-run time (issue 25: keep it near 10 min on 2 cores)
def test_dh_chain_and_its_urdf_export_calibrate_identically(tmp_path):
    robot, meas, ex = _dh_experiment()
    chain = chain_from_dh(robot)
    export_urdf(chain, None, tmp_path / "hsr.urdf")
    urdf = load_urdf(tmp_path / "hsr.urdf", base="base_link", tip="flange", tool=np.asarray(robot.tool))
    r1 = jaxcal.calibrate(chain, meas, ex.train, "lm", prior=None)
    r2 = jaxcal.calibrate(urdf, meas, ex.train, "lm", prior=None)
    assert r1.ok and r2.ok
    assert r1.space.free_names == r2.space.free_names
    np.testing.assert_allclose(r1.x, r2.x, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(r1.evaluate(ex.test).rmse, r2.evaluate(ex.test).rmse, rtol=1e-9)
    # and the DH robot itself (its own 4-parameter DH errors) reaches the same accuracy:
    # the chain's error set contains every DH deviation, so both are at the noise floor
    rd = jaxcal.calibrate(robot, meas, ex.train, "lm", prior=None)
    floor = 0.05 * np.sqrt(3)
    assert abs(rd.evaluate(ex.test).rmse - r1.evaluate(ex.test).rmse) < 0.05 * floor
    assert r1.evaluate(ex.test).rmse < 1.1 * floor


@pytest.mark.slow  # default-run time (issue 25: keep it near 10 min on 2 cores)
def test_chain_result_json_cli_export_round_trip(tmp_path):
    """simulate (URDF, prismatic joint) → calibrate → JSON → export URDF → same predictions."""
    from jaxcal.cli import main

    urdf = str(URDFS["fetch"][0])
    data = tmp_path / "d.csv"
    args = ["--robot", urdf, "--base", "base_link", "--tip", "gripper_link", "--measurement", "position"]
    assert main(["--no-cache", "simulate", "--out", str(data), "--samples", "200", "--noise-std", "0.05", *args]) == 0
    assert "q1_mm" in data.read_text()  # the prismatic joint's column is in mm
    out = tmp_path / "r.json"
    assert main(["--no-cache", "calibrate", str(data), *args, "--out", str(out)]) == 0
    assert main(["--no-cache", "export", str(out), "--out", str(tmp_path / "cal.urdf")]) == 0
    assert main(["--no-cache", "export", str(out), "--dh-out", str(tmp_path / "x.csv")]) == 2  # not a DH table
    res = jaxcal.load_result(out)
    assert isinstance(res.robot, SerialChain) and res.robot.joint_types[0] == "prismatic"
    ds = jaxcal.load_csv(data)
    cal = load_urdf(tmp_path / "cal.urdf", base="base_link", tip="gripper_link")
    np.testing.assert_allclose(jaxcal.fk_position(cal, ds.q), res.predict(ds.q), rtol=0, atol=1e-9)
    with pytest.raises(TypeError, match="generic chain"):
        res.dh_table()


def test_dh_result_export_writes_urdf_and_dh_table(tmp_path):
    robot, meas, ex = _dh_experiment(200)
    res = jaxcal.calibrate(robot, meas, ex.train, "lm")
    jaxcal.save_result(res, tmp_path / "r.json")
    from jaxcal.cli import main

    assert main(["--no-cache", "export", str(tmp_path / "r.json"), "--out", str(tmp_path / "c.urdf"),
                 "--dh-out", str(tmp_path / "c.csv")]) == 0
    cal = load_urdf(tmp_path / "c.urdf", base="base_link", tip="jaxcal_tool_point")
    np.testing.assert_allclose(jaxcal.fk_position(cal, ex.test.q), jaxcal.fk_position(robot, ex.test.q, res.deviations),
                               rtol=0, atol=1e-9)
    from jaxcal._calibration._io import load_robot_csv

    dh = load_robot_csv(tmp_path / "c.csv")
    np.testing.assert_allclose(jaxcal.fk_position(dh, ex.test.q), jaxcal.fk_position(robot, ex.test.q, res.deviations),
                               rtol=0, atol=1e-6)


def test_coverage_of_a_prismatic_joint_is_in_mm():
    from jaxcal._fit._diagnostics import Checks, coverage, narrow_joints

    fetch = load_urdf(URDFS["fetch"][0], base="base_link", tip="gripper_link")
    q = np.zeros((3, 8))
    q[:, 0] = [0.0, 20.0, 40.0]  # torso: 40 mm of its 386 mm range (1/12 = 32 mm)
    q[:, 1] = np.radians([0.0, 10.0, 20.0])  # shoulder pan: 20° < 30°
    cov = coverage(fetch, q)
    np.testing.assert_allclose(cov[0], [40.0, 386.15])
    np.testing.assert_allclose(cov[1, 0], 20.0)
    assert narrow_joints(fetch, cov, Checks())[:1] == (2,)  # the torso moved enough, the pan did not
    q[:, 0] = [0.0, 10.0, 20.0]
    assert narrow_joints(fetch, coverage(fetch, q), Checks())[:2] == (1, 2)
