"""The calibration store, drift and the fleet report: add/list/get round trips, --at and the
age warning, the index rebuilt from the folder against the one kept incrementally, two
processes adding at once, drift of two devices made by imucal.synth read back from the .rrd,
a fleet report that flags the one unit far out of spec, and one-line errors for bad input."""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess
import sys
import time
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from imucal.cli import main
from imucal.fleet.index import INDEX, rebuild_index, refresh_index
from imucal.io.calibration_file import save_calibration
from imucal.io.export import write_session_mat
from imucal.models import SensorModel, acc_theta
from imucal.pipeline import calibrate
from imucal.synth import make_session, random_acc_model, random_gyro_model

UTC = timezone.utc
DATES = [datetime(2024, 1, 10, tzinfo=UTC) + timedelta(days=30 * k) for k in range(4)]
# Truth of the drift: per 30 days, devA's accelerometer bias b_x grows 4 mg and its scale s_z
# 0.2 %; devB's bias b_z falls 3 mg. Everything else stays.
DRIFT = {"devA": {"b": np.array([0.004, 0.0, 0.0]), "s": np.array([0.0, 0.0, 0.002])},
         "devB": {"b": np.array([0.0, 0.0, -0.003]), "s": np.zeros(3)}}
FLEET = ("devC", "devD", "devE", "devF", "devG", "devX")  # devX: 120 mg of bias on x
SHORT = {"poses": 12, "still": 2.5, "move": 1.0, "init_still": 4.0}


def _models(seed: int) -> tuple[SensorModel, SensorModel]:
    """A unit well inside the spec of tests/test_fleet.py (bias ~10 mg, scale ~0.5 %)."""
    rng = np.random.default_rng(seed)
    return random_acc_model(rng, mis=0.002, scale=0.005, bias=0.01), random_gyro_model(rng)


def _calibrated(acc: SensorModel, gyro: SensorModel, seed: int, path: Path) -> Path:
    sess, _ = make_session(seed=seed, acc_truth=acc, gyro_truth=gyro, **SHORT)
    save_calibration(calibrate(sess), path)
    return path


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> dict:
    """devA and devB calibrated on four dates each (calib.json files, the truth of each), and
    six more units recorded as .mat files for imucal batch, devX far out of spec."""
    root = tmp_path_factory.mktemp("lab")
    calibs, truth = {}, {}
    for d, device in enumerate(DRIFT):
        acc, gyro = _models(10 + d)
        for k, when in enumerate(DATES):
            drifted = SensorModel(T=acc.T, K=acc.K * (1 + k * DRIFT[device]["s"]),
                                  b=acc.b + k * DRIFT[device]["b"])
            name = f"{device}_{when:%Y%m%d}.json"
            calibs[(device, k)] = _calibrated(drifted, gyro, 100 * d + k, root / name)
            truth[(device, k)] = drifted
    for i, device in enumerate(FLEET):
        acc, gyro = _models(20 + i)
        if device == "devX":
            acc = SensorModel(T=acc.T, K=acc.K, b=np.array([0.12, acc.b[1], acc.b[2]]))
        sess, _ = make_session(seed=200 + i, acc_truth=acc, gyro_truth=gyro, **SHORT)
        (root / "in" / device).mkdir(parents=True)
        write_session_mat(root / "in" / device / "2024-04-20_s.mat", sess)
    return {"root": root, "calibs": calibs, "truth": truth}


def _run(capsys, *args: str) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def _add(capsys, store: Path, calib: Path, device: str, when: datetime) -> str:
    rc, out, err = _run(capsys, "store", "add", calib, "--store", store, "--device", device,
                        "--when", when.isoformat())
    assert rc == 0, err
    return out


def _cells(line: str) -> list[str]:
    return line.split()


# --- add, list, get ------------------------------------------------------------------------------


