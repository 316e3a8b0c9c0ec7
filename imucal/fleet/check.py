"""``imucal batch --check STORE``: every recording of a fleet checked (method.md §10) against
its device's latest calibration in a calibration store, on a Dask cluster as batch runs.

The driver (:func:`run_check`) finds each recording's device as batch does (its parent folder,
or ``--device-from``), picks the device's newest stored calibration
(:func:`imucal.fleet.store.get`), and submits one job per recording; a worker
(:func:`run_check_job`) loads, checks and returns a row; it never raises (a bad file, a device
with no calibration: the row says so). :func:`by_device` folds the rows into one verdict per
device: drifted when a recording of it says so, else holds when one does, else cannot tell.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from imucal.errors import ImucalError
from imucal.fleet import naming
from imucal.fleet.batch import Counts, cluster_client, local_workers, run_on_cluster

HOLDS, DRIFTED, CANNOT_TELL, FAILED = "holds", "drifted", "cannot tell", "failed"
LEVELS = (HOLDS, DRIFTED, CANNOT_TELL, FAILED)


@dataclass(frozen=True)
class CheckJob:
    """One recording to check against one stored calibration."""

    path: str
    device: str
    calibration: str  # the stored calib.json's path
    calibrated_at: str  # its time, ISO (UTC)
    load_kw: dict[str, Any]
    acc_limit_mg: float
    gyro_limit_deg_s: float

    def row(self) -> dict[str, Any]:
        return {"device": self.device, "path": self.path, "calibration": self.calibration,
                "calibrated_at": self.calibrated_at, "verdict": None, "exit_code": None,
                "reason": None, "still_moments": None, "still_seconds": None,
                "orientations": None, "parts": None, "error": None, "seconds": None}


def run_check_job(job: CheckJob) -> dict[str, Any]:
    """Check one recording; its row (an error is the row's, never raised)."""
    t0 = time.perf_counter()
    row = job.row()
    try:
        from imucal.fleet.threads import limit_blas_threads
        from imucal.inuse.check import check
        from imucal.io.calibration_file import recorded_units
        from imucal.io.inuse_file import read_for_check
        from imucal.io.load import load_session

        limit_blas_threads(1)
        cal, stored, _ = read_for_check(job.calibration)
        _, units = recorded_units(job.calibration)
        kw = dict(job.load_kw)
        for key, unit in units.items():  # a still gyroscope cannot tell rad/s from deg/s
            if kw.get(key, "auto") == "auto":
                kw[key] = unit
        session = load_session(job.path, **kw, threads=1)
        c = check(cal, stored, session, acc_limit_mg=job.acc_limit_mg,
                  gyro_limit_deg_s=job.gyro_limit_deg_s)
        m = c.moments
        row |= {"verdict": c.level, "exit_code": c.exit_code, "reason": c.reason,
                "still_moments": m.count,
                "still_seconds": float(m.durations.sum()) if m.count else 0.0,
                "orientations": m.orientations, "parts": [p.to_dict() for p in c.parts]}
    except ImucalError as e:
        row |= {"verdict": FAILED, "error": str(e)}
    except Exception as e:  # a bug in imucal: the row says so, the others go on
        row |= {"verdict": FAILED, "error": f"internal error: {e.__class__.__name__}: {e}"}
    row["seconds"] = time.perf_counter() - t0
    return row


@dataclass(frozen=True)
class CheckReport:
    rows: list[dict[str, Any]]  # one per recording, by device then path
    devices: list[dict[str, Any]]  # one per device (by_device)
    cluster: str

    @property
    def exit_code(self) -> int:
        """batch's convention: 1 when a recording failed or a device drifted; else 2 when a
        device cannot tell; else 0 (every device holds)."""
        levels = {d["verdict"] for d in self.devices} | {r["verdict"] for r in self.rows}
        if FAILED in levels or DRIFTED in levels:
            return 1
        return 2 if CANNOT_TELL in levels else 0

    def to_dict(self) -> dict:
        return {"exit_code": self.exit_code, "cluster": self.cluster, "devices": self.devices,
                "recordings": self.rows}


def plan_checks(files: list[Path], store: Path, *, device_from: str | None,
                load_kw: dict[str, Any], acc_limit_mg: float, gyro_limit_deg_s: float
                ) -> tuple[list[CheckJob], list[dict[str, Any]]]:
    """One job per recording whose device has a stored calibration; a failed row for each
    other (a path the pattern does not match, a device the store does not hold)."""
    from imucal.fleet import store as st

    pattern = naming.compile_pattern(device_from) if device_from else None
    latest: dict[str, Any] = {}
    jobs, bad = [], []
    for path in files:
        row = {"device": None, "path": str(path), "calibration": None, "calibrated_at": None}
        try:
            ident = naming.identify(path, pattern, device_from or "")
            row["device"] = ident.device
            if ident.device not in latest:
                try:
                    latest[ident.device] = st.get(store, ident.device)
                except ImucalError as e:
                    latest[ident.device] = e
            picked = latest[ident.device]
            if isinstance(picked, ImucalError):
                raise picked
        except ImucalError as e:
            bad.append(CheckJob(str(path), row["device"] or "?", "", "", {}, 0.0, 0.0).row()
                       | row | {"verdict": FAILED, "error": str(e)})
            continue
        jobs.append(CheckJob(path=str(path), device=ident.device, calibration=str(picked.path),
                             calibrated_at=st.iso(picked.row["calibrated_at"]), load_kw=load_kw,
                             acc_limit_mg=acc_limit_mg, gyro_limit_deg_s=gyro_limit_deg_s))
    return jobs, bad


def by_device(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One verdict per device: drifted when any of its recordings says so (a drift shown once
    is shown), else holds when one does, else cannot tell, else failed; with the counts and
    the reasons of the recordings that decided it."""
    out = []
    for dev in sorted({r["device"] for r in rows}):
        mine = [r for r in rows if r["device"] == dev]
        counts = {level: sum(r["verdict"] == level for r in mine) for level in LEVELS}
        verdict = next(v for v in (DRIFTED, HOLDS, CANNOT_TELL, FAILED) if counts[v])
        deciding = [r for r in mine if r["verdict"] == verdict]
        reasons = sorted({(r["reason"] or r["error"] or "") for r in deciding})
        out.append({"device": dev, "verdict": verdict, "recordings": len(mine),
                    "counts": counts,
                    "calibration": next((r["calibration"] for r in mine if r["calibration"]),
                                        None),
                    "calibrated_at": next((r["calibrated_at"] for r in mine
                                           if r["calibrated_at"]), None),
                    "reasons": reasons})
    return out


def run_check(files: list[Path], store: Path, *, load_kw: dict[str, Any],
              acc_limit_mg: float, gyro_limit_deg_s: float, scheduler: str | None = None,
              workers: int | None = None, device_from: str | None = None, retries: int = 2,
              progress: Callable[[Counts], None] | None = None) -> CheckReport:
    """Check ``files`` against their devices' latest calibrations in ``store`` on a cluster
    (a LocalCluster of ``workers``, as :func:`imucal.fleet.batch.run_batch` sizes it)."""
    if scheduler is not None:
        from imucal.fleet.scheduler import probe

        probe(scheduler)
    if not store.is_dir():
        raise ImucalError("no calibration store here (the folder does not exist)",
                          source=str(store), field="--check")
    jobs, rows = plan_checks(files, store, device_from=device_from, load_kw=load_kw,
                             acc_limit_mg=acc_limit_mg, gyro_limit_deg_s=gyro_limit_deg_s)
    counts = Counts(total=len(files), failed=len(rows))
    workers, capped = local_workers(workers, len(jobs))
    where = "nothing to do"
    if jobs:
        with cluster_client(scheduler, workers) as (client, where):
            where += capped
            rows += list(run_on_cluster(
                client, run_check_job, jobs, [f"imucal-check-{i}" for i in range(len(jobs))],
                retries, counts, progress, ok=lambda row: row["verdict"] != FAILED,
                lost=lambda job, why: job.row() | {"verdict": FAILED, "error": why}))
    rows.sort(key=lambda r: (r["device"] or "", r["path"]))
    if progress is not None:
        progress(counts)
    return CheckReport(rows=rows, devices=by_device(rows), cluster=where)


def check_lines(report: CheckReport) -> list[str]:
    """The per-device table, then the recordings that failed."""
    from imucal.fleet.store import format_table

    body = [[d["device"], d["verdict"], str(d["recordings"]),
             *(str(d["counts"][v]) for v in LEVELS), d["calibrated_at"] or "-",
             "-" if d["verdict"] == HOLDS else "; ".join(d["reasons"])]  # --json: all
            for d in report.devices]
    lines = [f"cluster         {report.cluster}",
             f"devices         {len(report.devices)}: " + ", ".join(
                 f"{sum(d['verdict'] == v for d in report.devices)} {v}" for v in LEVELS), ""]
    lines += format_table(["device", "verdict", "recordings", "holds", "drifted",
                           "cannot tell", "failed", "calibrated_at", "why"], body,
                          right={2, 3, 4, 5, 6})
    failed = [r for r in report.rows if r["verdict"] == FAILED]
    if failed:
        lines.append("failed:")
        lines += [f"  - {r['path']}: {r['error']}" if r["path"] not in (r["error"] or "")
                  else f"  - {r['error']}" for r in failed]
    return lines


__all__ = ["CheckJob", "CheckReport", "by_device", "check_lines", "plan_checks", "run_check",
           "run_check_job"]
