"""Orientation from sampled body rates: classic RK4 on quaternions (method.md M5), compiled.

For ``dq/dt = 1/2 q (x) W(t)`` (W the pure quaternion of the body rate) one RK4 step is linear
in ``q``: ``q_(n+1) = q_n (x) P_n``, with ``P_n`` a quaternion built from the rates at the
step's start, middle and end only. The integration is sequential within an interval, so it is
a compiled loop over each interval's samples (numba), not vector operations across intervals.

- :mod:`.step`: the affine rate model, one RK4 step in closed form, the Hamilton product and
  the rotation matrix, for one sample;
- :mod:`.kernels`: the passes over many intervals (their rotations under one or several models
  or each under its own, the sensitivity of the rotation to the model, the largest step, the
  turn of the raw rate);
- :mod:`.intervals`: :class:`Intervals`, the samples read where they lie or gathered a chunk
  of intervals at a time, for the kernels;
- :mod:`.jit`: ``numba.njit`` with numba's on-disk cache wherever it can write one.

Only :mod:`.intervals` is imported with this package: numba is imported by the first pass.
"""

from imucal.numerics.rk4.intervals import Intervals, Sensitivity, integrate_transitions

__all__ = ["Intervals", "Sensitivity", "integrate_transitions"]
