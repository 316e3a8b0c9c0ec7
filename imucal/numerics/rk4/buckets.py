"""Intervals of very different lengths grouped into buckets of similar length, each laid out
time-major: ``(L, K_b)`` arrays (step, interval), padded with identity steps (``dt = 0``).

Time-major, every operation of a reduction reads contiguous runs of ``K_b`` values; bucketing by
length keeps the padding small.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

# A bucket of its own costs a few hundred numpy calls per evaluation (about the work of this
# many padded steps); shorter intervals share the longer bucket unless that saves more.
BUCKET_OVERHEAD_STEPS = 10000
BUCKET_RATIO = 0.8


class Bucket(NamedTuple):
    """The intervals ``idx`` (K_b,) laid out time-major: the sample index of every step's start
    (``i0``, (L + 1, K_b): the last row is the end of the last step), which of those samples
    belong to the interval (``valid``), every step's ``dt`` (L, K_b; 0 for padding) and
    ``dt^2``."""

    idx: np.ndarray
    i0: np.ndarray
    valid: np.ndarray
    dt: np.ndarray
    dt2: np.ndarray


def length_buckets(n_steps: np.ndarray) -> list[np.ndarray]:
    """Intervals grouped by length (indices into ``n_steps``), longest first.

    Lengths fall into classes a factor ``BUCKET_RATIO`` apart; a class shares the bucket of
    the longer ones before it unless a bucket of its own saves more padded steps than it costs.
    """
    if len(n_steps) == 0:
        return []
    order = np.argsort(-n_steps, kind="stable")
    lengths = np.maximum(n_steps[order], 1)
    top = lengths[0]
    cls = np.floor(np.log(top / lengths) / -np.log(BUCKET_RATIO)).astype(np.int64)
    edges = np.flatnonzero(np.diff(cls)) + 1
    groups = np.split(np.arange(len(order)), edges)
    out: list[list[int]] = []
    cur_len = None
    for g in groups:
        g_len = int(lengths[g[0]])
        if cur_len is not None and len(g) * (cur_len - g_len) < BUCKET_OVERHEAD_STEPS:
            out[-1].extend(g.tolist())
            continue
        out.append(g.tolist())
        cur_len = g_len
    return [np.sort(order[np.array(b)]) for b in out]


def lay_out(t: np.ndarray, starts: np.ndarray, n_steps: np.ndarray, idx: np.ndarray) -> Bucket:
    """The bucket of intervals ``idx``: interval k takes ``n_steps[k]`` steps from sample
    ``starts[k]`` on the timestamps ``t``."""
    L = int(max(n_steps[idx].max(), 1))
    j = np.arange(L + 1)[:, None]
    valid = j <= n_steps[idx][None, :]  # samples: L steps have L + 1 ends
    i0 = np.where(valid, np.minimum(starts[idx][None, :] + j, len(t) - 1), 0)
    step = valid[1:]  # step j runs from sample j to sample j + 1
    dt = np.where(step, t[i0[1:]] - t[i0[:-1]], 0.0)
    return Bucket(idx, i0, valid, dt, dt * dt)
