"""Calibrate many recordings on a dask.distributed cluster and write one summary table.

The driver (:func:`run_batch`) plans one job per file (device, names, input hash, what to
skip), submits the jobs to the cluster, and writes ``OUT/summary.parquet`` with one row per
session. A worker (:func:`run_job`) loads, calibrates (method.md §1-§5) and writes the
session's calib.json; it never raises: a bad file is a row with its error. A worker process
that dies is Dask's to recover: the scheduler reruns its tasks elsewhere, and ``retries``
covers a task that raised on its way.

Each worker runs its numerics single-threaded (BLAS thread variables set in a LocalCluster
worker's environment before numpy loads, and every job sets the loaded OpenBLAS libraries to
one thread itself, for workers started by hand: :mod:`imucal.fleet.threads`), so that workers,
not threads, use the cores. Each row says the BLAS threads the libraries reported and the
worker process's peak memory so far.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from imucal.errors import ImucalError
from imucal.fleet import naming
from imucal.fleet.spec import Spec, check
from imucal.fleet.summary import empty_row, result_columns, to_frame, verdict_columns

SUMMARY = "summary.parquet"
SINGLE_THREAD_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
                     "MKL_NUM_THREADS": "1"}
_CHUNK = 1 << 20


@dataclass(frozen=True)
class Job:
    """One session to calibrate: everything a worker needs, nothing it must look up."""

    path: str
    out_dir: str
    name: str  # "device/session"
    identity: naming.Identity
    sha256: str
    settings_hash: str
    load_kw: dict[str, Any]
    settings: dict[str, Any]
    spec: Spec | None = None

    @property
    def calib_path(self) -> Path:
        return Path(self.out_dir) / f"{self.name}.calib.json"

    def row(self) -> dict[str, Any]:
        """The identity columns of this job's summary row."""
        ident = self.identity
        return empty_row() | {
            "device": ident.device, "device_from": ident.device_from,
            "session": self.name.split("/", 1)[1], "path": self.path,
            "recorded_at": ident.recorded_at, "recorded_from": ident.recorded_from,
            "sha256": self.sha256, "settings_hash": self.settings_hash,
            "spec_hash": None if self.spec is None else self.spec.hash}


@dataclass
class Counts:
    """Progress of a run, handed to the progress callback after each session."""

    total: int
    done: int = 0
    failed: int = 0
    skipped: int = 0
    started: float = field(default_factory=time.monotonic)

    @property
    def left(self) -> int:
        return self.total - self.done - self.failed - self.skipped

    @property
    def rate(self) -> float:
        """Sessions calibrated (or failed) per second of this run."""
        elapsed = time.monotonic() - self.started
        return (self.done + self.failed) / elapsed if elapsed > 0 else 0.0

    @property
    def eta(self) -> float | None:
        return self.left / self.rate if self.rate > 0 else None


@dataclass(frozen=True)
class BatchReport:
    rows: list[dict[str, Any]]
    counts: Counts
    summary: Path
    workers: int
    cluster: str  # "LocalCluster of N workers on 127.0.0.1" or the scheduler's address
    stored: StoreTally | None = None  # with --store: what went into the calibration store


@dataclass
class StoreTally:
    """The batch's calibrations added to a store (:mod:`imucal.fleet.store`)."""

    store: Path
    added: int = 0
    already: int = 0  # the same calibration was there (a rerun, a skipped session)
    failed: list[str] = field(default_factory=list)

    def add(self, row: dict[str, Any]) -> None:
        """Store one calibrated session's calib.json under its device (the index is brought
        up to date once, at the end); a failure is a warning on the row, not a lost batch."""
        if row["status"] != "ok":
            return
        from imucal.fleet.store import add

        try:
            added = add(self.store, row["calib_path"], row["device"], update_index=False)
        except (ImucalError, OSError) as e:
            message = str(e) if isinstance(e, ImucalError) else f"{e.strerror or e}"
            self.failed.append(f"{row['calib_path']}: {message}")
            row["warnings"] = [*row["warnings"], f"not stored in {self.store}: {message}"]
            return
        if added.already:
            self.already += 1
        else:
            self.added += 1


