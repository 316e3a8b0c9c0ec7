"""imucal capture --spec: a unit out of the limits stops failed as soon as its parameters are
known to the targets, and writes no calibration (as `imucal calibrate --spec`); one within them
passes."""

import subprocess

import pytest
from synth_device import free_port, synth_stream

from imucal.cli.main import main

SAMPLES = 20147  # 40 poses, seed 3, at 100 Hz


@pytest.mark.parametrize("limits, rc, stopped", [
    # The synthetic scales are off by about 3 %: a 0.01 % limit is broken, 20 % is kept.
    ("acc_scale_pct = 0.01\n", 1, "out of the spec"),
    ("acc_scale_pct = 20\nacc_misalignment_mrad = 100\n", 0, "targets met"),
])
def test_spec(tmp_path, capsys, limits, rc, stopped):
    spec = tmp_path / "limits.toml"
    spec.write_text(limits)
    port = free_port()
    synth = synth_stream(tmp_path, f"tcp://127.0.0.1:{port}", stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    out = tmp_path / "D"
    try:
        got = main(["capture", f"tcp://127.0.0.1:{port}", "--out", str(out), "--no-view",
                    "--spec", str(spec), "--until", "60"])
    finally:
        synth.kill()
        synth.wait()
    text = capsys.readouterr()
    assert got == rc, text
    assert f"stopped: {stopped}" in text.out
    rows = len((out / "session.csv").read_text().splitlines()) - 1
    assert rows < 0.8 * SAMPLES  # stopped by itself, either way
    assert (out / "calib.json").exists() == (rc == 0)
    if rc:
        assert "acc_scale_pct" in text.out and "nothing written" in text.err
