"""Session.acc_step / gyro_step: np.median(np.diff(t)) to the bit, computed once per session."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import imucal.session as session_module
from imucal.session import MEDIAN_SMALL, Session


def _clock(rng: np.random.Generator, n: int, rate: float) -> np.ndarray:
    # A logger's clock: whole steps of 1/rate, a jitter of a few ulps, some doubled steps.
    steps = np.full(n - 1, 1.0 / rate) * (1 + 1e-9 * rng.integers(-3, 4, n - 1))
    steps[rng.integers(0, n - 1, n // 50)] *= 2
    return np.concatenate([[12.5], 12.5 + np.cumsum(steps)])


@pytest.mark.parametrize("n", [50, 1001, MEDIAN_SMALL + 7, MEDIAN_SMALL + 10])
def test_steps_are_numpys_median(n):
    rng = np.random.default_rng(n)
    t = _clock(rng, n, 1000.0)
    tg = _clock(rng, n, 200.0)
    s = Session(acc=np.zeros((n, 3)), t_acc=t, gyro=np.zeros((n, 3)), t_gyro=tg)
    assert s.acc_step == float(np.median(np.diff(t)))
    assert s.gyro_step == float(np.median(np.diff(tg)))
    assert s.acc_rate == float(1.0 / np.median(np.diff(t)))
    assert s.gyro_rate == float(1.0 / np.median(np.diff(tg)))


def test_computed_once_and_shared_by_one_clock(monkeypatch):
    rng = np.random.default_rng(3)
    t = _clock(rng, 5000, 100.0)
    calls = []
    real = session_module.median_step

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(session_module, "median_step", counted)
    s = Session(acc=np.zeros((len(t), 3)), t_acc=t, gyro=np.ones((len(t), 3)), t_gyro=t)
    rates = [s.acc_rate, s.gyro_rate, s.acc_rate, s.gyro_rate, s.acc_step, s.gyro_step]
    assert len(calls) == 1  # one clock, one median, however often asked
    assert rates[0] == rates[1] == float(1.0 / np.median(np.diff(t)))
    # A replaced session (another clock) computes its own.
    t2 = t * 2.0
    s2 = dataclasses.replace(s, t_acc=t2, t_gyro=t2)
    assert s2.acc_rate == float(1.0 / np.median(np.diff(t2)))
    assert len(calls) == 2


def test_no_gyroscope_has_no_step():
    s = Session(acc=np.zeros((10, 3)), t_acc=np.arange(10) / 10.0)
    assert s.gyro_step is None and s.gyro_rate is None
