"""jaxcal: kinematic calibration of industrial robots in JAX.

Differentiable batched DH kinematics, draw-wire / position / pose measurement models, the
simulated experiment of Chen & Li (AdaModW), identifiability analysis, measurement planning, and calibration methods
(LM, Gauss–Newton, AdaModW and other optax optimizers, population and filter baselines).

Float64: ``import jaxcal`` changes nothing global; call :func:`jaxcal.enable_x64` once at
program start (see ``jaxcal._precision`` for the policy).
"""

from . import methods as methods
from . import optim as optim
from . import robots as robots
from ._calibrate import CalibrationError as CalibrationError
from ._calibrate import CalibrationWarning as CalibrationWarning
from ._calibrate import Calibrator as Calibrator
from ._calibrate import calibrate as calibrate
from ._camera import Camera as Camera
from ._camera import checkerboard as checkerboard
from ._camera import hand_eye_park as hand_eye_park
from ._camera import simulate_camera as simulate_camera
from ._camera import solve_pnp as solve_pnp
from ._chain import SerialChain as SerialChain
from ._contact import FixedPoint as FixedPoint
from ._contact import PlaneContact as PlaneContact
from ._contact import simulate_contact as simulate_contact
from ._dataset import Dataset as Dataset
from ._dataset import load_csv as load_csv
from ._dataset import save_csv as save_csv
from ._diagnostics import Checks as Checks
from ._diagnostics import Diagnostics as Diagnostics
from ._diagnostics import Uncertainty as Uncertainty
from ._evaluate import MEASURED_DEFAULTS as MEASURED_DEFAULTS
from ._evaluate import Evaluation as Evaluation
from ._evaluate import evaluate_result as evaluate_result
from ._identifiability import KEEP_PREFERENCE as KEEP_PREFERENCE
from ._identifiability import IdentifiabilityReport as IdentifiabilityReport
from ._identifiability import identifiability as identifiability
from ._initialise import ExtrasEstimate as ExtrasEstimate
from ._initialise import initial_extras as initial_extras
from ._initialise import pose_from_markers as pose_from_markers
from ._io import load_result as load_result
from ._io import load_sweep as load_sweep
from ._io import save_result as save_result
from ._kinematics import fk_pose as fk_pose
from ._kinematics import fk_position as fk_position
from ._measurement import CableLength as CableLength
from ._measurement import Markers as Markers
from ._measurement import MeasurementModel as MeasurementModel
from ._measurement import Pose as Pose
from ._measurement import Position as Position
from ._measurement import residuals as residuals
from ._metrics import Metrics as Metrics
from ._metrics import compute_metrics as compute_metrics
from ._metrics import format_table as format_table
from ._metrics import statistical_floor as statistical_floor
from ._nongeometric import MassModel as MassModel
from ._nongeometric import gravity_torques as gravity_torques
from ._objective import Prior as Prior
from ._params import Deviations as Deviations
from ._params import ParameterSpace as ParameterSpace
from ._precision import PrecisionWarning as PrecisionWarning
from ._precision import enable_x64 as enable_x64
from ._problem import Problem as Problem
from ._result import CalibrationResult as CalibrationResult
from ._result import DHTable as DHTable
from ._result import Status as Status
from ._result import iterations_to_converge as iterations_to_converge
from ._robot import DHRobot as DHRobot
from ._sessions import SessionHoldout as SessionHoldout
from ._sessions import SessionMarkers as SessionMarkers
from ._sessions import holdout_session as holdout_session
from ._sessions import initial_sessions as initial_sessions
from ._sessions import leave_one_session_out as leave_one_session_out
from ._simulate import Experiment as Experiment
from ._simulate import simulate_experiment as simulate_experiment
from ._urdf import chain_from_dh as chain_from_dh
from ._urdf import export_urdf as export_urdf
from ._urdf import load_urdf as load_urdf

__version__ = "0.1.0"

