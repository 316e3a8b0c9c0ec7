"""The live view of a capture saved with --rrd (viewer/live.py): the signals as received, the
still state, the poses on the sphere, the fits' worst standard error over its target, the
guide; read back from the file."""

import signal
import subprocess
import urllib.request

import numpy as np
import pytest
from synth_device import CLI, ENV, free_port, synth_stream

from imucal.cli.main import main
from viewer import readback


def test_rrd_of_a_tcp_capture(tmp_path, capsys):
    port = free_port()
    synth = synth_stream(tmp_path, f"tcp://127.0.0.1:{port}", stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
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
    assert "- hold: " in str(guide[-1]) and "counts from 1.5 s" in str(guide[-1])
    assert "of the limit 1000 deg/s" in str(guide[-1])
    # The turn's rate, its peak and the limit (10 deg per sample at 100 Hz), in deg/s: the
    # peak is the largest |w - still bias| of the rows received, and never under the rate.
    _, turn = readback.scalars(rrd, "live/turn_rate")
    assert len(turn) > 10 and np.all(turn[:, 2] == 1000.0)
    assert np.all(turn[:, 1] >= turn[:, 0] - 0.05)
    w = sent[:, 4:7]
    still_bias = np.median(w[: 300], axis=0)  # the first 3 s lie still
    peak = np.degrees(np.linalg.norm(w - still_bias, axis=1).max())
    assert turn[:, 1].max() == pytest.approx(peak, rel=0.02)
    assert 20 < peak < 1000  # real turns, all under the limit



def test_web_live_view_serves_while_capturing(tmp_path):
    """--web: the web viewer answers at the printed address during the capture, the recording
    is also saved with --rrd, and the view stays until Ctrl-C; the exit code is the pass."""
    synth = synth_stream(tmp_path, "-", stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    rrd = tmp_path / "capture.rrd"
    cap = subprocess.Popen(CLI + ["capture", "-", "--out", str(tmp_path / "D"), "--web",
                                  "--rrd", str(rrd), "--json-status"],
                           stdin=synth.stdout, stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, env=ENV, text=True)
    synth.stdout.close()
    answered = None
    try:
        for line in cap.stderr:
            if line.startswith("live view: "):
                url = line.split(": ", 1)[1].strip()
                with urllib.request.urlopen(url, timeout=10) as page:
                    answered = page.status
            if line.startswith("the live view stays at"):
                cap.send_signal(signal.SIGINT)
                break
        rc = cap.wait(timeout=60)
    finally:
        if cap.poll() is None:  # a failure above: end it politely, so it ends its viewer
            cap.terminate()
            try:
                cap.wait(timeout=10)
            except subprocess.TimeoutExpired:
                cap.send_signal(signal.SIGINT)
                cap.wait(timeout=10)
        synth.kill()
        synth.wait()
    assert answered == 200 and rc == 0
    assert (tmp_path / "D" / "calib.json").exists()
    t, _ = readback.scalars(rrd, "live/accelerometer")
    rows = (tmp_path / "D" / "session.csv").read_text().splitlines()[1:]
    assert len(t) == len(rows)
