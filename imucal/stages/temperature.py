"""Temperature (method.md §12): a triad's bias as a polynomial in its temperature (M16), fitted
to the still blocks after the constant-bias calibration (M17), its order (0-3) chosen by
cross-validation over the blocks, and never extrapolated beyond the temperatures seen.

The rest of the model (misalignment, scale) stays as §3 and §4 fitted it: PX4 assumes the same,
and a session's still blocks hardly determine a scale's slope in temperature.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.errors import plural
from imucal.models import SensorModel, acc_model, acc_theta
from imucal.numerics.windows import samples_within

ORDERS = (0, 1, 2, 3)
# A span under this tells a slope from noise poorly (ArduPilot's limit for its own fit).
MIN_SPAN_C = 10.0
FOLDS = 5
# The fewest-terms order whose held-out error is within this factor of the lowest wins.
CV_TOLERANCE = 1.05


def block_temperatures(t_temp: np.ndarray, temp: np.ndarray,
                       block_times: np.ndarray) -> np.ndarray:
    """(B,) each still block's temperature: the mean of the temperature samples inside its time
    interval, or the temperature interpolated at its middle where none falls inside (a slow
    thermometer), NaN where the block lies outside the stream's time."""
    temp = np.asarray(temp, float).reshape(-1)
    idx = samples_within(t_temp, block_times)
    csum = np.concatenate([[0.0], np.cumsum(temp)])
    n = idx[:, 1] - idx[:, 0]
    inside = (csum[idx[:, 1]] - csum[idx[:, 0]]) / np.maximum(n, 1)
    mid = block_times.mean(axis=1)
    interp = np.interp(mid, t_temp, temp)
    out = np.where(n > 0, inside, interp)
    out[(mid < t_temp[0] - 1.0) | (mid > t_temp[-1] + 1.0)] = np.nan
    return out


