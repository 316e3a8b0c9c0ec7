"""Issue 27 on the fleet: ``--workers`` capped at the sessions and the cores, and two units
never folded into one device id. Both are decided before a cluster starts: fast."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import pytest

import imucal.fleet.batch as batch
from imucal.errors import ImucalError


class _Started(Exception):
    pass


@pytest.fixture
def started(monkeypatch) -> list[int]:
    """The LocalCluster size run_batch asks for; the cluster itself is never started."""
    asked: list[int] = []

    @contextlib.contextmanager
    def fake(scheduler, workers):
        asked.append(workers)
        raise _Started
        yield  # pragma: no cover

    monkeypatch.setattr(batch, "cluster_client", fake)
    return asked


def _sessions(root: Path, folders: list[str]) -> list[Path]:
    files = []
    for i, folder in enumerate(folders):
        (root / folder).mkdir(parents=True, exist_ok=True)
        f = root / folder / f"s{i}.csv"
        f.write_text(f"t,ax,ay,az\n{i},0,0,1\n")
        files.append(f)
    return files


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


@pytest.mark.parametrize("asked", [50, 1000])
def test_workers_are_capped_at_the_sessions_and_the_cores(tmp_path, started, asked):
    files = _sessions(tmp_path / "in", ["a", "b"])
    with pytest.raises(_Started):
        batch.run_batch(files, tmp_path / "out", load_kw={}, settings={}, workers=asked)
    assert started == [min(2, _cores())]
    n, said = batch.local_workers(asked, 2)
    assert n == min(2, _cores())
    assert said == f" (--workers {asked} capped at {n}: 2 sessions to run, {_cores()} core" + (
        "s)" if _cores() != 1 else ")")
    assert batch.local_workers(1, 2) == (1, "")  # fewer than allowed: as asked
    assert batch.local_workers(None, 1) == (1, "")


@pytest.mark.parametrize("folders", [["IMU 1", "IMU_1"], ["imu-1", "IMU-1"],
                                     ["IMU.1.", "IMU.1"]])
def test_two_units_are_never_one_device(tmp_path, started, folders):
    files = _sessions(tmp_path / "in", folders)
    with pytest.raises(ImucalError) as e:
        batch.run_batch(files, tmp_path / "out", load_kw={}, settings={}, workers=1)
    msg = str(e.value)
    assert "\n" not in msg and "two units would be merged" in msg
    assert repr(Path(folders[0]).name) in msg and repr(Path(folders[1]).name) in msg
    assert started == []  # refused before any work


def test_one_folder_is_one_device(tmp_path, started):
    files = _sessions(tmp_path / "in", ["IMU 1", "IMU 1", "IMU 2"])
    jobs, bad = batch.plan(files, tmp_path / "out", device_from=None, load_kw={}, settings={},
                           spec=None)
    assert bad == [] and [j.identity.device for j in jobs] == ["IMU_1", "IMU_1", "IMU_2"]


@pytest.fixture(scope="module")
def calib_doc(tmp_path_factory) -> dict:
    import json

    from imucal.io.calibration_file import save_calibration
    from imucal.pipeline import calibrate
    from imucal.synth import make_session

    path = tmp_path_factory.mktemp("calib") / "c.json"
    sess, _ = make_session(poses=12, seed=4, still=2.5, move=1.0, init_still=4.0)
    save_calibration(calibrate(sess), path)
    return json.loads(path.read_text())


def _batch_file(tmp_path: Path, doc: dict, named: str, when: str) -> Path:
    import json

    path = tmp_path / f"{len(list(tmp_path.iterdir()))}.calib.json"
    path.write_text(json.dumps(doc | {"device": "IMU_1", "device_named": named,
                                      "calibrated_at": when}))
    return path


def test_the_store_never_merges_two_units_of_one_id(tmp_path, calib_doc):
    """Batch runs on different days: folder 'IMU 1' then folder 'IMU_1' both make IMU_1."""
    from imucal.fleet.store import add, calibrations

    store = tmp_path / "store"
    (tmp_path / "in").mkdir()
    first = _batch_file(tmp_path / "in", calib_doc, "IMU 1", "2024-05-01T10:00:00+00:00")
    again = _batch_file(tmp_path / "in", calib_doc, "IMU 1", "2024-06-01T10:00:00+00:00")
    other = _batch_file(tmp_path / "in", calib_doc, "IMU_1", "2024-07-01T10:00:00+00:00")
    assert add(store, first).device == "IMU_1"
    assert add(store, again, "IMU_1").device == "IMU_1"  # the same unit, as batch adds it
    with pytest.raises(ImucalError) as e:
        add(store, other, "IMU_1")
    msg = str(e.value)
    assert "\n" not in msg and "two units would be merged" in msg
    assert "'IMU 1'" in msg and "'IMU_1'" in msg and msg.startswith(str(other))
    assert len(calibrations(store, "IMU_1")) == 2
    assert add(store, other, "IMU_1b").device == "IMU_1b"  # named apart by the user
