"""The recording's timelines and entity paths: a stable contract that scripts rely on.

No Rerun import here, so a program can name the paths without loading the SDK. The table of
what each path holds, its unit and its rate is in :mod:`viewer.recording`.
"""

from __future__ import annotations

APPLICATION_ID = "imucal"

# Timeline: the only one. The L-curve sweep and the optimiser's steps are plotted against
# their own axis (lambda, step) as 2D plots, so every view shows data on it.
TIME = "time"  # duration, seconds on the session's own clock

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

# 2D plots (static, Spatial2DView, :mod:`viewer.plot2d`): a plot's frame at <plot>/frame, its
# series at <plot>/<series> as Points2D at the data's own (x, y) (log10 of the value on a log
# axis, a Transform3D to the plot's scene) with AnyValues holding the values themselves, its
# legend at <plot>/legend.


def series(plot: str, name: str) -> str:
    """A series of a 2D plot: Points2D (and LineStrips2D) in data coordinates."""
    return f"{plot}/{name}"


# The L-curve: x = log10 rho, y = log10 eta; AnyValues lambda, residual_norm, solution_norm
LCURVE = "lcurve"
LCURVE_POINTS = series(LCURVE, "points")  # the whole-session fit's curve, labelled with lambda
LCURVE_CORNER = series(LCURVE, "corner")  # Points2D + AnyValues(lambda, index, ...)


def lcurve_segment(i: int) -> str:
    """Segment ``i``'s (its number, from 1) own L-curve, logged only when the session has
    more than one segment."""
    return series(LCURVE, f"segment_{i}")


# What each lambda of the whole-session sweep gives: x = log10 lambda, AnyValues lambda
LAMBDA_STATIC = "lambda/static_norm_error_mg"  # y = log10 mg; AnyValues mg
LAMBDA_STATIC_RMS = series(LAMBDA_STATIC, "rms")  # RMS over the still blocks
LAMBDA_STATIC_MAX = series(LAMBDA_STATIC, "max")  # largest |block error|
LAMBDA_CHOSEN = series(LAMBDA_STATIC, "chosen")  # one point, at the corner: RMS there
LAMBDA_MISALIGNMENT = "lambda/misalignment"  # series a_yz, a_zy, a_zx (rad)
LAMBDA_SCALE = "lambda/scale"  # series s_x, s_y, s_z
LAMBDA_BIAS = "lambda/bias"  # series b_x, b_y, b_z (raw unit)


def iteration(sensor: str, what: str) -> str:
    """The optimiser's plot of ``what`` (``log10_cost``, ``misalignment``, ``scale``,
    ``bias``) for ``sensor`` (``accelerometer`` or ``gyroscope``), x = accepted step (0 = the
    start)."""
    return f"iteration/{sensor}/{what}"


def iteration_series(fit: str, sensor: str, what: str, param: str) -> str:
    """One parameter's trace: ``fit`` is ``segment_<i>`` (or ``whole`` for the first
    whole-session fit when it differs from segment 1's); ``param`` a parameter name (``cost``
    for ``log10_cost``, whose y is log10 of the cost)."""
    return series(iteration(sensor, what), f"{fit}/{param}")


# The Overview's evidence (:mod:`viewer.evidence`): 2D plots, x = time (s), y = log10 of the
# error's size; series before | after with AnyValues t_s and deg / mg (signed)
EVIDENCE_TURNS = "evidence/rotation_error_deg"  # per turn: GyroFit.angle_before | angle_after
EVIDENCE_BLOCKS = "evidence/block_norm_error_mg"  # per block: Quality.block_norm_error_*mg

# Results (static)
SUMMARY = "calibration/summary"  # TextDocument, markdown
INFO = "calibration/info"  # AnyValues: source, units, lambda, warnings, ...
QUALITY = "calibration/quality"  # AnyValues: the quality figures, before/after


