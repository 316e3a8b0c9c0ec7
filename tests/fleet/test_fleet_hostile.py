"""Issue 27 on the fleet: ``--workers`` capped at the sessions and the cores, and two units
never folded into one device id. Both are decided before a cluster starts: fast."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np
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


# --- --scheduler: what is at the address, said at once in one line (issue 27) ----------------


def _run_cli(args: list) -> tuple[int, str]:
    import io
    import signal

    from imucal.cli.main import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = main([str(a) for a in args])
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    return rc, err.getvalue()


@contextlib.contextmanager
def _server(behaviour: str):
    """A plain TCP server on 127.0.0.1 that is no Dask scheduler: it says nothing and holds
    the connection, closes it at once, or greets with another protocol's banner (SSH's)."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(4)
    held: list = []

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = srv.accept()
                if behaviour == "closes":
                    conn.close()
                    continue
                if behaviour == "banner":
                    conn.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")
                held.append(conn)

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        srv.close()
        for conn in held:
            conn.close()


def _closed_port() -> str:
    import socket

    with socket.socket() as s:  # bound, never listening: the port is ours and refuses
        s.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


@pytest.fixture
def one_session(tmp_path) -> Path:
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "s.csv").write_text("t,ax,ay,az\n0,0,0,1\n")  # never read: the
    return tmp_path / "a" / "s.csv"  # address is checked first


@pytest.mark.parametrize("address", ["notanaddress", "tcp://", "tcp://host", "tcp://:8786",
                                     "tcp://h:port", "tcp://h:70000", "foo://h:1"])
def test_a_scheduler_that_is_no_address_is_a_usage_error(tmp_path, one_session, address):
    rc, err = _run_cli(["batch", one_session, "--out-dir", tmp_path / "o", "--scheduler",
                        address])
    assert rc == 2, err  # was exit 3, an internal error
    assert "Invalid value for '--scheduler'" in err and "expected tcp://HOST:PORT" in err
    assert not (tmp_path / "o").exists()


def test_a_closed_port_is_said_at_once(tmp_path, one_session):
    import time

    address = _closed_port()
    t0 = time.monotonic()
    rc, err = _run_cli(["batch", one_session, "--out-dir", tmp_path / "o", "--scheduler",
                        address])
    assert time.monotonic() - t0 < 3  # was 23 s, then "OSError"
    assert rc == 1 and err.count("\n") == 1, err
    assert err == (f"imucal: error: --scheduler: no Dask scheduler at {address}: connection "
                   "refused (nothing listens on that port)\n")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("behaviour, said", [
    ("silent", "it sent nothing within 0.5 s of the connection"),
    ("closes", "it closed the connection without a Dask greeting"),
    ("banner", "its greeting is not Dask's); its first bytes: b'SSH-2.0-OpenSSH_'"),
])
def test_a_server_that_is_no_scheduler_is_said_as_such(tmp_path, one_session, monkeypatch,
                                                       behaviour, said):
    import time

    import imucal.fleet.scheduler as scheduler

    monkeypatch.setattr(scheduler, "PROBE_SECONDS", 0.5)
    with _server(behaviour) as address:
        t0 = time.monotonic()
        rc, err = _run_cli(["batch", one_session, "--out-dir", tmp_path / "o",
                            "--scheduler", address])
    assert time.monotonic() - t0 < 3
    assert rc == 1 and err.count("\n") == 1, err  # the banner was "not enough memory"
    assert err.startswith(f"imucal: error: --scheduler: {address} is a server, but not a "
                          "Dask scheduler"), err
    assert said in err


def test_a_scheduler_address_as_dask_reads_it():
    from imucal.fleet.scheduler import split_address

    assert split_address("tcp://10.0.0.5:8786") == ("tcp", "10.0.0.5", 8786)
    assert split_address("10.0.0.5:8786") == ("tcp", "10.0.0.5", 8786)  # Dask's default
    assert split_address("tcp://[::1]:8786") == ("tcp", "::1", 8786)
    assert split_address("tls://sched.lan:8786") == ("tls", "sched.lan", 8786)


# --- fleet report: an outlier among three or four units (issue 27) ----------------------------


def _fleet_rows(b_x: list[float]) -> list[dict]:
    """One calibration per unit, the accelerometer's b_x as given (g), the rest alike."""
    from datetime import datetime, timezone

    from imucal.fleet.drift import PARAMS

    when = datetime(2024, 4, 20, tzinfo=timezone.utc)
    rows = []
    for i, b in enumerate(b_x):
        row = {p.column: (1.0 if p.group == "scale" else 0.0) + 1e-4 * ((i * 7 + k) % 5)
               for k, p in enumerate(PARAMS)}  # spread, nothing out: only b_x stands out
        rows.append(row | {"device": f"u{i}", "calibrated_at": when, "seq": 1,
                           "path": f"u{i}/c.json", "acc_unit_raw": "g",
                           "gyro_unit_raw": "rad/s", "acc_b_x": b})
    return rows


