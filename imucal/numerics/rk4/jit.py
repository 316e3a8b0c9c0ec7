"""``numba.njit`` with numba's on-disk cache wherever it can write one.

numba caches compiled code next to the source (``__pycache__``), or, where the package is not
writable (an installation owned by another user), in the user's cache directory
(``$XDG_CACHE_HOME/numba`` or ``~/.cache/numba``; ``NUMBA_CACHE_DIR`` chooses another). With
neither writable, numba refuses ``cache=True`` outright; the kernels are then compiled in
every process instead (some seconds) rather than not at all.
"""

from __future__ import annotations

from numba import njit


def jit(*signatures: str, **options):
    """``numba.njit(*signatures, cache=True, **options)``, or without the cache when numba has
    nowhere to write it."""

    def wrap(f):
        try:
            return njit(*signatures, cache=True, **options)(f)
        except RuntimeError as e:
            if "cannot cache" not in str(e):
                raise
            return njit(*signatures, **options)(f)

    return wrap