def test_add_list_get_round_trip(lab, tmp_path, capsys) -> None:
    store, calibs = tmp_path / "store", lab["calibs"]
    out = _add(capsys, store, calibs[("devA", 0)], "devA", DATES[0])
    assert out.strip() == (f"stored {store}/devA/2024-01-10T000000Z.calib.json (device devA, "
                           "calibrated_at 2024-01-10T00:00:00Z from --when)")
    _add(capsys, store, calibs[("devA", 1)], "devA", DATES[1] + timedelta(hours=9.5))
    _add(capsys, store, calibs[("devB", 0)], "devB", DATES[0])
    # The same calibration at the same second is stored once; another one gets its own name.
    again = _add(capsys, store, calibs[("devA", 0)], "devA", DATES[0])
    assert again.startswith(f"already stored as {store}/devA/2024-01-10T000000Z.calib.json")
    _add(capsys, store, calibs[("devA", 2)], "devA", DATES[0])

    rc, out, err = _run(capsys, "store", "list", "--store", store)
    assert rc == 0 and err == ""
    lines = out.splitlines()
    assert _cells(lines[0]) == ["device", "calibrated_at", "from", "age", "static_mg", "spec",
                                "file"]
    static = {k: json.loads(calibs[k].read_text())["quality"]["static_norm_rms_mg"]["after"]
              for k in (("devA", 0), ("devA", 1), ("devA", 2), ("devB", 0))}
    expected = [("devA", "2024-01-10T00:00:00Z", ("devA", 0), "devA/2024-01-10T000000Z"),
                ("devA", "2024-01-10T00:00:00Z", ("devA", 2), "devA/2024-01-10T000000Z-2"),
                ("devA", "2024-02-09T09:30:00Z", ("devA", 1), "devA/2024-02-09T093000Z"),
                ("devB", "2024-01-10T00:00:00Z", ("devB", 0), "devB/2024-01-10T000000Z")]
    assert len(lines) == 1 + len(expected)
    now = datetime.now(UTC)
    for line, (device, when, key, name) in zip(lines[1:], expected):
        cells = _cells(line)
        age = (now - datetime.fromisoformat(when.replace("Z", "+00:00"))).days
        assert cells == [device, when, "--when", cells[3], "days", f"{static[key]:.3g}", "-",
                         f"{name}.calib.json"]
        assert abs(int(cells[3]) - age) <= 1
    rc, out, _ = _run(capsys, "store", "list", "--store", store, "--device", "devB")
    assert rc == 0 and len(out.splitlines()) == 2 and out.splitlines()[1].startswith("devB ")

    # A stored file is the calibration as given plus where its time came from.
    stored = json.loads((store / "devA/2024-02-09T093000Z.calib.json").read_text())
    block = stored.pop("store")
    assert stored == json.loads(calibs[("devA", 1)].read_text())
    assert block["device"] == "devA" and block["calibrated_at"] == "2024-02-09T09:30:00Z"
    assert block["when_from"] == "--when"
    assert block["added_from"] == str(calibs[("devA", 1)].resolve())

    # get: the path on stdout; --out a byte copy; the later add of one second wins.
    rc, out, err = _run(capsys, "store", "get", "--store", store, "--device", "devA", "--at",
                        "2024-01-20")
    assert rc == 0 and out.strip() == f"{store}/devA/2024-01-10T000000Z-2.calib.json"
    assert "older than" not in err
    rc, out, _ = _run(capsys, "store", "get", "--store", store, "--device", "devA", "--at",
                      "2024-02-10", "--out", tmp_path / "got.json", "--max-age", "400d")
    assert rc == 0
    assert (tmp_path / "got.json").read_bytes() == (
        store / "devA/2024-02-09T093000Z.calib.json").read_bytes()
    assert out.startswith(f"wrote {tmp_path}/got.json (device devA, calibrated_at "
                          "2024-02-09T09:30:00Z, 14.5 hours before 2024-02-10T00:00:00Z")
    # The copy is a calibration imucal apply reads (the store block is ignored).
    from imucal.io.calibration_file import load_calibration

    cal = load_calibration(tmp_path / "got.json")
    np.testing.assert_allclose(acc_theta(cal.segments[0].acc)[6:],
                               lab["truth"][("devA", 1)].b, atol=1.5e-3)


