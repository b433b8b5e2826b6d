"""The sensor-kind registry: every kind's data file written and read back the same, recognised from
its columns alone, its model as plain data and back; and a kind added by one class and one
registry entry works through `Dataset`, `save_csv`, `load_csv` and `measurement_for` with no other
edit (what a new sensor needs)."""

from __future__ import annotations

import numpy as np
import pytest

import jaxcal
from jaxcal import robots
from jaxcal._core._rotvec import rotvec_to_matrix
from jaxcal._datasets._dataset import Dataset, load_csv, save_csv
from jaxcal._sensors import _kind
from jaxcal._sensors._kind import SensorKind, kind_names, register_kind, sensor_kind, sensor_kinds

N = 7


def _readings(kind: str, rng, dof: int):
    """``(y, metadata, labels)`` of ``N`` valid readings of ``kind``, made here by hand."""
    if kind == "cable":
        return rng.uniform(500, 900, N), {}, ()
    if kind == "position":
        return rng.normal(0, 300, (N, 3)), {}, ()
    if kind == "pose":
        y = np.zeros((N, 4, 4))
        y[:, :3, :3] = rotvec_to_matrix(rng.normal(0, 0.8, (N, 3)))
        y[:, :3, 3], y[:, 3, 3] = rng.normal(0, 300, (N, 3)), 1.0
        return y, {}, ()
    if kind == "markers":
        y = rng.normal(0, 200, (N, 3, 3))
        y[2, 1] = np.nan  # a marker missing in one row: an empty cell, masked
        return y, {}, tuple(("s1", "f1", "p1") if i < 4 else ("s2", "f2", "p1") for i in range(N))
    if kind == "camera":
        y = rng.uniform(0, 640, (N, 4, 2))
        y[1, 3] = np.nan  # a corner not detected
        return y, {}, ()
    if kind in ("plane", "point"):
        return rng.integers(0, 3, N).astype(float), {f"{kind}_labels": "a,b,c"}, ()
    if kind == "distance":
        return np.concatenate([rng.uniform(-1, 1, (N, dof)), rng.uniform(100, 300, (N, 1))], axis=1), {}, ()
    if kind == "self_contact":
        return rng.uniform(20, 80, N), {"tips": "left_tool,right_tool"}, ()
    raise AssertionError(f"no readings written for kind {kind!r}: add them here")


def _tree():
    """A two-armed robot (for the kinds whose readings name tips)."""
    import pathlib

    from jaxcal._models._urdf import load_urdf

    urdf = pathlib.Path(__file__).resolve().parents[1] / "data" / "urdf" / "humanoid_tree.urdf"
    return load_urdf(urdf, tips=["left_tool", "right_tool"])


def _same(a: Dataset, b: Dataset):
    assert (a.kind, a.labels) == (b.kind, b.labels)
    np.testing.assert_allclose(np.asarray(a.q), np.asarray(b.q), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(a.y), np.asarray(b.y), rtol=1e-12, atol=1e-9, equal_nan=True)
    assert {k: v for k, v in a.metadata} == {k: v for k, v in b.metadata}


@pytest.mark.parametrize("kind", kind_names())
def test_every_kind_file_round_trip_and_recognised_from_columns(kind, tmp_path):
    jaxcal.enable_x64()
    rng = np.random.default_rng(sum(map(ord, kind)))
    robot = robots.hsr_jr680()
    y, meta, labels = _readings(kind, rng, robot.dof)
    data = Dataset(rng.uniform(-1.5, 1.5, (N, robot.dof)), y, kind, meta, labels)
    path = tmp_path / f"{kind}.csv"
    save_csv(data, path, angle_unit="rad")
    _same(data, load_csv(path, dof=robot.dof))
    # the same file without its '# kind:' line: the kind is recognised from its columns
    text = path.read_text().replace(f"# kind: {kind}\n", "")
    bare = tmp_path / f"{kind}_bare.csv"
    bare.write_text(text)
    assert f"# kind: {kind}" not in text
    _same(data, load_csv(bare, dof=robot.dof))


