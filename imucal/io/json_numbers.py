"""Numbers as JSON writes them (no NaN or Infinity), for calib.json's sections."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def json_number(x: float | None) -> float | None:
    """JSON has no NaN or Infinity: write them as null."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def json_numbers(a: Any) -> Any:
    arr = np.asarray(a, dtype=float)
    if arr.ndim == 0:
        return json_number(arr)
    return [json_numbers(v) for v in arr]
