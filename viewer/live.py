"""The live view of ``imucal capture`` (issue 25, item 2): the signals scrolling, the detector's
still/moving state and the hold's timer against the minimum, the turn's rate and its peak
against the method's limit (the rotation M5's integration carries per sample), the sphere of
poses held so far with the current direction of gravity and the pose to hold next, and the
worst standard error against its target shrinking as holds come in.

The capture's core calls :meth:`LiveView.batch` with each batch and :meth:`LiveView.status`
with each status; rows are sent at most every ``SEND_S`` seconds (10 Hz), a batch of columns
per entity, so the view costs a few calls a second whatever the sample rate.
"""

from __future__ import annotations

import time
import uuid

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from .paths import APPLICATION_ID

SEND_S = 0.1  # the view is updated at 10 Hz
ACC, GYRO, STILL, HOLD = "live/accelerometer", "live/gyroscope", "live/still", "live/hold"
POSES, RATIO, TURN = "live/orientations", "live/worst_over_target", "live/turn_rate"
SPHERE_POSES, SPHERE_NOW, SPHERE_NEXT = "sphere/poses", "sphere/gravity", "sphere/next"
SPHERE_AXES, GUIDE = "sphere/axes", "guide"
XYZ = [[230, 80, 80], [80, 200, 80], [80, 120, 240]]


def blueprint() -> rrb.Blueprint:
    """Signals and the detector on the left; the sphere, the poses, the fits and the guide on
    the right. The time panel follows the newest data (live), so a saved capture opens at its
    end."""
    def series(name: str, *paths: str, y: tuple[float, float] | None = None
               ) -> rrb.TimeSeriesView:
        axis = {} if y is None else {"axis_y": rrb.ScalarAxis(range=y)}
        return rrb.TimeSeriesView(name=name, origin="/", contents=list(paths), **axis)

    sphere = rrb.Spatial3DView(
        name="Poses held: the axis that was up; gravity now; the next pose", origin="/sphere",
        line_grid=rrb.LineGrid3D(visible=False),
        eye_controls=rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=[1.5, -1.9, 1.2],
                                       look_target=[0, 0, 0], eye_up=[0, 0, 1]))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(series("Accelerometer (raw)", ACC), series("Gyroscope (raw)", GYRO),
                         series("Still (1) or moving (0)", STILL, y=(-0.1, 1.1)),
                         series("Hold timer and the shortest hold that counts (s)", HOLD,
                                y=(0.0, 6.0)),
                         series("Turn rate, the turn's peak and the limit (deg/s)", TURN)),
            rrb.Vertical(sphere,
                         rrb.Horizontal(series("Poses held", POSES, y=(0.0, 30.0)),
                                        series("Worst standard error / its target", RATIO,
                                               y=(0.0, 4.0))),
                         rrb.TextDocumentView(name="Guide", origin="/guide"),
                         row_shares=[3, 2, 2]),
            column_shares=[3, 2]),
        rrb.TimePanel(timeline="time", state="collapsed", play_state="following"),
        collapse_panels=True)