# --- the worker's side ---------------------------------------------------------------------------


def run_job(job: Job) -> dict[str, Any]:
    """Calibrate one session and write its calib.json; return its summary row (never raises
    for a bad file: the error is in the row)."""
    t0 = time.perf_counter()
    row = job.row()
    row["worker"] = _worker_address()
    try:
        from imucal.fleet.threads import blas_threads_text, limit_blas_threads

        row["blas_threads"] = blas_threads_text(limit_blas_threads(1))
        from imucal.io.calibration_file import result_to_dict
        from imucal.io.load import load_session
        from imucal.pipeline import calibrate
        from imucal.stages.verdict import with_spec

        session = load_session(job.path, **job.load_kw, threads=1)  # workers use the cores
        if session.sha256 != job.sha256:
            raise ImucalError("the file changed while the batch ran", source=job.path)
        result = calibrate(session, **job.settings)
        row |= result_columns(result)
        row["calibrated_at"] = datetime.now(timezone.utc)
        verdict = None
        if job.spec is not None:
            verdict = check(job.spec, row)
            row |= {"spec_pass": verdict.passed, "spec_broken": verdict.broken,
                    "spec_unchecked": verdict.unchecked}
            # One verdict: a unit out of its limits is not usable (as `imucal calibrate
            # --spec` says it), in the table and in its calib.json.
            result = dataclasses.replace(result, verdict=with_spec(
                result.verdict, verdict.to_dict() | {"limits": job.spec.limits},
                job.spec.source))
            row |= verdict_columns(result.verdict)
        doc = result_to_dict(result) | {
            "device": job.identity.device, "device_named": job.identity.named,
            "session": row["session"],
            "calibrated_at": row["calibrated_at"].isoformat(),
            "recorded_at": None if row["recorded_at"] is None else row["recorded_at"].isoformat(),
            "settings_hash": job.settings_hash}
        if verdict is not None:
            doc["spec"] = verdict.to_dict() | {"limits": job.spec.limits, "file": job.spec.source}
        _write_json(job.calib_path, doc)
        row |= {"status": "ok", "calib_path": str(job.calib_path)}
    except ImucalError as e:
        row |= {"status": "failed", "error": str(e)}
    except Exception as e:  # a bug in imucal: the row says so, the batch goes on
        row |= {"status": "error", "error": f"internal error: {e.__class__.__name__}: {e}"}
    row["seconds"] = time.perf_counter() - t0
    row["worker_peak_mb"] = _peak_rss_mb()
    return row


def _peak_rss_mb() -> float | None:
    """The worker process's peak resident memory so far, MB (None where unknown)."""
    with contextlib.suppress(ImportError, OSError):
        import resource
        import sys

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak / (2**20 if sys.platform == "darwin" else 2**10)  # bytes there, KB here
    return None


def _write_json(path: Path, doc: dict) -> None:
    from imucal.io.atomic import write_text_atomic

    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(doc, indent=2, allow_nan=False) + "\n")


def _worker_address() -> str | None:
    with contextlib.suppress(Exception):
        from distributed import get_worker

        return get_worker().address
    return None


# --- planning ------------------------------------------------------------------------------------