@dataclass(frozen=True)
class BiasPolynomial:
    """M16 for one sensor: ``b(T) = b_0 + sum_j c_j (T - T_0)^j`` (``coefs[j]``, raw unit per
    deg C^j, ``coefs[0]`` the constant's offset from ``b_0``), held at its end values outside
    ``span``."""

    sensor: str  # "accelerometer" or "gyroscope"
    b0: np.ndarray  # (3,) the constant bias of M2 / M4, raw unit
    t0: float  # deg C, the middle of the span
    span: tuple[float, float]  # deg C, the still blocks' lowest and highest temperatures
    order: int
    coefs: np.ndarray  # (order + 1, 3)
    cv_rms: np.ndarray  # (4,) held-out RMS of the bias per order 0-3 (NaN: not tried), raw
    blocks: int
    notes: tuple[str, ...] = ()
    # The accelerometer's M2 with the small correction M17 fitted beside the polynomial (its
    # misalignments and scales; its bias b0): the model b(T) belongs to. None: the fit's own.
    model: SensorModel | None = None
    # (9, 9) the covariance of that model's parameters from the same fit (its residuals'
    # scatter): what the rotation between triads propagates (M13) once temperature is modelled.
    cov: np.ndarray | None = None
    # Each block's residual after the fit (the gyroscope's (n, 3) in its raw unit, the
    # accelerometer's (n,) norm residual in mg) and which of the run's blocks they are.
    residuals: np.ndarray | None = None
    used: np.ndarray | None = None  # (n,) block indices
    temps: np.ndarray | None = None  # (n,) those blocks' temperatures, deg C (the data points)
    hysteresis: str | None = None  # heating against cooling, said (method.md §12)
    # (3,) the scales' relative change per deg C about T_0 where the data determine it
    # (cross-validated beside the bias's order); None: the scales held constant.
    scale_slope: np.ndarray | None = None
    # (n,) each of those blocks' leg: +1 heating, -1 cooling, 0 neither (block_legs); None:
    # not known.
    legs: np.ndarray | None = None
    # (n,) the accelerometer's still-norm error |u_k| / |g| - 1 of each of those blocks with the
    # constant-bias fit (mg): what the polynomial was fitted to explain (M17's r_k).
    before_mg: np.ndarray | None = None
    # (n,) the same with this model, as apply uses it (M16 with M2, method.md §8): in-sample,
    # and each block predicted by the model fitted without it (the figures the verdict
    # judges; imucal.stages.temperature_judged). None: not computed (the gyroscope's).
    after_mg: np.ndarray | None = None
    held_out_mg: np.ndarray | None = None

    def points(self) -> np.ndarray | None:
        """(n, 3) the gyroscope's bias measured in each still block (raw unit): the data points
        M16 was fitted to (``b(T_k)`` plus the block's residual); None for the accelerometer,
        whose still blocks see its bias only along gravity."""
        if self.residuals is None or self.temps is None or self.residuals.ndim != 2:
            return None
        return self.bias_at(self.temps) + self.residuals

    def calibrated(self, raw: np.ndarray, temp: np.ndarray) -> np.ndarray:
        """(N, 3) ``T K (raw - b(T))`` (M2 with M16's bias) of raw readings at temperatures
        ``temp``; needs :attr:`model`."""
        m = self.model
        out = (np.asarray(raw, float) - self.bias_at(temp)) * m.K[None, :]
        if self.scale_slope is not None:
            x = np.clip(np.asarray(temp, float).reshape(-1), *self.span) - self.t0
            out *= 1.0 + self.scale_slope[None, :] * x[:, None]
        return out @ m.T.T

    def scale_at(self, temp: np.ndarray) -> np.ndarray:
        """(N, 3) the scales K at temperatures ``temp`` (needs :attr:`model`), constant
        outside the span."""
        x = np.clip(np.asarray(temp, float).reshape(-1), *self.span) - self.t0
        slope = np.zeros(3) if self.scale_slope is None else self.scale_slope
        return self.model.K[None, :] * (1.0 + slope[None, :] * x[:, None])

    def bias_at(self, temp: np.ndarray) -> np.ndarray:
        """(N, 3) the bias at temperatures ``temp``, constant outside the span (never
        extrapolated, method.md §12)."""
        x = np.clip(np.asarray(temp, float).reshape(-1), *self.span) - self.t0
        return self.b0 + sum(self.coefs[j][None, :] * x[:, None] ** j
                             for j in range(len(self.coefs)))

    @property
    def span_c(self) -> float:
        return self.span[1] - self.span[0]


def _levels(temps: np.ndarray) -> int:
    """Distinct temperatures (to 1 deg C): a polynomial of order p needs p + 1 of them (several
    sessions each at one temperature give one level each)."""
    return len(np.unique(np.round(temps)))


def _design(x: np.ndarray, order: int) -> np.ndarray:
    return np.vander(x, order + 1, increasing=True)


# A gyroscope block whose mean lies this many times the blocks' median distance from the
# others' polynomial is not still: a turn's start or end inside it (method.md §12).
OUTLIER_TIMES = 5.0


