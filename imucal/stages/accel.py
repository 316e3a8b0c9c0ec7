"""Accelerometer calibration (method.md §3: M2, M3 and the L-curve)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from imucal.errors import ImucalError
from imucal.models import ACC_PARAM_NAMES, ACC_THETA0, SensorModel, acc_theta
from imucal.numerics.determinacy import Determinacy, determinacy
from imucal.numerics.lcurve import lcurve_corner
from imucal.numerics.least_squares import FactoredCov, FitReport, fit_tikhonov, sandwich_cov
from imucal.numerics.windows import block_means, centred_segment_sums
from imucal.settings import AccSettings, Settings
from imucal.stages.accel_points import (
    BlockNoise,
    FitPoints,
    block_scatter,
    excess_variance,
    jacobian,
    ml_points,
    residuals,
    select_points,
)
from imucal.stages.accel_start import (
    Nominal,
    ellipsoid_start,
    make_nominal,
    sphere_fit,
    to_raw_model,
)
from imucal.warning import RunWarning

TIE_RTOL = 1e-10  # regularised costs this close (relative) are the same minimum
EXCESS_ROUNDS = 3  # renewals of the ML weights with the excess variance tau^2
# A parameter the data alone (method.md M6) pin no better than this (nominal frame: 1 = |g|
# for a scale or a bias, 1 rad for a misalignment, each moving the calibrated output by about
# its own size in units of |g|) is undetermined (issue 27): a pose along the direction it
# governs could be off by more than the verdict's not-usable limit, 10 mg
# (imucal.stages.verdict.ACC_POOR_MG), one standard error away. Measured: 6e-5 to 1.8e-4 on
# well-posed synthetic sessions and the sample; 0.03 to 2e4 for the parameters a coplanar
# session leaves open.
UNDETERMINED_STD = 0.01


@dataclass(frozen=True)
class LCurve:
    lambdas: np.ndarray
    residual_norm: np.ndarray  # rho = |r_data|
    solution_norm: np.ndarray  # eta = |theta - theta_0| (nominal frame)
    thetas: np.ndarray  # (L, 9) nominal-frame solutions
    corner: int  # index of the chosen lambda, -1 when lambda was fixed off the grid
    curvature: np.ndarray

    SAME_FIT = 1e-3  # two fits are "the same" when their rho and eta agree to 0.1 %

    @property
    def same_fit_until(self) -> int:
        """Index of the largest lambda whose fit is the smallest lambda's (rho and eta both
        within :attr:`SAME_FIT` of its): below it the prior changes nothing."""
        rho, eta = np.asarray(self.residual_norm, float), np.asarray(self.solution_norm, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            same = ((np.abs(rho / rho[0] - 1) <= self.SAME_FIT)
                    & (np.abs(eta / eta[0] - 1) <= self.SAME_FIT))
        return int(np.argmin(same) - 1) if not same.all() else len(same) - 1

    @property
    def well_posed(self) -> bool:
        """No L (M3): the chosen lambda lies on the flat stretch where every lambda gives the
        unregularised fit (or just past it), so the data fix the parameters unaided and the
        "corner" is only where the prior starts to bias them; an ill-posed fit's L has eta
        falling steeply before rho rises, far past the flat stretch."""
        return 0 <= self.corner <= self.same_fit_until + 1


@dataclass(frozen=True)
class AccFit:
    """The accelerometer calibration of one segment, in the raw signal's units."""

    model: SensorModel  # a = T K (a_raw - b), a in units of |g| (g_out)
    # standard errors of (a_yz, a_zy, a_zx, s_x, s_y, s_z, b_x, b_y, b_z) from the data alone
    # (the prior is no measurement), NaN for the undetermined ones (numerics/determinacy.py)
    std: np.ndarray
    cov: np.ndarray  # (9, 9) the regularised estimator's covariance, raw units (propagated)
    theta_nominal: np.ndarray
    nominal: Nominal
    g_out: float
    lam: float
    report: FitReport
    starts: dict[str, float]  # regularised cost reached from each start
    lcurve: LCurve | None
    n_points: int
    n_blocks: int
    sweep: LambdaSweep | None = None  # the L-curve's solutions in raw units (None: fixed lambda)
    warnings: list[RunWarning] = field(default_factory=list)
    points: FitPoints | None = None  # the data fitted: weights, targets, noise model (M3)
    undetermined: tuple[str, ...] = ()  # parameters the data do not determine (UNDETERMINED_STD)

    def model_for(self, theta_nominal: np.ndarray) -> SensorModel:
        """The raw-unit model of a nominal-frame solution (an L-curve point, an LM step)."""
        return to_raw_model(theta_nominal, self.nominal, self.g_out)

    @property
    def params(self) -> np.ndarray:
        """(9,) the solution's raw-unit parameters, in ``ACC_PARAM_NAMES`` order."""
        return acc_theta(self.model)

    @property
    def trace_params(self) -> np.ndarray:
        """(I, 9) raw-unit parameters at each accepted step of the fit (``report.trace_theta``,
        what the optimiser's report records), in ``ACC_PARAM_NAMES`` order."""
        return raw_params(self.report.trace_theta, self.nominal, self.g_out)

    def nominal_norm(self, acc_raw: np.ndarray) -> np.ndarray:
        """``|a_raw|`` through the nominal frame, in the calibrated unit: what the sensor reads
        before calibration (the raw signal itself for input in g or m/s^2; offset and scale of
        the sphere fit for raw counts), to set beside the calibrated magnitude."""
        return np.linalg.norm(self.nominal.to_nominal(acc_raw), axis=1) * self.g_out


