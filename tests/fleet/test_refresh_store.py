"""``imucal refresh CALIB RECORDING --out NEW.json --store STORE``: the refreshed calibration as
a new version of its device in the store, with its provenance; never over an existing version;
--out and the store's file both written or neither."""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from cli_run import run

from imucal.cli.main import main
from imucal.fleet import refresh_store

WHEN = 1_790_000_000  # the recording's modification time: 2026-09-21T14:13:20Z
STAMP = "2026-09-21T141320Z"


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> Path:
    """Three minutes on a desk, the gyroscope's bias moved 0.4 deg/s about x and the
    accelerometer's 8 mg along z, and the calibration from before."""
    d = tmp_path_factory.mktemp("refreshstore")
    assert main(["synth", str(d / "rec.mat"), "--activity", "desk", "--minutes", "3", "--seed",
                 "2", "--drift-gyro-bias", "0.4,0,0", "--drift-acc-bias", "0,0,8"]) == 0
    os.utime(d / "rec.mat", (WHEN, WHEN))
    return d


@pytest.fixture
def store(made, tmp_path) -> tuple[Path, Path]:
    s = tmp_path / "store"
    assert main(["store", "add", str(made / "rec.mat.calib.json"), "--store", str(s),
                 "--device", "unit7", "--when", "2026-01-02"]) == 0
    return s, s / "unit7" / "2026-01-02T000000Z.calib.json"


def snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def test_a_new_version_with_its_provenance_and_never_over_another(made, store, tmp_path,
                                                                    capsys):
    s, old = store
    before = old.read_bytes()
    # a version already at the recording's second (another unit's file put there by hand)
    squatter = s / "unit7" / f"{STAMP}.calib.json"
    shutil.copy(old, squatter)
    squat = squatter.read_bytes()
    new = tmp_path / "new.json"
    rc, out, _ = run(capsys, "refresh", old, made / "rec.mat", "--out", new, "--store", s)
    assert rc == 0
    version = s / "unit7" / f"{STAMP}-2.calib.json"
    assert f"stored {version} (device unit7" in out
    assert old.read_bytes() == before and squatter.read_bytes() == squat  # untouched
    doc = json.loads(version.read_text())
    assert {k: v for k, v in doc.items() if k != "store"} == json.loads(new.read_text())
    assert doc["store"]["refreshed_from"] == "unit7/2026-01-02T000000Z.calib.json"
    assert doc["store"]["calibrated_at"] == "2026-09-21T14:13:20Z"
    prov = doc["refresh"]
    assert prov["recording"]["file"].endswith("rec.mat")
    assert len(prov["recording"]["sha256"]) == 64
    changed = {(c["sensor"], c["parameter"]): c for c in prov["changed"]}
    assert abs(changed["gyroscope", "b_x"]["change"] - np.radians(0.4)) < np.radians(0.03)
    assert abs(changed["accelerometer", "b_z"]["change"] - 0.008) < 1e-3
    assert ("accelerometer", "s_x") not in changed
    # the store's latest is the refreshed one
    rc, out, _ = run(capsys, "store", "get", "--store", s, "--device", "unit7")
    assert rc == 0 and out.strip() == str(version)
    # the same refresh again: already stored, nothing more in the store
    rc, out, _ = run(capsys, "refresh", old, made / "rec.mat", "--out", tmp_path / "again.json",
                     "--store", s)
    assert rc == 0 and f"already stored as {version}" in out
    assert len(list((s / "unit7").glob("*.calib.json"))) == 3


def test_all_outputs_or_none(made, store, tmp_path, capsys, monkeypatch):
    s, old = store
    was = snapshot(s / "unit7")

    def full_disk(tmp: Path, text: str) -> None:
        tmp.write_text(text[:100])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(refresh_store, "_write_version", full_disk)
    new = tmp_path / "new.json"
    new.write_text("previous\n")
    rc, _, err = run(capsys, "refresh", old, made / "rec.mat", "--out", new, "--store", s)
    assert rc == 1 and "No space left on device" in err
    assert new.read_text() == "previous\n"  # --out unchanged
    assert snapshot(s / "unit7") == was  # no version, no temporary left
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".imucal")]


def test_the_device_comes_from_the_file_or_device(made, tmp_path, capsys):
    s = tmp_path / "store"
    calib = made / "rec.mat.calib.json"  # synth's: no device in it
    rc, _, err = run(capsys, "refresh", calib, made / "rec.mat", "--out", tmp_path / "n.json",
                     "--store", s)
    assert rc == 1 and "give --device" in err and not (tmp_path / "n.json").exists()
    rc, out, _ = run(capsys, "refresh", calib, made / "rec.mat", "--out", tmp_path / "n.json",
                     "--store", s, "--device", "unit9")
    assert rc == 0 and (s / "unit9" / f"{STAMP}.calib.json").exists()
    assert json.loads((s / "unit9" / f"{STAMP}.calib.json").read_text())["store"][
        "refreshed_from"] is None  # not a version of this store
    rc, _, err = run(capsys, "refresh", calib, made / "rec.mat", "--out", tmp_path / "m.json",
                     "--device", "unit9")
    assert rc == 2 and "give --store" in err