def test_get_at_picks_the_newest_before_and_warns_on_age(lab, tmp_path, capsys) -> None:
    store = tmp_path / "store"
    for k in (0, 1, 3):
        _add(capsys, store, lab["calibs"][("devA", k)], "devA", DATES[k])

    def get(at: str, *extra: str) -> tuple[int, str, str]:
        return _run(capsys, "store", "get", "--store", store, "--device", "devA", "--at", at,
                    *extra)

    name = {k: f"{store}/devA/{DATES[k]:%Y-%m-%dT%H%M%SZ}.calib.json" for k in (0, 1, 3)}
    assert get("2024-01-10T00:00:00Z")[1].strip() == name[0]  # at its time: that one
    assert get("2024-02-08T23:59:59Z")[1].strip() == name[0]  # a second before the next
    assert get("2024-02-09")[1].strip() == name[1]
    rc, out, err = get("2024-04-08")  # 59 days after the second: the third is not made yet
    assert rc == 0 and out.strip() == name[1]
    assert err == ""  # younger than the default --max-age (90 days)
    rc, out, err = get("2024-04-08", "--max-age", "8w")
    assert rc == 0 and out.strip() == name[1]
    assert err.strip() == ("imucal: warning: the calibration of devA in force at "
                           "2024-04-08T00:00:00Z is 59 days old, older than --max-age 8w "
                           f"({name[1]})")
    rc, out, err = get("2024-04-09T12:00:00+02:00", "--max-age", "8w")  # 10:00 UTC
    assert rc == 0 and out.strip() == name[3] and err == ""
    rc, out, err = get("2023-12-31")
    assert rc == 1 and out == ""
    assert err.strip() == (f"imucal: error: {store}: --at: no calibration of devA at or before "
                           "2023-12-31T00:00:00Z (its oldest is of 2024-01-10T00:00:00Z)")


# --- the index -----------------------------------------------------------------------------------


def test_index_rebuilt_from_the_folder_equals_the_incremental_one(lab, tmp_path, capsys
                                                                   ) -> None:
    store = tmp_path / "store"
    for (device, k), calib in lab["calibs"].items():
        _add(capsys, store, calib, device, DATES[k])
    incremental = pl.read_parquet(store / INDEX)
    assert incremental.height == 8 and incremental["error"].null_count() == 8
    (store / INDEX).unlink()
    rebuilt = rebuild_index(store)
    assert rebuilt.equals(incremental)
    assert pl.read_parquet(store / INDEX).equals(incremental)
    row = rebuilt.filter(pl.col("path") == "devB/2024-03-10T000000Z.calib.json").row(
        0, named=True)
    truth = lab["truth"][("devB", 2)]
    assert row["device"] == "devB" and row["seq"] == 1 and row["when_from"] == "--when"
    assert row["calibrated_at"] == DATES[2]
    got = np.array([row[f"acc_{n}"] for n in ("b_x", "b_y", "b_z")])
    std = np.array([row[f"acc_std_{n}"] for n in ("b_x", "b_y", "b_z")])
    assert np.all(np.abs(got - truth.b) < 6 * std + 1e-4)

    # The folder is the truth: a file removed, renamed or damaged by hand, and a damaged
    # index, are followed on the next read; only what changed is read again.
    (store / "devA/2024-01-10T000000Z.calib.json").unlink()
    os.rename(store / "devB/2024-01-10T000000Z.calib.json",
              store / "devB/2024-01-11T120000Z.calib.json")
    (store / "devB/notes.calib.json").write_text("{}")
    after = refresh_index(store)
    assert after.height == 8
    moved = after.filter(pl.col("path") == "devB/2024-01-11T120000Z.calib.json").row(
        0, named=True)
    assert moved["when_from"] == "file name" and moved["calibrated_at"] == datetime(
        2024, 1, 11, 12, tzinfo=UTC)
    bad = after.filter(pl.col("error").is_not_null())["error"].to_list()
    assert bad == ["devB/notes.calib.json: not named DEVICE/YYYY-MM-DDTHHMMSSZ.calib.json; "
                   "left out"]
    (store / INDEX).write_bytes(b"not parquet")
    assert rebuild_index(store).equals(after) and refresh_index(store).equals(after)
    rc, out, err = _run(capsys, "store", "list", "--store", store)
    assert rc == 0 and len(out.splitlines()) == 1 + 7
    assert err.strip() == ("imucal: warning: devB/notes.calib.json: not named "
                           "DEVICE/YYYY-MM-DDTHHMMSSZ.calib.json; left out")