def _fit(data: FitPoints, lam: float, start: np.ndarray, name: str) -> FitReport:
    return fit_tikhonov(data.residuals, data.jacobian, start, ACC_THETA0, lam, start_name=name)


def best_fit(data: FitPoints, lam: float, starts: dict[str, np.ndarray]
             ) -> tuple[FitReport, dict[str, float]]:
    """Run LM from every start; keep the lowest regularised cost (the thesis's local minima)."""
    reports = {}
    for name, th in starts.items():
        try:
            reports[name] = _fit(data, lam, th, name)
        except FloatingPointError:
            continue
    if not reports:
        raise ImucalError("the accelerometer fit produced non-finite residuals from every start",
                          source="accelerometer", field="fit")
    # Starts that reach the same minimum differ in cost by rounding only (1e-14 relative):
    # count those as ties, and break ties by name, so that which start "won" does not depend
    # on the last bit of the arithmetic.
    low = min(r.cost for r in reports.values())
    tied = [r for r in reports.values() if r.cost <= low + TIE_RTOL * abs(low)]
    best = min(tied, key=lambda r: r.start_name)
    return best, {k: r.cost for k, r in reports.items()}


def calibrate_accelerometer(acc: np.ndarray, blocks: np.ndarray, *, acc_unit: str, g_in: float,
                            g_out: float, settings: AccSettings = Settings().acc,
                            nominal: Nominal | None = None) -> AccFit:
    """Fit M2 to the still blocks of one segment by M3, lambda from the L-curve or fixed.

    ``g_in`` is |g| in the raw signal's units (1 for g, 9.80665 for m/s^2; unused for counts)
    and ``g_out`` the norm the calibrated still samples must have.
    """
    noise = None
    if settings.points == "ml" and len(blocks):
        pts_raw, noise = block_scatter(acc, blocks)
    else:
        pts_raw, _ = select_points(acc, blocks, settings.points, settings.n_select,
                                   settings.n_group)
    return fit_points(pts_raw, noise, len(blocks), lambda: block_means(acc, blocks),
                      acc_unit=acc_unit, g_in=g_in, g_out=g_out, settings=settings,
                      nominal=nominal)


