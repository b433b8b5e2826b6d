"""The robot protocol (``jaxcal.AbstractRobot``) that every robot type implements, checked on each
type: a DH preset, a DH table file, a modified-DH (Craig) table, a URDF chain, a chain built from a
DH table, a chain built by hand and a kinematic tree of three tips (its default tip: the first). The rest of jaxcal asks a robot only through it."""

import json
import pathlib

import jax.numpy as jnp
import numpy as np
import pytest

import jaxcal
from jaxcal import robots
from jaxcal._calibration._io import load_robot_csv, robot_from_dict, save_robot_csv
from jaxcal._core._params import Deviations, layout_for
from jaxcal._models._nongeometric import nongeometric_from_dict
from jaxcal._models._urdf import tree_from_dict

URDF = pathlib.Path(__file__).parents[1] / "data" / "urdf" / "ur10e.urdf"
TREE_URDF = URDF.with_name("humanoid_tree.urdf")


def _from_dict(d):
    """``robot_from_dict``; a kinematic tree's file form is read by the models' ``tree_from_dict``
    (the result files' reader does not know trees yet)."""
    if d.get("type") == "kinematic_tree":
        return nongeometric_from_dict(tree_from_dict(d), d.get("nongeometric"))
    return robot_from_dict(d)


def _robot(kind, tmp_path):
    if kind == "preset":
        return robots.hsr_jr680(tool_mm=(40.0, -30.0, 120.0))
    if kind == "dh_file":
        save_robot_csv(robots.puma560(), tmp_path / "puma.csv")
        return load_robot_csv(tmp_path / "puma.csv")
    if kind == "modified_dh_file":
        (tmp_path / "craig.csv").write_text(
            "# convention: modified\n# tool_mm: 0,0,207\nalpha_deg,a_mm,d_mm,theta_deg\n"
            "0,0,333,0\n-90,0,0,0\n90,0,316,0\n90,82.5,0,0\n-90,-82.5,384,0\n90,0,0,0\n90,88,0,0\n")
        return load_robot_csv(tmp_path / "craig.csv")
    if kind == "urdf":
        return jaxcal.load_urdf(URDF, base="base_link", tip="tool0", tool=(10.0, 0.0, 50.0))
    if kind == "tree":
        return jaxcal.load_urdf(TREE_URDF, tips=["left_tool", "right_tool", "head_camera"], tool=(0.0, 5.0, 40.0))
    if kind == "chain_from_dh":
        return jaxcal.chain_from_dh(robots.hsr_jr680())
    return jaxcal.SerialChain.build(  # by hand: a prismatic and two revolute joints
        origin_R=[np.eye(3), np.eye(3), np.eye(3)], origin_t=[[0, 0, 100.0], [300.0, 0, 0], [0, 250.0, 20.0]],
        joint_types=["prismatic", "revolute", "revolute"], q_min=[0, -3, -3], q_max=[500, 3, 3],
        flange_t=[0.0, 0.0, 80.0], tool=(5.0, 0.0, 30.0))


KINDS = ["preset", "dh_file", "modified_dh_file", "urdf", "chain_from_dh", "by_hand", "tree"]


def _q(robot, n=16, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(robot.q_min), np.asarray(robot.q_max)
    return jnp.asarray(rng.uniform(np.maximum(lo, -3.0), np.minimum(hi, 3.0), size=(n, robot.dof)))


@pytest.mark.parametrize("kind", KINDS)
def test_protocol(kind, tmp_path):
    robot = _robot(kind, tmp_path)
    assert isinstance(robot, jaxcal.AbstractRobot)
    assert len(robot.joint_units()) == robot.dof and set(robot.joint_units()) <= {"rad", "mm"}
    assert robot.reach_mm() > 0
    # the file form round trips: same dictionary, same kinematics
    d = json.loads(json.dumps(robot.to_dict()))
    back = _from_dict(d)
    assert type(back) is type(robot) and back.to_dict() == d
    assert json.loads(json.dumps(back.fingerprint())) == json.loads(json.dumps(robot.fingerprint()))
    q = _q(robot)
    np.testing.assert_allclose(np.asarray(jaxcal.fk_position(back, q)), np.asarray(jaxcal.fk_position(robot, q)),
                               rtol=0, atol=1e-9)
    # the DH table where there is one
    rows = robot.dh_rows_deg()
    if isinstance(robot, jaxcal.DHRobot):
        np.testing.assert_array_equal(rows, robot.dh_table_deg())
    else:
        assert rows is None


@pytest.mark.parametrize("kind", KINDS)
def test_nominal_lengths_scale_the_robot(kind, tmp_path):
    """Deviations of ``(s − 1) ×`` every nominal length (and the tool point) make a robot ``s`` times
    larger: every tool position is multiplied by ``s`` (a prismatic joint's stroke is a reading, so
    those joints are held at 0 here). This is what the combined fit's length-scale direction uses."""
    robot = _robot(kind, tmp_path)
    layout = layout_for(robot)
    lengths = robot.nominal_lengths()
    units = dict(zip(layout.names, layout.units))
    assert lengths and all(units[n] == "mm" for n in lengths), lengths
    s = 1.25
    flat = np.zeros(layout.size)
    index = {n: i for i, n in enumerate(layout.names)}
    for n, v in (lengths | dict(zip(("tool_x", "tool_y", "tool_z"), np.asarray(robot.tool, np.float64)))).items():
        flat[index[n]] = (s - 1.0) * v
    dev = Deviations.unravel(jnp.asarray(flat), layout)
    q = np.array(_q(robot))
    q[:, [u == "mm" for u in robot.joint_units()]] = 0.0
    q = jnp.asarray(q)
    np.testing.assert_allclose(np.asarray(jaxcal.fk_position(robot, q, dev)),
                               s * np.asarray(jaxcal.fk_position(robot, q)), rtol=1e-12, atol=1e-9)
