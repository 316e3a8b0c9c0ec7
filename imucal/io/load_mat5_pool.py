"""The variables of a MAT file read in parallel threads, with the outcome of reading them one
after another (issue 12: a 6-hour session is mostly inflating; zlib releases the GIL).

Each job fills its own, already allocated array, so the threads share nothing but the file
descriptor (read with ``pread``). The outcome does not depend on the number of threads: the
arrays are kept in the order of the file, and the error raised is the one of the first variable
that fails, which is the one a single thread would have met first. Jobs after a failure stop at
their next piece (their work would be thrown away); jobs before it finish.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor

Job = Callable[[Callable[[], bool]], None]
Keep = Callable[[], None]


def usable_threads() -> int:
    """The cores this process may run on (its affinity, not the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return max(1, os.cpu_count() or 1)


def run_in_order(jobs: Iterable[tuple[Job, Keep]], threads: int) -> None:
    """Run each ``(job, keep)``: ``job(stop)`` in up to ``threads`` threads, ``keep()`` in the
    calling thread, in order, once every job up to it succeeded. ``jobs`` is consumed in the
    calling thread; an error it raises comes after those of the jobs already started."""
    if threads <= 1:
        for job, keep in jobs:
            job(_never)
            keep()
        return
    failed_at = [float("inf")]  # index of the earliest job known to have failed
    lock = threading.Lock()

    def run(i: int, job: Job) -> None:
        try:
            job(lambda: failed_at[0] < i)
        except BaseException:
            with lock:
                failed_at[0] = min(failed_at[0], i)
            raise

    started: list[tuple[Future[None], Keep]] = []
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="imucal-inflate") as pool:
        try:
            for i, (job, keep) in enumerate(jobs):
                started.append((pool.submit(run, i, job), keep))
        except BaseException:
            failed_at[0] = min(failed_at[0], len(started))
            _finish(started)  # an earlier job's error goes first
            raise
        _finish(started)


def _finish(started: list[tuple[Future[None], Keep]]) -> None:
    """Wait for the jobs in order; raise the first one's error, else keep each result."""
    for future, _ in started:
        future.exception()  # wait: every array is complete (or abandoned) before returning
    for future, keep in started:
        error = future.exception()
        if error is not None:
            raise error
        keep()


def _never() -> bool:
    return False
