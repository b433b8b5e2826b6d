"""A data file's measurement model and extras from its kind and metadata lines
(:func:`jaxcal.measurement_for`, :func:`jaxcal.block_from_file`), without a fit: the set-up
``jaxcal calibrate`` and ``jaxcal plan --with`` build, for a library user. The set-up reads the
file's kind, columns, labels and metadata lines, never the readings' values: the files are written
from a few rows of made-up readings (no simulation to compile)."""

import numpy as np
import pytest

import jaxcal
from jaxcal._simulation._simulate import default_anchor


@pytest.fixture(scope="module")
def cable_rows(paper_robot):
    """Joint angles inside the limits and wire lengths: what the set-up is built from (values unused)."""
    rng = np.random.default_rng(0)
    q = rng.uniform(np.asarray(paper_robot.q_min), np.asarray(paper_robot.q_max), (6, paper_robot.dof))
    return q, rng.uniform(800, 1500, 6)


def _file(tmp_path, name, q, y, kind, meta):
    path = tmp_path / name
    jaxcal.Dataset(q, y, kind, meta).to_csv(path)
    return path


def test_cable_file_with_and_without_anchor(paper_robot, cable_rows, tmp_path):
    """The file's anchor_mm line is the known anchor (nothing estimated); without it the anchor and
    the cable offset are estimated from the default start; a keyword replaces the file's line."""
    known = _file(tmp_path, "known.csv", *cable_rows, "cable", {"anchor_mm": "1000,50,-20", "noise_std_mm": "0.4"})
    unknown = _file(tmp_path, "unknown.csv", *cable_rows, "cable", {})
    s = jaxcal.measurement_for(jaxcal.load_csv(known), paper_robot)
    assert isinstance(s.measurement, jaxcal.CableLength)
    np.testing.assert_allclose(np.asarray(s.measurement.anchor), [1000, 50, -20])
    assert s.estimate == frozenset() and s.extras == [] and s.notes == ()
    given = jaxcal.measurement_for(jaxcal.load_csv(known), paper_robot, anchor_mm=(1, 2, 3))
    np.testing.assert_allclose(np.asarray(given.measurement.anchor), [1, 2, 3])
    s = jaxcal.measurement_for(jaxcal.load_csv(unknown), paper_robot)
    np.testing.assert_allclose(np.asarray(s.measurement.anchor), np.asarray(default_anchor(paper_robot)))
    assert s.estimate == {"anchor", "offset"} and s.extras == ["anchor", "cable_offset"]
    assert "anchor and the cable offset are estimated" in s.notes[0]
    # the same set-up as a block: σ from the file's noise_std_mm line, or given
    b = jaxcal.block_from_file(known, paper_robot)
    assert (b.name, b.sigma, b.extras) == ("known", 0.4, ())
    b = jaxcal.block_from_file(str(unknown), paper_robot, sigma=0.5, name="wire")
    assert (b.name, b.sigma, b.extras) == ("wire", 0.5, ("anchor", "offset"))
    with pytest.raises(ValueError, match=r"unknown.csv: give its noise σ \(mm\)"):
        jaxcal.block_from_file(unknown, paper_robot)


def test_point_file_with_radius_is_spheres(paper_robot, cable_rows, tmp_path):
    """A point file's radius_mm line makes the points spheres of that radius (known); ``"radius"``
    in ``estimate`` estimates it; a radius for plane data is an error."""
    q, _ = cable_rows
    meta = {"point_labels": "p1,p2", "radius_mm": "12.5"}
    data = jaxcal.load_csv(_file(tmp_path, "balls.csv", q, np.arange(len(q)) % 2, "point", meta))
    s = jaxcal.measurement_for(data, paper_robot)
    m = s.measurement
    assert isinstance(m, jaxcal.FixedPoint) and m.sphere and not m.estimate_radius
    assert m.labels == ("p1", "p2")
    np.testing.assert_allclose(np.asarray(m.radii), [12.5, 12.5])
    assert s.estimate == {"tool"} and "radius 12.5 mm (known)" in s.notes[0]
    s = jaxcal.measurement_for(data, paper_robot, estimate="radius", radius_mm=10.0)
    assert s.measurement.estimate_radius and np.allclose(np.asarray(s.measurement.radii), 10.0)
    with pytest.raises(ValueError, match="--estimate base does not apply to point data"):
        jaxcal.measurement_for(data, paper_robot, estimate=["base"])