def fit_points(pts_raw: np.ndarray, noise: BlockNoise | None, n_blocks: int,
               sweep_means: Callable[[], np.ndarray], *, acc_unit: str, g_in: float,
               g_out: float, settings: AccSettings = Settings().acc,
               nominal: Nominal | None = None) -> AccFit:
    """M3 on fit points already made (raw units): the block means and their noise for the
    "ml" points (``noise`` None for the other modes). :func:`calibrate_accelerometer` makes
    them from the samples; a live capture from the block means it keeps (method.md §13).
    ``sweep_means`` gives the blocks' raw means for the L-curve's sweep, when there is one."""
    if len(pts_raw) < 9:
        raise ImucalError(f"only {n_blocks} static blocks ({len(pts_raw)} fit points); the "
                          "9-parameter accelerometer model needs at least 9 points from several "
                          "orientations", source="accelerometer", field="static blocks")
    if settings.lam != "auto":
        if not np.isfinite(float(settings.lam)) or float(settings.lam) < 0:
            raise ImucalError(f"lambda must be 'auto' or a number >= 0, got {settings.lam!r}",
                              source="settings", field="lambda")
    nominal = nominal or make_nominal(pts_raw, acc_unit, g_in)
    pts = nominal.to_nominal(pts_raw)

    starts = {"prior": ACC_THETA0.copy()}
    ell = ellipsoid_start(pts)
    if ell is not None and np.all(ell[3:6] > 0):
        starts["ellipsoid"] = ell
    if noise is None:
        data = FitPoints.plain(pts)
        curve, report, start_costs = _solve(data, settings, starts)
    else:
        noise = BlockNoise(n=noise.n, var=noise.var / nominal.scale**2)
        data, curve, report, start_costs = _solve_ml(pts, noise, settings, starts)

    det = _determinacy(report, data)
    warnings = _sanity(report, pts, pts_raw, nominal, det)
    theta = report.theta
    model = to_raw_model(theta, nominal, g_out)
    k_scale = g_out / nominal.scale  # standard errors scale as the parameters do
    d = np.r_[np.ones(3), np.full(3, k_scale), np.full(3, nominal.scale)]
    cov = _cov_nominal(report, data) * np.outer(d, d)
    std = det.std * d
    sweep = None if curve is None else lambda_sweep(curve, nominal, g_out, sweep_means())
    return AccFit(model=model, std=std, cov=cov, theta_nominal=theta, nominal=nominal, g_out=g_out,
                  lam=report.lam, report=report, starts=start_costs, lcurve=curve,
                  n_points=len(pts), n_blocks=n_blocks, sweep=sweep, warnings=warnings,
                  points=data, undetermined=det.undetermined)


def _s2(report: FitReport, data: FitPoints) -> float | None:
    """The variance of one weighted residual the noise model gives ("ml" points; see
    :func:`_cov_nominal`), None for the point modes without one."""
    if data.white_var is None:
        return None
    return float(np.mean(data.weight**2 * (data.white_var + data.excess_var)))


def _determinacy(report: FitReport, data: FitPoints) -> Determinacy:
    """The data-only standard errors (nominal frame) and the parameters they leave open."""
    s2 = _s2(report, data)
    if s2 is None:  # the fit's own estimate, as report.cov's
        s2 = report.data_cost / max(report.n_data - len(report.theta), 1)
    return determinacy(report.jac, s2, ACC_PARAM_NAMES, UNDETERMINED_STD)


def _cov_nominal(report: FitReport, data: FitPoints) -> np.ndarray:
    """Covariance of the nominal-frame parameters, from the weighted Jacobian (sandwich form).

    The "ml" data know the variance of each weighted residual, ``w_k^2 (v_k + tau^2)`` (the
    same for every block, see :func:`ml_points`), from the blocks' own scatter of thousands of
    samples; the fit's residuals estimate it from ``B - 9`` degrees of freedom (a 30-block fit
    gives it to +-30 %, its standard errors to +-15 %). Where the residuals scatter more
    than white noise, ``tau^2`` has already taken that up; where they scatter less, the noise
    model's larger value is kept. Other point modes have no noise model: the fit's own
    estimate.
    """
    s2 = _s2(report, data)
    if s2 is None:
        return report.cov
    cov, _ = sandwich_cov(report.jac, report.lam, s2)
    return cov


