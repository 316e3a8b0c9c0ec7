"""A C99 runtime for the device (issue 26 item 3): the calibration applied to each sample, the
streaming still detector of method.md §10 and the recursive refresh of the gyroscope's bias.

``imucal export CALIB.json --to c-runtime --out DIR`` writes ``DIR/imucal_runtime.h`` (the state
struct the caller owns, its fixed size, the API) and ``DIR/imucal_runtime.c`` (the stored
calibration baked in as float constants, and the code). float32 throughout, no allocation, only
``<math.h>`` and ``<stdint.h>``.

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
(check.MIN_GYRO_STILL_S), as refresh.py does. The accelerometer's bias is not refreshed here.

Where it differs from the Python: the Python's windows are mirrored at the recording's ends,
and the C takes them as still where the first (last) full window is, so a moment at the very
start begins at half a window and one still running at the end of the stream
(``imucal_rt_finish``) ends half a window before it, as the Python's usually do; the raw
samples are assumed evenly spaced at the rate given to ``imucal_rt_init`` (the Python reads
timestamps) with the accelerometer and gyroscope sampled together; and float32 can put a
window within rounding of the threshold on the other side of it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from imucal.errors import ImucalError
from imucal.inuse.check import MIN_GYRO_STILL_S
from imucal.inuse.estimate import PRIOR_GYRO_BIAS_DEG_S
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


def _f(x: float) -> str:
    """A float32 literal that reads back to the float32 nearest ``x``."""
    v = float(np.float32(x))
    if not math.isfinite(v):
        raise ImucalError(f"{x!r} does not fit a float32", field="calibration")
    text = f"{v:.9g}"  # 9 significant digits: any float32 exactly
    return text + ("f" if ("." in text or "e" in text) else ".0f")


def _arr(values) -> str:
    return "{" + ", ".join(_f(v) for v in np.ravel(values)) + "}"


_H = """\
/*
 * imucal C runtime: the calibration applied to each sample (method.md M2, M4), the streaming
 * still detector of method.md section 10 and the recursive refresh of the gyroscope's bias.
@PROVENANCE@
 *
 * C99, float32, no allocation, no dependency beyond <math.h> and <stdint.h>.
 * Memory: one imucal_rt_state, owned by the caller (static or on the stack), of
 *   sizeof(imucal_rt_state) = 260 + 24 * IMUCAL_RT_RING bytes (every member 4 bytes), with
 *   IMUCAL_RT_RING = IMUCAL_RT_MAX_RATE_HZ + 8 samples (half a second of window and half a second
 *   of a moment's end); @BYTES@ bytes at the default IMUCAL_RT_MAX_RATE_HZ = @MAXRATE@
 *   (define it before including this header, and when compiling imucal_runtime.c, for another).
 * Time per sample: O(1) amortised (once per window, a pass over the window; once per moment,
 *   one over the ring).
 *
 * Use:
 *   static imucal_rt_state st;
 *   imucal_rt_init(&st, 100.0f);                 rate in Hz, <= IMUCAL_RT_MAX_RATE_HZ
 *   each sample:  if (imucal_rt_step(&st, acc_raw, gyro_raw, acc, gyro)) { st.last ... }
 *   at the end of a stream: imucal_rt_finish(&st);
 * acc_raw in @ACC_RAW@, gyro_raw in @GYRO_RAW@ (the calibration's raw units; deg/s input converted
 * to rad/s first); acc out in @ACC_OUT@, gyro out in rad/s. st.gyro_b is the current gyroscope
 * bias (raw units), to be saved across power cycles if wished.
 */
#ifndef IMUCAL_RUNTIME_H
#define IMUCAL_RUNTIME_H

#include <stdint.h>

#ifndef IMUCAL_RT_MAX_RATE_HZ
#define IMUCAL_RT_MAX_RATE_HZ @MAXRATE@
#endif
/* window <= rate/2 + 2 samples, a moment's edge <= rate/2 + 1: the ring holds both. */
#define IMUCAL_RT_RING (IMUCAL_RT_MAX_RATE_HZ + 8)

