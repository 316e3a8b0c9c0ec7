"""The live view of a capture saved with --rrd (viewer/live.py): the signals as received, the
still state, the poses on the sphere, the fits' worst standard error over its target, the
guide; read back from the file."""

import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np

from imucal.cli.main import main
from viewer import readback

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
CLI = [sys.executable, "-c", "import sys; from imucal.cli.main import main; sys.exit(main())"]


def test_rrd_of_a_tcp_capture(tmp_path, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    synth = subprocess.Popen(CLI + ["synth", str(tmp_path / "s.mat"), "--poses", "40",
                                    "--seed", "3", "--stream", f"tcp://127.0.0.1:{port}",
                                    "--speed", "50"],
                             env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    rrd = tmp_path / "capture.rrd"
    try:
        rc = main(["capture", f"tcp://127.0.0.1:{port}", "--out", str(tmp_path / "D"),
                   "--rrd", str(rrd), "--until", "60"])
    finally:
        synth.kill()
        synth.wait()
    assert rc == 0, capsys.readouterr()
    rows = (tmp_path / "D" / "session.csv").read_text().splitlines()[1:]
    t, acc = readback.scalars(rrd, "live/accelerometer")
    # Every sample received is in the view, as received.
    assert len(t) == len(rows)
    sent = np.array([[float(x) for x in r.split(",")] for r in rows])
    np.testing.assert_allclose(t, sent[:, 0], atol=1e-6)
    np.testing.assert_array_equal(acc, sent[:, 1:4])
    _, still = readback.scalars(rrd, "live/still")
    assert 0.3 < still.mean() < 0.9  # holds and turns both seen
    _, poses = readback.scalars(rrd, "live/orientations")
    assert poses[-1] >= 9 and np.all(np.diff(poses) >= 0)
    _, ratio = readback.scalars(rrd, "live/worst_over_target")
    assert ratio[-1] <= 1.0 < ratio[0]  # the standard errors shrank to the target
    _, pts = readback.column(rrd, "sphere/poses", "Points3D:positions")
    last = np.array(pts[-1]).reshape(-1, 3)
    assert len(last) >= 9 and np.allclose(np.linalg.norm(last, axis=1), 1, atol=1e-6)
    _, guide = readback.column(rrd, "guide", "TextDocument:text")
    assert "next: hold with" in str(guide[-1])