ADDER = """
import sys, time
from datetime import datetime, timedelta, timezone
from pathlib import Path
from imucal.fleet.store import add
store, calib, go = sys.argv[1], sys.argv[2], Path(sys.argv[3])
import imucal.fleet.index, imucal.io.calibration_file, polars  # noqa: E401  (imports done)
Path(sys.argv[4]).touch()
while not go.exists():
    time.sleep(0.005)
t0 = datetime(2024, 6, 1, tzinfo=timezone.utc)
for k in range(15):
    add(store, calib, "devA", t0 + timedelta(days=k))
"""


def test_two_processes_adding_at_once_lose_nothing(lab, tmp_path) -> None:
    """Two processes add 15 calibrations each to one device at the same 15 times (every name
    contested) and both keep the index: 30 files, 30 index rows."""
    store, go = tmp_path / "store", tmp_path / "go"
    calibs = [lab["calibs"][("devA", 0)], lab["calibs"][("devB", 0)]]
    ready = [tmp_path / f"ready{i}" for i in range(2)]
    procs = [subprocess.Popen([sys.executable, "-c", ADDER, str(store), str(c), str(go),
                               str(r)], stderr=subprocess.PIPE, text=True)
             for c, r in zip(calibs, ready)]
    deadline = time.monotonic() + 120
    while not all(r.exists() for r in ready):  # both past their imports: start together
        assert time.monotonic() < deadline and all(p.poll() is None for p in procs)
        time.sleep(0.01)
    go.touch()
    for p in procs:
        assert p.wait(timeout=120) == 0, p.stderr.read()
    files = sorted(p.name for p in (store / "devA").glob("*.calib.json"))
    assert len(files) == 30
    sources = {}
    for name in files:
        doc = json.loads((store / "devA" / name).read_text())
        sources.setdefault(name[:18], set()).add(doc["source"]["file"])
    assert sorted(sources) == [f"{datetime(2024, 6, 1) + timedelta(days=k):%Y-%m-%dT%H%M%SZ}"
                               for k in range(15)]
    names = {json.loads(c.read_text())["source"]["file"] for c in calibs}
    assert all(s == names for s in sources.values())  # each time: both calibrations
    index = pl.read_parquet(store / INDEX)  # as the last writer left it
    assert index.height == 30 and sorted(index["seq"].to_list()) == [1] * 15 + [2] * 15
    assert index.equals(rebuild_index(store))


# --- batch --store, the fleet report, drift ------------------------------------------------------


@pytest.fixture(scope="module")
def fleet_store(lab, tmp_path_factory) -> dict:
    """A store fed by hand (devA, devB: four calibrations each) and by imucal batch --store
    (six units, one calibration each), and what the batch printed on its first and second
    runs."""
    root, store = lab["root"], tmp_path_factory.mktemp("fleet_store") / "store"
    for (device, k), calib in lab["calibs"].items():
        assert main(["store", "add", str(calib), "--store", str(store), "--device", device,
                    "--when", DATES[k].isoformat()]) == 0
    batch = ["batch", str(root / "in" / "*" / "*.mat"), "--out-dir", str(store.parent / "out"),
             "--device-from", "{device}/{date}_*.mat", "--store", str(store), "--workers", "2"]
    printed = []
    for _ in range(2):
        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer):
            rc = main(batch)
        printed.append((rc, buffer.getvalue()))
    return {"store": store, "batch": printed}


def test_batch_adds_each_calibration_to_the_store(fleet_store) -> None:
    store = fleet_store["store"]
    (rc, out), (rc2, out2) = fleet_store["batch"]
    assert rc == 0, out
    assert f"store           {store}: 6 added, 0 already there, 0 not stored" in out
    rows = {r["device"]: r for r in refresh_index(store).to_dicts()}
    for device in FLEET:
        assert rows[device]["calibrated_at"] == datetime(2024, 4, 20, tzinfo=UTC)
        assert rows[device]["when_from"] == "recorded_at"  # the date in the path
        assert rows[device]["path"] == f"{device}/2024-04-20T000000Z.calib.json"
        assert rows[device]["error"] is None
    # A rerun skips every session and stores none twice.
    assert rc2 == 0 and "cluster         nothing to do" in out2
    assert f"{store}: 0 added, 6 already there, 0 not stored" in out2
    assert len(list(store.glob("*/*.calib.json"))) == 8 + 6