/* A still moment, [start, end) in samples since imucal_rt_init. */
typedef struct {
    uint32_t start;
    uint32_t end;
    int32_t accepted;   /* 1: pooled into the gyroscope's bias; 0: refused (norm, rate, NaN) */
    float acc_mean[3];  /* calibrated accelerometer mean */
    float rate[3];      /* M10's rate at rest left by the stored model, rad/s */
    float rate_se[3];   /* its standard error, rad/s */
} imucal_rt_moment;

typedef struct {
    /* set by imucal_rt_init */
    float rate_hz;
    int32_t window, half, edge, min_len;
    float threshold;             /* on M1: 9 * 3 sigma^4 */
    float gyro_b[3];             /* current gyroscope bias, raw units */
    /* the last IMUCAL_RT_RING calibrated samples (gyroscope with the stored bias) */
    float ring_acc[IMUCAL_RT_RING][3];
    float ring_gyro[IMUCAL_RT_RING][3];
    uint32_t n;                  /* samples seen, modulo 2^32 (a sample's number) */
    uint32_t pos;                /* the ring's slot of sample n - 1 */
    int32_t filled;              /* samples in the window so far, up to window */
    int32_t since_exact;         /* samples since the window was last computed afresh */
    float win_mean[3], win_m2[3];
    /* the moment in progress */
    int32_t in_run;
    uint32_t start;
    float acc_shift[3], acc_sum[3];        /* [start, now) */
    float e0_sum[3], e0_sq[3];             /* its first edge */
    float rc_sum[3];                       /* stored-model rate over [start, now) */
    float gy_shift[3], gy_sum[3], gy_sq[3];/* from start + edge/2 on (M10's span) */
    /* the pooled bias: prior weight and sums (estimate.gyro_bias), seconds of moments */
    float pool_w[3], pool_s[3], still_s;
    uint32_t moments;            /* accepted */
    imucal_rt_moment last;
} imucal_rt_state;

/* 0, or -1 when rate_hz is outside (4 Hz, IMUCAL_RT_MAX_RATE_HZ]. */
int imucal_rt_init(imucal_rt_state *st, float rate_hz);
/* Calibrate one sample; 1 when a still moment ended with it (in st->last), else 0. */
int imucal_rt_step(imucal_rt_state *st, const float acc_raw[3], const float gyro_raw[3],
                   float acc_out[3], float gyro_out[3]);
/* End of stream: close a moment still in progress; 1 if one was closed. */
int imucal_rt_finish(imucal_rt_state *st);

#endif /* IMUCAL_RUNTIME_H */
"""

_C = """\
/* imucal C runtime: see imucal_runtime.h. Written by imucal from @NAME@. */
#include <math.h>
#include <stdint.h>

#include "imucal_runtime.h"

/* The stored calibration (method.md M2, M4): out = A (raw - b), A = T K, row major. */
static const float ACC_A[9] = @ACC_A@;
static const float ACC_B[3] = @ACC_B@;
static const float GYRO_A[9] = @GYRO_A@;
static const float GYRO_B0[3] = @GYRO_B@;
static const float GYRO_A_INV[9] = @GYRO_AI@;  /* calibrated rate -> raw units */
static const float G = @G@;                     /* |g| in the calibrated unit */
static const float NOISE_DENSITY = @ND@;        /* per sqrt(Hz), calibrated unit */
/* method.md section 10, as imucal/inuse/moments.py and refresh.py */
#define WINDOW_S @WINDOW_S@
#define MIN_MOMENT_S @MIN_S@
#define MIN_MOMENT_SAMPLES @MIN_N@
#define EDGE_S @EDGE_S@
#define K_INUSE @K@
#define MAX_NORM_OFF @NORM_OFF@
#define MAX_RATE @MAX_RATE@        /* rad/s */
#define PRIOR_W @PRIOR_W@          /* 1 / (1 deg/s)^2 */
#define MIN_GYRO_STILL_S @MIN_GYRO_S@