class LiveView:
    """A capture's recording; ``rec`` is connected (a viewer) or saving (a file)."""

    def __init__(self, rec: rr.RecordingStream, min_hold_s: float) -> None:
        self.rec, self.min_hold_s = rec, min_hold_s
        self.parts: list[tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]] = []
        self.last_send = 0.0
        self.t = 0.0
        self.state = None
        rec.log(ACC, rr.SeriesLines(names=["x", "y", "z"], colors=XYZ), static=True)
        rec.log(GYRO, rr.SeriesLines(names=["x", "y", "z"], colors=XYZ), static=True)
        rec.log(STILL, rr.SeriesLines(names="still"), static=True)
        rec.log(HOLD, rr.SeriesLines(names=["hold", "counts from"]), static=True)
        rec.log(TURN, rr.SeriesLines(names=["rate", "turn's peak", "limit"],
                                     colors=[[80, 120, 240], [240, 160, 40], [220, 60, 60]]),
                static=True)
        rec.log(POSES, rr.SeriesLines(names="poses"), static=True)
        rec.log(RATIO, rr.SeriesLines(names="worst / target"), static=True)
        rec.log(SPHERE_AXES, rr.Arrows3D(vectors=np.eye(3) * 1.3, colors=XYZ,
                                         labels=["x", "y", "z"]), static=True)

    @classmethod
    def new(cls, min_hold_s: float) -> LiveView:
        return cls(rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4()), min_hold_s)

    def batch(self, batch, st) -> None:
        """Take a batch of samples and the detector's state after it (imucal.capture.run)."""
        still = np.full(len(batch.t), 1.0 if st.state == "still" else 0.0)
        self.parts.append((batch.t, batch.acc, batch.gyro, still))
        self.t, self.state = float(batch.t[-1]), st
        now = time.monotonic()
        if now - self.last_send >= SEND_S:
            self.send()
            self.last_send = now

    def send(self) -> None:
        if not self.parts:
            return
        t = np.concatenate([p[0] for p in self.parts])
        index = [rr.TimeColumn("time", duration=t)]
        self.rec.send_columns(ACC, indexes=index, columns=rr.Scalars.columns(
            scalars=np.vstack([p[1] for p in self.parts])))
        if self.parts[0][2] is not None:
            self.rec.send_columns(GYRO, indexes=index, columns=rr.Scalars.columns(
                scalars=np.vstack([p[2] for p in self.parts])))
        self.rec.send_columns(STILL, indexes=index, columns=rr.Scalars.columns(
            scalars=np.concatenate([p[3] for p in self.parts])))
        self.parts = []
        st = self.state
        self.rec.set_time("time", duration=self.t)
        self.rec.log(HOLD, rr.Scalars([st.hold_s, self.min_hold_s]))
        self.rec.log(POSES, rr.Scalars(float(st.orientations)))
        turn = st.turn or {}
        if turn.get("rate_dps") is not None and turn.get("rate_limit_dps") is not None:
            self.rec.log(TURN, rr.Scalars([turn["rate_dps"], turn["turn_peak_dps"],
                                           turn["rate_limit_dps"]]))
        if len(st.up):
            self.rec.log(SPHERE_POSES, rr.Points3D(st.up, radii=0.04, colors=[90, 90, 90]))
        if st.gravity is not None:
            self.rec.log(SPHERE_NOW, rr.Arrows3D(vectors=[st.gravity], colors=[250, 200, 40],
                                                 labels=["now"]))
        if st.next_up is not None:
            self.rec.log(SPHERE_NEXT, rr.Arrows3D(vectors=[st.next_up * 1.15],
                                                  colors=[60, 200, 220], labels=["next"]))

    def status(self, st: dict) -> None:
        """A status of the capture (imucal.capture.run.status): the guide's text, the fit."""
        self.rec.set_time("time", duration=self.t)
        cal = st.get("calibration")
        if st["event"] == "calibration" and cal is not None:
            self.rec.log(RATIO, rr.Scalars(float(cal["ratio"])))
        lines = [f"**{st['guide']}**", "",
                 f"- poses {st['orientations']} ({st['orientations_needed']} needed), "
                 f"sphere covered {st['coverage'] * 100:.0f} %",
                 f"- next: hold with {st['next_pose']}",
                 f"- hold: {st['hold_s']:.1f} s (counts from {st['hold_min_s']:g} s, "
                 f"{st['hold_advised_s']:g} s advised)",
                 "- turn: " + (f"{st['rate_dps']:.0f} deg/s now, peak {st['turn_peak_dps']:.0f}"
                               f" of the limit {st['rate_limit_dps']:.0f} deg/s"
                               if st.get("rate_dps") is not None and st.get("rate_limit_dps")
                               else "rate not known yet (the gyroscope's unit)"),
                 f"- samples {st['samples']}, garbled lines {st['garbled']}"]
        if cal is not None:
            lines.append(f"- calibration so far: {cal['verdict']}; worst {cal['worst']} at "
                         f"{cal['ratio']:.2f} x its target" + (" (met)" if cal["met"] else ""))
        self.rec.log(GUIDE, rr.TextDocument("\n".join(lines),
                                            media_type=rr.MediaType.MARKDOWN))

    def close(self) -> None:
        self.send()
        self.rec.flush()


class LiveViewer:
    """The viewer a live capture logs to: the native viewer, or the web viewer (``web``), run
    by the ``rerun`` launcher in its own process group with its gRPC server on a free port of
    127.0.0.1 (rerun's own defaults are every interface and port 9876, where another viewer may
    already listen). ``rrd`` also saves the recording."""

    def __init__(self, live: LiveView, *, web: bool, rrd: str | None = None) -> None:
        import subprocess
        import tempfile

        from imucal.errors import ImucalError

        from .app import (
            LOOPBACK,
            free_port,
            rerun_executable,
            viewer_env,
            viewer_error,
            wait_serving,
            web_url,
        )

        rerun = rerun_executable()
        if rerun is None:
            raise ImucalError("the viewer is not available: no 'rerun' launcher (pip install "
                              "'rerun-sdk==0.41.0'); --no-view captures without it",
                              source="viewer")
        grpc = free_port()
        cmd = [rerun, "--bind", LOOPBACK, "--port", str(grpc)]
        self.url = None
        if web:
            web_port = free_port()
            cmd += ["--web-viewer", "--web-viewer-port", str(web_port)]
            self.url = web_url(web_port, grpc)
        self.log = tempfile.NamedTemporaryFile(prefix="imucal-live-", suffix=".log",  # noqa: SIM115
                                               delete=False)
        self.proc = subprocess.Popen(cmd, start_new_session=True, env=viewer_env(False),
                                     stdin=subprocess.DEVNULL, stdout=self.log,
                                     stderr=subprocess.STDOUT)
        if not wait_serving(self.proc, LOOPBACK, grpc, timeout=30.0):
            self.log.flush()
            text = open(self.log.name, errors="replace").read()
            self.close()
            raise ImucalError(viewer_error(text, self.proc.returncode or 0), source="viewer")
        sinks = [rr.GrpcSink(f"rerun+http://{LOOPBACK}:{grpc}/proxy")]
        if rrd is not None:
            sinks.append(rr.FileSink(rrd))
        live.rec.set_sinks(*sinks, default_blueprint=blueprint())

    def wait(self) -> None:
        """Until the viewer exits or Ctrl-C (the web viewer serves until then)."""
        try:
            self.proc.wait()
        except KeyboardInterrupt:
            pass
        finally:
            self.close()

    def close(self) -> None:
        """End the viewer (its process group), then :meth:`detach`."""
        import contextlib

        from .app import _end_group

        with contextlib.suppress(OSError):
            if self.proc.poll() is None:
                _end_group(self.proc)
        self.detach()

    def detach(self) -> None:
        """Leave the viewer running (a native window the user closes); drop its log file (the
        viewer keeps writing to it until it exits, then it is gone)."""
        import contextlib
        import os

        self.log.close()
        with contextlib.suppress(OSError):
            os.unlink(self.log.name)
