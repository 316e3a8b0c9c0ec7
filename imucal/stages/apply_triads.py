"""A calibration of several triads applied (method.md §11, §12, M18): each triad through its
own models, with its bias at each sample's temperature where a temperature model was fitted
(M16, held constant outside the span seen), turned into one frame; the low-range and
high-range accelerometers combined; and the triad chosen as the reference put first
(``--reference``).

A triad is named as its stream is (``acc a2``); the calibrated pair of a session is the
stream a log's loader chose (``Session.chosen``), or a table's ``a`` (columns ax, ay, az)."""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

import numpy as np

from imucal.errors import ImucalError
from imucal.session import Session
from imucal.stages.apply import CalibratedSignals, Calibration
from imucal.stages.combine import BAND, ClipLevels, Step, combine, step_text
from imucal.stages.temperature import BiasPolynomial
from imucal.streams import Stream

# The name of a table's calibrated pair, as the roles name their columns (ax…, gx…).
TABLE_ACC, TABLE_GYRO = "acc a", "gyro g"


def main_names(session: Session) -> tuple[str, str | None]:
    """The session's calibrated accelerometer's and gyroscope's stream names: a log's chosen
    streams (``acc sensor_accel:0``), a table's ``acc a`` and ``gyro g``."""
    if session.chosen:
        acc = " ".join(session.chosen[0].split(" ")[:2])
        gyro = " ".join(session.chosen[1].split(" ")[:2]) if len(session.chosen) > 1 else None
        return acc, gyro if session.has_gyro else None
    return TABLE_ACC, TABLE_GYRO if session.has_gyro else None


def matches(stream_name: str, imu: str | None, wanted: str) -> bool:
    """Does ``wanted`` (a user's name) name this triad: its stream name, its instance, its
    IMU?"""
    w = wanted.strip().lower()
    instance = stream_name.split(" ", 1)[1] if " " in stream_name else stream_name
    return w in {stream_name.lower(), instance.lower(), (imu or "").lower()}


def triad_names(session: Session) -> list[str]:
    """Every accelerometer triad of the session by its instance: the calibrated one first."""
    main = main_names(session)[0].split(" ", 1)[1]
    return [main] + [s.instance for s in session.others if s.kind == "acc"]


def reference_session(session: Session, wanted: str | None) -> Session:
    """The session with the accelerometer triad ``wanted`` (and its IMU's gyroscope) as the
    calibrated pair, the reference of every other (``--reference``, method.md §11): the
    former pair goes among the other streams under its own name (a table's ``a`` and ``g``),
    as one IMU. ``None``, or the pair's own name: the session as it is. An unknown name is
    one line naming the triads there are."""
    if wanted is None:
        return session
    acc_name, gyro_name = main_names(session)
    if matches(acc_name, None, wanted):
        return session
    accs = [s for s in session.others if s.kind == "acc"]
    found = [s for s in accs if matches(s.name, s.imu, wanted)]
    if not found:
        raise ImucalError(f"no accelerometer triad {wanted!r}; the session has: "
                          f"{', '.join(triad_names(session))}", source=session.source,
                          field="--reference")
    new = found[0]
    partner = gyro_partner(session.others, new)
    imu = f"imu {acc_name.split(' ', 1)[1]}"  # the former pair stays one IMU
    old = [Stream("acc", acc_name.split(" ", 1)[1], session.t_acc, session.acc,
                  session.acc_unit, "the former calibrated accelerometer", imu=imu)]
    if session.has_gyro and gyro_name is not None:
        old.append(Stream("gyro", gyro_name.split(" ", 1)[1], session.t_gyro, session.gyro,
                          session.gyro_unit, "the former calibrated gyroscope", imu=imu))
    rest = tuple(s for s in session.others if s is not new and s is not partner)
    g_values = g_unit = None
    if partner is not None:
        g_values, g_unit = partner.values, partner.unit or session.gyro_unit or "rad/s"
        if g_unit == "deg/s":
            g_values, g_unit = np.radians(g_values), "rad/s"
    return dataclasses.replace(
        session, acc=new.values, t_acc=new.t, acc_unit=new.unit or session.acc_unit,
        gyro=g_values, t_gyro=None if partner is None else partner.t,
        gyro_unit=g_unit if partner is not None else session.gyro_unit,
        chosen=tuple(f"{s.name} ({s.origin})" for s in (new, partner) if s is not None),
        others=rest + tuple(old))