def _solve(data: FitPoints, settings: AccSettings, starts: dict[str, np.ndarray]
           ) -> tuple[LCurve | None, FitReport, dict[str, float]]:
    """M3 on ``data`` at the L-curve's corner or at the fixed lambda."""
    if settings.lam == "auto":
        curve, (report, costs) = _lcurve(data, np.asarray(settings.lambdas, float), starts)
        return curve, report, costs
    report, costs = best_fit(data, float(settings.lam), starts)
    return None, report, costs


def _solve_ml(pts: np.ndarray, noise: BlockNoise, settings: AccSettings,
              starts: dict[str, np.ndarray]
              ) -> tuple[FitPoints, LCurve | None, FitReport, dict[str, float]]:
    """The ML fit (:func:`~imucal.stages.accel_points.ml_points`), its weights from the data.

    First with white-noise weights (``sqrt(n_k)``), their reference the closed-form start.
    Where the fit's residuals scatter more between blocks than white noise explains, the
    common excess ``tau^2`` is estimated (:func:`excess_variance`) and the weights renewed
    with it, their reference now the fit itself, and the fit repeated at the chosen lambda,
    until ``tau^2`` settles (a few rounds); the L-curve is then run once more on the final
    weights, so the curve, lambda and solution recorded are those of the data fitted.
    """
    data = ml_points(pts, noise, starts.get("ellipsoid", ACC_THETA0))
    first = data
    curve, report, costs = _solve(data, settings, starts)
    for _ in range(EXCESS_ROUNDS):
        r = residuals(report.theta, pts, data.target)
        tau2 = excess_variance(r, data.white_var, _dof(report))
        if abs(tau2 - data.excess_var) <= 0.05 * max(tau2, data.excess_var):
            break
        data = ml_points(pts, noise, report.theta, tau2)
        report, costs = best_fit(data, report.lam,
                                 {**starts, f"{report.start_name}, reweighted": report.theta})
    if data is not first and settings.lam == "auto":
        curve, report, costs = _solve(data, settings, starts)
    return data, curve, report, costs


def _dof(report: FitReport) -> float:
    """Residual degrees of freedom of a regularised fit: points minus the effective number of
    parameters, ``tr((J'J + lambda I)^-1 J'J)`` (9 at lambda = 0)."""
    J = report.jac
    JtJ = J.T @ J
    try:
        p_eff = float(np.trace(np.linalg.solve(JtJ + report.lam * np.eye(len(JtJ)), JtJ)))
    except np.linalg.LinAlgError:
        p_eff = float(J.shape[1])
    return J.shape[0] - p_eff


def _lcurve(data: FitPoints, lambdas: np.ndarray, starts: dict[str, np.ndarray]
            ) -> tuple[LCurve, tuple[FitReport, dict[str, float]]]:
    """Solve on the lambda grid, record (rho, eta), pick the corner (thesis ch. 5).

    Every start is tried at the smallest lambda; each larger lambda then starts from the
    previous solution (continuation), which follows one branch of minima along the curve and
    costs one LM run per grid point. At the corner every start is tried again, so the
    solution returned is the best one found for the chosen lambda. ``rho`` is the norm of the
    weighted data residuals, the part of the cost the fit minimises besides the prior.
    """
    lambdas = np.sort(lambdas)
    first, _ = best_fit(data, float(lambdas[0]), starts)
    fits = [first]
    for lam in lambdas[1:]:
        fits.append(_fit(data, float(lam), fits[-1].theta, fits[-1].start_name))
    rho = np.array([f.residual_norm for f in fits])
    eta = np.array([f.solution_norm(ACC_THETA0) for f in fits])
    corner, curv = lcurve_corner(lambdas, rho, eta)
    curve = LCurve(lambdas=lambdas, residual_norm=rho, solution_norm=eta,
                   thetas=np.array([f.theta for f in fits]), corner=corner, curvature=curv)
    return curve, best_fit(data, float(lambdas[corner]),
                           {**starts, f"{fits[corner].start_name}, continued along the L-curve":
                            fits[corner].theta})


