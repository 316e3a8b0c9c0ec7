"""A C99 runtime for the device (issue 26 item 3): the calibration applied to each sample, the
streaming still detector of method.md §10 and the refresh of the gyroscope's bias and of the
accelerometer's biases and scales from each still moment.

``imucal export CALIB.json --to c-runtime --out DIR`` writes ``DIR/imucal_runtime.h`` (the state
struct the caller owns, its fixed size, the API) and ``DIR/imucal_runtime.c`` (the stored
calibration baked in as float constants, and the code). float32 throughout, no allocation, only
``<math.h>`` and ``<stdint.h>``. The C is package data (``c_runtime_src/*.in``: the stored
figures go in at the ``@NAME@`` marks); this module fills it in.

Per sample (``imucal_rt_step``): M2 and M4 with the current biases; the M1 statistic of the
calibrated accelerometer over a window of 0.5 s ending at the sample (so the centred statistic
of the sample half a window back: the same value as moments.py's, a half window late), by a
sliding update of each axis' mean and sum of squared deviations (recomputed from the window
once per window to stop float32 drift: O(1) amortised); a sample is still where M1 < 9 * 3
sigma^4, sigma the stored white noise density times sqrt(rate) (moments.py's rule). A run of
still samples, trimmed by half a window at each end, of at least 2 s is a moment; it must read a
mean norm within 10 % of |g| and a mean rate below 3 deg/s (the stored model's). Each moment's
M10 rate at rest (the tilt its two 0.5 s ends saw removed) and its standard error are pooled by
inverse variance with the prior of refresh.py (the stored bias, 1 deg/s wide): exactly the
pooled mean of estimate.gyro_bias, kept as running sums, so the bias after the last moment is
the one ``imucal refresh`` writes. The bias is moved once the moments add up to 3 s
(check.MIN_GYRO_STILL_S), as refresh.py does.

The accelerometer (M11, estimate.fit_acc): each accepted moment's mean (under the stored model)
and the variance of its mean norm are held (the last IMUCAL_RT_MAX_MOMENTS, 64 by default), and
at each moment the model is refitted from the stored one exactly as the Python does on the
moments so far: the axes with moments at 0.3 g on both sides (GGIR's coverage; none before 6
moments), then the biases, or the biases and scales, of those axes, whichever has the smaller
held-out still-norm RMS over 10 folds in time order, else nothing; Gauss-Newton with the priors
of estimate.py (scipy's trust region in the Python: the same minimum). The model in force
calibrates each sample; the detector reads the stored model's, as the Python's check does.

Where it differs from the Python: the Python's windows are mirrored at the recording's ends,
and the C takes them as still where the first (last) full window is, so a moment at the very
start begins at half a window and one still running at the end of the stream
(``imucal_rt_finish``) ends half a window before it, as the Python's usually do; the raw
samples are assumed evenly spaced at the rate given to ``imucal_rt_init`` (the Python reads
timestamps) with the accelerometer and gyroscope sampled together; float32 can put a
window within rounding of the threshold on the other side of it; and past
IMUCAL_RT_MAX_MOMENTS moments the accelerometer is refitted on the last ones only (the Python
on every moment of the recording).
"""

from __future__ import annotations

import math
from importlib import resources
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.inuse.check import DEFAULT_NORM_MG, MIN_GYRO_STILL_S
from imucal.inuse.estimate import (
    COVERAGE_G,
    FOLDS,
    MIN_ACC_MOMENTS,
    PRIOR_ACC_BIAS_G,
    PRIOR_ACC_SCALE,
    PRIOR_GYRO_BIAS_DEG_S,
)
from imucal.inuse.moments import (
    EDGE_S,
    K_INUSE,
    MAX_NORM_OFF,
    MAX_RATE_DEG_S,
    MIN_MOMENT_S,
    MIN_MOMENT_SAMPLES,
    WINDOW_S,
)
from imucal.io.exports.common import Exported, ExportInput
from imucal.io.inuse_file import stored_figures

HEADER = "imucal_runtime.h"
SOURCE = "imucal_runtime.c"
DEFAULT_MAX_RATE_HZ = 200
DEFAULT_MAX_MOMENTS = 64


def _f(x: float) -> str:
    """A float32 literal that reads back to the float32 nearest ``x``."""
    v = float(np.float32(x))
    if not math.isfinite(v):
        raise ImucalError(f"{x!r} does not fit a float32", field="calibration")
    text = f"{v:.9g}"  # 9 significant digits: any float32 exactly
    return text + ("f" if ("." in text or "e" in text) else ".0f")


def _arr(values) -> str:
    return "{" + ", ".join(_f(v) for v in np.ravel(values)) + "}"