def gyro_partner(others: tuple[Stream, ...], acc: Stream) -> Stream | None:
    """The gyroscope of the accelerometer's IMU (a log's), or a table's g2x… beside a2x…."""
    gyros = [s for s in others if s.kind == "gyro"]
    if acc.imu is not None:
        same = [g for g in gyros if g.imu == acc.imu]
        if same:
            return same[0]
    if re.fullmatch(r"a\d+", acc.instance):
        same = [g for g in gyros if g.instance == "g" + acc.instance[1:]]
        if same:
            return same[0]
    return None


@dataclass(frozen=True)
class TriadCal:
    """One triad's calibration as applying it needs: its own models (M2, M4, in its own raw
    units), its rotation to the reference's frame (M12; the identity for the reference, and
    its gyroscope's too, §11), and its bias in temperature where fitted (M16)."""

    name: str  # the accelerometer stream's name
    gyro: str | None  # its gyroscope stream's name
    calibration: Calibration
    R: np.ndarray
    acc_temp: BiasPolynomial | None = None
    gyro_temp: BiasPolynomial | None = None
    # How far its clock read ahead of the reference's where its times were moved (§11's two
    # clocks), s: subtracted from its stream's times; 0 where they were not moved.
    time_shift: float = 0.0


@dataclass(frozen=True)
class CombinedSpec:
    """The low-range/high-range pair as a calibration file holds it (M18)."""

    low: str  # triad names, as TriadCal.name
    high: str
    levels: ClipLevels
    band: tuple[float, float] = BAND
    high_noise_mg: float | None = None


@dataclass(frozen=True)
class Combination:
    """A run's low-range/high-range pair (M18): ``spec`` None where the two triads are not
    one (``said`` tells why), and the step at the switch measured on the run's session."""

    spec: CombinedSpec | None
    step: Step | None
    said: tuple[str, ...] = ()


@dataclass(frozen=True)
class TriadSignals:
    """Every triad calibrated, on the calibrated accelerometer's clock (``t``): ``columns``
    maps a column's name (``a2x``, ``g2y``, ``acx``, ``temp``) to its values, the pair's own
    (``ax…``, ``gx…``) in ``acc``/``gyro`` as for one triad; ``notes`` what was done."""

    acc: np.ndarray
    gyro: np.ndarray | None
    columns: dict[str, np.ndarray]
    notes: tuple[str, ...]
    step: Step | None = None
    frame: np.ndarray = dataclasses.field(default_factory=lambda: np.eye(3))  # applied last
    acc_unit: str = "g"  # the pair's calibrated unit


def on_clock(t_from: np.ndarray, x: np.ndarray, t_to: np.ndarray) -> np.ndarray:
    """(N, k) ``x`` interpolated linearly onto ``t_to``, NaN outside ``t_from``'s span; the
    values themselves where the clocks are one."""
    if len(t_from) == len(t_to) and np.array_equal(t_from, t_to):
        return np.asarray(x, float)
    out = np.empty((len(t_to), x.shape[1]))
    for j in range(x.shape[1]):
        out[:, j] = np.interp(t_to, t_from, x[:, j], left=np.nan, right=np.nan)
    return out


def temp_stream(session: Session, acc: str, imu: str | None = None) -> Stream | None:
    """The temperature of a triad: the stream of its instance or IMU, else the device's one
    (a table's ``temp``); None without one."""
    temps = [s for s in session.others if s.kind == "temp" and s.samples >= 2]
    instance = acc.split(" ", 1)[1] if " " in acc else acc
    own = [s for s in temps if s.instance == instance or (imu is not None and s.imu == imu)]
    if own:
        return own[0]
    device = [s for s in temps if s.imu is None]
    return device[0] if device else (temps[0] if len(temps) == 1 else None)


