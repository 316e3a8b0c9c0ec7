"""``imucal capture``: calibrate while you record (issue 25). Parses its options, runs the core's
capture loop (imucal.capture), then calibrates the session file exactly as ``imucal calibrate``
does (the same function), so DIR/calib.json is what ``imucal calibrate DIR/session.csv`` gives.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from imucal.cli.app import app
from imucal.cli.commands import calibrate
from imucal.cli.options import (
    INPUT_OPTIONS,
    SETTING_OPTIONS,
    SessionArg,
    _one_of,
    load_kwargs,
    pick,
    positive,
    shared_options,
    usage_error,
)

_TARGETS = "quick, default or factory"


def _target(value: str) -> str:
    from imucal.capture.stop import PRESETS

    if value not in PRESETS:
        raise typer.BadParameter(f"expected {_TARGETS}, got {value!r}")
    return value


@app.command("capture")
def capture_cmd(
    source: Annotated[str, typer.Argument(
        metavar="SOURCE", show_default=False,
        help="'-' (lines on standard input), tcp://HOST:PORT (connect), udp://[HOST]:PORT "
             "(listen), serial:/dev/ttyX?baud=N, or MAVLink: mavlink:udp:HOST:PORT (listen), "
             "mavlink:/dev/ttyX?baud=N.")],
    out: Annotated[str, typer.Option(
        "--out", "-o", metavar="DIR", show_default=False,
        help="Directory to write session.csv (every sample as received) and calib.json.")],
    until: Annotated[float | None, typer.Option(
        "--until", metavar="SECONDS", callback=positive, show_default=False,
        help="Stop after this long even if the targets are not met.")] = None,
    target: Annotated[str, typer.Option(
        "--target", metavar="quick|default|factory", callback=_target,
        help="How good is enough: every parameter's standard error under the preset's "
             "target. quick: misalignment 1 mrad, scale 0.1 %, accelerometer bias 1 mg; "
             "default: 0.5 mrad, 0.05 %, 0.5 mg; factory: 0.25 mrad, 0.025 %, 0.25 mg "
             "(and the verdict 'good').")] = "default",
    columns: Annotated[str | None, typer.Option(
        "--columns", metavar="NAMES", show_default=False,
        help="The names of the fields in order, for a device that sends no header line "
             "(e.g. t,ax,ay,az,gx,gy,gz; the names the table loader understands).")] = None,
    rate: Annotated[float | None, typer.Option(
        "--rate", metavar="HZ", callback=positive, show_default=False,
        help="Sample rate, for a stream without a time column (the samples are numbered).")
    ] = None,
    spec: Annotated[Path | None, typer.Option(
        "--spec", metavar="LIMITS.toml", show_default=False,
        help="Limits the unit must be within (as for 'imucal batch'): the capture passes when "
             "the targets are met within them, and stops failed (exit 1, the limit named) as "
             "soon as one can no longer be met: a parameter more than 5 standard errors past "
             "its limit, or still poses that scatter more than static_norm_error_mg whatever "
             "is recorded.")] = None,
    no_view: Annotated[bool, typer.Option(
        "--no-view", help="No live viewer (scripts and tests); the guide is printed.")] = False,
    web: Annotated[bool, typer.Option(
        "--web", help="Show the live view in the web viewer (its address is printed; it "
                      "serves until Ctrl-C after the capture).")] = False,
    json_status: Annotated[bool, typer.Option(
        "--json-status", help="The guide as one JSON object a line on standard output (for a "
                              "factory script), instead of text.")] = False,
    rrd: Annotated[str | None, typer.Option(
        "--rrd", metavar="CAPTURE.rrd", help="Save the live view's Rerun recording (the "
                                              "signals, holds, poses and fits as they came).")
    ] = None,
) -> int:
    """Capture a device's stream and calibrate it while you record: the guide says which pose
    to hold next; the capture stops by itself when the calibration is good enough (--target),
    at --until, at the end of the stream or on Ctrl-C, then calibrates DIR/session.csv with
    the full method into DIR/calib.json.

    Exit 0 when the whole session's calibration meets the targets (the verdict good,
    within --spec's limits), 1 otherwise (batch's pass/fail). Nothing is lost: session.csv
    is written as samples arrive (at least every 0.5 s); garbled lines are counted and
    skipped.
    """
    from imucal.capture.run import capture
    from imucal.capture.sources import open_source
    from imucal.capture.stop import targets

    goal = targets(target)
    limits = None
    if spec is not None:
        limits = spec_check(spec)  # before the capture: a bad spec is one line, nothing read
    src = open_source(source)

    if no_view and web:
        raise usage_error("--web shows the live view: leave out --no-view", "'--web'")
    live, viewer = _live_view(no_view, web, rrd)

    def on_status(st: dict) -> None:
        if live is not None:
            live.status(st)
        if json_status:
            line = json.dumps(st)
        elif st["event"] in ("hold", "state", "tick", "calibration"):
            line = st["guide"]
            if st["event"] == "calibration" and st["calibration"] is not None:
                c = st["calibration"]
                line = (f"calibration so far: {c['verdict']}; worst {c['worst']} at "
                        f"{c['ratio']:.2f} x its target")
                if c["lost"]:
                    line += f"; can no longer meet the spec: {'; '.join(c['lost'])}"
        else:
            return
        print(line, flush=True)

    try:
        report = capture(src, out, goal, columns=columns, rate=rate, until=until,
                         on_status=on_status, on_batch=None if live is None else live.batch,
                         spec=limits)
    finally:
        if live is not None:
            live.close()
    out_stream = sys.stderr if json_status else sys.stdout
    print("\n".join(report.lines()), file=out_stream, flush=True)
    options = {name: default for name, _, default in INPUT_OPTIONS + SETTING_OPTIONS}
    saved = sys.stdout
    try:  # the calibration as `imucal calibrate DIR/session.csv [--spec LIMITS]` makes it
        if json_status:
            sys.stdout = sys.stderr  # the summary stays off the JSON lines
        calibrate.__wrapped__(session=report.session, out=str(Path(out) / "calib.json"),
                              rrd=None, calibrated=None, allow_poor=False, spec=spec,
                              options=options, verbose=False)
    finally:
        sys.stdout = saved
    if not report.passed:
        print(f"targets not met ({goal.text()}): fail", file=out_stream)
    if viewer is not None and viewer.url is not None:
        try:  # Ctrl-C ends the view, not the run: the exit code stays the pass
            print(f"the live view stays at {viewer.url} until Ctrl-C", file=sys.stderr,
                  flush=True)
            viewer.wait()
        except KeyboardInterrupt:
            viewer.close()
    elif viewer is not None:
        viewer.detach()  # the native window stays until the user closes it
    return 0 if report.passed else 1


def spec_check(path: Path):
    """A limits file as the capture judges it (imucal.capture.stop.SpecCheck): the batch's
    check of a summary row, as `imucal calibrate --spec` makes it."""
    from imucal.capture.stop import SpecCheck
    from imucal.fleet.spec import check, load_spec
    from imucal.fleet.summary import result_columns

    limits = load_spec(path)
    return SpecCheck(limits.limits, lambda row: check(limits, row).broken, result_columns)


def _live_view(no_view: bool, web: bool, rrd: str | None):
    """The live view and its viewer: the web viewer (--web), else the native viewer where
    there is a display; the recording saved to ``rrd`` when given. (None, None) for --no-view
    without --rrd; without a display (and without --web) one line says so."""
    import os

    display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    show = not no_view and (web or display)
    if not no_view and not show:
        print("no display (neither DISPLAY nor WAYLAND_DISPLAY is set): the guide is printed; "
              "--web serves the live view, --rrd FILE saves it", file=sys.stderr)
    if not show and rrd is None:
        return None, None
    from imucal.capture.detector import MIN_HOLD_S
    from imucal.cli.outputs import viewer_available

    with viewer_available():
        from viewer.live import LiveView, LiveViewer, blueprint
    live = LiveView.new(MIN_HOLD_S)
    if not show:
        live.rec.save(rrd, default_blueprint=blueprint())
        return live, None
    viewer = LiveViewer(live, web=web, rrd=rrd)
    if viewer.url is not None:
        print(f"live view: {viewer.url}", file=sys.stderr, flush=True)
    return live, viewer


@app.command("replay")
@shared_options(INPUT_OPTIONS)
def replay_cmd(
    session: SessionArg,
    stream: Annotated[str, typer.Option(
        "--stream", metavar="-|tcp://HOST:PORT|udp://HOST:PORT", show_default=False,
        help="Where to send it: standard output, one TCP client (listening on HOST:PORT) or "
             "UDP datagrams.")],
    speed: Annotated[float | None, typer.Option(
        "--speed", metavar="X", callback=positive, show_default=False,
        help="X times faster than real time [default: real time].")] = None,
    stream_format: Annotated[str, typer.Option(
        "--format", metavar="lines|motioncal|mavlink",
        callback=_one_of("lines", "motioncal", "mavlink"),
        help="Lines of t,ax,ay,az,gx,gy,gz, MotionCal's Raw: lines or MAVLink HIGHRES_IMU.")
    ] = "lines",
    options: dict[str, Any] = None,  # INPUT_OPTIONS
) -> None:
    """Send a recording as a device would, for 'imucal capture' (e.g. `imucal replay rec.csv
    --stream - --speed 20 | imucal capture - --out D`): the samples as read, in real time or
    --speed times faster."""
    import imucal
    from imucal.capture.send import stream_session
    from imucal.cli.outputs import check_inputs

    load_kw = load_kwargs(**pick(options, INPUT_OPTIONS))
    check_inputs([session, load_kw["gyro_path"]])
    sess = imucal.load_session(session, **load_kw)
    print(f"replaying {session}: {len(sess.t_acc)} samples, {sess.duration:.1f} s",
          file=sys.stderr, flush=True)
    stream_session(sess, stream, 1.0 if speed is None else speed, stream_format)
