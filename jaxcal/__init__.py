"""jaxcal: kinematic calibration of industrial robots in JAX.

Differentiable batched DH kinematics, draw-wire / position / pose measurement models, the
simulated experiment of Chen & Li (AdaModW), identifiability analysis, measurement planning, and calibration methods
(LM, Gauss–Newton, AdaModW and other optax optimizers, population and filter baselines).

Float64: ``import jaxcal`` changes nothing global; call :func:`jaxcal.enable_x64` once at
program start (see ``jaxcal._precision`` for the policy).
"""

from . import methods as methods
from . import optim as optim
from . import plots as plots
from . import report as report
from . import robots as robots
from ._calibrate import CalibrationError as CalibrationError
from ._calibrate import CalibrationWarning as CalibrationWarning
from ._calibrate import Calibrator as Calibrator
from ._calibrate import calibrate as calibrate
from ._chain import SerialChain as SerialChain
from ._dataset import Dataset as Dataset
from ._dataset import load_csv as load_csv
from ._dataset import save_csv as save_csv
from ._diagnostics import Checks as Checks
from ._diagnostics import Diagnostics as Diagnostics
from ._diagnostics import Uncertainty as Uncertainty
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
from ._messy import MessyExperiment as MessyExperiment
from ._messy import region_folds as region_folds
from ._messy import region_split as region_split
from ._messy import simulate_messy as simulate_messy
from ._metrics import Metrics as Metrics
from ._metrics import compute_metrics as compute_metrics
from ._metrics import format_table as format_table
from ._metrics import statistical_floor as statistical_floor
from ._nongeometric import MassModel as MassModel
from ._nongeometric import gravity_torques as gravity_torques
from ._objective import Prior as Prior
from ._params import Deviations as Deviations
from ._params import ParameterSpace as ParameterSpace
from ._plan import AccuracyCurve as AccuracyCurve
from ._plan import ObservabilityIndices as ObservabilityIndices
from ._plan import PoseSelection as PoseSelection
from ._plan import PredictedAccuracy as PredictedAccuracy
from ._plan import accuracy_curve as accuracy_curve
from ._plan import candidate_poses as candidate_poses
from ._plan import observability_indices as observability_indices
from ._plan import predicted_accuracy as predicted_accuracy
from ._plan import relaxed_design as relaxed_design
from ._plan import select_poses as select_poses
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
from ._sweep import PAPER_METHODS as PAPER_METHODS
from ._sweep import SweepResult as SweepResult
from ._sweep import sweep as sweep
from ._urdf import chain_from_dh as chain_from_dh
from ._urdf import export_urdf as export_urdf
from ._urdf import load_urdf as load_urdf
from ._validation import PriorCV as PriorCV
from ._validation import cross_validate_prior as cross_validate_prior

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
    "SessionMarkers",
    "SessionHoldout",
    "holdout_session",
    "initial_sessions",
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
