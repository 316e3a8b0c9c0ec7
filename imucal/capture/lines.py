"""Bytes to rows of numbers: lines with a header line (the names the table loader understands,
:mod:`imucal.io.column_names`) or ``--columns``.

A line that does not hold a number for every column, holds a non-finite one, or whose time does
not move forward is garbled: counted and skipped, never fatal (a serial line at the wrong baud
rate is all garbled lines). The valid lines are kept as text, commas between the fields, so the
session file holds every sample exactly as received.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from imucal.errors import ImucalError
from imucal.io.column_names import AXES, classify_name
from imucal.io.units import TIME_UNITS

# MotionCal's lines (the PJRC/Adafruit calibration sketches): "Raw:" integer counts of the
# accelerometer (8192 per g), gyroscope (16 per deg/s) and magnetometer (0.1 uT), "Uni:" the
# same in m/s^2, rad/s and uT; nine numbers, no time (--rate numbers the samples).
MOTIONCAL = {"Raw:": ["ax (counts)", "ay (counts)", "az (counts)", "gx (counts)",
                      "gy (counts)", "gz (counts)", "mx (counts)", "my (counts)", "mz (counts)"],
             "Uni:": ["ax (m/s^2)", "ay (m/s^2)", "az (m/s^2)", "gx (rad/s)", "gy (rad/s)",
                      "gz (rad/s)", "mx (uT)", "my (uT)", "mz (uT)"]}
PREVIEW_BYTES = 160  # what the "no valid data" message quotes of what came
MAX_LINE = 4096  # a "line" longer than this without a newline is noise (a wrong baud rate)


@dataclass
class Batch:
    """The valid rows of what came since the last batch."""

    values: np.ndarray  # (N, F) every column, as received
    text: list[str]  # the N lines, fields separated by commas (the session file's rows)
    t: np.ndarray  # (N,) time, seconds
    acc: np.ndarray  # (N, 3)
    gyro: np.ndarray | None  # (N, 3)


@dataclass
class Layout:
    """What the header (or --columns) says: the names, where each role is, the time's unit."""

    names: list[str]
    delimiter: str | None  # None: runs of whitespace
    t: int | None
    acc: list[int]
    gyro: list[int] | None
    time_scale: float | None  # seconds per time unit; None: from the steps (as the loader does)
    notes: list[str] = field(default_factory=list)


def layout_of(names: list[str], delimiter: str | None, source: str) -> Layout:
    """The roles of ``names`` by the table loader's own rule (the first of two names with one
    role wins, as it does when the rank is equal)."""
    found: dict[str, tuple[int, int, str | None]] = {}
    for i, name in enumerate(names):
        meaning = classify_name(name, None)
        if meaning.role is None:
            continue
        old = found.get(meaning.role)
        if old is None or meaning.rank < old[1]:
            found[meaning.role] = (i, meaning.rank, meaning.unit)
    missing = [r for r in AXES["acc"] if r not in found]
    if missing:
        raise ImucalError(f"no accelerometer column for {', '.join(missing)} among "
                          f"{', '.join(names)}; expected a header such as t,ax,ay,az,gx,gy,gz "
                          "or --columns", source=source, field="header")
    gyro = [found[r][0] for r in AXES["gyro"]] if all(r in found for r in AXES["gyro"]) else None
    t = found.get("t")
    scale = None
    if t is not None and t[2] is not None:
        scale = TIME_UNITS.get(t[2])
    return Layout(names=list(names), delimiter=delimiter, t=None if t is None else t[0],
                  acc=[found[r][0] for r in AXES["acc"]], gyro=gyro, time_scale=scale)


def _delimiter(line: str) -> str | None:
    for d in (",", "\t", ";"):
        if d in line:
            return d
    return None


def _split(line: str, d: str | None) -> list[str]:
    return [p.strip() for p in line.split(d)] if d is not None else line.split()


def _numbers(fields: list[str]) -> bool:
    try:
        for f in fields:
            float(f)
    except ValueError:
        return False
    return True