static void apply3(const float A[9], const float b[3], const float raw[3], float out[3])
{
    const float d0 = raw[0] - b[0], d1 = raw[1] - b[1], d2 = raw[2] - b[2];
    out[0] = A[0] * d0 + A[1] * d1 + A[2] * d2;
    out[1] = A[3] * d0 + A[4] * d1 + A[5] * d2;
    out[2] = A[6] * d0 + A[7] * d1 + A[8] * d2;
}

static int32_t iround(float x) { return (int32_t)floorf(x + 0.5f); }

int imucal_rt_init(imucal_rt_state *st, float rate_hz)
{
    int i;
    float sigma;
    if (!(rate_hz > 4.0f) || rate_hz > (float)IMUCAL_RT_MAX_RATE_HZ) {
        return -1;
    }
    st->rate_hz = rate_hz;
    st->window = iround(WINDOW_S * rate_hz) | 1;
    if (st->window < 3) st->window = 3;
    st->half = st->window / 2;
    st->edge = iround(EDGE_S * rate_hz);
    if (st->edge < 2) st->edge = 2;
    st->min_len = iround(MIN_MOMENT_S * rate_hz);
    if (st->min_len < MIN_MOMENT_SAMPLES) st->min_len = MIN_MOMENT_SAMPLES;
    if (st->min_len < st->window) st->min_len = st->window;
    sigma = NOISE_DENSITY * sqrtf(rate_hz);
    st->threshold = K_INUSE * 3.0f * sigma * sigma * sigma * sigma;
    st->n = 0;
    st->pos = IMUCAL_RT_RING - 1;
    st->filled = 0;
    st->since_exact = st->window - 1;  /* the first full window: afresh */
    st->in_run = 0;
    st->still_s = 0.0f;
    st->moments = 0;
    for (i = 0; i < 3; ++i) {
        st->gyro_b[i] = GYRO_B0[i];
        st->pool_w[i] = PRIOR_W;
        st->pool_s[i] = 0.0f;
        st->win_mean[i] = 0.0f;
        st->win_m2[i] = 0.0f;
    }
    return 0;
}

/* The ring's slot of sample k, one of the last IMUCAL_RT_RING: by its age, so sample numbers
 * may wrap past 2^32 (49 days at 1 kHz) without a jump. */
static uint32_t slot(const imucal_rt_state *st, uint32_t k)
{
    const uint32_t age = (st->n - 1u) - k;
    return (st->pos + IMUCAL_RT_RING - age) % IMUCAL_RT_RING;
}

static float *ring_acc(imucal_rt_state *st, uint32_t k)
{
    return st->ring_acc[slot(st, k)];
}

static float *ring_gyro(imucal_rt_state *st, uint32_t k)
{
    return st->ring_gyro[slot(st, k)];
}

/* Each axis' mean and sum of squared deviations over the window ending at sample k, afresh. */
static void window_exact(imucal_rt_state *st, uint32_t k)
{
    int i, j;
    const int32_t w = st->window;
    for (i = 0; i < 3; ++i) {
        float m = 0.0f, m2 = 0.0f;
        for (j = 0; j < w; ++j) m += ring_acc(st, k - (uint32_t)j)[i];
        m /= (float)w;
        for (j = 0; j < w; ++j) {
            const float d = ring_acc(st, k - (uint32_t)j)[i] - m;
            m2 += d * d;
        }
        st->win_mean[i] = m;
        st->win_m2[i] = m2;
    }
}

static void run_begin(imucal_rt_state *st, uint32_t a)
{
    int i;
    const float *x = ring_acc(st, a);
    st->in_run = 1;
    st->start = a;
    for (i = 0; i < 3; ++i) {
        st->acc_shift[i] = x[i];
        st->acc_sum[i] = st->e0_sum[i] = st->e0_sq[i] = 0.0f;
        st->rc_sum[i] = st->gy_sum[i] = st->gy_sq[i] = 0.0f;
    }
}

