"""A calibration of several triads applied (method.md §11): read back from calib.json's dict,
a triad on another clock and rate is put on the reference's clock and frame."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from imucal.io.calibration_file import calibration_from_dict, result_to_dict
from imucal.io.triads_calibration import triads_from_dict
from imucal.pipeline import calibrate, calibrate_triads
from imucal.synth import SecondTriad, make_session


def test_a_triad_on_its_own_clock_applied_on_the_reference_s():
    offset = 0.5  # its clock half a second ahead: the run moved its times, apply must too
    session, truth = make_session(poses=16, seed=3, acc_rate=200.0,
                                  second_acc=SecondTriad(rate=400.0, gyro=True))
    session = dataclasses.replace(session, others=tuple(
        dataclasses.replace(s, t=s.t + offset) for s in session.others))
    result = calibrate_triads(calibrate(session))
    data = json.loads(json.dumps(result_to_dict(result)))
    (entry,) = data["triads"]["triads"]
    assert abs(entry["times_moved_by_s"] + offset) < 0.01
    triads = triads_from_dict(data, calibration_from_dict(data), "calib.json")
    out = triads.apply(session)
    assert list(out.columns) == ["a2x", "a2y", "a2z", "g2x", "g2y", "g2z"]
    a2 = np.column_stack([out.columns[f"a2{x}"] for x in "xyz"])
    g2 = np.column_stack([out.columns[f"g2{x}"] for x in "xyz"])
    t = session.t_acc
    diffs = []
    for lo, hi in truth.pose_times:  # each still pose: the two triads' means agree
        m = (t > lo + 0.3) & (t < hi - 0.3)
        diffs.append(np.linalg.norm(a2[m].mean(axis=0) - out.acc[m].mean(axis=0)) * 1e3)
    assert np.sqrt(np.mean(np.square(diffs))) < 2.0  # mg
    # In the turns the two gyroscopes read one rate, on one clock (0.5 s apart they would not).
    moving = np.linalg.norm(out.gyro, axis=1) > 0.5
    ok = moving & np.all(np.isfinite(g2), axis=1)
    assert ok.sum() > 1000
    assert np.sqrt(np.mean(np.sum((g2 - out.gyro)[ok] ** 2, axis=1))) < 0.03
    # Before the time shift: the same rows disagree by the turns themselves.
    unmoved = dataclasses.replace(triads, triads=(triads.triads[0], dataclasses.replace(
        triads.triads[1], time_shift=0.0)))
    late = unmoved.apply(session).columns
    g_late = np.column_stack([late[f"g2{x}"] for x in "xyz"])
    ok &= np.all(np.isfinite(g_late), axis=1)
    assert np.sqrt(np.mean(np.sum((g_late - out.gyro)[ok] ** 2, axis=1))) > 0.3
    # A damaged file is one line naming the field, never a scrambled signal.
    import pytest

    from imucal.errors import ImucalError

    for path, value, says in ((("rotation_to_reference",), [[1, 0, 0], [0, 1, 0], [0, 0, 2]],
                               "rotation_to_reference must be a rotation"),
                              (("segments", 0, "accelerometer", "K"), [1, 0, 1],
                               "a scale factor in K is zero"),
                              (("times_moved_by_s",), "soon", "times_moved")):
        bad = json.loads(json.dumps(data))
        node = bad["triads"]["triads"][0]
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
        with pytest.raises(ImucalError) as e:
            triads_from_dict(bad, calibration_from_dict(bad), "calib.json")
        assert says in e.value.problem and e.value.field.startswith("triads.triads[0]")
