"""``numba.njit`` with numba's on-disk cache wherever it can write one, loaded without numba's
full start-up.

numba caches compiled code next to the source (``__pycache__``), or, where the package is not
writable (an installation owned by another user), in the user's cache directory
(``$XDG_CACHE_HOME/numba`` or ``~/.cache/numba``; ``NUMBA_CACHE_DIR`` chooses another). With
neither writable, numba refuses ``cache=True`` outright; the kernels are then compiled in
every process instead (some seconds) rather than not at all.

Loading a kernel from the cache is all a run does with numba once installed, and numba's own
load first "refreshes" its CPU target: it imports and registers every implementation it could
compile (numpy's array functions, random, typed containers, extensions' entry points...),
about 0.1 s of CPU in every process (a third of numba's cost to a short run, issue 22), none of
which a cached kernel uses: the cached object code is linked against numba's runtime (NRT)
and nothing else. So our dispatchers load from the cache after initialising only the runtime
(:func:`_lean_cache_load`); a cache miss compiles exactly as before (numba's compiler refreshes
the target itself), and the code that runs is the same object code, so the same numbers.
Other numba functions in the process are left to numba's own load.
"""

from __future__ import annotations

from numba import njit


def _lean_cache_load(dispatcher) -> None:
    """Make ``dispatcher`` load cached code after initialising numba's runtime alone (see the
    module's note). Relies on numba's ``Cache`` internals (as in numba 0.68); when they are not
    there, numba's own load is left in place (slower, the same code)."""
    cache = getattr(dispatcher, "_cache", None)
    load = getattr(cache, "_load_overload", None)
    guard = getattr(cache, "_guard_against_spurious_io_errors", None)
    if load is None or guard is None:
        return
    try:
        from numba.core.runtime import rtsys
    except ImportError:
        return

    def load_overload(sig, target_context):
        rtsys.initialize(target_context)  # what the cached code calls: np.empty's allocator
        with guard():  # numba's own: an unreadable cache file is a miss, not an error
            return load(sig, target_context)
        return None  # the guard swallowed an error: a miss

    cache.load_overload = load_overload


def jit(*signatures: str, **options):
    """``numba.njit(*signatures, cache=True, **options)``, or without the cache when numba has
    nowhere to write it. Each signature is loaded (or compiled) at decoration, as numba does;
    with signatures, no other types compile later (numba's ``disable_compile``)."""

    def wrap(f):
        try:
            disp = njit(cache=True, **options)(f)
        except RuntimeError as e:
            if "cannot cache" not in str(e):
                raise
            return njit(*signatures, **options)(f)
        if not hasattr(disp, "disable_compile"):  # NUMBA_DISABLE_JIT: the Python function
            return disp
        _lean_cache_load(disp)
        if signatures:
            # numba.njit's own steps for signatures given (numba/core/decorators.py)
            from numba.core import typeinfer

            with typeinfer.register_dispatcher(disp):
                for sig in signatures:
                    disp.compile(sig)
                disp.disable_compile()
        return disp

    return wrap
