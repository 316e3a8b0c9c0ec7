"""The Tikhonov fit, its covariance and the bounded 1-D search, against closed forms and
direct scipy / numpy computations (method.md §3 M3, §4 M5)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares, minimize_scalar

from imucal.numerics.least_squares import FactoredCov, fit_tikhonov, sandwich_cov, trace_of


def _stacked(residuals, theta0, lam):
    return lambda th: np.concatenate([residuals(th), np.sqrt(lam) * (th - theta0)])


# --- a linear problem: the regularised solution in closed form --------------------------------


@pytest.fixture()
def linear():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(40, 5)) * [1.0, 3.0, 0.2, 1.0, 10.0]
    truth = np.array([0.5, -1.0, 2.0, 0.1, -0.3])
    b = A @ truth + 0.05 * rng.normal(size=40)
    theta0 = np.array([0.0, 0.0, 1.0, 0.0, 0.0])
    return A, b, theta0


@pytest.mark.parametrize("lam", [0.0, 0.3, 30.0])
def test_linear_fit_is_the_closed_form(linear, lam):
    """``argmin |A t - b|^2 + lam |t - t0|^2 = (A'A + lam I)^-1 (A'b + lam t0)``."""
    A, b, theta0 = linear
    start = np.array([3.0, 3.0, -3.0, 3.0, 3.0])
    rep = fit_tikhonov(lambda th: A @ th - b, lambda th: A, start, theta0, lam, start_name="far")
    exact = np.linalg.solve(A.T @ A + lam * np.eye(5), A.T @ b + lam * theta0)
    np.testing.assert_allclose(rep.theta, exact, rtol=1e-9, atol=1e-12)
    # and it is what scipy gives on the stacked residual, called directly
    direct = least_squares(_stacked(lambda th: A @ th - b, theta0, lam), start, method="lm",
                           jac=lambda th: np.vstack([A, np.sqrt(lam) * np.eye(5)]))
    np.testing.assert_allclose(rep.theta, direct.x, rtol=1e-9, atol=1e-12)

    # the account: costs recomputed, not copied from the solver's own bookkeeping
    def cost(th):
        return float(np.sum((A @ th - b) ** 2) + lam * np.sum((th - theta0) ** 2))

    assert rep.cost_start == pytest.approx(cost(start), rel=1e-12)
    assert rep.cost == pytest.approx(cost(exact), rel=1e-12)
    assert rep.data_cost == pytest.approx(float(np.sum((A @ exact - b) ** 2)), rel=1e-10)
    assert rep.cost_start > 100 * rep.cost
    assert rep.start_name == "far" and np.array_equal(rep.start, start)
    assert rep.status in (1, 2, 3, 4) and "termination" in rep.message
    assert rep.nfev >= 2 and rep.njev >= 1 and rep.n_data == 40
    assert rep.jac_cond == pytest.approx(np.linalg.cond(A), rel=1e-10)
    np.testing.assert_array_equal(rep.jac, A)
    # the trace starts at the start, ends at the solution, and only goes down
    assert rep.trace_cost[0] == rep.cost_start and rep.trace_cost[-1] == rep.cost
    np.testing.assert_array_equal(rep.trace_theta[0], start)
    assert np.all(np.diff(rep.trace_cost) < 0)
    # standard errors: s^2 H^-1 A'A H^-1, H = A'A + lam I, s^2 = |r|^2 / (n - p)
    H_inv = np.linalg.inv(A.T @ A + lam * np.eye(5))
    s2 = np.sum((A @ exact - b) ** 2) / (40 - 5)
    np.testing.assert_allclose(rep.cov, s2 * H_inv @ A.T @ A @ H_inv, rtol=1e-8)
    np.testing.assert_allclose(rep.std, np.sqrt(np.diag(s2 * H_inv @ A.T @ A @ H_inv)), rtol=1e-8)


def test_max_nfev_stops_the_fit_and_says_so(linear):
    A, b, theta0 = linear
    # A stiff nonlinear twist so that one evaluation cannot be enough.
    rep = fit_tikhonov(lambda th: A @ np.sinh(th) - b, lambda th: A * np.cosh(th),
                       np.full(5, 2.0), theta0, 0.0, max_nfev=2)
    assert rep.status == 0 and "maximum number of function evaluations" in rep.message
    assert rep.nfev == 2


@pytest.mark.filterwarnings("ignore:invalid value encountered in log")
def test_nonfinite_start_raises(linear):
    A, b, theta0 = linear
    with pytest.raises(FloatingPointError):
        fit_tikhonov(lambda th: A @ np.log(th) - b, lambda th: A / th, -np.ones(5), theta0, 1.0)


# --- a nonlinear problem: the ellipsoid norm residual of M3 -----------------------------------


def _ellipsoid_problem(noise: float, seed: int = 0, unit: float = 1.0):
    """Points ``a`` with ``|D (a - c)| = 1``: the residual ``1 - |D (a - c)|`` with
    ``theta = (d_x, d_y, d_z, c_x / unit, c_y / unit, c_z / unit)`` is zero at the truth when
    noise-free. A small ``unit`` scales the centre's parameters badly against the others."""
    rng = np.random.default_rng(seed)
    truth = np.array([1.05, 0.95, 1.1, 0.03, -0.02, 0.05])
    u = rng.normal(size=(60, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pts = u / truth[:3] + truth[3:] + noise * rng.normal(size=(60, 3))
    truth[3:] /= unit

    def res(th):
        return 1.0 - np.linalg.norm(th[:3] * (pts - unit * th[3:]), axis=1)

    def jac(th):
        v = th[:3] * (pts - unit * th[3:])
        n = np.linalg.norm(v, axis=1, keepdims=True)
        return np.hstack([-(v / n) * (pts - unit * th[3:]), unit * (v / n) * th[:3]])

    return truth, res, jac


def test_ellipsoid_recovers_the_truth_without_noise():
    truth, res, jac = _ellipsoid_problem(noise=0.0)
    theta0 = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    rep = fit_tikhonov(res, jac, theta0, theta0, 0.0)
    np.testing.assert_allclose(rep.theta, truth, atol=1e-9)
    assert rep.cost < 1e-20 and rep.cost_start > 1e-3


FAR = (3.0, 0.3, 2.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize(("lam", "unit", "start"), [
    (1e-4, 1.0, None), (0.1, 1.0, None), (10.0, 1.0, None), (1e-4, 1e-3, None),
    (1e-4, 1.0, FAR)])
def test_ellipsoid_matches_a_direct_scipy_call(lam, unit, start):
    """The same steps as scipy's LM with MINPACK's own column scaling (``x_scale="jac"``,
    scipy's default only since 1.16): from the far start the trust region binds, and
    another scaling ends 1e-7 away."""
    truth, res, jac = _ellipsoid_problem(noise=0.01, seed=4, unit=unit)
    theta0 = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    start = theta0 if start is None else np.array(start)
    rep = fit_tikhonov(res, jac, start, theta0, lam)
    f = _stacked(res, theta0, lam)
    direct = least_squares(f, start, jac=lambda th: np.vstack([jac(th), np.sqrt(lam) *
                                                               np.eye(6)]),
                           method="lm", x_scale="jac")
    np.testing.assert_allclose(rep.theta, direct.x, rtol=1e-12, atol=1e-14)
    assert rep.nfev == direct.nfev and rep.status == direct.status
    assert rep.cost == pytest.approx(2 * direct.cost, rel=1e-12)  # scipy's cost is half
    r = f(rep.theta)
    assert rep.cost == pytest.approx(float(r @ r), rel=1e-12)
    assert rep.cost_start == pytest.approx(float(f(start) @ f(start)), rel=1e-12)
    # a solution, not merely a stop: every component of the regularised cost's gradient
    # fell by five orders of magnitude or more from the start (ftol stops LM near there)
    grad = jac(rep.theta).T @ res(rep.theta) + lam * (rep.theta - theta0)
    grad_start = jac(start).T @ res(start) + lam * (start - theta0)
    assert np.all(np.abs(grad) < 1e-5 * np.abs(grad_start))
    if lam == 10.0:  # a strong pull: the solution sits visibly between prior and truth
        assert 0 < np.linalg.norm(rep.theta - theta0) < 0.9 * np.linalg.norm(truth - theta0)


def test_finite_differences_agree_with_the_analytic_jacobian():
    _, res, jac = _ellipsoid_problem(noise=0.01, seed=4)
    theta0 = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
    calls = []

    def counted(th):
        calls.append(th.copy())
        return res(th)

    exact = fit_tikhonov(res, jac, theta0, theta0, 0.1)
    fd = fit_tikhonov(counted, None, theta0, theta0, 0.1)
    np.testing.assert_allclose(fd.theta, exact.theta, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(fd.jac, jac(fd.theta), rtol=1e-5, atol=1e-7)
    # the trace holds the steps only, not the difference quotients' evaluations
    assert len(fd.trace_cost) == len(exact.trace_cost)
    # one evaluation per trial point and six per Jacobian (the residuals at the point are
    # reused); one more Jacobian at the solution, for the covariance
    assert len(calls) <= fd.nfev + 6 * (fd.njev + 1)


# --- covariance ----------------------------------------------------------------------------------


def _random_factored(rng, m: int, r: int, upper: bool) -> FactoredCov:
    U = rng.normal(size=(3 * m, r))
    C = np.cov(rng.normal(size=(r, 3 * r)))
    L = rng.normal(size=(m, 3, 3)) * 0.1
    diag = L @ np.transpose(L, (0, 2, 1)) + 0.5 * np.eye(3)
    up = 0.05 * rng.normal(size=(m - 1, 3, 3)) if upper else None
    return FactoredCov(U, C, diag, up)


def _dense(fc: FactoredCov) -> np.ndarray:
    """U C U' + B assembled element by element, the plain way."""
    m = len(fc.diag)
    B = np.zeros((3 * m, 3 * m))
    for k in range(m):
        B[3 * k:3 * k + 3, 3 * k:3 * k + 3] = fc.diag[k]
        if fc.upper is not None and k + 1 < m:
            B[3 * k:3 * k + 3, 3 * k + 3:3 * k + 6] = fc.upper[k]
            B[3 * k + 3:3 * k + 6, 3 * k:3 * k + 3] = fc.upper[k].T
    return fc.U @ fc.C @ fc.U.T + B


@pytest.mark.parametrize("upper", [False, True])
def test_factored_cov_matches_its_dense_form(upper):
    rng = np.random.default_rng(7)
    fc = _random_factored(rng, m=6, r=4, upper=upper)
    dense = _dense(fc)
    np.testing.assert_allclose(np.asarray(fc), dense, rtol=1e-13, atol=1e-13)
    assert trace_of(fc) == pytest.approx(np.trace(dense), rel=1e-13)
    assert trace_of(dense) == pytest.approx(np.trace(dense), rel=1e-13)
    J = rng.normal(size=(18, 5))
    np.testing.assert_allclose(fc.quad(J), J.T @ dense @ J, rtol=1e-11, atol=1e-11)
    keep = np.array([True, True, False, True, True, True])
    rows = np.repeat(keep, 3)
    np.testing.assert_allclose(np.asarray(fc.select(keep)), dense[np.ix_(rows, rows)],
                               rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("meat_kind", [None, "dense", "factored"])
def test_sandwich_cov_against_numpy(meat_kind):
    """``H^-1 J' (s2 I + M) J H^-1`` with ``H = J'J + lam I``, formed densely."""
    rng = np.random.default_rng(11)
    J = rng.normal(size=(24, 6)) * [1, 2, 0.1, 1, 5, 1]
    lam, s2 = 0.2, 0.03
    meat = None
    M = np.zeros((24, 24))
    if meat_kind is not None:
        fc = _random_factored(rng, m=8, r=3, upper=True)
        M = _dense(fc)
        meat = fc if meat_kind == "factored" else M
    cov, cond = sandwich_cov(J, lam, s2, meat)
    Hi = np.linalg.inv(J.T @ J + lam * np.eye(6))
    expect = Hi @ J.T @ (s2 * np.eye(24) + M) @ J @ Hi
    np.testing.assert_allclose(cov, expect, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(cov, cov.T, rtol=1e-10, atol=1e-14)
    assert cond == pytest.approx(np.linalg.cond(J), rel=1e-10)


def test_sandwich_cov_of_a_rank_deficient_jacobian():
    J = np.zeros((10, 3))
    J[:, 0] = 1.0
    cov, cond = sandwich_cov(J, 0.0, 1.0)
    assert cond == np.inf and np.all(np.isinf(cov))
    cov, _ = sandwich_cov(J, 0.5, 1.0)  # the regularisation makes it invertible
    assert np.all(np.isfinite(cov)) and cov[0, 0] == pytest.approx(10 / 10.5 ** 2)


# --- the bounded 1-D search of the gyroscope's nominal scale (stages/gyro.py) -----------------


def test_bounded_scalar_search_finds_a_known_scale():
    """The shape of the gyroscope's scale search: gravity directions turned about z by
    ``s_true`` times a raw angle; the cost over ``log s`` has its minimum at ``log s_true``."""
    rng = np.random.default_rng(2)
    raw = rng.uniform(500, 2000, size=12) * rng.choice([-1, 1], size=12)  # counts * s
    s_true = 1.0 / 939.65
    u = rng.normal(size=(12, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)

    def turn(a):
        c, s = np.cos(a), np.sin(a)
        return np.column_stack([c * u[:, 0] - s * u[:, 1], s * u[:, 0] + c * u[:, 1], u[:, 2]])

    meas = turn(s_true * raw)

    def cost(log_s):
        r = meas - turn(np.exp(log_s) * raw)
        return float(np.sum(r * r))

    lo, hi = np.log(s_true / 1.19), np.log(s_true * 1.3)
    best = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    assert abs(best.x - np.log(s_true)) < 1e-6
    assert best.success and best.fun < 1e-10
    # a minimum at the bound: the search returns the bound, within its tolerance
    edge = minimize_scalar(lambda x: (x - 5.0) ** 2, bounds=(0.0, 1.0), method="bounded",
                           options={"xatol": 1e-6})
    assert 1.0 - 1e-5 < edge.x <= 1.0
