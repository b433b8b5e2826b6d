"""A chain's tip transform (last moving joint → tip link) as calibration parameters (issue 22):
``tip_translation`` (tip_dx, tip_dy, tip_dz, mm) and ``tip_rotation`` (tip_drx, tip_dry, tip_drz,
rad). FK against a plain NumPy product of 4×4 transforms, the Jacobian against finite
differences, URDF export → reload, and LM at the statistical floor on tool-point position and
pose data of a robot whose tip transform is off."""

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import central_differences
from test_chain import URDFS, numpy_urdf_fk

import jaxcal
from jaxcal import SerialChain, chain_from_dh, export_urdf, load_urdf, robots
from jaxcal._calibration._calibrate import candidate_space
from jaxcal._core._params import Deviations, ParameterSpace, layout_for
from jaxcal._models._chain import GEOMETRIC_GROUPS, TIP_GROUPS
from jaxcal._models._kinematics import rotvec_to_matrix

DATA = pathlib.Path(__file__).parents[1] / "data" / "urdf"
TIP_NAMES = ("tip_dx", "tip_dy", "tip_dz", "tip_drx", "tip_dry", "tip_drz")


# ---------------------------------------------------------------- independent NumPy reference


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _hom(R=None, t=(0.0, 0.0, 0.0)):
    T = np.eye(4)
    T[:3, :3] = np.eye(3) if R is None else R
    T[:3, 3] = t
    return T


def numpy_chain_fk(chain, dev, q):
    """``T_base_tip`` [4, 4] mm for one ``q``: the module docstring's error model written out as a
    product of 4×4 matrices (no code shared with the kernels)."""
    g = {k: np.asarray(v, np.float64) for k, v in dev.items()}
    T = np.eye(4)
    for i in range(chain.dof):
        d = np.array([g["dx"][i], g["dy"][i], g["dz"][i]])
        T = T @ _hom(np.asarray(chain.origin_R[i]), np.asarray(chain.origin_t[i]) + d)
        T = T @ _hom(_rx(g["drx"][i]) @ _ry(g["dry"][i]))
        if chain.prismatic[i]:
            T = T @ _hom(_rz(g["drz"][i])) @ _hom(t=(0.0, 0.0, q[i] + g["offset"][i]))
        else:
            T = T @ _hom(_rz(q[i] + g["offset"][i]))
    dt, dr = g["tip_translation"], g["tip_rotation"]
    return T @ _hom(np.asarray(chain.flange_R), np.asarray(chain.flange_t) + dt) @ _hom(_rx(dr[0]) @ _ry(dr[1]) @ _rz(dr[2]))


def _random_dev(chain, seed=1, joint_scale=1.0, tip_scale=1.0):
    rng = np.random.default_rng(seed)
    out = {g: rng.normal(0, (0.5 if u != "rad" else 0.003) * joint_scale, chain.dof) for g, u in GEOMETRIC_GROUPS}
    out["tip_translation"] = rng.normal(0, 0.8 * tip_scale, 3)
    out["tip_rotation"] = rng.normal(0, 0.004 * tip_scale, 3)
    return out