def _camera_data(meta, n=3):
    q = np.zeros((n, 6)) + np.linspace(0.1, 0.3, 6)  # a camera's set-up needs the image columns only
    y = np.random.default_rng(0).uniform(0, 1000, (n, 54, 2))
    return jaxcal.Dataset(q, y, "camera", meta)


def test_camera_meta_lines_make_the_camera(paper_robot, tmp_path):
    """The target, intrinsics, mount and image size come from the file's lines; keywords replace them."""
    meta = {"target": "checkerboard:9x6:20", "camera_intrinsics": "1000,1010,640,512,-0.05,0.02,0,0",
            "mount": "eye-to-hand", "image_size_px": "1280,1024"}
    s = jaxcal.measurement_for(_camera_data(meta), paper_robot, estimate="intrinsics")
    cam = s.measurement
    assert isinstance(cam, jaxcal.Camera) and cam.mount == "eye_to_hand" and cam.image_size == (1280, 1024)
    np.testing.assert_allclose(np.asarray(cam.intrinsics), [1000, 1010, 640, 512, -0.05, 0.02, 0, 0, 0])
    np.testing.assert_allclose(np.asarray(cam.points), np.asarray(jaxcal.checkerboard(9, 6, 20.0)))
    assert cam.calibrate_intrinsics and s.estimate == frozenset() and "intrinsics estimated" in s.notes[0]
    # a target file named relative to the data file is looked for next to it
    (tmp_path / "board.csv").write_text("x_mm,y_mm,z_mm\n" + "".join(f"{x},{y},0\n" for y in range(6) for x in range(9)))
    path = tmp_path / "images.csv"
    _camera_data({**meta, "target": "board.csv"}).to_csv(path)
    cam = jaxcal.measurement_for(jaxcal.load_csv(path), paper_robot, path=path).measurement
    np.testing.assert_allclose(np.asarray(cam.points), np.asarray(jaxcal.checkerboard(9, 6, 1.0)))
    other = jaxcal.measurement_for(_camera_data(meta), paper_robot, camera_intrinsics=(900, 900, 600, 500),
                                   mount="eye_in_hand")
    assert other.measurement.mount == "eye_in_hand"
    np.testing.assert_allclose(np.asarray(other.measurement.intrinsics)[:4], [900, 900, 600, 500])


def test_clear_errors(paper_robot, cable_rows):
    """A camera file without its target or intrinsics, an extra or option of another kind: ValueError
    naming what is missing or wrong."""
    with pytest.raises(ValueError, match="needs the target layout"):
        jaxcal.measurement_for(_camera_data({"camera_intrinsics": "1000,1000,640,512"}), paper_robot)
    with pytest.raises(ValueError, match="needs the camera's intrinsics"):
        jaxcal.measurement_for(_camera_data({"target": "checkerboard:9x6:20"}), paper_robot)
    with pytest.raises(ValueError, match="the target has 9 points but the data have image columns for 54"):
        jaxcal.measurement_for(_camera_data({"target": "checkerboard:3x3:20"}), paper_robot)
    with pytest.raises(ValueError, match="takes intrinsics only"):
        jaxcal.measurement_for(_camera_data({}), paper_robot, estimate="tool")
    q, y = cable_rows
    position = jaxcal.Dataset(q, np.zeros((len(q), 3)), "position")
    with pytest.raises(ValueError, match="--anchor applies to --measurement cable only"):
        jaxcal.measurement_for(position, paper_robot, anchor_mm=(1, 2, 3))
    with pytest.raises(ValueError, match="apply to --measurement cable only"):
        jaxcal.measurement_for(position, paper_robot, estimate="anchor")
    with pytest.raises(ValueError, match="the file's anchor_mm must be 3"):
        jaxcal.measurement_for(jaxcal.Dataset(q, y, "cable", {"anchor_mm": "1,2"}), paper_robot)
    with pytest.raises(ValueError, match="cannot be planned with"):
        jaxcal.block_from_file(jaxcal.Dataset(q, np.zeros((len(q), 2, 3)), "markers"), paper_robot, sigma=1.0)
