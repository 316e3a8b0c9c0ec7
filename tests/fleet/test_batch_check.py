"""``imucal batch --check STORE``: a small synthetic fleet of everyday use (imucal synth
--activity) checked on a LocalCluster against each device's latest stored calibration: the
verdict per device, the exit code (1 drifted or failed, 2 cannot tell, 0 all hold), --json."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_run import run

from imucal.cli.main import main

pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    """devA and devC hold (3 min on a desk), devB's gyroscope bias moved 0.4 deg/s about x and
    its accelerometer's 8 mg along z, devD has half a minute of walking (too few moments). The
    store holds each one's calibration from before (synth writes it), devA's also an older,
    wrong one (the latest must be taken)."""
    root = tmp_path_factory.mktemp("fleetcheck")
    plan = {"devA": ("desk", "3", "1", []), "devB": ("desk", "3", "2", [
        "--drift-gyro-bias", "0.4,0,0", "--drift-acc-bias", "0,0,8"]),
        "devC": ("desk", "3", "3", []), "devD": ("walk", "0.5", "4", [])}
    for dev, (activity, minutes, seed, drift) in plan.items():
        (root / "fleet" / dev).mkdir(parents=True)
        rec = root / "fleet" / dev / "day1.mat"
        assert main(["synth", str(rec), "--activity", activity, "--minutes", minutes,
                     "--seed", seed, *drift]) == 0
        calib = rec.with_name("day1.mat.calib.json")
        assert main(["store", "add", str(calib), "--store", str(root / "store"), "--device",
                     dev, "--when", "2026-01-02"]) == 0
        shutil.move(calib, root / f"{dev}.calib.json")  # not a recording of the fleet
    old = json.loads((root / "devB.calib.json").read_text())  # devB's: wrong for devA
    (root / "old.json").write_text(json.dumps(old))
    assert main(["store", "add", str(root / "old.json"), "--store", str(root / "store"),
                 "--device", "devA", "--when", "2025-06-01"]) == 0
    return root


def test_each_device_judged_against_its_latest_calibration(fleet, capsys):
    rc, out, _ = run(capsys, "batch", "--check", fleet / "store", fleet / "fleet/*/*.mat",
                     "--workers", "2")
    assert rc == 1  # devB drifted
    assert "LocalCluster of 2 workers on 127.0.0.1" in out
    assert "devices         4: 2 holds, 1 drifted, 1 cannot tell, 0 failed" in out
    table = {line.split()[0]: line for line in out.splitlines() if line.startswith("dev")}
    assert table["devA"].split()[1] == "holds" and table["devC"].split()[1] == "holds"
    assert table["devB"].split()[1] == "drifted" and "b_x by +0.00" in table["devB"]
    assert "b_z by +0.00" in table["devB"]
    assert " ".join(table["devD"].split()[1:3]) == "cannot tell"
    assert "too few still moments" in table["devD"]

    rc, out, _ = run(capsys, "batch", "--check", fleet / "store", fleet / "fleet/*/*.mat",
                     "--workers", "2", "--json")
    data = json.loads(out)
    assert rc == 1 and data["exit_code"] == 1
    dev = {d["device"]: d for d in data["devices"]}
    assert {k: d["verdict"] for k, d in dev.items()} == {
        "devA": "holds", "devB": "drifted", "devC": "holds", "devD": "cannot tell"}
    assert dev["devA"]["calibrated_at"] == "2026-01-02T00:00:00Z"  # the latest, not 2025's
    rec = {Path(r["path"]).parent.name: r for r in data["recordings"]}
    gyro = {p["sensor"]: p for p in rec["devB"]["parts"]}["gyroscope"]
    moved = {c["parameter"]: c["change"] for c in gyro["changes"]}
    assert abs(moved["b_x"] - np.radians(0.4)) < np.radians(0.03)
    acc = {p["sensor"]: p for p in rec["devB"]["parts"]}["accelerometer"]
    assert abs({c["parameter"]: c["change"] for c in acc["changes"]}["b_z"] - 0.008) < 1e-3
    assert rec["devA"]["exit_code"] == 0 and rec["devD"]["exit_code"] == 2


def test_exit_codes_follow_the_worst_device(fleet, capsys):
    rc, out, _ = run(capsys, "batch", "--check", fleet / "store", fleet / "fleet/dev[AC]/*.mat",
                     "--workers", "1")
    assert rc == 0 and "2 holds, 0 drifted, 0 cannot tell, 0 failed" in out
    rc, out, _ = run(capsys, "batch", "--check", fleet / "store",
                     fleet / "fleet/dev[ACD]/*.mat", "--workers", "2")
    assert rc == 2 and "2 holds, 0 drifted, 1 cannot tell" in out


def test_a_device_without_a_stored_calibration_fails_its_row(fleet, capsys, tmp_path):
    (tmp_path / "devE").mkdir()
    shutil.copy(fleet / "fleet/devA/day1.mat", tmp_path / "devE" / "day1.mat")
    rc, out, _ = run(capsys, "batch", "--check", fleet / "store", tmp_path / "devE/day1.mat")
    assert rc == 1
    assert "devE    failed" in out and "no calibrations of device 'devE'" in out
    assert "nothing to do" in out  # no cluster started for it
    rc, _, err = run(capsys, "batch", "--check", fleet / "store", tmp_path / "devE/day1.mat",
                     "--out-dir", tmp_path / "o")
    assert rc == 2 and "--out-dir calibrates; --check only checks" in err
    rc, _, err = run(capsys, "batch", "--check", tmp_path / "nostore", tmp_path / "devE/day1.mat")
    assert rc == 1 and "no calibration store here" in err