def apply_one(tc: TriadCal, sub: Session, temp: Stream | None, notes: list[str],
              base: CalibratedSignals | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """One triad's calibrated accelerometer and gyroscope on their own clocks, in the
    reference's frame: its models (M2, M4), the bias at each sample's temperature (M16, held
    at its end values outside the span) where a temperature model was fitted and the session
    holds a temperature, then ``R``. ``base``: ``tc.calibration.apply(sub)`` where the caller
    has it already."""
    cal = tc.calibration
    sig = cal.apply(sub) if base is None else base
    acc, gyro = sig.acc, sig.gyro
    temps = [f for f in (tc.acc_temp, tc.gyro_temp) if f is not None]
    if temps and len(cal.segments) == 1:
        if temp is None:
            notes.append(f"{tc.name}: its bias in temperature was fitted, this session holds no "
                         "temperature: its constant calibration applied")
        else:
            if tc.acc_temp is not None and tc.acc_temp.model is not None:
                acc = tc.acc_temp.calibrated(sub.acc, np.interp(sub.t_acc, temp.t,
                                                                temp.values[:, 0]))
            if gyro is not None and tc.gyro_temp is not None:
                heat = np.interp(sub.t_gyro, temp.t, temp.values[:, 0])
                model = cal.segments[0].gyro
                gyro = (sub.gyro - tc.gyro_temp.bias_at(heat)) @ model.matrix.T
            lo, hi = min(f.span[0] for f in temps), max(f.span[1] for f in temps)
            t_lo, t_hi = float(np.min(temp.values)), float(np.max(temp.values))
            outside = "" if lo <= t_lo and t_hi <= hi else (
                f"; this session's {t_lo:.1f} to {t_hi:.1f} deg C leaves the span, where the "
                "model is held at its end values (never extrapolated)")
            notes.append(f"{tc.name}: bias at each sample's temperature ({temp.instance}), the "
                         f"model fitted over {lo:.1f} to {hi:.1f} deg C{outside}")
    if not np.array_equal(tc.R, np.eye(3)):
        acc = acc @ tc.R.T
        gyro = None if gyro is None else gyro @ tc.R.T
    return acc, gyro


def column_prefix(name: str, k: int) -> str:
    """A triad's columns as a table's roles name them: ``a2`` for ``acc a2``; a log's k-th
    other triad (from 2) ``a{k}``."""
    instance = name.split(" ", 1)[1] if " " in name else name
    return instance if re.fullmatch(r"a\d*", instance) else f"a{k}"


@dataclass(frozen=True)
class TriadsCalibration:
    """Every triad a calibration file holds (method.md §11): the reference first."""

    triads: tuple[TriadCal, ...]
    combined: CombinedSpec | None = None

    def apply(self, session: Session, reference: str | None = None,
              base: CalibratedSignals | None = None) -> TriadSignals:
        """Each triad of ``session`` calibrated, on the calibrated accelerometer's clock, in
        the frame of the reference (``reference``: another triad of the file, by name); the
        combined accelerometer (M18), in the pair's unit; the temperature as ``temp``.
        ``base``: the pair's own calibrated signals, where the caller has them already."""
        acc_name, gyro_name = main_names(session)
        first = self.triads[0]
        alias = {}
        if first.name not in [s.name for s in session.others if s.kind == "acc"]:
            # The file's reference is this session's calibrated pair (a table's, or a log's
            # chosen by --acc as at calibration).
            alias[first.name] = acc_name
        by_name = {alias.get(tc.name, tc.name): dataclasses.replace(
            tc, name=alias.get(tc.name, tc.name)) for tc in self.triads}
        frame = np.eye(3)
        if reference is not None:
            ref = [tc for tc in by_name.values() if matches(tc.name, None, reference)]
            if not ref:
                raise ImucalError(f"no accelerometer triad {reference!r} in the calibration; it "
                                  f"holds: {', '.join(n.split(' ', 1)[-1] for n in by_name)}",
                                  source=session.source, field="--reference")
            frame = ref[0].R.T  # the reference's frame into the chosen triad's
        notes: list[str] = []
        if reference is not None:
            notes.append(f"every triad in the frame of {ref[0].name}")
        elif not alias:
            notes.append(f"every triad in the frame of {first.name}, the calibration's "
                         "reference")
        t = session.t_acc
        main = by_name.get(acc_name)
        if main is None:
            raise ImucalError(f"the calibration holds no model for this session's accelerometer "
                              f"({acc_name})", source=session.source, field="accelerometer")
        own: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, str]] = {}
        # base is the file's reference's models on the pair: this pair's only where it is that
        acc, gyro = apply_one(main, session, temp_stream(session, acc_name), notes,
                              base if alias else None)
        own[main.name] = (t, session.acc, acc, session.acc_unit)
        columns: dict[str, np.ndarray] = {}
        k = 2
        for stream in [s for s in session.others if s.kind == "acc"]:
            tc = by_name.get(stream.name)
            if tc is None:
                notes.append(f"{stream.name}: not in the calibration: not written")
                continue
            g = next((s for s in session.others if s.name == tc.gyro), None)
            if tc.gyro is None:  # the file's reference: its IMU's gyroscope, as at calibration
                g = gyro_partner(session.others, stream)
            sub = triad_session(session, stream, g, tc.time_shift)
            a, w = apply_one(tc, sub, temp_stream(session, stream.name, stream.imu), notes)
            own[tc.name] = (sub.t_acc, sub.acc, a, sub.acc_unit)
            prefix = column_prefix(tc.name, k)
            k += 1
            a_here = on_clock(sub.t_acc, a @ frame.T, t)
            for j, axis in enumerate("xyz"):
                columns[f"{prefix}{axis}"] = a_here[:, j]
            if w is not None:
                w_here = on_clock(sub.t_gyro, w @ frame.T, t)
                for j, axis in enumerate("xyz"):
                    columns[f"g{prefix[1:]}{axis}"] = w_here[:, j]
        step = None
        if self.combined is not None:
            step = self._combine(own, by_name, alias, t, frame, columns, notes)
        temp = temp_stream(session, acc_name)
        if temp is not None:
            columns["temp"] = np.interp(t, temp.t, temp.values[:, 0])
        acc = acc @ frame.T
        gyro = None if gyro is None else gyro @ frame.T
        return TriadSignals(acc=acc, gyro=gyro, columns=columns, notes=tuple(notes), step=step,
                            frame=frame, acc_unit=main.calibration.acc_unit)

    def reference_is_pair(self, session: Session) -> bool:
        """Is the file's reference this session's calibrated pair (not one of its other
        streams, as after ``calibrate --reference``)?"""
        return self.triads[0].name not in [s.name for s in session.others if s.kind == "acc"]

    def _combine(self, own: dict, by_name: dict, alias: dict[str, str], t: np.ndarray,
                 frame: np.ndarray, columns: dict[str, np.ndarray],
                 notes: list[str]) -> Step | None:
        """M18 on this session: the low-range triad's samples and nearness to its limit, the
        high-range one's on its clock, the blend, then onto the pair's clock as acx…"""
        spec = self.combined
        names = [alias.get(n, n) for n in (spec.low, spec.high)]
        missing = [n for n in names if n not in own]
        if missing:
            notes.append(f"combined accelerometer not written: {missing[0]} is not in this "
                         "session")
            return None
        t_low, raw_low, a_low, unit_low = own[names[0]]
        t_high, _, a_high, unit_high = own[names[1]]
        g_low = by_name[names[0]].calibration.g
        g_high = by_name[names[1]].calibration.g
        high = on_clock(t_high, a_high * (g_low / g_high), t_low)
        out, step = combine(a_low, high, spec.levels.nearness(raw_low), g_low, spec.band)
        g_pair = by_name[next(iter(own))].calibration.g  # the pair's unit, as ax… (first)
        out = on_clock(t_low, out @ frame.T * (g_pair / g_low), t)
        for j, axis in enumerate("xyz"):
            columns[f"ac{axis}"] = out[:, j]
        notes.append(step_text(step, names[0], names[1], spec.high_noise_mg))
        return step


def triad_session(session: Session, acc: Stream, gyro: Stream | None,
                  shift: float = 0.0) -> Session:
    """A Session of one triad's streams (units as the streams state them; one unstated is the
    calibrated pair's), its times less ``shift``."""
    g_values, g_unit = None, None
    if gyro is not None:
        g_values, g_unit = gyro.values, gyro.unit or session.gyro_unit or "rad/s"
        if g_unit == "deg/s":
            g_values, g_unit = np.radians(g_values), "rad/s"
    return Session(acc=acc.values, t_acc=acc.t - shift if shift else acc.t, gyro=g_values,
                   t_gyro=None if gyro is None else (gyro.t - shift if shift else gyro.t),
                   acc_unit=acc.unit or session.acc_unit,
                   gyro_unit=g_unit if gyro is not None else "rad/s",
                   source=f"{session.source} [{acc.name}]")