def settings_hash(load_kw: dict[str, Any], settings: dict[str, Any]) -> str:
    """A short hash of every option that changes a session's result (where the signals are
    held does not)."""
    given = {k: v for k, v in load_kw.items() if k != "spill"}
    text = json.dumps({"input": given, "settings": settings}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def file_sha256(path: Path) -> str:
    """The same digest as Session.sha256 for a one-file session."""
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        while chunk := fh.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def plan(files: list[Path], out_dir: Path, *, device_from: str | None,
         load_kw: dict[str, Any], settings: dict[str, Any], spec: Spec | None
         ) -> tuple[list[Job], list[dict[str, Any]]]:
    """One job per file, and an error row for each file that cannot become one (a path the
    device pattern does not match, an unreadable file)."""
    pattern = naming.compile_pattern(device_from) if device_from else None
    shash = settings_hash(load_kw, settings)
    found, bad = [], []
    for path in files:
        try:
            ident = naming.identify(path, pattern, device_from or "")
            sha = file_sha256(path)
        except (ImucalError, OSError) as e:
            msg = str(e) if isinstance(e, ImucalError) else f"{path}: {e.strerror or e}"
            bad.append(empty_row() | {"path": str(path), "session": path.stem,
                                      "status": "failed", "error": msg,
                                      "settings_hash": shash})
            continue
        found.append((path, ident, sha))
    naming.check_distinct([(p, i) for p, i, _ in found])  # before any work
    names = naming.output_names([(i.device, naming.safe_name(p.stem), s) for p, i, s in found])
    jobs = [Job(path=str(p), out_dir=str(out_dir), name=n, identity=i, sha256=s,
                settings_hash=shash, load_kw=load_kw, settings=settings, spec=spec)
            for (p, i, s), n in zip(found, names)]
    return jobs, bad


def _previous(out_dir: Path) -> dict[str, dict[str, Any]]:
    """Last run's rows by path (nothing when there is no readable summary)."""
    path = out_dir / SUMMARY
    if not path.exists():
        return {}
    import polars as pl

    try:
        return {r["path"]: r for r in pl.read_parquet(path).to_dicts()}
    except Exception:  # an unreadable summary is redone, not fatal
        return {}


def _reusable(job: Job, prev: dict[str, Any] | None) -> bool:
    """Skip a session whose input bytes, settings and spec are those of a finished row (a
    failure for the input's sake fails again; a lost worker or a bug is worth another try)."""
    if prev is None or prev["status"] not in ("ok", "failed"):
        return False
    same = (prev["sha256"] == job.sha256 and prev["settings_hash"] == job.settings_hash
            and prev["spec_hash"] == (None if job.spec is None else job.spec.hash))
    if prev["status"] == "ok":
        same = same and prev["calib_path"] == str(job.calib_path) and job.calib_path.exists()
    return same


# --- the driver ----------------------------------------------------------------------------------


FLEET_EXTRA = "pip install 'imucal-rerun[fleet]'"


def require_dask() -> None:
    """Dask is an extra (``[fleet]``: only this module imports it): without it, one line that
    says how to install it, before any file is read."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise ImucalError(f"not installed; imucal batch runs on a Dask cluster: {FLEET_EXTRA}",
                          source="dask") from None


@contextlib.contextmanager
def cluster_client(scheduler: str | None, workers: int) -> Iterator[tuple[Any, str]]:
    """A client of the given scheduler (used as it is), or of a LocalCluster on loopback."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        from imucal.fleet.scheduler import CLIENT_TIMEOUT, probe

        probe(scheduler)  # one prompt line for a closed port or another kind of server
        try:
            client = Client(scheduler, timeout=CLIENT_TIMEOUT)
        except (OSError, MemoryError, ValueError) as e:  # a Dask server that is no scheduler
            raise ImucalError(f"{scheduler}: a Dask server that does not act as a scheduler "
                              f"({e.__class__.__name__}: {e})", field="--scheduler") from None
        with client:
            yield client, scheduler
        return
    with contextlib.ExitStack() as stack:
        with _interrupts_are_the_drivers():
            # Dask's own logs only when critical: a session's failure is its row's, and an
            # interrupted batch's workers log the closed scheduler at ERROR with a traceback.
            cluster = stack.enter_context(LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address=None, silence_logs=50, env=SINGLE_THREAD_ENV))
            client = stack.enter_context(Client(cluster))
        try:
            yield client, f"LocalCluster of {workers} workers on 127.0.0.1"
        finally:  # nor its close: an interrupt meanwhile takes effect once it is down
            from imucal.io.atomic import held_back

            with held_back():
                stack.close()


