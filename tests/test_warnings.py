"""Warnings as data: a stable code, the segment they concern, a message; written to calib.json
as objects and printed by the CLI with their segment in front."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

import imucal
from imucal.cli.summary import print_summary
from imucal.session import Session
from imucal.synth import make_session
from imucal.warning import RunWarning


def _printed_warnings(result, capsys) -> list[str]:
    print_summary(result, [])
    lines = capsys.readouterr().out.splitlines()
    return lines[lines.index("warnings:") + 1:]


def test_few_orientations_is_warned_with_its_code(tmp_path, capsys):
    """Seven poses held three times over: 21 still blocks, but only 7 directions."""
    s, _ = make_session(poses=7, seed=1)
    n = len(s.t_acc)
    acc = np.vstack([s.acc] * 3)
    t = np.arange(3 * n) * (s.t_acc[1] - s.t_acc[0])
    r = imucal.calibrate(Session(acc=acc, t_acc=t, acc_unit="g", source="tiled"))
    assert r.segments[0].orientations == 7 and len(r.detection.blocks) == 21
    codes = [w.code for w in r.warnings]
    assert "few_orientations" in codes and "acc_undetermined" in codes
    few = r.warnings[codes.index("few_orientations")]
    assert few.segment is None and few.text == few.message  # one segment: the session
    assert few.message.startswith("only 7 distinct still orientations")
    imucal.save_calibration(r, tmp_path / "calib.json")
    written = json.loads((tmp_path / "calib.json").read_text())["warnings"]
    assert written == [{"code": w.code, "segment": None, "message": w.message}
                       for w in r.warnings]
    assert f"  - {few.message}" in _printed_warnings(r, capsys)


def test_a_segments_warnings_name_it(tmp_path, capsys):
    """Two segments, a gyroscope clipped throughout: the session is told once, each segment
    of its own rotations left out, its number (from 1, as the summary prints it and as
    ``imucal export --segment`` takes it) in the field and in front of the text."""
    s, _ = make_session(poses=40, seed=5, change_at=0.5)
    peak = np.abs(s.gyro).max(axis=0).min()
    r = imucal.calibrate(dataclasses.replace(s, gyro=np.clip(s.gyro, -0.8 * peak, 0.8 * peak)))
    assert len(r.segments) == 2
    codes = [(w.code, w.segment) for w in r.warnings]
    assert codes[:3] == [("gyro_saturated", None), ("gyro_rotations_saturated", 1),
                         ("gyro_rotations_saturated", 2)]
    # Anything after them is another finding (e.g. the held-out turns' check), not saturation.
    assert all("saturated" not in code for code, _ in codes[3:])
    for w, seg in zip(r.warnings[1:], r.segments):
        n_out = int(seg.gyro.excluded.sum())
        assert w.message.startswith(f"{n_out} of {len(seg.gyro.excluded)} rotations")
        assert w.text == f"segment {w.segment}: {w.message}"
    printed = _printed_warnings(r, capsys)
    assert printed[:3] == [f"  - {w.text}" for w in r.warnings[:3]]
    assert printed[1].startswith("  - segment 1: ") and printed[2].startswith("  - segment 2: ")
    imucal.save_calibration(r, tmp_path / "calib.json")
    written = json.loads((tmp_path / "calib.json").read_text())["warnings"]
    assert written[2] == {"code": "gyro_rotations_saturated", "segment": 2,
                          "message": r.warnings[2].message}


def test_run_warning_text():
    w = RunWarning("few_orientations", "only 5 distinct still orientations")
    assert w.text == "only 5 distinct still orientations"
    assert w.in_segment(2).text == "segment 2: only 5 distinct still orientations"
    assert w.in_segment(2).to_dict() == {"code": "few_orientations", "segment": 2,
                                         "message": "only 5 distinct still orientations"}