def _sanity(report: FitReport, pts: np.ndarray, pts_raw: np.ndarray, nominal: Nominal,
            det: Determinacy) -> list[RunWarning]:
    """Flag the escape routes of the norm cost (method.md §3) instead of returning them."""
    out: list[RunWarning] = []
    th = report.theta
    if np.any(th[3:6] <= 0):
        out.append(RunWarning("acc_scale_not_positive", "accelerometer fit reached a "
                              "non-positive scale: the result is not physical"))
    elif np.any((th[3:6] < 0.5) | (th[3:6] > 2.0)):
        out.append(RunWarning("acc_scale_far", f"accelerometer scales "
                              f"{np.round(th[3:6], 3).tolist()} are far from the nominal 1: check "
                              "the units and the still blocks"))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    if np.any(th[6:9] < lo - 0.5) or np.any(th[6:9] > hi + 0.5):
        out.append(RunWarning("acc_bias_outside", "accelerometer bias lies outside the range "
                              "of the signal: the fit took the 'huge sphere' escape route; record "
                              "more orientations"))
    if report.cost > report.cost_start * (1 + 1e-9):
        out.append(RunWarning("acc_cost_rose", "accelerometer fit ended with a higher cost "
                              "than it started from"))
    weak = det.undetermined
    if weak:
        # Plain words first; the fit's condition number (method.md §3) last, for who wants it.
        out.append(RunWarning("acc_undetermined", f"the still poses do not determine "
                              f"{', '.join(weak)}: kept near the nominal value, not measured "
                              f"(the data alone leave each more than {UNDETERMINED_STD:g} "
                              "uncertain; no standard error given); the other figures cannot "
                              "see the directions they govern: record poses in more directions "
                              f"(condition number {report.jac_cond:.3g})"))
    if np.max(np.abs(th[:3])) > 0.2:
        out.append(RunWarning("acc_misalignment_large", f"accelerometer misalignment angles "
                              f"{np.round(th[:3], 3).tolist()} rad are implausibly large"))
    return out


def output_sensitivity(model: SensorModel, raw: np.ndarray) -> np.ndarray:
    """d y / d theta (raw units) of ``y = T K (raw - b)`` for each row of ``raw``: (B, 3, 9)."""
    T, K = model.T, model.K
    v = raw - model.b
    u = v * K
    S = np.zeros((len(raw), 3, 9))
    S[:, 0, 0] = -u[:, 1]
    S[:, 0, 1] = u[:, 2]
    S[:, 1, 2] = -u[:, 2]
    S[:, :, 3:6] = T[None, :, :] * v[:, None, :]
    S[:, :, 6:9] = -T[None, :, :] * K[None, None, :]
    return S


def block_mean_cov(acc: np.ndarray, blocks: np.ndarray, fit: AccFit) -> FactoredCov:
    """Covariance (3B, 3B) of the calibrated block means: sensor noise averaged over each
    block (independent between blocks) plus the calibration's own uncertainty, which is
    common to all blocks. Feeds honest standard errors to the gyroscope fit (M5 compares
    directions that carry both).

    Returned factored (``S cov S'`` plus 3 x 3 noise blocks on the diagonal, see
    :class:`~imucal.numerics.least_squares.FactoredCov`): the dense matrix grows with the
    square of the number of blocks (``np.asarray`` gives it)."""
    n = (blocks[:, 1] - blocks[:, 0]).astype(float)
    s1, s2 = centred_segment_sums(acc, blocks[:, 0], blocks[:, 1], acc[0])  # no copy of acc
    m1, m2 = s1 / n[:, None], s2 / n[:, None]
    var_mean = np.clip(m2 - m1 * m1, 0, None) / np.maximum(n - 1, 1)[:, None]  # per axis
    return mean_cov(m1 + acc[0], var_mean, fit)


