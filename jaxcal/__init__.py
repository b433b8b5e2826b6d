"""jaxcal: kinematic calibration of industrial robots in JAX.

Differentiable batched DH kinematics, draw-wire / position / pose measurement models, the
simulated experiment of Chen & Li (AdaModW), identifiability analysis, measurement planning, and calibration methods
(LM, Gauss–Newton, AdaModW and other optax optimizers, population and filter baselines).

Float64: ``import jaxcal`` changes nothing global; call :func:`jaxcal.enable_x64` once at
program start (see ``jaxcal._precision`` for the policy).
"""

__version__ = "0.1.0"

__all__ = [
    "bucket_size",
    "set_buckets",
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


#: Every public name is imported on first use (PEP 562): ``import jaxcal`` imports neither JAX
#: nor any jaxcal module, so ``jaxcal --help`` (and a command that needs a part of the package)
#: pays only for what it uses; ``from jaxcal import calibrate`` imports the calibration modules.
#: ``name: (module, attribute or None for the module)``.
_LAZY = {
    'bucket_size': ('_buckets', 'bucket_size'),
    'set_buckets': ('_buckets', 'set_buckets'),
    'AccuracyCurve': ('_plan', 'AccuracyCurve'),
    'CableLength': ('_measurement', 'CableLength'),
    'CalibrationError': ('_calibrate', 'CalibrationError'),
    'CalibrationResult': ('_result', 'CalibrationResult'),
    'CalibrationWarning': ('_calibrate', 'CalibrationWarning'),
    'Calibrator': ('_calibrate', 'Calibrator'),
    'Checks': ('_diagnostics', 'Checks'),
    'DHRobot': ('_robot', 'DHRobot'),
    'DHTable': ('_result', 'DHTable'),
    'Dataset': ('_dataset', 'Dataset'),
    'Deviations': ('_params', 'Deviations'),
    'Diagnostics': ('_diagnostics', 'Diagnostics'),
    'Experiment': ('_simulate', 'Experiment'),
    'ExtrasEstimate': ('_initialise', 'ExtrasEstimate'),
    'IdentifiabilityReport': ('_identifiability', 'IdentifiabilityReport'),
    'KEEP_PREFERENCE': ('_identifiability', 'KEEP_PREFERENCE'),
    'Markers': ('_measurement', 'Markers'),
    'MassModel': ('_nongeometric', 'MassModel'),
    'MeasurementModel': ('_measurement', 'MeasurementModel'),
    'MessyExperiment': ('_messy', 'MessyExperiment'),
    'Metrics': ('_metrics', 'Metrics'),
    'ObservabilityIndices': ('_plan', 'ObservabilityIndices'),
    'PAPER_METHODS': ('_sweep', 'PAPER_METHODS'),
    'ParameterSpace': ('_params', 'ParameterSpace'),
    'Pose': ('_measurement', 'Pose'),
    'PoseSelection': ('_plan', 'PoseSelection'),
    'Position': ('_measurement', 'Position'),
    'PrecisionWarning': ('_precision', 'PrecisionWarning'),
    'PredictedAccuracy': ('_plan', 'PredictedAccuracy'),
    'Prior': ('_objective', 'Prior'),
    'PriorCV': ('_validation', 'PriorCV'),
    'Problem': ('_problem', 'Problem'),
    'SerialChain': ('_chain', 'SerialChain'),
    'SessionHoldout': ('_sessions', 'SessionHoldout'),
    'SessionMarkers': ('_sessions', 'SessionMarkers'),
    'Status': ('_result', 'Status'),
    'SweepResult': ('_sweep', 'SweepResult'),
    'Uncertainty': ('_diagnostics', 'Uncertainty'),
    'accuracy_curve': ('_plan', 'accuracy_curve'),
    'calibrate': ('_calibrate', 'calibrate'),
    'candidate_poses': ('_plan', 'candidate_poses'),
    'chain_from_dh': ('_urdf', 'chain_from_dh'),
    'compute_metrics': ('_metrics', 'compute_metrics'),
    'cross_validate_prior': ('_validation', 'cross_validate_prior'),
    'enable_x64': ('_precision', 'enable_x64'),
    'export_urdf': ('_urdf', 'export_urdf'),
    'fk_pose': ('_kinematics', 'fk_pose'),
    'fk_position': ('_kinematics', 'fk_position'),
    'format_table': ('_metrics', 'format_table'),
    'gravity_torques': ('_nongeometric', 'gravity_torques'),
    'holdout_session': ('_sessions', 'holdout_session'),
    'identifiability': ('_identifiability', 'identifiability'),
    'initial_extras': ('_initialise', 'initial_extras'),
    'initial_sessions': ('_sessions', 'initial_sessions'),
    'iterations_to_converge': ('_result', 'iterations_to_converge'),
    'leave_one_session_out': ('_sessions', 'leave_one_session_out'),
    'load_csv': ('_dataset', 'load_csv'),
    'load_result': ('_io', 'load_result'),
    'load_sweep': ('_sweep', 'load_sweep'),
    'load_urdf': ('_urdf', 'load_urdf'),
    'methods': ('methods', None),
    'observability_indices': ('_plan', 'observability_indices'),
    'optim': ('optim', None),
    'plots': ('plots', None),
    'pose_from_markers': ('_initialise', 'pose_from_markers'),
    'predicted_accuracy': ('_plan', 'predicted_accuracy'),
    'region_folds': ('_messy', 'region_folds'),
    'region_split': ('_messy', 'region_split'),
    'relaxed_design': ('_plan', 'relaxed_design'),
    'report': ('report', None),
    'residuals': ('_measurement', 'residuals'),
    'robots': ('robots', None),
    'save_csv': ('_dataset', 'save_csv'),
    'save_result': ('_io', 'save_result'),
    'select_poses': ('_plan', 'select_poses'),
    'simulate_experiment': ('_simulate', 'simulate_experiment'),
    'simulate_messy': ('_messy', 'simulate_messy'),
    'statistical_floor': ('_metrics', 'statistical_floor'),
    'sweep': ('_sweep', 'sweep'),
    'Camera': ('_camera', 'Camera'),
    'checkerboard': ('_camera', 'checkerboard'),
    'hand_eye_park': ('_camera', 'hand_eye_park'),
    'simulate_camera': ('_camera', 'simulate_camera'),
    'solve_pnp': ('_camera', 'solve_pnp'),
    'FixedPoint': ('_contact', 'FixedPoint'),
    'PlaneContact': ('_contact', 'PlaneContact'),
    'simulate_contact': ('_contact', 'simulate_contact'),
    'MEASURED_DEFAULTS': ('_objective', 'MEASURED_DEFAULTS'),
    'Evaluation': ('_evaluate', 'Evaluation'),
    'evaluate_result': ('_evaluate', 'evaluate_result'),
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        mod = importlib.import_module(f".{module}", __name__)
        value = mod if attr is None else getattr(mod, attr)
        globals()[name] = value
        return value
    if not name.startswith("__"):  # a submodule (jaxcal._simulate...): imported eagerly before
        import importlib

        try:
            return importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module 'jaxcal' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