def _still_enough(temps: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(B,) False for a block whose bias sample ``d`` is far from a polynomial through the
    others (the highest order their temperatures allow, up to 3): beyond ``OUTLIER_TIMES``
    times the median distance, the median taken so that a hysteresis shifting half the blocks
    raises the bar rather than cutting them. Twice, as the polynomial moves without them."""
    keep = np.ones(len(temps), bool)
    p = min(3, _levels(temps) - 1, len(temps) - 5)
    if p < 0:
        return keep
    half = max(float(np.ptp(temps)) / 2, 1e-6)
    x = (temps - float(temps.min()) - half) / half
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(_design(x[keep], p), d[keep], rcond=None)
        dist = np.linalg.norm(d - _design(x, p) @ coef, axis=1)
        new = dist <= OUTLIER_TIMES * float(np.median(dist[keep]))
        if np.array_equal(new, keep) or new.sum() < len(temps) // 2:
            break
        keep = new
    return keep


def fit_bias_polynomial(temps: np.ndarray, d: np.ndarray, b0: np.ndarray,
                        sensor: str, legs: np.ndarray | None = None) -> BiasPolynomial | None:
    """M16 fitted to bias samples ``d`` (B, 3) less ``b0`` (a gyroscope's still block means)
    at block temperatures ``temps`` (B,): the order by ``FOLDS``-fold cross-validation over
    the blocks (sorted by temperature, every ``FOLDS``-th block in one fold, so each fold spans
    the range and none is extrapolated); None without two blocks of known temperature.
    ``legs`` (per block, :func:`block_legs`) is kept beside the data points."""
    ok = np.isfinite(temps) & np.all(np.isfinite(d), axis=1)
    moved = ~_still_enough(temps[ok], d[ok])
    ok[np.flatnonzero(ok)[moved]] = False
    temps, d = temps[ok], d[ok]
    b = len(temps)
    if b < 2:
        return None
    lo, hi = float(temps.min()), float(temps.max())
    t0 = (lo + hi) / 2
    half = max((hi - lo) / 2, 1e-6)
    x = (temps - t0) / half  # on [-1, 1]: a well-conditioned Vandermonde matrix
    fold = np.empty(b, int)
    fold[np.argsort(temps, kind="stable")] = np.arange(b) % FOLDS
    cv = np.full(len(ORDERS), np.nan)
    for p in ORDERS:
        if b - int(np.ceil(b / FOLDS)) < p + 2 or p >= _levels(temps):
            break  # each training set must over-determine it, at enough temperatures
        err = np.empty_like(d)
        for f in range(FOLDS):
            test = fold == f
            coef, *_ = np.linalg.lstsq(_design(x[~test], p), d[~test], rcond=None)
            err[test] = d[test] - _design(x[test], p) @ coef
        cv[p] = float(np.sqrt(np.mean(err**2)))
    notes = []
    if moved.any():
        notes.append(f"{sensor}: {plural(int(moved.sum()), 'still block')} left out: "
                     f"{'its' if moved.sum() == 1 else 'their'} mean lies beyond "
                     f"{OUTLIER_TIMES:g} times the blocks' median distance from a polynomial "
                     "through the others (the sensor turned in it: a block found by a noisier "
                     "accelerometer)")
    if np.all(np.isnan(cv)):
        order = 0
        notes.append(f"{sensor}: {b} still blocks with a temperature: too few to choose an "
                     "order, the bias is held constant at their mean")
    else:
        order = int(min(p for p in ORDERS if np.isfinite(cv[p])
                        and cv[p] <= CV_TOLERANCE * np.nanmin(cv)))
    coef, *_ = np.linalg.lstsq(_design(x, order), d, rcond=None)
    coefs = coef / half ** np.arange(order + 1)[:, None]  # per deg C^j
    if hi - lo < MIN_SPAN_C:
        notes.append(f"{sensor}: the still blocks span only {hi - lo:.1f} deg C ({lo:.1f} to "
                     f"{hi:.1f}), under the {MIN_SPAN_C:g} deg C that tell a slope from noise: "
                     "the bias model holds for that span only and is not extrapolated (kept "
                     "constant outside it); record over a wider temperature range")
    else:
        notes.append(f"{sensor}: bias of order {order} in temperature over {lo:.1f} to "
                     f"{hi:.1f} deg C ({b} still blocks), held constant outside that span")
    return BiasPolynomial(sensor=sensor, b0=np.asarray(b0, float), t0=t0, span=(lo, hi),
                          order=order, coefs=coefs, cv_rms=cv, blocks=b, notes=tuple(notes),
                          residuals=d - _design(x, order) @ coef, used=np.flatnonzero(ok),
                          temps=temps, legs=None if legs is None else np.asarray(legs)[ok])


def _norm_jacobian(means: np.ndarray, params: np.ndarray, eps: float = 1e-7) -> np.ndarray:
    """(B, 9) d|u_k| / d theta for u_k = T K (m_k - b) (M2), each block with its own parameters
    (``params`` (B, 9)); central differences, a loop over the 9 parameters and the blocks."""
    out = np.empty((len(means), 9))
    for k, (m, p) in enumerate(zip(means, params)):
        for j in range(9):
            h = eps * max(1.0, abs(float(p[j])))
            up, dn = p.copy(), p.copy()
            up[j] += h
            dn[j] -= h
            out[k, j] = (np.linalg.norm(acc_model(up).apply(m[None])[0])
                         - np.linalg.norm(acc_model(dn).apply(m[None])[0])) / (2 * h)
    return out


def _inside_others(temps: np.ndarray) -> np.ndarray:
    """(B,) True where a block's temperature lies within the other blocks' span: held out,
    it is interpolated, as the model is used (a block alone at an end of the span would be
    extrapolated, which the model never is, method.md §12)."""
    order = np.sort(temps)
    lo = np.where(temps == order[0], order[1], order[0])  # the others' lowest
    hi = np.where(temps == order[-1], order[-2], order[-1])  # the others' highest
    return (temps >= lo) & (temps <= hi)


def loo_residuals(a: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    """(B,) each row's leave-one-out residual of the least-squares fit ``a x = y``: its
    in-sample residual over ``1 - h_kk`` (PRESS; ``h_kk`` the hat matrix's diagonal, exact
    for a linear fit), None where some row alone determines a parameter (``h_kk`` = 1)."""
    q, rr = np.linalg.qr(a)
    if np.min(np.abs(np.diag(rr))) < 1e-10 * np.max(np.abs(np.diag(rr))):
        return None  # rank-deficient: the data do not determine every unknown
    h = np.sum(q**2, axis=1)
    if np.max(h) > 1.0 - 1e-6:
        return None
    res = y - q @ (q.T @ y)
    return res / (1.0 - h)


def fit_accel_bias_polynomial(temps: np.ndarray, means: np.ndarray,
                              models: list[SensorModel], g: float,
                              legs: np.ndarray | None = None) -> BiasPolynomial | None:
    """M16 for an accelerometer. A still block says only how far its calibrated norm is from
    ``|g|`` (M17 seen along gravity: a bias across gravity turns the vector and keeps its
    norm), so the polynomial is fitted to the blocks' norm residuals, linearised at the §3
    fit, together with a small correction of all of M2 (a drift the constant fit absorbed into
    a scale is given back): ``|u_k| - |g| + J_k dtheta + sum_j a_k (T_k - T_0)^j . c_j = 0``,
    ``a_k = d|u_k| / db``. The order is chosen by leave-one-out cross-validation (PRESS,
    :func:`loo_residuals`), scored on the blocks a held-out fit interpolates: with 9 + 3p
    unknowns from one norm per block, five folds leave too few blocks to try order 2 from 20
    poses (method.md §12). With
    ``legs`` (+1 heating, -1 cooling, 0 neither, per block), a bias step between the legs is
    fitted beside the chosen order and said (hysteresis)."""
    ok = np.isfinite(temps)
    legs = None if legs is None else np.asarray(legs)[ok]
    temps, means = temps[ok], means[ok]
    models = [m for m, keep in zip(models, ok) if keep]
    b = len(temps)
    if b < 10:
        return None
    params = np.array([acc_theta(m) for m in models])
    r = np.array([np.linalg.norm(m.apply(x[None])[0]) for m, x in zip(models, means)]) - g
    jac = _norm_jacobian(means, params)
    lo, hi = float(temps.min()), float(temps.max())
    t0 = (lo + hi) / 2
    half = max((hi - lo) / 2, 1e-6)
    x = (temps - t0) / half

    def design(rows: np.ndarray, order: int, slope: bool = False) -> np.ndarray:
        poly = [jac[rows, 6:9] * x[rows, None] ** j for j in range(1, order + 1)]
        scale = [jac[rows, 3:6] * x[rows, None]] if slope else []
        return np.hstack([jac[rows], *poly, *scale])

    scored = _inside_others(temps)
    # Both legs seen: the orders are compared with the legs' step (below) fitted beside each,
    # else a hysteresis several times the noise drowns their differences (method.md §12).
    two_legs = legs is not None and min((legs > 0).sum(), (legs < 0).sum()) >= MIN_LEG_BLOCKS
    step = (jac[:, 6:9] * ((legs < 0).astype(float) - (legs > 0))[:, None] / 2 if two_legs
            else np.zeros((b, 0)))
    # Candidates (order, scale slope), fewest unknowns first: the bias of order 0-3, each with
    # and without a linear slope of the scales (where the data determine one, method.md §12).
    candidates = sorted(((p, sl) for p in ORDERS for sl in (False, True)),
                        key=lambda c: (3 * c[0] + 3 * c[1], c[0]))
    cv_of: dict[tuple[int, bool], float] = {}
    for p, sl in candidates:
        if b - 1 < 9 + 3 * p + 3 * sl + step.shape[1] + 2 or p + sl >= _levels(temps):
            continue  # each training set (all blocks but one) must over-determine it
        err = loo_residuals(np.hstack([design(np.ones(b, bool), p, sl), step]), -r)
        if err is not None:
            cv_of[p, sl] = float(np.sqrt(np.mean(err[scored] ** 2)))
    cv = np.array([cv_of.get((p, False), np.nan) for p in ORDERS])
    notes = []
    slope = False
    if not cv_of:
        order = 0
        notes.append(f"accelerometer: {b} still blocks with a temperature: too few to fit a "
                     "bias in temperature beside M2's 9 parameters")
    else:
        best = min(cv_of.values())
        order, slope = next(c for c in candidates
                            if c in cv_of and cv_of[c] <= CV_TOLERANCE * best)
        short = [p for p in ORDERS
                 if b - 1 < 9 + 3 * p + step.shape[1] + 2 and p < _levels(temps)]
        if short:  # said: the order chosen is the highest these blocks could test
            p = short[0]
            need = 9 + 3 * p + step.shape[1] + 3
            notes.append(f"accelerometer: orders {p} and above not tried: {b} still blocks, "
                         f"and order {p} needs {need} (M2's 9 parameters and 3 per order from "
                         "one norm per block, one held out, two to spare); record more poses "
                         "for it")
    full = design(np.ones(b, bool), order, slope)
    sol, *_ = np.linalg.lstsq(full, -r, rcond=None)
    dof = max(b - full.shape[1], 1)
    cov = np.linalg.pinv(full.T @ full)[:9, :9] * float(np.sum((r + full @ sol) ** 2)) / dof
    c = sol[9:9 + 3 * order].reshape(order, 3) / half ** np.arange(1, order + 1)[:, None]
    coefs = np.vstack([sol[6:9][None, :], c])  # the constant's correction, then c_1..c_p
    b0 = models[0].b
    corrected = acc_model(np.r_[params[0][:6] + sol[:6], b0])
    scale_slope = None
    if slope:  # K(T) = K (1 + k (T - T_0)), k relative per deg C
        scale_slope = sol[-3:] / half / corrected.K
        notes.append("accelerometer: scales change with temperature by "
                     + ", ".join(f"{v * 1e6:+.0f}" for v in scale_slope)
                     + " ppm per deg C (x, y, z), which the still poses determine")
    hyst = None
    if two_legs:
        both = np.hstack([full, step])
        sol_h, *_ = np.linalg.lstsq(both, -r, rcond=None)
        ssr = float(np.sum((r + both @ sol_h) ** 2))
        cov_h = np.linalg.pinv(both.T @ both)[-3:, -3:] * ssr / max(b - both.shape[1], 1)
        m = corrected.matrix * 1e3 / g  # the step as the calibrated output sees it, in mg
        hyst = hysteresis_text("accelerometer", m @ sol_h[-3:], m @ cov_h @ m.T,
                               int((legs > 0).sum()), int((legs < 0).sum()), "mg")
        notes.append(hyst)
    if hi - lo < MIN_SPAN_C:
        notes.append(f"accelerometer: the still blocks span only {hi - lo:.1f} deg C ({lo:.1f} "
                     f"to {hi:.1f}), under the {MIN_SPAN_C:g} deg C that tell a slope from "
                     "noise: the bias model holds for that span only and is not extrapolated "
                     "(kept constant outside it); record over a wider temperature range")
    else:
        notes.append(f"accelerometer: bias of order {order} in temperature over {lo:.1f} to "
                     f"{hi:.1f} deg C ({b} still blocks), held constant outside that span")
    return BiasPolynomial(sensor="accelerometer", b0=np.asarray(b0, float), t0=t0,
                          span=(lo, hi), order=order, coefs=coefs, cv_rms=cv, blocks=b,
                          notes=tuple(notes), model=corrected, cov=cov,
                          residuals=(r + full @ sol) / g * 1e3, used=np.flatnonzero(ok),
                          temps=temps, hysteresis=hyst, scale_slope=scale_slope, legs=legs,
                          before_mg=r / g * 1e3)


# A block is on a heating or cooling leg where the temperature moves faster than this.
LEG_RATE_C_PER_S = 0.003  # 0.2 deg C a minute
LEG_WINDOW_S = 30.0  # each side of the block's middle, for that rate
MIN_LEG_BLOCKS = 5


def block_legs(t_temp: np.ndarray, temp: np.ndarray, block_times: np.ndarray) -> np.ndarray:
    """(B,) +1 where a block lies on a heating leg, -1 on a cooling one, 0 otherwise: the
    temperature's slope over ``LEG_WINDOW_S`` each side of the block's middle."""
    temp = np.asarray(temp, float).reshape(-1)
    mid = block_times.mean(axis=1)
    lo = np.maximum(mid - LEG_WINDOW_S, t_temp[0])
    hi = np.minimum(mid + LEG_WINDOW_S, t_temp[-1])
    slope = (np.interp(hi, t_temp, temp) - np.interp(lo, t_temp, temp)) / np.maximum(hi - lo,
                                                                                     1e-9)
    return np.where(slope > LEG_RATE_C_PER_S, 1, np.where(slope < -LEG_RATE_C_PER_S, -1, 0))


def hysteresis_text(sensor: str, diff: np.ndarray, cov: np.ndarray, n_up: int, n_down: int,
                    unit: str) -> str:
    """Heating against cooling said (method.md §12): the difference (a vector, ``cov`` its
    covariance), significant beyond 3 times its standard error ``sqrt(trace cov)``."""
    size, size_se = float(np.linalg.norm(diff)), float(np.sqrt(np.trace(cov)))
    head = (f"{sensor}: heating ({n_up} still poses) and cooling ({n_down}) legs differ by "
            f"{size:.3g} {unit} (+- {size_se:.2g})")
    if size > 3 * size_se:
        return f"{head}: hysteresis, which one polynomial in temperature cannot model"
    return f"{head}: no hysteresis beyond the noise"


def hysteresis(fit: BiasPolynomial, legs: np.ndarray, unit: str,
               scale: float = 1.0) -> str | None:
    """A gyroscope's heating against cooling: the mean residual of its fit on each leg, their
    difference (``scale`` turns it into ``unit``); None without ``MIN_LEG_BLOCKS`` on each
    leg. (The accelerometer's is fitted inside M17: :func:`fit_accel_bias_polynomial`.)"""
    if fit.residuals is None or fit.used is None or fit.residuals.ndim != 2:
        return fit.hysteresis
    leg = legs[fit.used]
    res = np.asarray(fit.residuals, float) * scale
    up, down = res[leg > 0], res[leg < 0]
    if len(up) < MIN_LEG_BLOCKS or len(down) < MIN_LEG_BLOCKS:
        return None
    diff = up.mean(axis=0) - down.mean(axis=0)
    cov = np.diag(up.var(axis=0, ddof=1) / len(up) + down.var(axis=0, ddof=1) / len(down))
    return hysteresis_text(fit.sensor, diff, cov, len(up), len(down), unit)