def mean_cov(means: np.ndarray, var_mean: np.ndarray, fit: AccFit) -> FactoredCov:
    """:func:`block_mean_cov` from the blocks' raw means (B, 3) and the per-axis variances of
    those means (B, 3), as a live capture keeps them (method.md §13)."""
    B = len(means)
    M = fit.model.matrix
    noise = np.einsum("ij,bj,kj->bik", M, var_mean, M)  # M diag(var/n) M'
    S = output_sensitivity(fit.model, means).reshape(3 * B, 9)
    return FactoredCov(S, fit.cov, noise)


def undetermined(J: np.ndarray, names: tuple[str, ...], rel: float = 1e-3) -> list[str]:
    """Parameters that the data barely constrain: the main components of the right singular
    vectors whose singular values are below ``rel`` times the largest."""
    _, sv, vt = np.linalg.svd(J, full_matrices=False)
    weak: list[str] = []
    for s_i, v in zip(sv, vt):
        if s_i < rel * sv[0]:
            for j in np.flatnonzero(np.abs(v) > 0.3):
                if names[j] not in weak:
                    weak.append(names[j])
    return weak


@dataclass(frozen=True)
class LambdaSweep:
    """What each lambda of the L-curve would have given (thesis ch. 5): its solution in raw
    units and the error it leaves on the still blocks, the figure the corner is judged by."""

    params: np.ndarray  # (L, 9) raw-unit parameters at each of LCurve.lambdas (ACC_PARAM_NAMES)
    block_norm_error_mg: np.ndarray  # (L, B) |mean a| / |g| - 1 of each still block, mg

    @property
    def static_norm_rms_mg(self) -> np.ndarray:
        """(L,) RMS over the still blocks: the quality figure (method.md §5) at each lambda."""
        return np.sqrt(np.mean(np.square(self.block_norm_error_mg), axis=1))

    @property
    def static_norm_max_mg(self) -> np.ndarray:
        """(L,) the largest block error in absolute value at each lambda."""
        return np.max(np.abs(self.block_norm_error_mg), axis=1)


def raw_params(thetas: np.ndarray, nominal: Nominal, g_out: float) -> np.ndarray:
    """(k, 9) raw-unit parameters of nominal-frame solutions (rows of ``thetas``)."""
    return np.array([acc_theta(to_raw_model(th, nominal, g_out)) for th in thetas]).reshape(-1, 9)


def lambda_sweep(curve: LCurve, nominal: Nominal, g_out: float, means_raw: np.ndarray
                 ) -> LambdaSweep:
    """The L-curve's solutions in raw units, each applied to the still blocks' raw means: the
    model is affine, so calibrating a block's mean equals averaging its calibrated samples."""
    errors = np.empty((len(curve.thetas), len(means_raw)))
    for i, th in enumerate(curve.thetas):
        a = to_raw_model(th, nominal, g_out).apply(means_raw)
        errors[i] = (np.linalg.norm(a, axis=1) / g_out - 1.0) * 1e3
    return LambdaSweep(params=raw_params(curve.thetas, nominal, g_out),
                       block_norm_error_mg=errors)


# The stage's interface; jacobian, residuals and select_points (accel_points.py) are re-exported
# for the grouping (group.py) and the pipeline.
__all__ = ["AccFit", "FitPoints", "LCurve", "LambdaSweep", "Nominal", "best_fit", "block_mean_cov",
           "calibrate_accelerometer", "ellipsoid_start", "fit_points", "jacobian", "lambda_sweep",
           "make_nominal", "mean_cov", "output_sensitivity", "residuals", "select_points",
           "sphere_fit", "to_raw_model", "undetermined"]