@pytest.mark.parametrize("kind", kind_names())
def test_every_kind_model_as_plain_data(kind):
    jaxcal.enable_x64()
    from jaxcal._calibration._io import measurement_from_dict, measurement_to_dict
    from jaxcal._sensors._camera import planning_camera

    robot = _tree() if kind == "self_contact" else robots.hsr_jr680()
    rng = np.random.default_rng(1)
    y, meta, labels = _readings(kind, rng, robot.dof)
    data = Dataset(rng.uniform(-1.5, 1.5, (N, robot.dof)), y, kind, meta, labels)
    spec = sensor_kind(kind)
    model = planning_camera(robot) if kind == "camera" else spec.setup(data, robot, set(), _kind.SetupOptions())[0]
    assert model.kind == kind
    d = measurement_to_dict(model)
    assert d["kind"] == kind
    back = measurement_from_dict(d)
    again = measurement_to_dict(back)
    # a pose's orientation weight read back from a result is the fit's, taken as given from then on
    again.pop("orientation_scale_estimated", None), d.pop("orientation_scale_estimated", None)
    assert type(back) is type(model) and again == d


def test_registry_order_and_errors():
    assert [k.name for k in sensor_kinds()] == list(kind_names())
    assert sensor_kind("pose").found_in(("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"))
    # a pose file has a position's columns too: pose is recognised first
    assert kind_names().index("pose") < kind_names().index("position")
    with pytest.raises(ValueError, match="unknown measurement kind 'laser'.*cable"):
        sensor_kind("laser")
    with pytest.raises(ValueError, match="unknown measurement kind"):
        Dataset(np.zeros((2, 6)), np.zeros(2), "laser")
    with pytest.raises(TypeError, match="SensorKind"):
        register_kind(int)


@pytest.fixture
def gauge_kind():
    """A made-up sensor kind, defined the way a new sensor's module defines its kind."""

    @register_kind
    class GaugeKind(SensorKind):
        """A dial gauge against a fixed block: one reading ``gap_mm`` per row."""

        name = "gauge"
        columns = ("gap_mm",)

        def default_model(self, robot, *, data=None, anchor_mm=None, n_markers=None):
            self.refuse_anchor(anchor_mm)
            return jaxcal.CableLength(np.zeros(3))  # any model: the test checks the plumbing

    yield GaugeKind
    _kind._REGISTRY.pop("gauge")


def test_a_new_kind_needs_only_its_class(gauge_kind, tmp_path):
    jaxcal.enable_x64()
    assert "gauge" in kind_names()
    data = Dataset(np.full((3, 6), 0.1), np.array([1.5, 2.0, 2.5]), "gauge")
    path = tmp_path / "g.csv"
    data.to_csv(path)
    text = path.read_text()
    assert "# kind: gauge" in text and "gap_mm" in text.splitlines()[2]
    back = load_csv(path)
    assert back.kind == "gauge"
    np.testing.assert_allclose(np.asarray(back.y), [1.5, 2.0, 2.5])
    setup = jaxcal.measurement_for(back, robots.hsr_jr680(), estimate="tool")
    assert setup.estimate == {"tool"}
    with pytest.raises(ValueError, match="--anchor applies to --measurement cable only"):
        jaxcal.measurement_for(back, robots.hsr_jr680(), anchor_mm=(1, 2, 3))
    with pytest.raises(ValueError, match="gauge measurements must have shape"):
        Dataset(np.zeros((3, 6)), np.zeros((3, 2)), "gauge")


def test_command_line_offers_match_the_kind_classes():
    """The parser's NumPy-free table of what `jaxcal simulate` / `jaxcal plan` offer (_kind._OFFERED)
    says what the kind classes say: a simulator named, plannable; and the hooks the kinds name
    (simulator, planner, messy session) resolve."""
    import importlib

    assert set(_kind._OFFERED) == set(_kind._BUILTIN)
    for k in sensor_kinds():
        if k.name in _kind._OFFERED:
            assert _kind._OFFERED[k.name] == (k.simulator is not None, k.plannable), k.name
        for hook in (k.simulator, k.planner, k.messy):
            if hook is not None:
                module, _, name = hook.partition(":")
                assert callable(getattr(importlib.import_module(module), name)) or name.isupper(), hook
        if k.planner is not None:
            assert k.plannable, k.name
    assert "markers" not in _kind.simulated_kind_names() and "self_contact" not in _kind.plannable_kind_names()