/* Sample k into the moment in progress. */
static void run_add(imucal_rt_state *st, uint32_t k)
{
    int i;
    const uint32_t off = k - st->start;
    const float *x = ring_acc(st, k), *w = ring_gyro(st, k);
    if (off == (uint32_t)(st->edge / 2)) {
        for (i = 0; i < 3; ++i) st->gy_shift[i] = w[i];
    }
    for (i = 0; i < 3; ++i) {
        const float d = x[i] - st->acc_shift[i];
        st->acc_sum[i] += d;
        if (off < (uint32_t)st->edge) {
            st->e0_sum[i] += d;
            st->e0_sq[i] += d * d;
        }
        st->rc_sum[i] += w[i];
        if (off >= (uint32_t)(st->edge / 2)) {
            const float g = w[i] - st->gy_shift[i];
            st->gy_sum[i] += g;
            st->gy_sq[i] += g * g;
        }
    }
}

static float dot3(const float a[3], const float b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* Close the moment [start, b): samples b .. now are in the sums and come out again (they
 * are in the ring). Returns 1 when it was long enough to be a moment (st->last). */
static int run_end(imucal_rt_state *st, uint32_t b)
{
    const uint32_t a = st->start, now = st->n - 1;
    const int32_t e = st->edge;
    const uint32_t g0 = a + (uint32_t)(e / 2), g1 = b - (uint32_t)e + (uint32_t)(e / 2);
    float acc[3], rc[3], m0[3], m1[3], v0[3], v1[3], gm[3], gv[3], u0[3], u1[3], phi[3];
    float n0, n1, span, ng, norm;
    const int32_t len = (int32_t)(b - a);  /* < 0: a run shorter than a window */
    uint32_t k, n;
    int i;
    imucal_rt_moment *mo = &st->last;
    st->in_run = 0;
    if (len < st->min_len || len / 3 < e) {
        return 0;
    }
    n = (uint32_t)len;
    for (i = 0; i < 3; ++i) {
        float s = st->acc_sum[i], r = st->rc_sum[i], gs = st->gy_sum[i], gq = st->gy_sq[i];
        for (k = b; k != now + 1u; ++k) {
            s -= ring_acc(st, k)[i] - st->acc_shift[i];
            r -= ring_gyro(st, k)[i];
        }
        for (k = g1; k != now + 1u; ++k) {
            const float d = ring_gyro(st, k)[i] - st->gy_shift[i];
            gs -= d;
            gq -= d * d;
        }
        acc[i] = st->acc_shift[i] + s / (float)n;
        rc[i] = r / (float)n;
        ng = (float)(g1 - g0);
        gm[i] = st->gy_shift[i] + gs / ng;
        gv[i] = fmaxf((gq - gs * gs / ng) / (ng - 1.0f), 0.0f);  /* rounding: not below 0 */
        m0[i] = st->acc_shift[i] + st->e0_sum[i] / (float)e;
        v0[i] = fmaxf((st->e0_sq[i] - st->e0_sum[i] * st->e0_sum[i] / (float)e)
                      / (float)(e - 1), 0.0f);
        /* the last edge, [b - e, b): two passes over the ring */
        m1[i] = 0.0f;
        for (k = b - (uint32_t)e; k != b; ++k) m1[i] += ring_acc(st, k)[i];
        m1[i] /= (float)e;
        v1[i] = 0.0f;
        for (k = b - (uint32_t)e; k != b; ++k) {
            const float d = ring_acc(st, k)[i] - m1[i];
            v1[i] += d * d;
        }
        v1[i] /= (float)(e - 1);
    }
    mo->start = a;
    mo->end = b;
    for (i = 0; i < 3; ++i) mo->acc_mean[i] = acc[i];
    norm = sqrtf(dot3(acc, acc));
    mo->accepted = fabsf(norm - G) <= MAX_NORM_OFF * G && sqrtf(dot3(rc, rc)) <= MAX_RATE;
    /* M10: the mean rate between the centres of the two ends, less the tilt between them */
    n0 = sqrtf(dot3(m0, m0));
    n1 = sqrtf(dot3(m1, m1));
    for (i = 0; i < 3; ++i) {
        u0[i] = m0[i] / n0;
        u1[i] = m1[i] / n1;
    }
    phi[0] = u1[1] * u0[2] - u1[2] * u0[1];
    phi[1] = u1[2] * u0[0] - u1[0] * u0[2];
    phi[2] = u1[0] * u0[1] - u1[1] * u0[0];
    span = (float)(b - (uint32_t)e - a) / st->rate_hz;
    for (i = 0; i < 3; ++i) {
        const float var_u = (v0[i] / (n0 * n0) + v1[i] / (n1 * n1)) / (float)e;
        float se = sqrtf(gv[i] / (float)(g1 - g0) + var_u / (span * span));
        mo->rate[i] = gm[i] - phi[i] / span;
        mo->rate_se[i] = se;
    }
    for (i = 0; i < 3; ++i) {  /* a non-finite sample (a glitch, a NaN) spoils the moment */
        if (!isfinite(mo->rate[i]) || !isfinite(mo->rate_se[i])) mo->accepted = 0;
    }
    if (mo->accepted) {
        float post[3];
        for (i = 0; i < 3; ++i) {
            const float se = mo->rate_se[i] > 1e-12f ? mo->rate_se[i] : 1e-12f;
            const float w = 1.0f / (se * se);
            st->pool_w[i] += w;
            st->pool_s[i] += w * mo->rate[i];
        }
        st->still_s += (float)(b - 1 - a) / st->rate_hz;
        st->moments += 1;
        if (st->still_s >= MIN_GYRO_STILL_S) {  /* refresh.py: 3 s of moments or more */
            for (i = 0; i < 3; ++i) post[i] = st->pool_s[i] / st->pool_w[i];
            for (i = 0; i < 3; ++i) st->gyro_b[i] = GYRO_B0[i] + dot3(&GYRO_A_INV[3 * i], post);
        }
    }
    return 1;
}

int imucal_rt_step(imucal_rt_state *st, const float acc_raw[3], const float gyro_raw[3],
                   float acc_out[3], float gyro_out[3])
{
    const uint32_t k = st->n;
    const int32_t w = st->window;
    float *x, *g;
    int i, ended = 0, first = 0;
    st->n = k + 1u;
    st->pos = (st->pos + 1u) % IMUCAL_RT_RING;
    x = ring_acc(st, k);
    g = ring_gyro(st, k);
    apply3(ACC_A, ACC_B, acc_raw, acc_out);
    apply3(GYRO_A, st->gyro_b, gyro_raw, gyro_out);
    apply3(GYRO_A, GYRO_B0, gyro_raw, g);  /* the detector's rates: the stored model's */
    for (i = 0; i < 3; ++i) x[i] = acc_out[i];
    if (st->in_run) run_add(st, k);
    if (st->filled < w) {
        st->filled += 1;
        if (st->filled < w) return 0;
        first = 1;
    }
    if (++st->since_exact >= w) {  /* afresh once a window (the first one too) */
        st->since_exact = 0;
        window_exact(st, k);
    } else {  /* slide: sample k in, k - w out */
        const float *o = ring_acc(st, k - (uint32_t)w);
        for (i = 0; i < 3; ++i) {
            const float m = st->win_mean[i] + (x[i] - o[i]) / (float)w;
            st->win_m2[i] += (x[i] - o[i]) * (x[i] - m + o[i] - st->win_mean[i]);
            st->win_mean[i] = m;
        }
    }
    {
        /* M1 of the window [k - w + 1, k], centred on sample k - half */
        float s2 = 0.0f;
        for (i = 0; i < 3; ++i) {
            float v = st->win_m2[i] / (float)(w - 1);
            if (v < 0.0f) v = 0.0f;
            s2 += v * v;
        }
        if (s2 < st->threshold) {
            if (!st->in_run) {  /* the moment starts half a window after the centre: at k */
                /* the first window: the Python's mirrored windows before it taken as still
                 * too, so a recording that starts still starts its moment at half */
                const uint32_t a = first ? k - (uint32_t)st->half : k;
                uint32_t j;
                run_begin(st, a);
                for (j = a; j != k + 1u; ++j) run_add(st, j);
            }
        } else if (st->in_run) {  /* ends half a window before this centre */
            ended = run_end(st, k + 1 - 2u * (uint32_t)st->half - 1u);
        }
    }
    return ended;
}

int imucal_rt_finish(imucal_rt_state *st)
{
    if (!st->in_run) return 0;
    /* the last centre known still is n - 1 - half; the Python's mirrored windows after it
     * taken as still too, the run ends at n, the moment half a window before */
    return run_end(st, st->n - (uint32_t)st->half);
}
"""


def export(inp: ExportInput, out: Path, segment: int | None) -> Exported:
    """``out`` is a directory: the header and the source are written into it."""
    cal = inp.calibration
    number = len(cal.segments) if segment is None else inp.segment(segment, "c-runtime")[0]
    seg = cal.segments[number - 1]
    if seg.gyro is None:
        raise ImucalError("the C runtime refreshes the gyroscope's bias and this calibration "
                          "has no gyroscope", source=str(inp.path), field="segments")
    density = stored_figures({"noise": inp.noise} if inp.noise else {}, str(inp.path))
    nd = density.acc_noise_density
    if nd is None or nd <= 0:
        raise ImucalError("the still detector's threshold comes from the accelerometer's white "
                          "noise density, and the calibration stores none; give it with "
                          "--noise NOISE.json (imucal noise --out)", source=str(inp.path),
                          field="noise.accelerometer.white_noise_density")
    a, ga = seg.acc.matrix, seg.gyro.matrix
    prov = [f" * {line}" for line in inp.header_lines()]
    prov.append(f" * segment {number} of {len(cal.segments)} (the device's latest state)")
    h = (_H.replace("@PROVENANCE@", "\n".join(prov))
         .replace("@MAXRATE@", str(DEFAULT_MAX_RATE_HZ))
         .replace("@BYTES@", str(state_bytes(DEFAULT_MAX_RATE_HZ)))
         .replace("@ACC_RAW@", cal.acc_unit_raw).replace("@ACC_OUT@", cal.acc_unit)
         .replace("@GYRO_RAW@", cal.gyro_unit_raw or "rad/s"))
    subs = {"@NAME@": inp.path.name, "@ACC_A@": _arr(a), "@ACC_B@": _arr(seg.acc.b),
            "@GYRO_A@": _arr(ga), "@GYRO_B@": _arr(seg.gyro.b),
            "@GYRO_AI@": _arr(np.linalg.inv(ga)), "@G@": _f(cal.g), "@ND@": _f(nd),
            "@WINDOW_S@": _f(WINDOW_S), "@MIN_S@": _f(MIN_MOMENT_S),
            "@MIN_N@": str(MIN_MOMENT_SAMPLES), "@EDGE_S@": _f(EDGE_S), "@K@": _f(K_INUSE),
            "@NORM_OFF@": _f(MAX_NORM_OFF), "@MAX_RATE@": _f(math.radians(MAX_RATE_DEG_S)),
            "@PRIOR_W@": _f(1.0 / math.radians(PRIOR_GYRO_BIAS_DEG_S) ** 2),
            "@MIN_GYRO_S@": _f(MIN_GYRO_STILL_S)}
    c = _C
    for key, value in subs.items():
        c = c.replace(key, value)
    notes = [f"segment {number}'s model in float32; the still detector (method.md §10) and the "
             "gyroscope bias's refresh from each still moment (the accelerometer's: not here)",
             f"state: {state_bytes(DEFAULT_MAX_RATE_HZ)} bytes for rates up to "
             f"{DEFAULT_MAX_RATE_HZ} Hz (IMUCAL_RT_MAX_RATE_HZ)"]
    return Exported(files=[(out / HEADER, h), (out / SOURCE, c)], notes=notes)


def state_bytes(max_rate_hz: int) -> int:
    """sizeof(imucal_rt_state) on a target with 4-byte floats and ints and no padding beyond
    theirs (every member is 4 bytes): the tests check it against the compiler's."""
    ring = max_rate_hz + 8
    fixed = (1 + 4 + 1 + 3  # rate_hz; window, half, edge, min_len; threshold; gyro_b
             + 4 + 6  # n, pos, filled, since_exact; win_mean, win_m2
             + 2 + 6 + 6 + 3 + 9  # in_run, start; acc shift/sum; e0; rc; gy
             + 7 + 1  # pool_w, pool_s, still_s; moments
             + 3 + 9)  # last: start, end, accepted; acc_mean, rate, rate_se
    return 4 * (fixed + 6 * ring)


# A host program around the runtime, compiled by the tests and the benchmark (not written by
# the export): ``driver RATE IN OUT [REPEAT [FIRST]]`` reads IN, float32 rows (acc_raw[3],
# gyro_raw[3]); writes OUT, float32 rows (acc[3], gyro[3], gyro_b[3]) of the first pass;
# prints each moment ("moment start end accepted r_x r_y r_z se_x se_y se_z"), the final bias,
# sizeof the state and the nanoseconds per sample over REPEAT passes (each from
# imucal_rt_init). FIRST numbers the samples from there (modulo 2^32: a count that wraps).
DRIVER_C = """\
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "imucal_runtime.h"

static void report(const imucal_rt_state *st)
{
    const imucal_rt_moment *m = &st->last;
    printf("moment %u %u %d %.9g %.9g %.9g %.9g %.9g %.9g\\n", (unsigned)m->start,
           (unsigned)m->end, (int)m->accepted, m->rate[0], m->rate[1], m->rate[2],
           m->rate_se[0], m->rate_se[1], m->rate_se[2]);
}

int main(int argc, char **argv)
{
    static imucal_rt_state st;
    FILE *f;
    float *in, *out;
    long n, i;
    int r, repeat = argc > 4 ? atoi(argv[4]) : 1;
    unsigned long first = argc > 5 ? strtoul(argv[5], NULL, 10) : 0;
    struct timespec t0, t1;
    double ns;
    if (argc < 4) return 2;
    f = fopen(argv[2], "rb");
    if (!f) return 3;
    fseek(f, 0, SEEK_END);
    n = ftell(f) / (long)(6 * sizeof(float));
    fseek(f, 0, SEEK_SET);
    in = malloc((size_t)n * 6 * sizeof(float));
    out = malloc((size_t)n * 9 * sizeof(float));
    if (!in || !out || fread(in, 6 * sizeof(float), (size_t)n, f) != (size_t)n) return 4;
    fclose(f);
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (r = 0; r < repeat; ++r) {
        if (imucal_rt_init(&st, (float)atof(argv[1])) != 0) return 5;
        st.n = (uint32_t)first;  /* the samples' numbers from there, modulo 2^32 */
        for (i = 0; i < n; ++i) {
            float *o = out + 9 * i;
            if (imucal_rt_step(&st, in + 6 * i, in + 6 * i + 3, o, o + 3) && r == 0) report(&st);
            if (r == 0) {
                o[6] = st.gyro_b[0];
                o[7] = st.gyro_b[1];
                o[8] = st.gyro_b[2];
            }
        }
        if (imucal_rt_finish(&st) && r == 0) report(&st);
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    ns = ((double)(t1.tv_sec - t0.tv_sec) * 1e9 + (double)(t1.tv_nsec - t0.tv_nsec))
         / ((double)n * repeat);
    printf("bias %.9g %.9g %.9g\\n", st.gyro_b[0], st.gyro_b[1], st.gyro_b[2]);
    printf("sizeof %u\\n", (unsigned)sizeof(imucal_rt_state));
    printf("ns_per_sample %.3f\\n", ns);
    f = fopen(argv[3], "wb");
    if (!f || fwrite(out, 9 * sizeof(float), (size_t)n, f) != (size_t)n) return 6;
    fclose(f);
    return 0;
}
"""