def calibration(i: int, sensor: str) -> str:
    """AnyValues with segment ``i``'s parameters (its number, from 1, as the CLI prints it):
    ``sensor`` ``accelerometer`` or ``gyroscope``."""
    return f"calibration/segment_{i}/{sensor}"


# Guide to the recording (Overview tab): Result.guide (imucal.stages.guide)
GUIDE = "guide"  # the sphere's Spatial3DView origin
GUIDE_SPHERE = "guide/sphere"  # static LineStrips3D: equator and meridians of the unit sphere
GUIDE_AXES = "guide/axes"  # static Arrows3D body x, y, z
GUIDE_POSES = "guide/poses"  # static Points3D: each still block's gravity direction (up axis)
GUIDE_MISSING = "guide/missing"  # static Points3D: sphere directions no pose comes near
GUIDE_NEXT = "guide/next"  # static Arrows3D: poses to record next, labelled "+x, -z"
GUIDE_HOLD = "guide_holds/duration_s"  # Scalars per pose at its block's middle: its hold, s
GUIDE_HOLD_NEAR_MIN = "guide_holds/near_minimum_s"  # the holds near the minimum only
GUIDE_HOLD_MIN = "guide_holds/minimum_s"  # the shortest hold that counts, 2 rows (a line)
GUIDE_HOLD_WARN = "guide_holds/near_minimum_limit_s"  # the hold advised (the guide's), a line
GUIDE_TURN_RATE = "guide_turns/peak_rate"  # Scalars per turn at its middle: rad/s
GUIDE_TURN_FAST = "guide_turns/peak_rate_over_limit"  # the turns over the limit only
GUIDE_TURN_LIMIT = "guide_turns/rate_limit"  # rad/s, a line
GUIDE_TURN_TILT = "guide_turns/tilt_deg"  # gravity moved by each turn, deg
GUIDE_TURN_ANGLE = "guide_turns/angle_deg"  # integrated rotation angle, deg (NaN: none)
GUIDE_TURN_MIN_TILT = "guide_turns/min_tilt_deg"  # a line
GUIDE_INFO = "guide/info"  # static AnyValues: limits, their sources, the verdict

# The Magnetometer tab (:mod:`viewer.magnetometer`): only for a session whose magnetometer was
# calibrated (``Result.magnetometer``, M8). 3D scenes static, at most MAG_POINTS samples each.
MAG_RAW = "magnetometer/raw"  # the raw scene's origin (raw unit, the magnetometer's frame)
MAG_RAW_SAMPLES = "magnetometer/raw/samples"  # Points3D + AnyValues sample_index, used
MAG_RAW_ELLIPSOID = "magnetometer/raw/ellipsoid"  # LineStrips3D: MagFit.ellipsoid on circles
MAG_CALIBRATED = "magnetometer/calibrated"  # the calibrated scene's origin (raw unit)
MAG_CAL_SAMPLES = "magnetometer/calibrated/samples"  # Points3D MagFit.apply, same samples
MAG_CAL_SPHERE = "magnetometer/calibrated/sphere"  # LineStrips3D: circles of radius F
MAG_NORM_USED = "magnetometer_norm/used_pct"  # Scalars 100 (|m|/F - 1), samples the fit used
MAG_NORM_LEFT_OUT = "magnetometer_norm/left_out_pct"  # ... the samples left out (disturbed)
MAG_DISTURBED = "magnetometer_norm/disturbed"  # StateChange: MagFit.disturbances' kind / reset
MAG_DIP_USED = "magnetometer_dip/used_deg"  # Scalars per still block at its middle
MAG_DIP_LEFT_OUT = "magnetometer_dip/left_out_deg"  # blocks not used for R_am and the dip
MAG_DIP_FIT = "magnetometer_dip/fitted_deg"  # MagFit.dip_deg, 2 rows (a line)
MAG_INFO = "magnetometer/info"  # static AnyValues: the fit's figures (MagQuality's)
MAG_NOTE = "magnetometer/note"  # static TextDocument (markdown): coverage, disturbances
# M8r's L-curve, a 2D plot as LCURVE's: x = log10 rho (RMS norm residual, raw unit), y = log10
# eta (|M / (tr M / 3) - I|_F); AnyValues lambda, residual_norm, solution_norm
MAG_LCURVE = "magnetometer_lcurve"
MAG_LCURVE_POINTS = series(MAG_LCURVE, "points")
MAG_LCURVE_CORNER = series(MAG_LCURVE, "corner")  # Points2D + AnyValues(lambda, index, ...)