def _random_q(chain, n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(np.asarray(chain.q_min), np.asarray(chain.q_max), size=(n, chain.dof))


def _chain_T(chain, dev, q):
    X, Y, Z, P = chain.frame_soa(dev, jnp.asarray(q))
    T = np.zeros((q.shape[0], 4, 4))
    T[:, :3, :3] = np.stack([np.stack(X, -1), np.stack(Y, -1), np.stack(Z, -1)], -1)
    T[:, :3, 3] = np.stack(P, -1)
    T[:, 3, 3] = 1
    return T


def _chains():
    return {
        "ur10e": load_urdf(DATA / "ur10e.urdf", base="base_link", tip="tool0", tool=(40.0, -30.0, 120.0)),
        "fetch": load_urdf(DATA / "fetch.urdf", base="base_link", tip="gripper_link", tool=(20.0, 5.0, -10.0)),
        # no fixed joint after the last moving joint: the tip transform is the identity
        "panda_link7": load_urdf(DATA / "panda_arm.urdf", base="panda_link0", tip="panda_link7", tool=(0.0, 0.0, 107.0)),
        "hsr_dh": chain_from_dh(robots.hsr_jr680(tool_mm=(50.0, -20.0, 120.0))),
    }


CHAINS = _chains()


# ---------------------------------------------------------------- the groups


def test_tip_groups_names_units_prior_and_preference():
    chain = CHAINS["ur10e"]
    layout = layout_for(chain)
    assert [g for g, _, _ in TIP_GROUPS] == ["tip_translation", "tip_rotation"]
    i = layout.names.index("tip_dx")
    assert layout.names[i:i + 6] == TIP_NAMES and layout.names[i - 1] == f"drz_{chain.dof}"
    assert layout.units[i:i + 6] == ("mm",) * 3 + ("rad",) * 3
    assert layout.kinds[i:i + 6] == ("geometric",) * 6
    assert jaxcal._core._params.group_of("tip_drx") == "tip_rotation"
    # free by default, with the chain groups' default prior (2 mm, 0.5°)
    space = ParameterSpace.for_robot(chain, measurement=jaxcal.Position())
    assert set(TIP_NAMES) <= set(space.free_names)
    std = dict(zip(space.free_names, jaxcal.Prior().std(space)))
    assert [std[n] for n in TIP_NAMES] == pytest.approx([2.0] * 3 + [np.radians(0.5)] * 3)
    # kept after the joints' groups, translation before rotation, before the extras
    pref = jaxcal.KEEP_PREFERENCE
    assert pref.index("drz") + 1 == pref.index("tip_translation") == pref.index("tip_rotation") - 1
    # tables: mm and degrees
    dev = {"tip_translation": np.array([0.5, -0.25, 1.0]), "tip_rotation": np.radians([0.1, -0.2, 0.3])}
    entries = {n: (v, u) for n, v, u in jaxcal._models._chain.correction_entries(chain, dev)}
    assert entries["tip_dy"] == (-0.25, "mm") and entries["tip_drz"] == (pytest.approx(0.3), "deg")
    assert entries["offset_1"] == (0.0, "deg")  # a group the deviations lack reads 0
    # free=/fix= select them by "tip"
    cand = candidate_space(chain, jaxcal.Position(), fix="tip")
    assert not set(TIP_NAMES) & set(cand.free_names)
    assert candidate_space(chain, jaxcal.Position(), free="tip").free_names == TIP_NAMES


# ---------------------------------------------------------------- FK and Jacobian


@pytest.mark.parametrize("key", list(CHAINS))
def test_fk_with_tip_errors_equals_numpy_product(key):
    chain = CHAINS[key]
    dev = _random_dev(chain, seed=4)
    q = _random_q(chain, 25, seed=2)
    ref = np.stack([numpy_chain_fk(chain, dev, qi) for qi in q])
    T = _chain_T(chain, dev, q)
    np.testing.assert_allclose(T[:, :3, 3], ref[:, :3, 3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(T[:, :3, :3], ref[:, :3, :3], rtol=0, atol=1e-12)
    tool = np.asarray(chain.tool)
    p_ref = ref[:, :3, :3] @ tool + ref[:, :3, 3]
    for fused in (False, True):
        p = np.stack(chain.point_in_base(dev, jnp.asarray(q), jnp.asarray(tool), fused=fused), -1)
        np.testing.assert_allclose(p, p_ref, rtol=0, atol=1e-9)
    # the measurement models, through a Deviations of the layout
    full = Deviations({k: jnp.asarray(v) for k, v in dev.items()}, layout_for(chain))
    np.testing.assert_allclose(jaxcal.fk_position(chain, jnp.asarray(q), full), p_ref, rtol=0, atol=1e-9)
    pose = np.asarray(jaxcal.Pose().predict(chain, full, jnp.asarray(q)))
    np.testing.assert_allclose(pose[:, :3, 3], p_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(pose[:, :3, :3], ref[:, :3, :3], rtol=0, atol=1e-12)
    marks = np.array([[0.0, 0.0, 0.0], [30.0, -10.0, 5.0]])
    mp = np.asarray(jaxcal.Markers(marks, known=True).predict(chain, full, jnp.asarray(q)))
    np.testing.assert_allclose(mp, np.einsum("nij,kj->nki", ref[:, :3, :3], marks) + ref[:, None, :3, 3], atol=1e-9)
    # the host-side tip transform (export's)
    dt, dr = dev["tip_translation"], dev["tip_rotation"]
    F = _hom(np.asarray(chain.flange_R), np.asarray(chain.flange_t) + dt) @ _hom(_rx(dr[0]) @ _ry(dr[1]) @ _rz(dr[2]))
    np.testing.assert_allclose(chain.tip_numpy(dev), F, rtol=0, atol=1e-15)


def test_tip_errors_move_the_urdf_tip_frame():
    """Independent of the chain's own arrays: with only tip errors, FK is the URDF's (plain
    product of its joint transforms) times ``F⁻¹·F'`` in the tip frame."""
    path, base, tip = URDFS["ur10e"]
    chain = load_urdf(path, base=base, tip=tip)
    dt, dr = np.array([0.7, -0.4, 0.3]), np.radians([0.2, -0.15, 0.1])
    q = _random_q(chain, 10, seed=9)
    F = _hom(np.asarray(chain.flange_R), np.asarray(chain.flange_t))
    F2 = _hom(np.asarray(chain.flange_R), np.asarray(chain.flange_t) + dt) @ _hom(_rx(dr[0]) @ _ry(dr[1]) @ _rz(dr[2]))
    ref = np.stack([numpy_urdf_fk(chain.urdf, base, tip, qi) @ np.linalg.solve(F, F2) for qi in q])
    T = _chain_T(chain, {"tip_translation": dt, "tip_rotation": dr}, q)
    np.testing.assert_allclose(T, ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("key", ["ur10e", "fetch"])
def test_tip_jacobian_matches_finite_differences(key):
    chain = CHAINS[key]
    q = jnp.asarray(_random_q(chain, 15, seed=5))
    base = {k: jnp.asarray(v) for k, v in _random_dev(chain, seed=6, joint_scale=0.1).items()}
    tool = jnp.asarray(chain.tool)
    full0 = Deviations(base, layout_for(chain))
    y_pose = jaxcal.Pose().predict(chain, full0, q)

    def f(x):  # the six tip entries -> every kernel's output
        dev = {**base, "tip_translation": x[:3], "tip_rotation": x[3:]}
        p = chain.point_in_base(dev, q, tool)
        pf = chain.point_in_base(dev, q, tool, fused=True)
        X, Y, Z, P = chain.frame_soa(dev, q)
        r = jaxcal.Pose().residual(chain, full0.replace(tip_translation=x[:3], tip_rotation=x[3:]), q, y_pose)
        return jnp.concatenate([*p, *pf, *P, *X, *Z, r.ravel()])

    x0 = jnp.concatenate([base["tip_translation"], base["tip_rotation"]])
    J = np.asarray(jax.jacfwd(f)(x0))
    h = 1e-6
    Jfd = central_differences(f, x0, h)
    np.testing.assert_allclose(J, Jfd, rtol=1e-6, atol=1e-5)
    # the tip translation moves every point by its own amount in the last joint frame: |∂p/∂tip_d·| = 1
    n = q.shape[0]
    col = J[: 3 * n, :3].reshape(3, n, 3)
    np.testing.assert_allclose(np.linalg.norm(col, axis=0), 1.0, atol=1e-12)


# ---------------------------------------------------------------- export → reload


def _exported_fk(text, base, tip, chain, q):
    again = load_urdf(text, base=base, tip=tip)
    T = _chain_T(again, None, q)
    return T, np.stack(again.point_in_base(None, jnp.asarray(q), jnp.asarray(chain.tool)), -1)


@pytest.mark.parametrize("key", list(CHAINS))
def test_export_writes_tip_errors_reload_gives_same_fk(key, tmp_path):
    chain = CHAINS[key]
    dev = _random_dev(chain, seed=8)
    assert np.linalg.norm(dev["tip_translation"]) >= 0.5 and np.degrees(np.abs(dev["tip_rotation"]).max()) >= 0.1
    q = _random_q(chain, 30, seed=3)
    T = _chain_T(chain, dev, q)
    text = export_urdf(chain, dev, tmp_path / "cal.urdf")
    tip = chain.tip
    if key == "panda_link7":  # no fixed joint after the last moving joint: the calibrated tip is a new link
        assert 'link name="jaxcal_calibrated_tip"' in text
        tip = "jaxcal_calibrated_tip"
    T2, p2 = _exported_fk(text, chain.base, tip, chain, q)
    np.testing.assert_allclose(T2[:, :3, 3], T[:, :3, 3], rtol=0, atol=1e-9)  # mm
    np.testing.assert_allclose(T2[:, :3, :3], T[:, :3, :3], rtol=0, atol=1e-12)
    # and the tool point: through the tool link, and as a point in the (calibrated) tip frame
    p = np.stack(chain.point_in_base(dev, jnp.asarray(q), jnp.asarray(chain.tool)), -1)
    np.testing.assert_allclose(p2, p, rtol=0, atol=1e-9)
    if np.any(np.asarray(chain.tool) != 0):
        T3, _ = _exported_fk(text, chain.base, "jaxcal_tool_point", chain, q)
        np.testing.assert_allclose(T3[:, :3, 3], p, rtol=0, atol=1e-9)
    # the calibrated file is plain URDF: its own product of joint transforms agrees
    ref = np.stack([numpy_urdf_fk(text, chain.base, tip, qi) for qi in q])
    np.testing.assert_allclose(ref[:, :3, 3], T[:, :3, 3], rtol=0, atol=1e-9)


def test_export_keeps_fixed_joints_below_the_corrected_one(tmp_path):
    """UR10e: wrist_3_link → flange → tool0. The correction goes into ``wrist_3-flange`` (on the
    last moving link), so ``flange`` moves with it and ``flange-tool0`` is unchanged."""
    import xml.etree.ElementTree as ET

    chain = CHAINS["ur10e"]
    dev = _random_dev(chain, seed=8)
    text = export_urdf(chain, dev)
    joints = {j.get("name"): j for j in ET.fromstring(text).findall("joint")}
    orig = {j.get("name"): j for j in ET.fromstring(chain.urdf).findall("joint")}
    assert joints["flange-tool0"].find("origin").attrib == orig["flange-tool0"].find("origin").attrib
    assert joints["wrist_3-flange"].find("origin").attrib != orig["wrist_3-flange"].find("origin").attrib
    # without tip errors the fixed joints are left as they were
    nominal = export_urdf(chain, {g: v for g, v in dev.items() if not g.startswith("tip")})
    j0 = {j.get("name"): j for j in ET.fromstring(nominal).findall("joint")}
    assert j0["wrist_3-flange"].find("origin").attrib == orig["wrist_3-flange"].find("origin").attrib


# ---------------------------------------------------------------- the statistical floor

#: σ (mm per measured entry; pose orientation σ/orientation_scale rad), training and test sizes
SIGMA, N_TRAIN, N_TEST = 0.05, 300, 6000


def _with_tip(chain: SerialChain, R, t) -> SerialChain:
    """The same chain with another (nominal) tip transform: the "true" robot of the floor tests,
    built without the tip error groups."""
    return SerialChain.build(
        origin_R=np.asarray(chain.origin_R), origin_t=np.asarray(chain.origin_t), joint_types=chain.joint_types,
        q_min=np.asarray(chain.q_min), q_max=np.asarray(chain.q_max), flange_R=R, flange_t=t,
        align=np.asarray(chain.align), tool=np.asarray(chain.tool), joint_names=chain.joint_names,
        link_names=chain.link_names, base=chain.base, tip=chain.tip, name=chain.name)


@pytest.fixture(scope="module")
def truth():
    """UR10e with a tool point 130 mm off the flange; the true tip transform is off by 0.88 mm and
    0.27° (rotation vector), the joint origins by random 0.5 mm / 0.1° errors."""
    chain = CHAINS["ur10e"]
    dt, dr = np.array([0.6, -0.5, 0.4]), np.radians([0.15, -0.12, 0.2])
    true = _with_tip(chain, np.asarray(chain.flange_R) @ _rx(dr[0]) @ _ry(dr[1]) @ _rz(dr[2]),
                     np.asarray(chain.flange_t) + dt)
    rng = np.random.default_rng(0)
    joint = {g: rng.normal(0, np.radians(0.1) if u != "mm" else 0.5, chain.dof) for g, u in GEOMETRIC_GROUPS}
    dev = Deviations({g: jnp.asarray(v) for g, v in joint.items()}, layout_for(true))
    return chain, true, dev


def _data(true, dev, meas, n, seed):
    rng = np.random.default_rng(seed)
    q = jnp.asarray(rng.uniform(np.asarray(true.q_min), np.asarray(true.q_max), (n, true.dof)))
    y = np.array(meas.predict(true, dev, q))
    if isinstance(meas, jaxcal.Pose):  # σ per residual entry: position σ, orientation σ / orientation_scale
        y[:, :3, 3] += SIGMA * rng.normal(size=(n, 3))
        y[:, :3, :3] = y[:, :3, :3] @ np.asarray(rotvec_to_matrix(jnp.asarray(
            SIGMA / meas.orientation_scale * rng.normal(size=(n, 3)))))
    else:
        y += SIGMA * rng.normal(size=y.shape)
    return q, jnp.asarray(y)


@pytest.mark.parametrize("meas", [jaxcal.Position(), pytest.param(jaxcal.Pose(), marks=pytest.mark.slow)], ids=["position", "pose"])
def test_lm_reaches_floor_with_a_deviated_tip(truth, meas, tmp_path):
    """``calibrate(..., "lm")`` with the defaults on the nominal chain reaches the floor (measured
    here: 0.993× position, 0.994× pose). Without the tip errors (the code before them) the same
    data ended 8.94× (position, p = 26) and 28.3× (pose, p = 26) above the floor; with σ = 0.5 mm
    1.34× and 3.00×."""
    chain, true, dev = truth
    q, y = _data(true, dev, meas, N_TRAIN, 1)
    res = jaxcal.calibrate(chain, meas, (q, y), "lm")
    assert res.ok, res.message
    free = set(res.space.free_names)
    if isinstance(meas, jaxcal.Pose):
        assert {"tip_dx", "tip_dy", "tip_drx", "tip_dry"} <= free  # tip_drz is the joint offset, tip_dz dz_6's
    else:  # one tool point: the tip rotation acts like a tip translation, one of which is the joint offset
        assert free & set(TIP_NAMES) == {"tip_dx"}
    qt, yt = _data(true, dev, meas, N_TEST, 2)
    r = np.asarray(meas.residual(chain, res.deviations, qt, yt))
    test_rms = float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))  # every residual entry, as the floor counts them
    floor = jaxcal.statistical_floor(SIGMA, res.space.n_free, N_TRAIN, meas.size).test
    assert abs(test_rms / floor - 1) < 0.03, (test_rms, floor, res.space.n_free)
    # the result file and `jaxcal export` carry the calibrated tip: the URDF predicts what the result does
    from jaxcal.cli import main

    jaxcal.save_result(res, tmp_path / "r.json")
    np.testing.assert_allclose(jaxcal.load_result(tmp_path / "r.json").predict(qt[:50]), res.predict(qt[:50]),
                               rtol=0, atol=1e-9)
    assert main(["--no-cache", "export", str(tmp_path / "r.json"), "--out", str(tmp_path / "cal.urdf")]) == 0
    cal = load_urdf(tmp_path / "cal.urdf", base=chain.base, tip=chain.tip, tool=np.asarray(chain.tool))
    np.testing.assert_allclose(jaxcal.fk_pose(cal, qt[:50], tool=True),
                               jaxcal.fk_pose(chain, qt[:50], res.deviations, tool=True), rtol=0, atol=1e-9)
