"""What one kind of measured data is, in one place: :class:`SensorKind` and the registry of
kinds by name.

A kind of data (``"cable"``, ``"position"``, ``"pose"``, ``"markers"``, ``"camera"``,
``"plane"``, ``"point"``, ``"distance"``) is the ``kind`` of a :class:`~jaxcal.Dataset`, the
``# kind:`` line of a data file and the ``--measurement`` name of the command line. Its
:class:`SensorKind` says what that means for a data file: which value columns it has and how
they are read and written, the shape of one reading and what is checked in it, and which text
columns (labels) it keeps. The sensor's own module defines its kind next to its measurement
model (the camera's in ``_camera``, the contact kinds in ``_contact``, ...) and registers it with
:func:`register_kind`; the data sets, the CSV reader and writer loop over the registry instead
of comparing kind names.

Kinds are looked up lazily: :func:`sensor_kind` imports only the module of the kind asked for
(``_BUILTIN``), as :mod:`jaxcal.methods` does for its methods, so reading a draw-wire file
imports no camera code. Adding a sensor: define its :class:`SensorKind` subclass in the sensor's
module, decorate it with :func:`register_kind`, and add one line to ``_BUILTIN``. This module
imports no NumPy (the command line's parser reads :func:`kind_names` for ``jaxcal --help``).
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import TYPE_CHECKING, ClassVar

if TYPE_CHECKING:  # the registry's names are read by the command line's parser, which imports no NumPy
    import re

    import numpy as np

__all__ = ["SensorKind", "PointsKind", "SetupOptions", "register_kind", "sensor_kind", "sensor_kinds", "kind_names", "resolve_hook",
           "check_label", "check_tip", "resolve_tip", "simulated_kind_names", "plannable_kind_names"]

#: built-in kinds and the module (in this package) that defines each, in the order in which a
#: file without a ``# kind:`` line is recognised from its columns (the first whose columns are
#: all there wins: a pose file also has a position's columns).
_BUILTIN: dict[str, str] = {
    "distance": "_contact", "markers": "_sessions", "camera": "_camera", "plane": "_contact",
    "point": "_contact", "pose": "_measurement", "position": "_measurement", "cable": "_measurement",
    "self_contact": "_self_contact",
}
_REGISTRY: dict[str, SensorKind] = {}
#: what the command line offers of each built-in kind, in the order of its menus, known without
#: importing the kind's module (``jaxcal --help`` imports no NumPy): ``(simulated, plannable)``,
#: i.e. whether the kind names a :attr:`SensorKind.simulator` (``jaxcal simulate``) and is
#: :attr:`SensorKind.plannable` (``jaxcal plan``). ``tests/sensors/test_kinds.py`` keeps it equal
#: to the kind classes.
_OFFERED: dict[str, tuple[bool, bool]] = {
    "cable": (True, True), "position": (True, True), "pose": (True, True), "camera": (True, True),
    "plane": (True, True), "point": (True, True), "distance": (True, True), "self_contact": (True, False),
    "markers": (False, False),
}

#: every extra ``jaxcal calibrate --estimate`` names, whatever the kind (a kind takes some of them)
ESTIMATE_NAMES = frozenset({"anchor", "tool", "offset", "cable_offset", "base"})


@dataclasses.dataclass(frozen=True)
class SetupOptions:
    """The set-up of a data file that is not in its rows, as ``jaxcal calibrate``'s options give it
    (``None``: not given; the kind then reads the file's ``#`` metadata line or takes its default).

    Attributes:
        anchor_mm: draw-wire data: the anchor ``(x, y, z)`` mm in the base frame (``--anchor``).
        radius_mm: point data as spheres: sphere radius plus ball radius, mm (``--radius-mm``).
        estimate_radius: point data: the radius is estimated (``--estimate radius``).
        target, camera_intrinsics, mount: camera data (``--target``, ``--camera``, ``--mount``).
        path: the file the data came from (messages; a relative target file is looked for beside it).
    """

    anchor_mm: tuple[float, float, float] | None = None
    radius_mm: float | None = None
    estimate_radius: bool = False
    target: object = None
    camera_intrinsics: object = None
    mount: str | None = None
    path: object = None


class SensorKind:
    """One kind of measured data: its name, its data-file columns (read and written), the shape
    of one reading and what is checked in it.

    A subclass sets the class attributes and overrides what differs from the default, which is a
    kind with fixed numeric value columns (``columns``) whose readings are those numbers
    (``[n]`` for one column, else ``[n, k]``). Instances hold no state; the registry keeps one.

    Attributes:
        name: the kind's name (``Dataset.kind``, the ``# kind:`` line, ``--measurement``).
        columns: fixed value columns of a data file, in order (``("length_mm",)``); ``()`` for
            kinds whose columns depend on the file (markers, camera) or that have none (labels).
        noise_unit: the unit of a reading's noise σ (``"mm"``; a camera's ``"px"``): the file's
            ``# noise_std_<unit>:`` line.
        session_labels: rows may carry ``(session, frame, placement)`` labels
            (:attr:`jaxcal.Dataset.labels`).
        own_table: the file has joint columns of its own (a distance bar's two poses per row):
            the kind reads and writes the whole table (:meth:`read_table`, :meth:`write_file`).
        plannable: a file of this kind can be a block of a plan or a combined fit
            (:func:`jaxcal.block_from_file`); marker data, whose frames and marker positions are
            per file, cannot.
        labelled: each row names the object the probe touched (a plane, a point): a new file's
            labels are matched to a model's by name (:func:`jaxcal._datasets._dataset.relabel`).
        fleet: several files of this kind are units of a fleet (:func:`jaxcal.calibrate_many`,
            ``jaxcal calibrate`` of several files): one sensor set-up shared by every unit.
        simulator: the function that simulates a data file of this kind (``jaxcal simulate``,
            :func:`jaxcal._simulation._simulate_files.simulate_file`), named
            ``"module:function"`` (a module of this package), or ``None``: the kind is not
            simulated (marker data). The name is the hook: the simulation sits on a floor above
            the sensors and is imported by :func:`~jaxcal._simulation._simulate_files.simulate_file`,
            never from here. It is called as ``function(kind, request)`` with a
            :class:`~jaxcal._simulation._simulate_files.FileRequest` and returns a
            :class:`~jaxcal._simulation._simulate_files.SimulatedFile` (the rows with their set-up
            lines, such as a tree tip's ``# tip:``, and the words that describe them).
        planner: the function that makes this kind's planning candidates (``jaxcal plan``,
            :func:`jaxcal.candidate_poses`), named ``"module:function"`` as :attr:`simulator` is
            (the same hook: planning sits above the sensors), for a sensor whose candidates are
            more than joint angles (poses that touch a plane, bar pose pairs, poses that see a
            target); ``None``: random joint angles within the limits and the sensor's range
            (the workspace filters of :func:`~jaxcal._experiments._plan.candidate_poses`). It is
            called as ``function(key, robot, measurement, n, **options)`` with every option of
            ``candidate_poses`` and returns the candidates.
        plan_compressed: the planning selection works on each candidate's information
            ``J_kᵀJ_k`` through the ``R`` factor of its Jacobian rows
            (:func:`~jaxcal._experiments._plan._compress`): for a kind with many rows per
            reading (a camera image's ``2N``); the others keep their few rows as they are.
        plan_next: what to do with a planned poses file, in the words of ``jaxcal plan``'s last line.
        counts_markers: ``jaxcal calibrate --markers N`` (the number of points a reading of the file
            has, :func:`jaxcal.load_csv`'s ``n_markers``) applies to this kind (marker data).
        messy: the messy real-world session simulator of this kind (:func:`jaxcal.simulate_messy`),
            named ``"module:object"`` (the same hook as :attr:`simulator`), or ``None``: not offered.
    """

    name: ClassVar[str]
    columns: ClassVar[tuple[str, ...]] = ()
    noise_unit: ClassVar[str] = "mm"
    session_labels: ClassVar[bool] = False
    own_table: ClassVar[bool] = False
    plannable: ClassVar[bool] = True
    fleet: ClassVar[bool] = False
    labelled: ClassVar[bool] = False
    simulator: ClassVar[str | None] = None
    planner: ClassVar[str | None] = None
    plan_compressed: ClassVar[bool] = False
    plan_next: ClassVar[str] = "fill in the readings"
    counts_markers: ClassVar[bool] = False
    messy: ClassVar[str | None] = None

    # -- planning (jaxcal plan) -----------------------------------------------------------------
    def planning_model(self, robot, *, anchor_mm=None, mount: str = "eye_in_hand"):
        """The measurement model ``jaxcal plan`` plans for, before any reading exists: the kind's
        default set-up (:meth:`default_model`; ``anchor_mm``: a draw wire's anchor). A camera's
        takes its nominal frames from the simulation's set-up (``mount``)."""
        return self.default_model(robot, anchor_mm=anchor_mm)

    def plan_lines(self, model) -> dict:
        """The set-up lines (``{key: text}``) of a planned poses file of ``model`` (the draw wire's
        anchor, the labels, a camera's target): what ``jaxcal calibrate`` reads back with the
        readings. None by default."""
        return {}

    def plan_readings(self, model, n: int):
        """The empty readings (NaN) of ``n`` planned poses of a kind with a :attr:`planner` whose
        candidates are joint angles only (a camera's ``[n, N, 2]``), written as empty cells."""
        raise NotImplementedError(f"{self.name} plans have their candidates' readings")

    # -- reading a file ------------------------------------------------------------------------
    def found_in(self, header) -> bool:
        """Whether a file with these column names (no ``# kind:`` line) holds this kind of data."""
        return bool(self.columns) and all(c in header for c in self.columns)

    def column_hint(self) -> str:
        """The value columns in words, for the message of a file with none."""
        return ",".join(self.columns)

    def value_columns(self, path, header, n_points: int | None = None) -> list[str]:
        """The value columns to read from a file with ``header``.

        Args:
            path: the file, for messages.
            header: its column names (stripped, lower case).
            n_points: the number of markers / target points expected, or ``None``.

        Raises:
            ValueError: ``n_points`` given for a kind without points, or not the file's.
        """
        if n_points is not None:
            raise ValueError(f"{path}: n_markers applies to marker (and camera) data, not {self.name!r}")
        return list(self.columns)

    def label_columns(self, path, header) -> list[str]:
        """The text columns of ``header`` this kind reads (labels), beside its value columns.

        Raises:
            ValueError: a text column the kind needs is missing.
        """
        return []

    def read_values(self, table, columns: list[str]) -> np.ndarray:
        """``[n_rows, len(columns)]`` float64 values of ``columns`` (a bad cell is an error naming
        row, line and column)."""
        return table.floats(columns)

    def readings(self, values: np.ndarray, path, table, meta: dict) -> tuple[np.ndarray, dict, tuple]:
        """``(y, meta, labels)`` from the value cells ``[n, k]``: the readings in the layout of
        :attr:`jaxcal.Dataset.y`, the metadata (with anything the kind reads from its text
        columns), and the per-row session labels (``()`` for none)."""
        return (values[:, 0] if values.shape[1] == 1 else values), meta, ()

    def read_table(self, path, table, meta: dict, dof: int | None) -> tuple[np.ndarray, np.ndarray]:
        """``(q, y)`` of a file of a kind with :attr:`own_table` (the whole table, joint columns too)."""
        raise NotImplementedError(f"{self.name} data files have the common joint columns")

    # -- writing a file ------------------------------------------------------------------------
    def write_values(self, data) -> tuple[list[str], np.ndarray, list[str], list[list[str]]]:
        """``(value columns, values [n, k] float64, text columns, text cells [n][...])`` of a
        :class:`~jaxcal.Dataset` of this kind for its data file. NaN values are written as empty
        cells."""
        import numpy as np

        y = np.asarray(data.y, np.float64)
        return list(self.columns), y.reshape(y.shape[0], -1), [], [[] for _ in range(y.shape[0])]

    def write_file(self, data, path, angle_unit: str) -> None:
        """Write the whole data file of a kind with :attr:`own_table`."""
        raise NotImplementedError(f"{self.name} data files have the common joint columns")

    # -- a measurement model as plain data (result files) -----------------------------------------
    def model_to_dict(self, model) -> dict:
        """``model`` (a measurement model of this kind) as JSON-able plain data with its ``"kind"``."""
        raise TypeError(f"cannot serialise measurement model {type(model).__name__}")

    def model_from_dict(self, d: dict):
        """The measurement model of :meth:`model_to_dict`'s plain data ``d``."""
        raise ValueError(f"unknown measurement kind {self.name!r}")

    # -- a data file's set-up (jaxcal calibrate, jaxcal.measurement_for) -------------------------
    def check_options(self, estimate: set[str], options: SetupOptions) -> None:
        """Refuse what does not apply to this kind: extras of ``--estimate`` (names as the command
        line takes them: ``anchor``, ``offset``, ``tool``, ``base``) and options of other kinds.
        The default takes ``tool`` and ``base`` and no other kind's option.

        Raises:
            ValueError: naming the option and the kinds it applies to.
        """
        self.refuse_point_options(options)
        self.check_estimate_names(estimate)
        self.refuse_anchor(options.anchor_mm)

    @staticmethod
    def refuse_point_options(options: SetupOptions) -> None:
        """Raises ValueError: a sphere radius given or estimated (point data only)."""
        if options.radius_mm is not None or options.estimate_radius:
            raise ValueError("--radius-mm and --estimate radius apply to --measurement point only")

    def check_estimate_names(self, estimate: set[str]) -> None:
        """Raises ValueError: a name ``--estimate`` does not know, or the draw wire's ``anchor`` /
        ``offset`` for another kind."""
        bad = estimate - ESTIMATE_NAMES
        if bad:
            raise ValueError(f"--estimate takes anchor, offset, tool (cable) or base, tool (position); got {sorted(bad)}")
        if estimate & {"anchor", "offset", "cable_offset"}:
            raise ValueError("--estimate anchor/offset apply to --measurement cable only")

    def required_extras(self, estimate: set[str], *, anchor_known: bool = True, sessions: bool = False,
                        sphere: bool = False, estimate_radius: bool = False,
                        radius_mm: float | None = None) -> tuple[set[str], list[str]]:
        """``(extras, notes)``: the extras to estimate, those asked for (``estimate``, names as
        ``--estimate`` takes them) plus those this kind of data cannot do without, and one note
        per extra added (in the command line's words). The default adds nothing.

        Args:
            estimate: the extras asked for (already checked, :meth:`check_options`).
            anchor_known: draw-wire data: the anchor is known (given, or the file's line).
            sessions: marker data of several sessions (every session frame is estimated anyway).
            sphere, estimate_radius, radius_mm: point data as spheres: the radius estimated, or
                known (``radius_mm``); only for the notes.
        """
        return set(estimate), []

    def default_model(self, robot, *, data=None, anchor_mm=None, n_markers: int | None = None):
        """The measurement model of this kind with its set-up unknown or at a default (the start
        of a calibration, or a simulation's set-up without ``data``)."""
        raise ValueError(f"{self.name} data need their set-up; see jaxcal.measurement_for")

    @staticmethod
    def refuse_anchor(anchor_mm) -> None:
        """Raises ValueError: a draw-wire anchor given for another kind."""
        if anchor_mm is not None:
            raise ValueError("--anchor applies to --measurement cable only")

    def setup(self, data, robot, estimate: set[str], options: SetupOptions):
        """``(model, extras, notes)`` of a loaded data file: its measurement model (the set-up from
        ``options`` or the file's metadata lines, the unknowns at their start), the extras to
        estimate (:meth:`required_extras`) and the notes for the user.

        Raises:
            ValueError: an option or extra that does not apply (:meth:`check_options`), a
                malformed metadata line.
        """
        self.check_options(estimate, options)
        estimate, notes = self.required_extras(estimate)
        return self.default_model(robot, data=data), estimate, notes

    def at_file_tip(self, model, data, robot):
        """``model`` seeing the tip the file's ``# tip: NAME`` line names (:func:`resolve_tip`:
        ``tip=None`` for the robot's default tip); ``model`` itself without the line, or for a
        model that names no tip (:class:`~jaxcal.SelfContact` names its two with ``# tips:``).

        Raises:
            ValueError: a tip the robot does not have; the message lists its tips.
        """
        name = str(data.meta.get("tip", "")).strip()
        if not name or not hasattr(model, "tip"):
            return model
        try:
            tip = resolve_tip(robot, name)
        except ValueError as e:
            raise ValueError(f"the data file's '# tip: {name}' line: {e}") from None
        return model.at_tip(tip)

    def spheres(self, model, radius_mm: float | None, estimate_radius: bool):
        """``model`` as spheres of radius ``radius_mm`` (point data only).

        Raises:
            ValueError: this kind has no spheres.
        """
        raise ValueError("--radius-mm and --estimate radius apply to --measurement point only")

    def n_points(self, y) -> int | None:
        """The number of points per reading of ``y`` (markers, target points), where the file's
        columns depend on it; ``None`` for a kind with fixed columns. A second file of one set-up
        must have as many (``load_csv(..., n_markers=)``)."""
        return None

    # -- checks ---------------------------------------------------------------------------------
    def sample_shape(self, dof: int) -> tuple[int, ...]:
        """The shape of one reading of a robot with ``dof`` joints (fixed-size kinds)."""
        return () if len(self.columns) == 1 else (len(self.columns),)

    def checked_readings(self, y: np.ndarray, n: int, dof: int) -> np.ndarray:
        """``y`` with the entries the kind masks (a corner not detected, a marker missing) set to
        0, after checking its shape; the caller then refuses NaN/inf in what is left.

        Raises:
            ValueError: a shape other than ``[n, *sample_shape]``, or readings the kind refuses.
        """
        want = (n, *self.sample_shape(dof))
        if y.shape != want:
            raise ValueError(f"{self.name} measurements must have shape {list(want)}, got {list(y.shape)}")
        return y


class PointsKind(SensorKind):
    """A kind whose readings are ``N`` points of :attr:`width` coordinates each, ``N`` from the
    file (marker positions, a camera's image points): columns :meth:`point_columns`, recognised
    by :attr:`pattern` (the point's number in its group :attr:`number_group`); an empty cell is a
    point not seen (NaN; the model masks it), and the ``width`` cells of one point are empty
    together. Readings ``[n, N, width]``.

    Attributes:
        pattern, number_group: a column name of a point, and the regex group of its 1-based number.
        width: coordinates per point.
        columns_word, expected_hint, count_word: for the messages of a file without point
            columns or with another number of points than expected.
    """

    pattern: ClassVar[re.Pattern]
    number_group: ClassVar[int]
    width: ClassVar[int]
    columns_word: ClassVar[str]
    expected_hint: ClassVar[str]
    count_word: ClassVar[str]

    def point_columns(self, n_points: int) -> list[str]:
        """The value columns of ``n_points`` points, in file order."""
        raise NotImplementedError

    def found_in(self, header) -> bool:
        return any(self.pattern.fullmatch(h) for h in header)

    def column_hint(self) -> str:
        return ",".join(self.point_columns(1)[:2]) + ",..."

    def value_columns(self, path, header, n_points=None):
        found = [int(m[self.number_group]) for m in (self.pattern.fullmatch(h) for h in header) if m]
        if not found:
            raise ValueError(f"{path}: no {self.columns_word} columns (expected {self.expected_hint}); "
                             f"header: {list(header)}")
        n = max(found)
        if n_points is not None and n != n_points:
            raise ValueError(f"{path}: file has {n} {self.count_word} but {n_points} were expected")
        return self.point_columns(n)

    def n_points(self, y) -> int | None:
        import numpy as np

        return int(np.shape(y)[1])

    def read_values(self, table, columns):
        from .._core._csvfile import gap_floats

        return gap_floats(table, columns, self.width)

    def readings(self, values, path, table, meta):
        return values.reshape(values.shape[0], -1, self.width), meta, ()

    def write_values(self, data):
        import numpy as np

        y = np.asarray(data.y, np.float64)
        return self.point_columns(y.shape[1]), y.reshape(y.shape[0], -1), [], [[] for _ in range(y.shape[0])]


def register_kind(cls: type[SensorKind]) -> type[SensorKind]:
    """Class decorator: register ``cls`` (a :class:`SensorKind` subclass) under ``cls.name``."""
    if not (isinstance(cls, type) and issubclass(cls, SensorKind)):
        raise TypeError(f"register_kind takes a SensorKind subclass, got {cls!r}")
    _REGISTRY[cls.name] = cls()
    return cls


def kind_names() -> tuple[str, ...]:
    """The names of every kind (built-in first, in recognition order), without importing any."""
    return tuple(dict.fromkeys([*_BUILTIN, *_REGISTRY]))


def _offered(which: int) -> tuple[str, ...]:
    added = [k for k in _REGISTRY if k not in _OFFERED]  # registered at run time: their classes say
    flag = ((lambda k: k.simulator is not None), (lambda k: k.plannable))[which]
    return tuple([k for k, v in _OFFERED.items() if v[which]] + [k for k in added if flag(_REGISTRY[k])])


def simulated_kind_names() -> tuple[str, ...]:
    """The kinds ``jaxcal simulate`` writes (a :attr:`SensorKind.simulator`), without importing any
    built-in kind's module."""
    return _offered(0)


def plannable_kind_names() -> tuple[str, ...]:
    """The kinds ``jaxcal plan`` plans (:attr:`SensorKind.plannable`), without importing any
    built-in kind's module."""
    return _offered(1)


def sensor_kind(name: str, what: str = "measurement kind") -> SensorKind:
    """The :class:`SensorKind` called ``name`` (its module imported on first use).

    Raises:
        ValueError: no kind of that name; the message lists the kinds.
    """
    kind = _REGISTRY.get(name)
    if kind is None and name in _BUILTIN:
        importlib.import_module(f"{__package__}.{_BUILTIN[name]}")
        kind = _REGISTRY.get(name)
    if kind is None:
        raise ValueError(f"unknown {what} {name!r}; expected one of {list(kind_names())}")
    return kind


def resolve_hook(spec: str):
    """The object a kind's hook names (:attr:`SensorKind.simulator`, ``planner``, ``messy``):
    ``"module:name"``, the module imported on first use (a higher floor's code, which the sensors
    must not import at module level)."""
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)


def sensor_kinds() -> tuple[SensorKind, ...]:
    """Every kind, in recognition order (imports every kind's module)."""
    return tuple(sensor_kind(k) for k in kind_names())


def check_tip(robot, tip: str | None) -> str | None:
    """``tip`` (a tip of a :class:`~jaxcal.KinematicTree` other than its default one, or ``None``:
    the robot's default tip) checked against ``robot``, as the kinematics take it.

    Raises:
        ValueError: a tip the robot does not have (the message lists its tips), or the robot's
            default tip named (its tool point is the standard ``tool`` group: ``tip=None``).
    """
    if tip is None:
        return None
    have = tuple(robot.tip_names())
    if tip not in have:
        tips = list(have) if have else "none (it has one tool point)"
        raise ValueError(f"tip {tip!r} is not a tip of robot {robot.name!r}; its tips: {tips} (a URDF robot with "
                         "several tips: --tip A,B on the command line, load_urdf's tips argument in Python)")
    if tip == have[0]:
        raise ValueError(f"tip {tip!r} is robot {robot.name!r}'s default tip: a model sees it when it names no tip "
                         "(its tool point is the standard tool group); jaxcal.resolve_tip(robot, name) gives the "
                         "model's tip for a tip's name")
    return tip


def resolve_tip(robot, tip: str | None) -> str | None:
    """The ``tip=`` of a measurement model that sees the tip called ``tip`` of ``robot``: ``None``
    for ``None`` or the robot's default tip (``robot.tip_names()[0]``; a serial chain's own tip
    link), else the name, checked.

    Raises:
        ValueError: a tip the robot does not have; the message lists its tips.
    """
    if tip is None:
        return None
    if tip == robot.default_tip():  # a tree's first tip, a serial chain's own tip link
        return None
    return check_tip(robot, tip)


def check_label(label) -> str:
    """A row label (a plane's or point's name, a block's name) as text without the characters the
    data files and parameter names use as separators.

    Raises:
        ValueError: empty, surrounding spaces, or one of ``@``, ``,``, a line break.
    """
    s = str(label).strip()
    if not s or any(c in s for c in "@,\n\r") or s != str(label):
        raise ValueError(f"label {label!r} must be a non-empty string without '@', ',', line breaks or "
                         "surrounding spaces")
    return s