class LineParser:
    """Lines to :class:`Batch` es. ``columns`` (comma-separated names) stands for a header the
    device does not send; ``rate`` (Hz) numbers the samples of a stream without a time column."""

    def __init__(self, source: str, columns: str | None = None, rate: float | None = None):
        self.source = source
        self.rate = rate
        self.layout: Layout | None = None
        if columns is not None:
            names = [c.strip() for c in columns.split(",")]
            self.layout = self._with_time(layout_of(names, ",", "--columns"))
            self.layout.delimiter = "?"  # the first data line says which
        self.tail = b""
        self.garbled = 0
        self.headerless = 0  # lines of numbers before any header (give --columns)
        self.valid = 0
        self.received = 0  # bytes
        self.preview = b""
        self.last_t = -np.inf
        self.numbered = 0  # samples numbered by --rate so far
        self.prefix: str | None = None  # "Raw:" or "Uni:" once a MotionCal line came
        self.time_scale: float | None = None

    def _with_time(self, layout: Layout) -> Layout:
        if layout.t is None and self.rate is None:
            raise ImucalError("no time column among " + ", ".join(layout.names)
                              + "; name one (t, time, timestamp...) or give --rate HZ",
                              source=self.source, field="header")
        return layout

    @property
    def header(self) -> list[str]:
        """The session file's column names (a time column "t" first when --rate numbers the
        samples)."""
        assert self.layout is not None
        return (["t"] if self.layout.t is None else []) + self.layout.names

    def feed(self, data: bytes) -> Batch | None:
        """The valid rows among ``data`` (a partial last line waits for the rest)."""
        self.received += len(data)
        if len(self.preview) < PREVIEW_BYTES:
            self.preview += data[: PREVIEW_BYTES - len(self.preview)]
        buf = self.tail + data
        cut = buf.rfind(b"\n")
        if cut < 0:
            self.tail = buf if len(buf) <= MAX_LINE else b""
            self.garbled += len(buf) > MAX_LINE
            return None
        self.tail = buf[cut + 1:]
        if len(self.tail) > MAX_LINE:
            self.tail, self.garbled = b"", self.garbled + 1
        text = buf[:cut].decode("ascii", errors="replace")
        lines = [ln.strip() for ln in text.split("\n")]
        lines = [ln for ln in lines if ln]
        if self.layout is None or self.prefix is not None:
            lines = self._motioncal(lines)
        if self.layout is None:
            lines = self._find_header(lines)
        elif self.layout.delimiter == "?" and lines:
            self.layout.delimiter = _delimiter(lines[0])
        if not lines or self.layout is None:
            return None
        return self._rows(lines)

    def _motioncal(self, lines: list[str]) -> list[str]:
        """MotionCal's lines without their prefix (the other prefix's lines are garbled: one
        stream, one unit)."""
        if self.prefix is None:
            first = next((ln[:4] for ln in lines if ln[:4] in MOTIONCAL), None)
            if first is None:
                return lines
            self.prefix = first
            self.layout = self._with_time(layout_of(MOTIONCAL[first], ",", self.source))
        kept = [ln[4:] for ln in lines if ln.startswith(self.prefix)]
        self.garbled += len(lines) - len(kept)
        return kept

    def _find_header(self, lines: list[str]) -> list[str]:
        for i, line in enumerate(lines):
            d = _delimiter(line)
            fields = _split(line, d)
            if _numbers(fields):
                self.headerless += 1
                continue
            try:
                layout = layout_of(fields, d, self.source)
            except ImucalError:
                self.garbled += 1  # a banner, a boot message: not the header
                continue
            self.layout = self._with_time(layout)
            return lines[i + 1:]
        return []

    def _rows(self, lines: list[str]) -> Batch | None:
        lay = self.layout
        n_fields = len(lay.names)
        try:  # the common case, every line whole: one call, no Python loop over the samples
            values = np.loadtxt(lines, delimiter=lay.delimiter, ndmin=2, dtype=np.float64)
            if values.shape[1] != n_fields:
                raise ValueError
            keep = np.ones(len(lines), dtype=bool)
        except ValueError:  # some line is garbled: find which, line by line
            split = [_split(ln, lay.delimiter) for ln in lines]
            keep = np.array([len(f) == n_fields and _numbers(f) for f in split], dtype=bool)
            values = np.array([[float(x) for x in f] for f, k in zip(split, keep) if k],
                              dtype=np.float64).reshape(-1, n_fields)
        rows = np.flatnonzero(keep)
        finite = np.isfinite(values).all(axis=1)
        values, rows = values[finite], rows[finite]
        raw = values[:, lay.t] if lay.t is not None else None
        if raw is not None:  # time must move forward: a repeated or stale line is garbled
            forward = raw > np.maximum.accumulate(np.r_[self.last_t, raw])[:-1]
            values, rows = values[forward], rows[forward]
        self.garbled += len(lines) - len(rows)
        if not len(rows):
            return None
        t = self._time(values)
        if lay.t is not None:
            self.last_t = float(values[-1, lay.t])
        self.valid += len(rows)
        if lay.delimiter == "," and len(rows) == len(lines):
            text = lines  # every line whole: kept as it came
        elif lay.delimiter == ",":
            text = [lines[i] for i in rows]
        else:
            text = [",".join(_split(lines[i], lay.delimiter)) for i in rows]
        if lay.t is None:
            text = [f"{tt!r},{row}" for tt, row in zip(t.tolist(), text)]
        return Batch(values=values, text=text, t=t, acc=values[:, lay.acc],
                     gyro=None if lay.gyro is None else values[:, lay.gyro])

    def _time(self, values: np.ndarray) -> np.ndarray:
        lay = self.layout
        if lay.t is None:  # numbered by --rate (the session file's "t", in seconds)
            t = (self.numbered + np.arange(len(values))) / self.rate
            self.numbered += len(values)
            return t
        raw = values[:, lay.t]
        if self.time_scale is None:
            self.time_scale = lay.time_scale or _scale_from_steps(raw)
        return raw * (self.time_scale or 1.0)  # undecided (a row or two): seconds for now

    def said(self) -> str:
        """What came, for the message when no valid sample has: bytes, lines, a preview."""
        shown = self.preview.decode("ascii", errors="backslashreplace")
        shown = shown.replace("\r", "\\r").replace("\n", "\\n")
        parts = [f"{self.received} bytes"]
        if self.garbled:
            parts.append(f"{self.garbled} garbled lines")
        if self.headerless:
            parts.append(f"{self.headerless} lines of numbers but no header line (give "
                         "--columns, e.g. --columns t,ax,ay,az,gx,gy,gz)")
        return ", ".join(parts) + (f", starting {shown[:80]!r}" if self.received else "")


def _scale_from_steps(t: np.ndarray) -> float | None:
    """Seconds per unit of a time column that names none, by the loader's rule: seconds unless
    that puts the samples more than a second apart (imucal.io.time_base)."""
    step = np.diff(t)
    step = step[step > 0]
    if len(step) < 2:
        return None
    median = float(np.median(step))
    if median <= 1.0:
        return 1.0
    for unit in ("ms", "us", "ns"):
        if 1e-5 <= median * TIME_UNITS[unit] <= 1.0:
            return TIME_UNITS[unit]
    return 1.0
