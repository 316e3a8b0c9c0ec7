"""imucal capture end to end (issue 25): a synthetic device streamed over standard input, TCP,
UDP and a serial pseudo-terminal stops by itself with a calibration within the truth's
tolerances, and its calib.json is exactly `imucal calibrate DIR/session.csv`'s; a SIGKILL leaves
every flushed sample readable; garbled lines are counted; a wrong baud rate is one clear line."""

import json
import os
import select
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from synth_device import CLI, ENV, free_port, synth_stream

import imucal
from imucal.capture.run import calibrate_file, capture
from imucal.capture.send import frames_of, session_lines
from imucal.capture.sources import FdSource, SerialSource, UdpSource, open_source
from imucal.capture.stop import PRESETS, Targets
from imucal.cli.main import main
from imucal.errors import ImucalError
from imucal.models import acc_theta, gyro_theta
from imucal.session import STANDARD_GRAVITY
from imucal.synth import make_session

POSES, SEED = 40, 3  # about 200 s at 100 Hz; the default target is met at about 20 poses


@pytest.fixture(scope="module")
def truth():
    return make_session(poses=POSES, seed=SEED)


def _synth(tmp: Path, stream: str, speed: str = "50", **kw) -> subprocess.Popen:
    return synth_stream(tmp, stream, "--truth", str(tmp / "t.json"), poses=POSES, seed=SEED,
                        speed=speed, stderr=subprocess.PIPE, **kw)


def _within_truth(path: Path, truth, g: float = 1.0) -> imucal.Result:
    """The session file calibrates to the truth within four standard errors (``g``: the
    accelerometer's raw unit per g, its bias scales with it)."""
    result = imucal.calibrate(imucal.load_session(path))
    seg = result.segments[0]
    per = np.r_[np.ones(6), np.full(3, g)]
    za = (acc_theta(seg.acc.model) - acc_theta(truth.acc) * per) / seg.acc.std
    zg = (gyro_theta(seg.gyro.model) - gyro_theta(truth.gyro)) / seg.gyro.std[:9]
    assert np.abs(za).max() < 4 and np.abs(zg).max() < 4, (za, zg)
    return result


def _rows(path: Path) -> int:
    return len(path.read_text().splitlines()) - 1


