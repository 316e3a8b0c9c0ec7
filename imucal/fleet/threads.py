"""One BLAS thread per worker, whoever started the worker.

The fits call LAPACK through numpy and scipy, each with its own OpenBLAS; left alone, each
uses a thread per core (on a 60-minute session, the same wall time for 1.6-2.8x the CPU), and
a machine of workers then runs cores x workers threads. A LocalCluster's workers get the BLAS
thread variables in their environment before numpy loads, but a worker someone started with
``dask worker`` has whatever its shell had: so the job sets the limit itself, through
OpenBLAS's own ``openblas_set_num_threads`` in every OpenBLAS the process has loaded, and
reports what the libraries then say (not what a variable asked for).
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

# The entry points of OpenBLAS builds: plain, and the scipy-openblas wheels' (64-bit ints
# for numpy's, 32-bit for scipy's).
_PREFIXES = ("openblas_", "scipy_openblas_")
_SUFFIXES = ("", "64_")


def _loaded_openblas() -> list[Path]:
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:  # not Linux: nothing to find this way
        return []
    found = {line.split()[-1] for line in maps.splitlines()
             if "openblas" in line.lower() and ".so" in line and line.split()[-1].startswith("/")}
    return sorted(Path(p) for p in found)


def _function(lib: ctypes.CDLL, verb: str) -> ctypes._CFuncPtr | None:  # type: ignore[name-defined]
    for prefix in _PREFIXES:
        for suffix in _SUFFIXES:
            f = getattr(lib, f"{prefix}{verb}_num_threads{suffix}", None)
            if f is not None:
                return f
    return None


def limit_blas_threads(n: int = 1) -> int | None:
    """Set every loaded OpenBLAS to ``n`` threads (numpy and scipy.linalg are loaded first);
    return the largest thread count the libraries report afterwards, or None when none is
    found (another BLAS, or not Linux: then the environment variables are all there is)."""
    import numpy  # noqa: F401  (their OpenBLAS must be loaded to be limited)
    import scipy.linalg  # noqa: F401

    counts = []
    for path in _loaded_openblas():
        try:
            lib = ctypes.CDLL(str(path))
        except OSError:
            continue
        setter, getter = _function(lib, "set"), _function(lib, "get")
        if setter is not None:
            setter.argtypes = [ctypes.c_int]
            setter(int(n))
        if getter is not None:
            getter.restype = ctypes.c_int
            counts.append(int(getter()))
    return max(counts) if counts else None


def blas_threads_text(n: int | None) -> str | None:
    """What the summary's ``blas_threads`` says: the libraries' count, else the variable's."""
    return str(n) if n is not None else os.environ.get("OPENBLAS_NUM_THREADS")