def test_the_fleet_report_flags_the_unit_out_of_spec_and_only_it(lab, fleet_store, tmp_path,
                                                                  capsys) -> None:
    from viewer.readback import values

    rrd = tmp_path / "fleet.rrd"
    rc, out, err = _run(capsys, "fleet", "report", fleet_store["store"], "--rrd", rrd)
    assert rc == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("fleet: 8 devices, the newest calibration of each at or before")
    i = lines.index("outliers: 1:")
    assert lines[i + 1].startswith("  devX: accelerometer b_x = ")
    assert float(lines[i + 1].split()[4]) == pytest.approx(0.12, abs=2e-3)
    assert lines[i + 1].endswith("devX/2024-04-20T000000Z.calib.json")
    flagged = [ln for ln in lines[2:i] if not ln.endswith(" -")]
    assert len(lines[2:i]) == 21 and len(flagged) == 1
    assert flagged[0].startswith("accelerometer b_x") and "devX (z = +" in flagged[0]

    got = values(rrd, "fleet/outliers")
    assert got["count"] == 1 and got["device"] == "devX"
    assert got["parameter"] == "accelerometer b_x" and abs(got["value"] - 0.12) < 2e-3
    assert got["z"] > 3.5
    spread = values(rrd, "fleet/parameters/accelerometer/b_x")
    assert spread["outliers"] == "devX" and spread["unit"] == "g"
    assert sorted(spread["devices"]) == ["devA", "devB", *FLEET]
    points = values(rrd, "fleet/z/points")
    assert len(points["z"]) == 21 * 8
    out_of_range = [(d, p) for d, p, z in zip(points["device"], points["parameter"], points["z"])
                    if abs(z) > 3.5]
    assert out_of_range == [("devX", "accelerometer b_x")]
    # The newest of devA is its fourth (the fleet is judged on each unit's newest).
    assert spread["values"][spread["devices"].index("devA")] == pytest.approx(
        lab["truth"][("devA", 3)].b[0], abs=1.5e-3)


def test_drift_of_two_devices_read_back_from_the_recording(lab, tmp_path, capsys) -> None:
    from viewer.readback import scalars, values

    store = tmp_path / "store"
    for (device, k), calib in lab["calibs"].items():
        _add(capsys, store, calib, device, DATES[k])
    rrd = tmp_path / "drift.rrd"
    rc, out, err = _run(capsys, "drift", "--device", "devA", "--device", "devB", "--store",
                        store, "--rrd", rrd)
    assert rc == 0, err
    when = np.array([np.datetime64(d.replace(tzinfo=None), "ns") for d in DATES])
    for device in DRIFT:
        truth = [lab["truth"][(device, k)] for k in range(4)]
        for group, names, true in (("bias", ("b_x", "b_y", "b_z"), [m.b for m in truth]),
                                   ("scale", ("s_x", "s_y", "s_z"), [m.K for m in truth])):
            for axis, name in enumerate(names):
                t, v = scalars(rrd, f"drift/accelerometer/{group}/{device}/{name}",
                               timeline="calibrated_at")
                assert np.array_equal(t.astype("datetime64[ns]"), when), (device, name)
                np.testing.assert_allclose(v, [x[axis] for x in true], atol=1.5e-3,
                                           err_msg=f"{device} {name}")
        stats = values(rrd, f"drift/stats/{device}")
        by = dict(zip(stats["parameter"], zip(stats["change"], stats["change_sigma"],
                                              stats["per_30d"])))
        moving = {"devA": ("accelerometer b_x", 0.012), "devB": ("accelerometer b_z", -0.009)}
        label, change = moving[device]
        assert by[label][0] == pytest.approx(change, abs=1.5e-3)
        assert by[label][2] == pytest.approx(change / 3, abs=6e-4)  # per 30 days
        assert abs(by[label][1]) > 10  # far beyond the fits' errors
        assert abs(by["accelerometer b_y"][1]) < 5  # still: within the errors
    assert abs(values(rrd, "drift/stats/devA")["change"][5] - 0.006) < 1.5e-3  # s_z: +0.2 %x3

    # The table: a row per parameter, a column per calibration.
    block = out.split("\n\n")[0].splitlines()
    assert block[0].startswith("devA: 4 calibrations from 2024-01-10 to 2024-04-09 (90 days)")
    assert _cells(block[1]) == ["parameter", "unit", "2024-01-10", "2024-02-09", "2024-03-10",
                                "2024-04-09", "change", "per", "30", "d", "change/σ"]
    row = next(_cells(ln) for ln in block if ln.startswith("accelerometer b_x "))
    truth = [lab["truth"][("devA", k)].b[0] for k in range(4)]
    assert row[2] == "g" and np.allclose([float(x) for x in row[3:7]], truth, atol=1.5e-3)
    assert float(row[7]) == pytest.approx(0.012, abs=1.5e-3)
    assert out.split("\n\n")[1].startswith("devB: 4 calibrations")
    assert out.rstrip().endswith(f"wrote {rrd}")


