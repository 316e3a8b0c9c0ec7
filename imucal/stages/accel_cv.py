"""The accelerometer fit judged on still blocks it did not see (method.md §5, out-of-sample).

In-sample figures flatter a fit with few orientations: with 9 parameters and 10 blocks the
fit can bend to each block's noise (measured: 0.045 mg in-sample against 2.3 mg on
independently detected blocks with 7 orientations). Here every still block is predicted by the
fit without it (leave-one-block-out): the refit is the Gauss-Newton step from the full fit
(:func:`imucal.numerics.kfold.kfold_refits`), exact to first order and one (9, 9) solve per
block, so it costs nothing next to the fit itself.

When the held-out error is much larger than the in-sample one, the fit is overfitted: the
result names the parameters the data cannot pin (their data-only standard errors,
:mod:`imucal.numerics.determinacy`) and the directions of the sphere that no pose covers, so
a user knows what to record.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from imucal.models import ACC_THETA0
from imucal.numerics.kfold import kfold_refits
from imucal.stages.accel import AccFit, to_raw_model

# Held-out RMS above this many times the in-sample one is overfitting, and above 1.5 times
# what a well-posed fit of this size shows anyway: with B blocks and p effective parameters
# the held-out residuals of a linear fit are larger by about B / (B - p) (the in-sample fit
# spends p degrees of freedom on the noise).
OVERFIT_RATIO = 2.0
EXPECTED_MARGIN = 1.5
COVERAGE_ANGLE_DEG = 45.0  # a direction is covered by a pose within this angle of it
COVERAGE_DIRECTIONS = 200  # test directions spread evenly over the sphere


@dataclass(frozen=True)
class AccCrossValidation:
    """Each still block's norm error predicted by the fit without it (mg), and what follows."""

    block_error_mg: np.ndarray  # (B,) |calibrated mean| / |g| - 1, held-out fit
    in_sample_error_mg: np.ndarray  # (B,) the same with the fit on every block
    undetermined: tuple[str, ...]  # parameters the data do not determine (AccFit's)
    uncovered: np.ndarray  # (U, 3) unit directions (calibrated frame) no pose comes near
    coverage: float  # fraction of the sphere's test directions within reach of a pose
    expected_ratio: float  # held-out / in-sample RMS a well-posed fit of this size shows

    @property
    def rms_mg(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.block_error_mg))))

    @property
    def in_sample_rms_mg(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.in_sample_error_mg))))

    @property
    def overfitted(self) -> bool:
        limit = max(OVERFIT_RATIO, EXPECTED_MARGIN * self.expected_ratio)
        return self.rms_mg > limit * self.in_sample_rms_mg

    def advice(self) -> str:
        """What the data lack, in a sentence (for the overfitting warning)."""
        parts = []
        if self.undetermined:
            parts.append(f"the data barely determine {', '.join(self.undetermined)}")
        if len(self.uncovered):
            mean_dir = self.uncovered.mean(axis=0)
            hint = (f" (around {axis_words(mean_dir)})"
                    if np.linalg.norm(mean_dir) > 0.5 else "")
            parts.append(f"{100 * (1 - self.coverage):.0f} % of directions have no pose within "
                         f"{COVERAGE_ANGLE_DEG:g} degrees{hint}")
        return "; ".join(parts) if parts else "record more poses"


def leave_one_block_out(fit: AccFit, means_raw: np.ndarray) -> AccCrossValidation:
    """Predict every block's calibrated norm from the fit without that block.

    ``means_raw`` (B, 3) are the raw mean vectors of the fit's still blocks, in its order.
    The fit's points belong to its blocks in order, the same number per block (one for the
    "ml" and "mean" points, the chunks or thesis groups otherwise).
    """
    data = fit.points
    report = fit.report
    B = len(means_raw)
    if data is None or B < 2 or len(data.pts) % B:
        empty = np.full(B, np.nan)
        return AccCrossValidation(empty, empty, (), np.zeros((0, 3)), float("nan"),
                                  float("nan"))
    block_of_point = np.repeat(np.arange(B), len(data.pts) // B)
    J = data.jacobian(report.theta)
    r = data.residuals(report.theta)
    thetas = kfold_refits(J, r, report.theta, ACC_THETA0, report.lam, block_of_point, B)
    held_out = np.array([_norm_error_mg(to_raw_model(th, fit.nominal, fit.g_out), m, fit.g_out)
                         for th, m in zip(thetas, means_raw)])
    in_sample = _norm_error_mg(fit.model, means_raw, fit.g_out)
    uncovered, covered = coverage(fit.model.apply(means_raw))
    JtJ = J.T @ J
    p_eff = float(np.trace(np.linalg.solve(JtJ + report.lam * np.eye(len(JtJ)), JtJ)))
    n = len(r)
    return AccCrossValidation(block_error_mg=held_out.reshape(B),
                              in_sample_error_mg=np.atleast_1d(in_sample),
                              undetermined=fit.undetermined,
                              uncovered=uncovered, coverage=covered,
                              expected_ratio=n / max(n - p_eff, 1e-9))


def _norm_error_mg(model, raw: np.ndarray, g: float) -> np.ndarray:
    a = model.apply(np.atleast_2d(raw))
    return (np.linalg.norm(a, axis=1) / g - 1.0) * 1e3


def coverage(gravity: np.ndarray) -> tuple[np.ndarray, float]:
    """Test directions (a Fibonacci sphere) farther than COVERAGE_ANGLE_DEG from every pose."""
    n = COVERAGE_DIRECTIONS
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5**0.5) * i
    rho = np.sqrt(1 - z * z)
    dirs = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])
    u = gravity / np.linalg.norm(gravity, axis=1, keepdims=True)
    near = (dirs @ u.T).max(axis=1) >= np.cos(np.radians(COVERAGE_ANGLE_DEG))
    return dirs[~near], float(near.mean())


def axis_words(v: np.ndarray) -> str:
    """'+x, -z' for the axes a direction mostly points along."""
    v = v / np.linalg.norm(v)
    words = [f"{'+' if c > 0 else '-'}{name}" for c, name in zip(v, "xyz") if abs(c) > 0.4]
    return ", ".join(words) or "no single axis"