__all__ = [
    "SerialChain",
    "chain_from_dh",
    "export_urdf",
    "load_urdf",
    "AccuracyCurve",
    "ObservabilityIndices",
    "accuracy_curve",
    "PoseSelection",
    "PredictedAccuracy",
    "candidate_poses",
    "observability_indices",
    "predicted_accuracy",
    "relaxed_design",
    "select_poses",
    "MessyExperiment",
    "PriorCV",
    "cross_validate_prior",
    "region_folds",
    "region_split",
    "simulate_messy",
    "Checks",
    "Diagnostics",
    "ExtrasEstimate",
    "Prior",
    "Uncertainty",
    "initial_extras",
    "pose_from_markers",
    "PAPER_METHODS",
    "SweepResult",
    "load_result",
    "load_sweep",
    "plots",
    "report",
    "save_result",
    "sweep",
    "CalibrationError",
    "CalibrationResult",
    "CalibrationWarning",
    "Calibrator",
    "Status",
    "calibrate",
    "iterations_to_converge",
    "methods",
    "optim",
    "CableLength",
    "DHRobot",
    "Dataset",
    "Deviations",
    "Experiment",
    "IdentifiabilityReport",
    "MeasurementModel",
    "Metrics",
    "ParameterSpace",
    "Markers",
    "Camera",
    "checkerboard",
    "hand_eye_park",
    "simulate_camera",
    "solve_pnp",
    "SessionMarkers",
    "PlaneContact",
    "FixedPoint",
    "simulate_contact",
    "SessionHoldout",
    "holdout_session",
    "initial_sessions",
    "MEASURED_DEFAULTS",
    "Evaluation",
    "evaluate_result",
    "leave_one_session_out",
    "Pose",
    "Position",
    "PrecisionWarning",
    "Problem",
    "compute_metrics",
    "enable_x64",
    "fk_pose",
    "fk_position",
    "format_table",
    "identifiability",
    "KEEP_PREFERENCE",
    "MassModel",
    "gravity_torques",
    "DHTable",
    "load_csv",
    "residuals",
    "robots",
    "save_csv",
    "simulate_experiment",
    "statistical_floor",
]


#: Names imported on first use (PEP 562): the sweep, planning, messy-data, cross-validation,
#: report and plot modules are not needed to calibrate, and importing them with the package cost
#: ~0.1 s of every command-line call. ``name: (module, attribute or None for the module)``.
_LAZY = {
    'AccuracyCurve': ('_plan', 'AccuracyCurve'),
    'MessyExperiment': ('_messy', 'MessyExperiment'),
    'ObservabilityIndices': ('_plan', 'ObservabilityIndices'),
    'PAPER_METHODS': ('_sweep', 'PAPER_METHODS'),
    'PoseSelection': ('_plan', 'PoseSelection'),
    'PredictedAccuracy': ('_plan', 'PredictedAccuracy'),
    'PriorCV': ('_validation', 'PriorCV'),
    'SweepResult': ('_sweep', 'SweepResult'),
    'accuracy_curve': ('_plan', 'accuracy_curve'),
    'candidate_poses': ('_plan', 'candidate_poses'),
    'cross_validate_prior': ('_validation', 'cross_validate_prior'),
    'observability_indices': ('_plan', 'observability_indices'),
    'plots': ('plots', None),
    'predicted_accuracy': ('_plan', 'predicted_accuracy'),
    'region_folds': ('_messy', 'region_folds'),
    'region_split': ('_messy', 'region_split'),
    'relaxed_design': ('_plan', 'relaxed_design'),
    'report': ('report', None),
    'select_poses': ('_plan', 'select_poses'),
    'simulate_messy': ('_messy', 'simulate_messy'),
    'sweep': ('_sweep', 'sweep'),
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        mod = importlib.import_module(f".{module}", __name__)
        value = mod if attr is None else getattr(mod, attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'jaxcal' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