@pytest.mark.parametrize("b_x, flagged", [
    ([0.005, 0.005, 0.120], "u2"),  # the others agree: MAD = 0, |z| was at most 2.4
    ([0.005, 0.005, 0.005, 0.120], "u3"),  # ... at most 3.2
    ([0.120, 0.0050, 0.0052], "u0"),  # Q = 0.998
    ([0.005, 0.006, 0.004, -0.110], "u3"),  # Q = 0.991
])
def test_a_clear_outlier_among_three_or_four_units_is_flagged(b_x, flagged):
    from imucal.fleet.drift import fleet_lines, fleet_report

    rep = fleet_report(_fleet_rows(b_x))
    assert [(o.device, o.spread.param.label) for o in rep.outliers] == [
        (flagged, "accelerometer b_x")]
    text = "\n".join(fleet_lines(rep))
    assert f"outliers: 1:\n  {flagged}: accelerometer b_x = " in text
    assert "Dixon's Q = " in text
    n = len(b_x)
    assert f"note: {n} units: a robust z is degenerate with so few; Dixon's Q judged" in text


@pytest.mark.parametrize("b_x", [[0.003, 0.008, 0.120],  # Q = 0.957: with three, not clear
                                 [0.005, 0.020, 0.035, 0.050],  # evenly spread
                                 [0.005, 0.005, 0.005]])  # all equal
def test_three_or_four_units_without_a_clear_outlier_flag_none(b_x):
    from imucal.fleet.drift import dixon_q, fleet_report

    rep = fleet_report(_fleet_rows(b_x))
    assert rep.outliers == []
    q, _ = dixon_q(np.array(b_x))
    assert q is None if len(set(b_x)) == 1 else q < 0.96


def test_dixon_q_is_the_gap_over_the_range():
    from imucal.fleet.drift import dixon_q

    assert dixon_q(np.array([1.0, 2.0, 11.0])) == (pytest.approx(0.9), 2)
    assert dixon_q(np.array([-9.0, 0.0, 1.0, 1.0])) == (pytest.approx(0.9), 0)


def test_five_units_are_still_judged_by_robust_z():
    from imucal.fleet.drift import fleet_report

    rep = fleet_report(_fleet_rows([0.005, 0.006, 0.004, 0.0055, 0.120]))
    [o] = rep.outliers
    assert o.device == "u4" and o.spread.q is None and o.z > 3.5


def test_generalized_esd_reproduces_rosners_worked_example():
    # Rosner (1983)'s 54 values, as the NIST handbook works them (alpha 5 %, up to 10):
    # three outliers, the second one masked by the third (R_2 < lambda_2, R_3 > lambda_3).
    from imucal.fleet.drift import generalized_esd

    x = np.array([-0.25, 0.68, 0.94, 1.15, 1.20, 1.26, 1.26, 1.34, 1.38, 1.43, 1.49, 1.49,
                  1.55, 1.56, 1.58, 1.65, 1.69, 1.70, 1.76, 1.77, 1.81, 1.91, 1.94, 1.96,
                  1.99, 2.06, 2.09, 2.10, 2.14, 2.15, 2.23, 2.24, 2.26, 2.35, 2.37, 2.40,
                  2.47, 2.54, 2.62, 2.64, 2.90, 2.92, 2.92, 2.93, 3.21, 3.26, 3.30, 3.59,
                  3.68, 4.30, 4.64, 5.34, 5.42, 6.01])
    got = generalized_esd(x, alpha=0.05, r=10)
    assert [k for k, _, _ in got] == [53, 52, 51]
    assert [r for _, r, _ in got] == pytest.approx([3.119, 2.943, 3.179], abs=1e-3)
    assert [lam for _, _, lam in got] == pytest.approx([3.159, 3.151, 3.144], abs=1e-3)


@pytest.mark.parametrize("n", [5, 8, 12])
def test_a_normally_spread_fleet_rarely_flags_a_unit(n):
    # The |z| > 3.5 rule flagged some unit for 21 % (n = 5) to 12 % (n = 12) of normally
    # spread parameters; the generalized ESD test at 1 % must stay near 1 %.
    from imucal.fleet.drift import generalized_esd

    rng = np.random.default_rng(n)
    flagged = sum(bool(generalized_esd(rng.normal(0.005, 0.001, n))) for _ in range(2000))
    assert flagged / 2000 < 0.03


def test_two_wild_units_among_ten_are_both_flagged():
    from imucal.fleet.drift import fleet_report

    b_x = [0.005, 0.006, 0.004, 0.0055, 0.0045, 0.0052, 0.0048, 0.0058, 0.120, 0.135]
    rep = fleet_report(_fleet_rows(b_x))
    assert sorted(o.device for o in rep.outliers) == ["u8", "u9"]