def test_stdin_stops_by_itself_and_equals_batch(tmp_path, truth):
    session, tr = truth
    synth = _synth(tmp_path, "-", stdout=subprocess.PIPE)
    out = tmp_path / "D"
    try:
        cap = subprocess.run(CLI + ["capture", "-", "--out", str(out), "--no-view",
                                    "--json-status"],
                             stdin=synth.stdout, capture_output=True, text=True, env=ENV,
                             timeout=120)
    finally:
        synth.stdout.close()
        synth.kill()
        synth.wait()
    assert cap.returncode == 0, cap.stderr
    # --json-status: one object a line on stdout, the summary on stderr.
    assert "stopped: targets met" in cap.stderr and "0 garbled lines" in cap.stderr
    status = [json.loads(line) for line in cap.stdout.splitlines()]
    events = [s["event"] for s in status]
    assert events[-1] == "stop" and "hold" in events and "calibration" in events
    poses = [s["orientations"] for s in status]
    assert poses == sorted(poses) and poses[-1] >= 12
    assert {s["state"] for s in status} <= {"waiting", "still", "moving"}
    assert status[-1]["calibration"]["met"] and status[-1]["calibration"]["ratio"] <= 1
    assert all(s["next_pose"].endswith(" up") or "covered" in s["next_pose"] for s in status)
    # the hold's timer against the minimum, the turn's rate against the limit (10 deg per
    # sample at 100 Hz), in deg/s once the gyroscope's unit is known
    assert {s["hold_min_s"] for s in status} == {1.5}
    assert {s["rate_limit_dps"] for s in status} == {1000.0}
    peaks = [s["turn_peak_dps"] for s in status if s["turn_peak_dps"] is not None]
    assert peaks and 20 < max(peaks) < 1000
    # Stopped before the stream's end, with most poses still to come.
    rows = _rows(out / "session.csv")
    assert 20 * 100 < rows < 0.8 * len(session.t_acc)
    # Every sample as received: the lines the device sent, in order.
    _, lines = session_lines(session)
    assert (out / "session.csv").read_text().splitlines()[1:] == lines[:rows]
    assert main(["calibrate", str(out / "session.csv"), "--out", str(tmp_path / "b.json")]) == 0
    assert (out / "calib.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    _within_truth(out / "session.csv", tr)


def test_tcp_through_the_command_line(tmp_path, truth, capsys):
    port = free_port(socket.SOCK_STREAM)
    synth = _synth(tmp_path, f"tcp://127.0.0.1:{port}", stdout=subprocess.DEVNULL)
    out = tmp_path / "D"
    try:
        rc = main(["capture", f"tcp://127.0.0.1:{port}", "--out", str(out), "--no-view",
                   "--until", "60"])
    finally:
        synth.kill()
        synth.wait()
    text = capsys.readouterr().out
    assert rc == 0, text
    # The guide as plain lines: holds, the pose to hold next, the running fits.
    assert "next hold with" in text and "calibration so far: good" in text
    assert "stopped: targets met" in text and "wrote " + str(out / "calib.json") in text
    assert _rows(out / "session.csv") < 0.8 * len(truth[0].t_acc)
    _within_truth(out / "session.csv", truth[1])


def test_udp(tmp_path, truth):
    source = UdpSource("127.0.0.1", 0)
    synth = _synth(tmp_path, f"udp://127.0.0.1:{source.port}", stdout=subprocess.DEVNULL)
    try:
        report = capture(source, tmp_path / "D", PRESETS["default"], until=60)
    finally:
        synth.kill()
        synth.wait()
    assert report.stopped == "targets met" and report.garbled == 0
    _within_truth(report.session, truth[1])


class _Device(threading.Thread):
    """Writes bytes to a pseudo-terminal's master side until done or stopped."""

    def __init__(self, fd: int, data: bytes, pause: float = 0.0):
        super().__init__(daemon=True)
        self.fd, self.data, self.stop, self.pause = fd, data, threading.Event(), pause
        os.set_blocking(fd, False)

    def run(self) -> None:
        data = memoryview(self.data)
        while len(data) and not self.stop.is_set():
            if select.select([], [self.fd], [], 0.1)[1]:
                try:
                    data = data[os.write(self.fd, data[:4096]):]
                except BlockingIOError:
                    pass
                time.sleep(self.pause)


def test_serial_pty_with_garbled_lines(tmp_path, truth):
    session, tr = truth
    header, lines = session_lines(session)
    garbled = {500: "0.1,0.2", 900: "\x00\xff junk", 1500: "5.0,1,x,3,4,5,6"}
    sent = [header] + [garbled.get(i, "") + "\n" + ln if i in garbled else ln
                       for i, ln in enumerate(lines)]
    master, slave = os.openpty()
    # 4 KB (about 55 lines) every 10 ms: about 50 times the device's real time.
    dev = _Device(master, ("\r\n".join(sent) + "\r\n").encode("latin-1"), pause=0.01)
    source = SerialSource(os.ttyname(slave), 115200)
    dev.start()
    try:
        report = capture(source, tmp_path / "D", PRESETS["default"], until=60)
    finally:
        dev.stop.set()
        dev.join()
        os.close(master)
        os.close(slave)
    assert report.stopped == "targets met"
    assert report.garbled == 3
    got = report.session.read_text().splitlines()[1:]
    assert got == lines[:len(got)] and 2000 < len(got) < 0.8 * len(lines)
    _within_truth(report.session, tr)


def test_wrong_baud_rate_is_one_clear_line(tmp_path):
    master, slave = os.openpty()
    noise = np.random.default_rng(0).integers(0, 256, 3000, dtype=np.uint8).tobytes()
    dev = _Device(master, noise.replace(b"\n", b"\x80"))
    source = SerialSource(os.ttyname(slave), 9600)
    dev.start()
    try:
        with pytest.raises(ImucalError) as e:
            capture(source, tmp_path / "D", PRESETS["default"], no_data_s=1.0)
    finally:
        dev.stop.set()
        dev.join()
        os.close(master)
        os.close(slave)
    msg = str(e.value)
    assert "\n" not in msg and "baud rate" in msg and "no valid sample in 1 s" in msg
    assert "3000 bytes" in msg or "bytes" in msg
    assert not (tmp_path / "D" / "session.csv").exists()


def test_sigkill_leaves_every_flushed_sample(tmp_path, truth):
    session, _ = truth
    header, lines = session_lines(session)
    out = tmp_path / "D"
    cap = subprocess.Popen(CLI + ["capture", "-", "--out", str(out), "--no-view",
                                  "--target", "factory"], stdin=subprocess.PIPE,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV)
    try:
        first = 6000  # 60 s at 100 Hz: 10 poses, short of any target
        cap.stdin.write(("\n".join([header] + lines[:first]) + "\n").encode())
        cap.stdin.flush()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not (
                (out / "session.csv").exists() and _rows(out / "session.csv") >= first):
            time.sleep(0.05)
        # More samples, then a pause longer than the flush interval, then SIGKILL.
        cap.stdin.write(("\n".join(lines[first:first + 1000]) + "\n").encode())
        cap.stdin.flush()
        time.sleep(1.5)
        cap.send_signal(signal.SIGKILL)
        cap.wait(timeout=30)
    finally:
        cap.kill()
    assert cap.returncode == -signal.SIGKILL
    sess = imucal.load_session(out / "session.csv")
    assert len(sess.t_acc) == first + 1000
    np.testing.assert_array_equal(sess.acc, session.acc[:first + 1000])
    assert imucal.calibrate(sess).verdict.usable


def test_motioncal_raw_lines_over_udp(tmp_path, truth):
    source = UdpSource("127.0.0.1", 0)
    synth = synth_stream(tmp_path, f"udp://127.0.0.1:{source.port}", "--format", "motioncal",
                         poses=POSES, seed=SEED, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE)
    try:
        report = capture(source, tmp_path / "D", PRESETS["default"], rate=100.0, until=60)
    finally:
        synth.kill()
        synth.wait()
    assert report.stopped == "targets met" and report.garbled == 0
    head = report.session.read_text().splitlines()[:2]
    assert head[0].startswith("t,ax (counts),") and head[1].startswith("0.0,")
    # Counts of 8192 per g and 16 per deg/s: the misalignments do not depend on the unit.
    result = imucal.calibrate(imucal.load_session(report.session))
    seg = result.segments[0]
    za = (acc_theta(seg.acc.model)[:3] - acc_theta(truth[1].acc)[:3]) / seg.acc.std[:3]
    assert np.abs(za).max() < 4 and result.session.acc_unit == "counts"
    np.testing.assert_allclose(seg.acc.model.K * 8192, truth[1].acc.K, rtol=2e-3)


def test_mavlink_highres_imu_over_udp(tmp_path, truth):
    port = free_port(socket.SOCK_DGRAM)
    source = open_source(f"mavlink:udp:127.0.0.1:{port}")
    synth = synth_stream(tmp_path, f"udp://127.0.0.1:{port}", "--format", "mavlink",
                         poses=POSES, seed=SEED, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE)
    try:
        report = capture(source, tmp_path / "D", PRESETS["default"], until=60)
    finally:
        synth.kill()
        synth.wait()
    assert report.stopped == "targets met" and report.garbled == 0
    assert report.session.read_text().splitlines()[0].startswith("t (us),ax (m/s^2),")
    result = _within_truth(report.session, truth[1], g=STANDARD_GRAVITY)
    assert result.session.acc_unit == "m/s^2"


def test_a_real_recording_replayed_calibrates_as_the_file(tmp_path, shared_data):
    """The Xsens pair (raw counts, two files) sent as lines gives the file's calibration."""
    d = shared_data / "imu_tk_xsens"
    session = imucal.load_session(d / "xsens_acc.mat", gyro_path=d / "xsens_gyro.mat")
    head, frames = frames_of(session, "lines")
    r, w = os.pipe()

    def feed() -> None:
        with os.fdopen(w, "wb") as f:
            f.write(b"".join(head + frames))

    feeder = threading.Thread(target=feed)
    feeder.start()
    # Targets no run meets: the capture reads to the end of the stream.
    report = capture(FdSource(r), tmp_path / "D", Targets(1e-9, 1e-9, 1e-9))
    feeder.join()
    assert report.stopped == "end of stream" and report.samples == len(session.t_acc)
    assert report.orientations >= 9  # about the counts' zero offset, not the origin
    live = calibrate_file(report.session)
    batch = imucal.calibrate(session)
    assert len(live.segments) == len(batch.segments)
    for a, b in zip(live.segments, batch.segments):
        for fa, fb in ((a.acc, b.acc), (a.gyro, b.gyro)):
            np.testing.assert_array_equal(fa.model.T, fb.model.T)
            np.testing.assert_array_equal(fa.model.K, fb.model.K)
            np.testing.assert_array_equal(fa.model.b, fb.model.b)
    assert live.verdict.level == batch.verdict.level


def test_a_pulled_cable_keeps_every_sample_received(tmp_path, truth):
    """The device's connection reset mid-stream: the capture ends there, nothing lost."""
    session, _ = truth
    header, lines = session_lines(session)
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    sent = 9000

    def device() -> None:
        conn, _ = server.accept()
        conn.sendall(("\n".join([header] + lines[:sent]) + "\n").encode())
        time.sleep(0.3)
        # A reset, not a close: SO_LINGER 0 sends RST, as a pulled USB-serial bridge does.
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
        conn.close()

    dev = threading.Thread(target=device)
    dev.start()
    try:
        report = capture(open_source(f"tcp://127.0.0.1:{port}"), tmp_path / "D",
                         PRESETS["factory"], until=60)
    finally:
        dev.join()
        server.close()
    assert report.stopped == "end of stream" and report.samples == sent
    assert report.session.read_text().splitlines()[1:] == lines[:sent]


def test_ctrl_c_stops_and_calibrates_what_came(tmp_path, truth):
    session, _ = truth
    header, lines = session_lines(session)
    out = tmp_path / "D"
    cap = subprocess.Popen(CLI + ["capture", "-", "--out", str(out), "--no-view",
                                  "--target", "factory"], stdin=subprocess.PIPE,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV, text=True)
    try:
        cap.stdin.write("\n".join([header] + lines[:7000]) + "\n")  # 70 s: 12 poses
        cap.stdin.flush()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not (
                (out / "session.csv").exists() and _rows(out / "session.csv") >= 7000):
            time.sleep(0.05)
        cap.send_signal(signal.SIGINT)
        stdout, stderr = cap.communicate(timeout=60)
    finally:
        cap.kill()
    # Interrupted short of the factory's targets: the calibration of what came is written,
    # and the exit code says the targets were not met.
    assert cap.returncode == 1, stderr
    assert "stopped: interrupted" in stdout and "targets not met" in stdout, (stdout, stderr)
    assert (out / "calib.json").exists() and _rows(out / "session.csv") == 7000


def test_a_header_and_no_sample_leaves_nothing(tmp_path):
    r, w = os.pipe()
    os.write(w, b"t,ax,ay,az,gx,gy,gz\n1,2,3\nfoo,bar\n")
    with pytest.raises(ImucalError) as e:
        capture(FdSource(r, "test"), tmp_path / "D", PRESETS["default"], no_data_s=0.5)
    os.close(w)
    assert "2 garbled lines" in str(e.value) and "the format and the columns" in str(e.value)
    assert not (tmp_path / "D" / "session.csv").exists()