@contextlib.contextmanager
def _interrupts_are_the_drivers() -> Iterator[None]:
    """Start a LocalCluster so that Ctrl-C ends the batch in one line (issue 27: tracebacks).

    A terminal's Ctrl-C reaches every process of the foreground group, the workers too, which
    died printing theirs. The worker processes are started with SIGINT (and SIGHUP) blocked (a
    blocked signal stays blocked across fork and exec, and Dask starts them from its event-loop
    thread,
    which inherits this thread's mask); Ctrl-C is the driver's alone, whose closing the
    cluster ends them. And the start itself is not cut short (a cluster half started fails
    its exit-time close with a traceback, and waits 10 s on it): an interrupt meanwhile takes
    effect once it is up, and the caller's exit then closes it, the close held back alike
    (:func:`imucal.io.atomic.held_back`)."""
    import signal

    from imucal.io.atomic import held_back

    with held_back():
        blocked = None
        if hasattr(signal, "pthread_sigmask"):
            # SIGHUP too: a closed terminal sends it to the group, and it killed multiprocessing's
            # resource tracker (which ignores only SIGINT and SIGTERM) with tracebacks. The
            # tracker, started on first use, unblocks SIGINT in the thread that starts it
            # (Dask's event loop): started here first, under SIGHUP's block; then SIGINT's.
            from multiprocessing import resource_tracker

            hups = {signal.SIGHUP} if hasattr(signal, "SIGHUP") else set()
            blocked = signal.pthread_sigmask(signal.SIG_BLOCK, hups)
            resource_tracker.ensure_running()
            signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, *hups})
        try:
            yield
        finally:
            if blocked is not None:
                signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def local_workers(asked: int | None, sessions: int) -> tuple[int, str]:
    """A LocalCluster's size: ``asked`` or one per core, never more than the cores or the
    sessions to run (a worker more starts a process that only waits, and 1000 of them exhaust
    the machine); and what was said about a cap (empty if none)."""
    try:
        cores = len(os.sched_getaffinity(0))  # the cores this process may use (containers)
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    limit = max(1, min(cores, sessions))
    if asked is None or asked <= limit:
        return asked or limit, ""
    return limit, (f" (--workers {asked} capped at {limit}: {sessions} session"
                   f"{'s' if sessions != 1 else ''} to run, {cores} "
                   f"core{'s' if cores != 1 else ''})")