# The Triads tab (:mod:`viewer.triads`): only for a session with other triads (``Result.triads``,
# method.md §11); triad ``i`` numbered from 2 (the reference is 1), its name in its info.
TRIADS_NOTE = "triads/note"  # static TextDocument (markdown): each triad's figures side by side


def triad(i: int, what: str) -> str:
    """Triad ``i``'s entity ``what``: ``before_mg`` | ``unrotated_mg`` | ``held_out_mg`` |
    ``after_mg`` (Scalars per shared still block at its middle) or ``info`` (static
    AnyValues: the rotation, its standard errors, the figures)."""
    return f"triads/triad_{i}/{what}"


# The Temperature tab (:mod:`viewer.temperature`): only with a bias in temperature
# (``Result.temperature``, method.md §12). 2D plots against temperature (deg C).
TEMPERATURE = "temperature"
TEMP_NOTE = "temperature/note"  # static TextDocument (markdown): orders, spans, hysteresis
TEMP_SERIES = "temperature_time/degC"  # Scalars: the temperature stream over time


def temp_blocks(leg: str) -> str:
    """Each still block's temperature at its middle, on its ``leg``: heating | cooling |
    steady (Scalars)."""
    return f"temperature_time/{leg}_degC"


def temp_plot(sensor: str, what: str) -> str:
    """A 2D plot against temperature: ``sensor`` accelerometer | gyroscope, ``what`` bias
    (the accelerometer's curves), norm (its blocks' |a|/g - 1), scale, or bias_x|y|z (the
    gyroscope's points and curve per axis)."""
    return f"{TEMPERATURE}/{sensor}_{what}"


# ``imucal check`` / ``imucal refresh`` recordings (:mod:`viewer.inuse`, method.md §10)
INUSE_ACC_NORM = "inuse/signals/acc_norm"  # Scalars |a| calibrated with the stored model
INUSE_GYRO_NORM = "inuse/signals/gyro_norm_deg_s"  # Scalars |w| calibrated, deg/s
INUSE_MOMENTS = "inuse/moments"  # StateChange "still" / reset per moment
INUSE_NORM_MOMENT = "inuse_norm/moment_mg"  # Scalars M9 e_k per moment, mg
INUSE_NORM_REFRESHED = "inuse_norm/refreshed_mg"  # ... with the refreshed model
INUSE_NORM_RMS = "inuse_norm/rms_mg"  # Scalars [RMS, low, high] over the moments so far
INUSE_NORM_EXPECTED = "inuse_norm/expected_mg"  # 2 rows: the stored calibration's expectation
INUSE_NORM_LIMIT = "inuse_norm/limit_mg"  # 2 rows: the limit
INUSE_CHECK = "inuse/check"  # static AnyValues: verdict, figures
INUSE_REFRESH = "inuse/refresh"  # static AnyValues: parameters refreshed, kept
INUSE_NOTE = "inuse/note"  # static TextDocument (markdown)


def inuse_gyro(axis: str, what: str) -> str:
    """The gyroscope's rate at rest about ``axis`` (x, y, z): ``moment_deg_s`` | ``pooled_deg_s``
    | ``band_deg_s``."""
    return f"inuse_gyro_{axis}/{what}"


def refresh_plot(group: str) -> str:
    """A 2D plot of refreshed parameters' changes: ``accelerometer_bias`` | ``accelerometer_scale``
    | ``gyroscope_bias``."""
    return f"refresh/{group}"