def export(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    """``out`` is a directory: the header and the source are written into it."""
    cal = inp.calibration
    number = len(cal.segments) if segment is None else inp.segment(segment, "c-runtime")[0]
    seg = cal.segments[number - 1]
    if seg.gyro is None:
        raise ImucalError("the C runtime refreshes the gyroscope's bias and this calibration "
                          "has no gyroscope", source=str(inp.path), field="segments")
    density = stored_figures({"noise": inp.noise or {}, "quality": inp.quality or {}},
                             str(inp.path))
    nd = density.acc_noise_density
    norm_mg = DEFAULT_NORM_MG if density.static_norm_mg is None else density.static_norm_mg
    if nd is None or nd <= 0:
        raise ImucalError("the still detector's threshold comes from the accelerometer's white "
                          "noise density, and the calibration stores none; give it with "
                          "--noise NOISE.json (imucal noise --out)", source=str(inp.path),
                          field="noise.accelerometer.white_noise_density")
    a, ga = seg.acc.matrix, seg.gyro.matrix
    prov = [f" * {line}" for line in inp.header_lines()]
    prov.append(f" * segment {number} of {len(cal.segments)} (the device's latest state)")
    h = (_template("imucal_runtime.h.in").replace("@PROVENANCE@", "\n".join(prov))
         .replace("@MAXRATE@", str(DEFAULT_MAX_RATE_HZ))
         .replace("@MAXMOM@", str(DEFAULT_MAX_MOMENTS))
         .replace("@FIXED@", str(state_bytes(0, 0) - 24 * 8))
         .replace("@BYTES@", str(state_bytes(DEFAULT_MAX_RATE_HZ)))
         .replace("@ACC_RAW@", cal.acc_unit_raw).replace("@ACC_OUT@", cal.acc_unit)
         .replace("@GYRO_RAW@", cal.gyro_unit_raw or "rad/s"))
    subs = {"@NAME@": inp.path.name, "@ACC_A@": _arr(a), "@ACC_B@": _arr(seg.acc.b),
            "@ACC_T@": _arr(seg.acc.T), "@ACC_K@": _arr(seg.acc.K),
            "@ACC_AI@": _arr(np.linalg.inv(a)),
            "@GYRO_A@": _arr(ga), "@GYRO_B@": _arr(seg.gyro.b),
            "@GYRO_AI@": _arr(np.linalg.inv(ga)), "@G@": _f(cal.g), "@ND@": _f(nd),
            "@WINDOW_S@": _f(WINDOW_S), "@MIN_S@": _f(MIN_MOMENT_S),
            "@MIN_N@": str(MIN_MOMENT_SAMPLES), "@EDGE_S@": _f(EDGE_S), "@K@": _f(K_INUSE),
            "@NORM_OFF@": _f(MAX_NORM_OFF), "@MAX_RATE@": _f(math.radians(MAX_RATE_DEG_S)),
            "@PRIOR_W@": _f(1.0 / math.radians(PRIOR_GYRO_BIAS_DEG_S) ** 2),
            "@MIN_GYRO_S@": _f(MIN_GYRO_STILL_S),
            "@S_NORM@": _f(norm_mg * 1e-3 * cal.g), "@COVERAGE@": _f(COVERAGE_G),
            "@MIN_ACC@": str(MIN_ACC_MOMENTS), "@PRIOR_B@": _f(PRIOR_ACC_BIAS_G),
            "@PRIOR_S@": _f(PRIOR_ACC_SCALE), "@FOLDS@": f"{FOLDS}u"}
    c = _template("imucal_runtime.c.in")
    for key, value in subs.items():
        c = c.replace(key, value)
    notes = [f"segment {number}'s model in float32; the still detector (method.md §10), the "
             "gyroscope bias's refresh from each still moment and the accelerometer's biases "
             "and scales on the axes the moments cover (M11)",
             f"state: {state_bytes(DEFAULT_MAX_RATE_HZ)} bytes for rates up to "
             f"{DEFAULT_MAX_RATE_HZ} Hz (IMUCAL_RT_MAX_RATE_HZ)"]
    return Exported(files=[(out / HEADER, h), (out / SOURCE, c)], notes=notes)


def state_bytes(max_rate_hz: int, max_moments: int = DEFAULT_MAX_MOMENTS) -> int:
    """sizeof(imucal_rt_state) on a target with 4-byte floats and ints and no padding beyond
    theirs (every member is 4 bytes): the tests check it against the compiler's."""
    ring = max_rate_hz + 8
    fixed = (1 + 4 + 1 + 3  # rate_hz; window, half, edge, min_len; threshold; gyro_b
             + 4 + 6  # n, pos, filled, since_exact; win_mean, win_m2
             + 2 + 6 + 6 + 3 + 9  # in_run, start; acc shift/sum; e0; rc; gy
             + 7 + 1  # pool_w, pool_s, still_s; moments
             + 3 + 9  # last: start, end, accepted; acc_mean, rate, rate_se
             + 9 + 3 + 3 + 2 + 2 + 2)  # acc_a, acc_k, acc_b; choice, covered; nm; held, next
    return 4 * (fixed + 6 * ring + 4 * max_moments)


def _template(name: str) -> str:
    """A C source shipped as package data (``c_runtime_src/``, pyproject's package-data)."""
    return resources.files(__package__).joinpath("c_runtime_src", name).read_text("utf-8")


# The host program the tests and the benchmark compile around the runtime (see its comment).
DRIVER_C = _template("driver.c")