def run_batch(files: list[Path], out_dir: Path, *, load_kw: dict[str, Any],
              settings: dict[str, Any], scheduler: str | None = None, workers: int | None = None,
              device_from: str | None = None, spec: Spec | None = None, force: bool = False,
              retries: int = 2, progress: Callable[[Counts], None] | None = None,
              store: Path | None = None) -> BatchReport:
    """Calibrate ``files`` on a cluster; write ``out_dir/summary.parquet``; return the rows.

    ``workers`` (a LocalCluster's size) defaults to one per core, and is at most one per core
    and one per session (:func:`local_workers`; the cap is said in ``cluster``).
    ``store``: add every calibrated session to that calibration store, as its result comes in
    (the sessions a rerun skips too: the store keeps one copy of each)."""
    if scheduler is not None:  # before any file is read: a wrong address is said at once
        from imucal.fleet.scheduler import probe

        probe(scheduler)
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs, rows = plan(files, out_dir, device_from=device_from, load_kw=load_kw,
                      settings=settings, spec=spec)
    prev = {} if force else _previous(out_dir)
    originals: dict[str, Job] = {}
    dupes: list[Job] = []
    todo: list[Job] = []
    counts = Counts(total=len(files), failed=len(rows))
    for job in jobs:
        if job.sha256 in originals:
            dupes.append(job)
            counts.skipped += 1
            continue
        originals[job.sha256] = job
        if _reusable(job, prev.get(job.path)):
            rows.append(prev[job.path])
            counts.skipped += 1
        else:
            todo.append(job)
    by_sha: dict[str, dict[str, Any]] = {r["sha256"]: r for r in rows if r.get("sha256")}
    tally = None if store is None else StoreTally(store)
    for row in rows if tally is not None else ():
        tally.add(row)
    where = "nothing to do"
    workers, capped = local_workers(workers, len(todo))
    if todo:
        with cluster_client(scheduler, workers) as (client, where):
            workers = len(client.scheduler_info().get("workers", {})) or workers
            where += capped
            for row in _gather(client, todo, retries, counts, progress):
                rows.append(row)
                by_sha[row["sha256"]] = row
                if tally is not None:
                    tally.add(row)
    for job in dupes:
        rows.append(_duplicate_row(job, by_sha[job.sha256], originals[job.sha256]))
    rows.sort(key=lambda r: (r["device"] or "", r["session"] or "", r["path"]))
    from imucal.io.atomic import write_atomic

    summary = out_dir / SUMMARY
    frame = to_frame(rows)
    write_atomic(summary, frame.write_parquet)
    if tally is not None and store.is_dir():
        from imucal.fleet.index import refresh_index

        refresh_index(store)
    if progress is not None:
        progress(counts)
    return BatchReport(rows=rows, counts=counts, summary=summary, workers=workers, cluster=where,
                       stored=tally)


def _gather(client, todo: list[Job], retries: int, counts: Counts,
            progress: Callable[[Counts], None] | None) -> Iterator[dict[str, Any]]:
    return run_on_cluster(
        client, run_job, todo, [f"imucal-{i}-{job.sha256[:12]}" for i, job in enumerate(todo)],
        retries, counts, progress, ok=lambda row: row["status"] == "ok",
        lost=lambda job, why: job.row() | {"status": "error", "error": why})


def run_on_cluster(client, fn: Callable[[Any], dict[str, Any]], jobs: list, keys: list[str],
                   retries: int, counts: Counts, progress: Callable[[Counts], None] | None, *,
                   ok: Callable[[dict[str, Any]], bool],
                   lost: Callable[[Any, str], dict[str, Any]]) -> Iterator[dict[str, Any]]:
    """``fn(job)`` for every job on the cluster, each row as it comes back (the one module
    that speaks to dask.distributed: batch and batch --check both go through here). A task
    lost for good (KilledWorker after ``retries``) becomes ``lost(job, why)``; ``ok`` says
    which rows count as done and which as failed."""
    from distributed import as_completed

    futures = {client.submit(fn, job, retries=retries, pure=False, key=key): job
               for job, key in zip(jobs, keys)}
    for fut in as_completed(futures):
        job = futures[fut]
        try:
            row = fut.result()
        except Exception as e:  # the task was lost for good (KilledWorker after retries)
            row = lost(job, f"lost on the cluster: {e.__class__.__name__}: {e}")
        fut.release()
        if ok(row):
            counts.done += 1
        else:
            counts.failed += 1
        if progress is not None:
            progress(counts)
        yield row


def _duplicate_row(job: Job, original_row: dict[str, Any], original: Job) -> dict[str, Any]:
    """A file with the same bytes as another: its row repeats the other's results (computed
    once) and says whose they are."""
    row = job.row()
    copied = {k: v for k, v in original_row.items() if k not in row or row[k] is None}
    return row | copied | {"status": "duplicate", "duplicate_of": original.path,
                           "error": original_row.get("error"),
                           "calib_path": original_row.get("calib_path")}


__all__ = ["BatchReport", "Counts", "Job", "SUMMARY", "StoreTally", "plan", "run_batch",
           "run_job", "settings_hash"]
