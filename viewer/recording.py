"""An :class:`imucal.Result` as one Rerun recording (``.rrd``), layout included.

Everything is logged column-wise (``send_columns``, chunks of at most ``CHUNK_ROWS`` rows),
never sample by sample. The paths below are a contract: scripts read them back
(:mod:`viewer.readback`); the constants live in :mod:`viewer.paths`.

Timeline: ``time`` (duration, seconds on the session's clock), the only one. "static" rows
carry no time and hold at every time. What runs against lambda or the optimiser's step is a 2D
plot (:mod:`viewer.plot2d`): each series a static entity with ``Points2D`` at its data's own
``(x, y)`` (log10 on a log axis), a ``Transform3D`` to the plot's scene and ``AnyValues``
with the values themselves; the plot's axes at ``<plot>/frame``, its names at
``<plot>/legend``.

=========================================== ========== ============================================
Entity path                                  Timeline   Content
=========================================== ========== ============================================
imu/accelerometer/magnitude                  time       Scalars [raw, calibrated], calibrated unit
                                                        (g or m/s^2), every still sample (**):
                                                        ``Result.raw_acc_norm`` (``|a_raw|`` through
                                                        the fit's nominal frame: the raw signal
                                                        itself for input in g or m/s^2; offset and
                                                        scale of the sphere fit for raw counts),
                                                        ``calibrated.acc_norm``
imu/accelerometer/raw                        time       Scalars [x, y, z], raw unit (*)
imu/accelerometer/calibrated                 time       Scalars [x, y, z], calibrated unit (*)
imu/gyroscope/magnitude                      time       Scalars [raw, calibrated], rad/s (*):
                                                        ``Result.raw_gyro_norm``
                                                        (``|w_raw|`` for input in rad/s; for raw
                                                        counts ``|w_raw - b_g|`` times the nominal
                                                        scale, first segment),
                                                        ``calibrated.gyro_norm``
imu/gyroscope/raw                            time       Scalars [x, y, z], raw unit (*)
imu/gyroscope/calibrated                     time       Scalars [x, y, z], rad/s (*)
detector/statistic                           time       Scalars log10 s2 (M1) (*)
detector/threshold                           time       Scalars log10 (k s2_init), 2 rows
detector/blocks                              time       StateChange "still" at each block's first
                                                        sample, reset at its last
detector/segments                            time       StateChange "segment i" (from 1), "between
                                                        segments" (mean of neighbours' parameters)
blocks/norm_error_mg/before | after          time       Scalars ``|mean a| / g - 1`` in mg, one
                                                        row per static block at its middle
                                                        (``Quality.block_norm_error_[before_]mg``)
evidence/rotation_error_deg/before | after   static     Overview: 2D plot, x time (s) of the turn's
                                                        end, y log10 |angle| (deg):
                                                        ``GyroFit.angle_before|after``; AnyValues
                                                        t_s, deg
evidence/block_norm_error_mg/before | after  static     Overview: 2D plot, x block middle (s), y
                                                        log10 of ``|Quality.block_norm_error_
                                                        [before_]mg|``; AnyValues t_s, mg (signed)
gravity/axes                                 static     Arrows3D body x, y, z
gravity/measured                             time       Arrows3D unit gravity u_k of static block k
                                                        (mean calibrated acceleration,
                                                        ``GyroFit.u_blocks``), logged at the
                                                        block's first sample
gravity/previous                             time       Arrows3D u_(k-1), logged at block k (k > 0
                                                        within a segment)
gravity/predicted_before | predicted_after   time       Arrows3D ``R_k^T u_(k-1)`` (M5) with the raw
                                                        (nominal) / the calibrated gyroscope, at
                                                        block k (k > 0); drawn 1.24 / 1.12 long so
                                                        they do not hide in the measured arrow:
                                                        the direction is ``v / |v|``
gravity_angle/before | after                 time       Scalars angle u_k to the prediction, deg,
                                                        at block k (k > 0)
lcurve/points                                static     Points2D at (log10 rho, log10 eta) of the
                                                        whole-session fit (labels: lambda, blank
                                                        where points crowd) + AnyValues lambda,
                                                        residual_norm, solution_norm
lcurve/corner                                static     Points2D + AnyValues(lambda, index,
                                                        residual_norm, solution_norm)
lcurve/segment_<i> | segment_<i>_corner      static     each segment's own L-curve (only with more
                                                        than one segment)
lambda/static_norm_error_mg/rms | max        static     x log10 lambda, y log10 of the RMS / max
                                                        over static blocks of ``|mean a| / g - 1``
                                                        (mg) with the parameters solved at that
                                                        lambda (``AccFit.sweep``: ``LambdaSweep``);
                                                        AnyValues lambda, mg
lambda/static_norm_error_mg/chosen           static     one point, at the L-curve corner
lambda/misalignment|scale|bias/<param>       static     x log10 lambda, y the raw-unit parameter
                                                        (``LambdaSweep.params``)
iteration/<sensor>/<what>/<fit>/<param>      static     x accepted step (0 = the start), y the
                                                        raw-unit parameter (``AccFit.trace_params``,
                                                        ``GyroFit.trace_params``, ``trace_bias``);
                                                        <what> log10_cost (param ``cost``, y log10,
                                                        AnyValues cost) | misalignment | scale |
                                                        bias; <fit> segment_<i> (and ``whole`` when
                                                        the first whole-session fit is not segment
                                                        1's); <sensor> accelerometer | gyroscope
calibration/summary                          static     TextDocument (markdown): ``imucal.report``
                                                        (parameters with standard errors, quality,
                                                        warnings), as the CLI prints it
calibration/segment_<i>/accelerometer        static     AnyValues: T (9, row-major), K, b, params,
                                                        std, param_names, lambda, t_start, t_end,
                                                        start, cost_start, cost_end, n_points,
                                                        n_blocks, orientations
calibration/segment_<i>/gyroscope            static     AnyValues: T, K, b, params, std,
                                                        param_names, lambda, bias_source,
                                                        nominal_scale, transitions,
                                                        transitions_excluded, cost_start,
                                                        cost_end
calibration/quality                          static     AnyValues: static_norm_rms_mg_before|after,
                                                        sample_norm_rms_mg_before|after,
                                                        gravity_angle_rms_deg_before|after (NaN
                                                        where not defined), block_norm_error_mg
calibration/info                             static     AnyValues: source, sha256, units, g,
                                                        lambda, n_blocks, n_segments, grouping,
                                                        settings (JSON), warnings (text),
                                                        warning_codes
magnetometer/raw/samples                     static     Points3D raw field (raw unit), every k-th
                                                        sample (at most 3000), orange used / red
                                                        left out; AnyValues sample_index, used
magnetometer/raw/ellipsoid                   static     LineStrips3D ``MagFit.ellipsoid`` (b + F
                                                        M^-1 u) over circles of unit directions
magnetometer/calibrated/samples | sphere     static     Points3D ``MagFit.apply`` of the same
                                                        samples; LineStrips3D circles of radius F
magnetometer_norm/used_pct | left_out_pct    time       Scalars 100 ``MagFit.norm_error`` (%) of
                                                        the samples ``MagFit.used`` / not (*)
magnetometer_norm/disturbed                  time       StateChange kind of each
                                                        ``MagFit.disturbances`` / reset at its end
magnetometer_dip/used_deg | left_out_deg     time       Scalars ``block_dip_deg`` at each block's
                                                        middle (``MagFit.block_times``), split by
                                                        ``block_used``
magnetometer_dip/fitted_deg                  time       Scalars ``MagFit.dip_deg``, 2 rows
magnetometer/info                            static     AnyValues: field, dip, quality figures,
                                                        coverage, missing, disturbances (text)
magnetometer/note                            static     TextDocument (markdown): the same, read
magnetometer_lcurve/points | corner          static     Points2D (log10 rho, log10 eta) of
                                                        ``MagFit.lcurve`` (M8r) and its corner;
                                                        AnyValues lambda, residual_norm, ...
=========================================== ========== ============================================

(*) Signals longer than ``SCREEN_ROWS`` (20 000) samples are logged as a min/max envelope of at
most that many rows, whatever the session's length (:mod:`viewer.decimate`, which says why:
every peak kept, drawn at most one bucket from where it happened); the gyroscope's magnitude as
such an envelope inside the still blocks and one between them, no bucket across a block's edge.
(**) The accelerometer's magnitude keeps every still sample (the core's ``Result.acc_still``)
as it is while there are at most ``STILL_ROWS`` of them (else an envelope of buckets of a few
samples inside each block); between the blocks an envelope as (*). Each signal's entity holds
static AnyValues ``samples``, ``rows``, ``still_bucket``, ``moving_bucket`` (samples per
min/max pair; 1 = as they are): what was chosen for this session. The rows are made from the
signals read a chunk of rows at a time (:mod:`viewer.signal_rows`): a long session's calibrated
signals are never made whole, and the rows are the same to the bit as the whole arrays'.

Every number logged is the core's (``imucal.result.Result`` and the stage results it holds);
this package only lays them out: log10 for the log-scale plots, arrow lengths, labels,
decimation. One module per tab maps its entities: :mod:`viewer.signals` (Overview, Signals),
:mod:`viewer.gravity`, :mod:`viewer.lcurve`, :mod:`viewer.optimiser`, :mod:`viewer.summary`.

The gyroscope entities exist only for a session with a gyroscope; the L-curve and ``lambda``
entities only when lambda was chosen by the L-curve (not fixed); the ``magnetometer*``
entities only when the session's magnetometer was calibrated (``Result.magnetometer``); the
``triads*`` entities (:mod:`viewer.triads`) only with other triads (``Result.triads``), the
``temperature*`` ones (:mod:`viewer.temperature`) only with a bias in temperature
(``Result.temperature``): their tables are in those modules.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import rerun as rr

from imucal.io.atomic import atomic_path

from . import paths as P
from .decimate import DECIMATE_ABOVE, ENVELOPE_ROWS, SCREEN_ROWS, STILL_ROWS
from .evidence import log_evidence
from .gravity import log_gravity
from .guide import log_guide
from .lcurve import log_lcurves
from .magnetometer import log_magnetometer
from .optimiser import log_iterations
from .signal_rows import SignalRows, signal_rows
from .signals import log_block_errors, log_detector, log_signals
from .summary import log_results, summary_markdown
from .temperature import log_temperature
from .triads import log_triads

if TYPE_CHECKING:
    from imucal.result import Result

__all__ = ["DECIMATE_ABOVE", "ENVELOPE_ROWS", "SCREEN_ROWS", "STILL_ROWS", "log_result",
           "new_recording", "save_recording", "summary_markdown"]


def log_result(result: Result, rec: rr.RecordingStream, signals: SignalRows | None = None
               ) -> dict[str, int]:
    """Log everything the viewer shows about ``result`` to ``rec``; ``signals`` the signals'
    rows if made already (:func:`~viewer.signal_rows.signal_rows`: the layout's ranges come
    from the same pass).

    Returns the number of rows logged per temporal entity (what a test compares the file with).
    """
    rows: dict[str, int] = {}
    signals = signal_rows(result) if signals is None else signals
    log_signals(result, rec, rows, signals)
    log_detector(result, rec, rows, signals)
    log_block_errors(result, rec, rows)
    log_evidence(result, rec)
    log_gravity(result, rec, rows)
    log_guide(result, rec, rows)
    log_lcurves(result, rec, rows)
    log_iterations(result, rec, rows)
    log_magnetometer(result, rec, rows)
    log_triads(result, rec, rows)  # nothing for one triad
    log_temperature(result, rec, rows)  # nothing without a bias in temperature
    log_results(result, rec)
    return rows


def new_recording() -> rr.RecordingStream:
    """A fresh recording stream (its own id: two runs in one process never merge)."""
    return rr.RecordingStream(P.APPLICATION_ID, recording_id=uuid.uuid4())


def save_recording(result: Result, path: str | os.PathLike | BinaryIO) -> dict[str, int]:
    """Write ``result`` with its layout as one ``.rrd``: to ``path`` atomically (a temporary
    file in the same directory, then a rename), or to an open binary file (a run's
    transaction owns the rename). Bounded and interruptible: see :mod:`viewer.rrd_file`.

    Returns the rows logged per temporal entity (see :func:`log_result`).
    """
    if not hasattr(path, "write"):
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            return save_recording(result, f)
    from .blueprint import blueprint
    from .rrd_file import rrd_sink

    signals = signal_rows(result)  # the signals read once for the rows and the layout's ranges
    rec = new_recording()
    with rrd_sink(rec, path, default_blueprint=blueprint(result, signals=signals)):
        rec.send_recording_name(Path(result.session.source).name or "imucal")
        rows = log_result(result, rec, signals)
    return rows
