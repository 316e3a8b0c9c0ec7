"""The RK4 steps of many intervals laid out once (buckets of similar length, time-major, padded
with identity steps) for repeated integration under different rate models (method.md M5)."""

from __future__ import annotations

import numpy as np

from imucal.numerics.rk4.buckets import lay_out, length_buckets
from imucal.numerics.rk4.hamilton import Vec
from imucal.numerics.rk4.integrate import integrate_buckets
from imucal.numerics.rk4.lazy import LazyRows, lay_out_lazy, lazy_rows
from imucal.numerics.rk4.variational import Sensitivity, sensitivity


class StepLayout:
    """The RK4 steps of many transitions, laid out once for repeated integration.

    Transition k takes ``ends[k] - starts[k]`` steps from sample ``starts[k]`` on the
    timestamps ``t``. Each bucket (:class:`~imucal.numerics.rk4.buckets.Bucket`) holds the
    transitions ``idx`` as time-major arrays: the sample index of every step's start (``i0``,
    (L + 1, K_b): the last row is the end of the last step), which of those samples belong to
    the transition (``valid``), and every step's ``dt`` (L, K_b; 0 for padding) and ``dt^2``.
    With ``lazy``, a bucket keeps none of these arrays (:mod:`.lazy`): ``dt`` and ``dt2`` and
    :meth:`lazy_samples` are gathered a slab of rows at a time when read, and ``t`` is only
    read by gathers (it may be an array kept on disk).
    """

    def __init__(self, t, starts: np.ndarray, ends: np.ndarray, lazy: bool = False):
        if not lazy:
            t = np.asarray(t, float)
        self.starts = np.asarray(starts, np.int64)
        self.ends = np.asarray(ends, np.int64)
        self.n = len(self.starts)
        self.last = len(t) - 1
        n_steps = self.ends - self.starts
        # lazy: nothing the size of the steps is kept; slabs are gathered when integrated
        # (:mod:`.lazy`, the same values to the bit)
        make = lay_out_lazy if lazy else lay_out
        self.buckets = [make(t, self.starts, n_steps, idx) for idx in length_buckets(n_steps)]

    def gather(self, comps: list[np.ndarray]) -> list[Vec]:
        """The samples of every transition, per bucket ((L + 1, K_b) per component, zero in the
        padding): step j runs from row j to row j + 1, so each sample is calibrated once."""
        return [tuple(np.where(valid, c[i0], 0.0) for c in comps)
                for _, i0, valid, _, _ in self.buckets]

    def lazy_samples(self, x) -> list[LazyRows]:
        """:meth:`gather`'s samples of a lazy layout, read from ``x`` (N, C), one row per
        sample, a slab at a time when integrated (``x`` is kept as it is and only read by
        gathers of rows)."""
        return [lazy_rows(b, x) for b in self.buckets]

    def integrate(self, samples: list, models: list[tuple] | None = None) -> np.ndarray:
        """Quaternions (k, K, 4), normalised, of every transition under each of k models
        ``(M, b)`` (``w = M (w - b)``, M4; ``None``: the rates as they are), from
        :meth:`gather`'s ``samples`` (:func:`~imucal.numerics.rk4.integrate.integrate_buckets`).
        """
        return integrate_buckets(self.buckets, self.n, samples, models)

    def sensitivity(self, samples: list, M: np.ndarray, b: np.ndarray) -> Sensitivity:
        """Every transition's rotation (n, 4) and ``S`` (n, 3, 3, 4), what a fit's residuals
        and Jacobian need for the model ``w = M (w_raw - b)`` (M4)
        (:func:`~imucal.numerics.rk4.variational.sensitivity`)."""
        return sensitivity(self.buckets, self.n, samples, M, b)


def integrate_transitions(w: np.ndarray, t: np.ndarray, starts: np.ndarray, ends: np.ndarray
                          ) -> np.ndarray:
    """Body rotation over each interval ``[t[starts[k]], t[ends[k]]]`` from q = identity.

    ``w`` (M, 3) calibrated rates in rad/s at times ``t`` (M,); transition k takes
    ``ends[k] - starts[k]`` RK4 steps on the real timestamps. Returns (K, 4) quaternions.
    """
    if len(starts) == 0:
        return np.zeros((0, 4))
    layout = StepLayout(t, starts, ends)
    comps = [np.ascontiguousarray(w[:, i], dtype=float) for i in range(3)]
    return layout.integrate(layout.gather(comps))[0]