def test_robust_z_by_hand() -> None:
    from imucal.fleet.drift import robust_z

    # median 3, |x - 3| = 2 1 0 1 97, MAD 1: z = 0.6745 (x - 3)
    z, med, mad, how = robust_z(np.array([1.0, 2.0, 3.0, 4.0, 100.0]))
    assert (med, mad, how) == (3.0, 1.0, "MAD")
    np.testing.assert_allclose(z, 0.6745 * np.array([-2, -1, 0, 1, 97]))
    # more than half equal: MAD 0, the mean absolute deviation (0.5) stands in
    z, med, mad, how = robust_z(np.array([5.0, 5.0, 5.0, 5.0, 7.5]))
    assert (med, mad) == (5.0, 0.0) and how.startswith("mean absolute deviation")
    np.testing.assert_allclose(z, [0, 0, 0, 0, 2.5 / (1.253314 * 0.5)])
    assert robust_z(np.array([2.0, 2.0, 2.0]))[3] == "all equal"


# --- bad input -----------------------------------------------------------------------------------


def test_bad_input_is_one_line_and_exit_1(lab, tmp_path, capsys) -> None:
    store = tmp_path / "store"
    _add(capsys, store, lab["calibs"][("devA", 0)], "devA", DATES[0])
    (tmp_path / "notes.json").write_text('{"format": "something else"}')
    cases = [
        (["store", "get", "--store", store, "--device", "devZ"],
         f"{store}: --device: no calibrations of device 'devZ' in the store (it has 1 device: "
         "devA)"),
        (["store", "list", "--store", store, "--device", "devZ"], "devZ"),
        (["drift", "--device", "devZ", "--store", store], "devZ"),
        (["store", "get", "--store", store, "--device", "devA", "--at", "last tuesday"],
         "--at: cannot read 'last tuesday' as a time (expected e.g. 2024-05-01 or "
         "2024-05-01T12:30:00Z)"),
        (["store", "add", lab["calibs"][("devA", 1)], "--store", store, "--device", "devA",
          "--when", "2024-02-30"], "--when: cannot read '2024-02-30' as a time"),
        (["store", "get", "--store", store, "--device", "devA", "--max-age", "soon"],
         "--max-age: cannot read 'soon' as an age"),
        (["store", "add", tmp_path / "notes.json", "--store", store, "--device", "devA"],
         f"{tmp_path}/notes.json: format: expected format 'imucal-calibration'"),
        (["store", "add", lab["calibs"][("devA", 1)], "--store", store, "--device", "dev A"],
         "--device: 'dev A' is not a usable device id"),
        (["store", "add", lab["calibs"][("devA", 1)], "--store", store],
         "no device id in the file; give --device"),
        (["store", "list", "--store", tmp_path / "nowhere"],
         "no calibration store here (the folder does not exist)"),
        (["fleet", "report", tmp_path / "nowhere"], "no calibration store here"),
    ]
    for args, message in cases:
        rc, out, err = _run(capsys, *args)
        assert rc == 1, (args, out, err)
        assert err.count("\n") == 1 and err.startswith("imucal: error: "), (args, err)
        assert message in err, (args, err)
    assert sorted(p.name for p in (store / "devA").glob("*.calib.json")) == [
        "2024-01-10T000000Z.calib.json"]  # nothing was added by the refused commands
