"""The recording's timelines and entity paths: a stable contract that scripts rely on.

No Rerun import here, so a program can name the paths without loading the SDK. The table of
what each path holds, its unit and its rate is in :mod:`viewer.recording`.
"""

from __future__ import annotations

APPLICATION_ID = "imucal"

# Timelines
TIME = "time"  # duration, seconds on the session's own clock
LAMBDA = "lambda"  # sequence: index into the L-curve's lambda grid (value in LAMBDA_LOG10)
ITERATION = "iteration"  # sequence: accepted Levenberg-Marquardt step, 0 = the start

# Signals on TIME
ACC_MAGNITUDE = "imu/accelerometer/magnitude"  # [raw, calibrated], full rate when still
ACC_RAW = "imu/accelerometer/raw"  # [x, y, z], raw unit, min/max envelope when long
ACC_CALIBRATED = "imu/accelerometer/calibrated"  # [x, y, z]
GYRO_MAGNITUDE = "imu/gyroscope/magnitude"  # [raw, calibrated], rad/s, envelope when long
GYRO_RAW = "imu/gyroscope/raw"
GYRO_CALIBRATED = "imu/gyroscope/calibrated"

DETECTOR_STATISTIC = "detector/statistic"  # log10 of s2 (M1)
DETECTOR_THRESHOLD = "detector/threshold"  # log10 of k * s2_init
DETECTOR_BLOCKS = "detector/blocks"  # StateChange "still" / reset
DETECTOR_SEGMENTS = "detector/segments"  # StateChange "segment i" / "between segments"

BLOCK_ERROR_BEFORE = "blocks/norm_error_mg/before"  # per static block, at its middle
BLOCK_ERROR_AFTER = "blocks/norm_error_mg/after"

GRAVITY = "gravity"  # the Spatial3DView's origin
GRAVITY_AXES = "gravity/axes"  # static body x, y, z axes
GRAVITY_PREVIOUS = "gravity/previous"  # u_(k-1), measured at the block before
GRAVITY_MEASURED = "gravity/measured"  # u_k
GRAVITY_PREDICTED_BEFORE = "gravity/predicted_before"  # R_k^T u_(k-1), raw gyroscope
GRAVITY_PREDICTED_AFTER = "gravity/predicted_after"  # R_k^T u_(k-1), calibrated gyroscope
GRAVITY_ANGLE_BEFORE = "gravity_angle/before"  # deg between measured and predicted
GRAVITY_ANGLE_AFTER = "gravity_angle/after"

# L-curve (static, Spatial2DView): x = log10 rho, y = -log10 eta (2D views draw y down)
LCURVE = "lcurve"
LCURVE_POINTS = "lcurve/points"
LCURVE_LINE = "lcurve/line"
LCURVE_CORNER = "lcurve/corner"  # Points2D + AnyValues(lambda, index, residual_norm, ...)
LCURVE_FRAME = "lcurve/frame"  # axes and decade tick labels


def lcurve_segment(i: int) -> str:
    """A segment's own L-curve, logged only when the session has more than one segment."""
    return f"lcurve/segment_{i}"


# Lambda sweep on LAMBDA (the whole-session fit's grid)
LAMBDA_LOG10 = "lambda/log10_lambda"
LAMBDA_STATIC_RMS = "lambda/static_norm_rms_mg"
LAMBDA_STATIC_MAX = "lambda/static_norm_max_mg"
LAMBDA_CHOSEN = "lambda/chosen"  # one row, at the corner: static_norm_rms_mg there
LAMBDA_RESIDUAL = "lambda/log10_residual_norm"
LAMBDA_SOLUTION = "lambda/log10_solution_norm"
LAMBDA_MISALIGNMENT = "lambda/accelerometer/misalignment"  # [a_yz, a_zy, a_zx] rad
LAMBDA_SCALE = "lambda/accelerometer/scale"  # [s_x, s_y, s_z]
LAMBDA_BIAS = "lambda/accelerometer/bias"  # [b_x, b_y, b_z] raw unit


def iteration(fit: str, sensor: str, what: str) -> str:
    """Optimiser trace on ITERATION: ``fit`` is ``segment_<i>`` (or ``whole`` for the first
    whole-session fit when it differs from segment 0), ``sensor`` ``accelerometer`` or
    ``gyroscope``, ``what`` one of ``log10_cost``, ``misalignment``, ``scale``, ``bias``."""
    return f"iteration/{fit}/{sensor}/{what}"


# Results (static)
SUMMARY = "calibration/summary"  # TextDocument, markdown
INFO = "calibration/info"  # AnyValues: source, units, lambda, warnings, ...
QUALITY = "calibration/quality"  # AnyValues: the quality figures, before/after


def calibration(i: int, sensor: str) -> str:
    """AnyValues with a segment's parameters: ``sensor`` ``accelerometer`` or ``gyroscope``."""
    return f"calibration/segment_{i}/{sensor}"


# Guide to the recording (Overview tab): Result.guide (imucal.stages.guide)
GUIDE = "guide"  # the sphere's Spatial3DView origin
GUIDE_SPHERE = "guide/sphere"  # static LineStrips3D: equator and meridians of the unit sphere
GUIDE_AXES = "guide/axes"  # static Arrows3D body x, y, z
GUIDE_POSES = "guide/poses"  # static Points3D: each still block's gravity direction (up axis)
GUIDE_MISSING = "guide/missing"  # static Points3D: sphere directions no pose comes near
GUIDE_NEXT = "guide/next"  # static Arrows3D: poses to record next, labelled "+x, -z"
GUIDE_HOLD = "guide_holds/duration_s"  # Scalars per block at its middle: duration, s
GUIDE_HOLD_NEAR_MIN = "guide_holds/near_minimum_s"  # the blocks near the minimum only
GUIDE_HOLD_MIN = "guide_holds/minimum_s"  # the detector's minimum, 2 rows (a line)
GUIDE_HOLD_WARN = "guide_holds/near_minimum_limit_s"  # NEAR_MIN_FACTOR x minimum, a line
GUIDE_TURN_RATE = "guide_turns/peak_rate"  # Scalars per turn at its middle: rad/s
GUIDE_TURN_FAST = "guide_turns/peak_rate_over_limit"  # the turns over the limit only
GUIDE_TURN_LIMIT = "guide_turns/rate_limit"  # rad/s, a line
GUIDE_TURN_TILT = "guide_turns/tilt_deg"  # gravity moved by each turn, deg
GUIDE_TURN_ANGLE = "guide_turns/angle_deg"  # integrated rotation angle, deg (NaN: none)
GUIDE_TURN_MIN_TILT = "guide_turns/min_tilt_deg"  # a line
GUIDE_INFO = "guide/info"  # static AnyValues: limits, their sources, the verdict
