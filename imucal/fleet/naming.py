"""Which device a recording belongs to, when it was recorded, and what its results are named.

``--device-from '{device}/{date}_*.csv'`` matches the end of each path: ``{name}`` is one
path component's worth of text (no ``/``), ``*`` any text within a component. ``{device}`` is
required; ``{date}`` (and ``{time}``) give the recording time. Without a pattern the device is
the file's parent folder and the time its modification time; each row says which
(``device_from``, ``recorded_from``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from imucal.errors import ImucalError

_FIELD = re.compile(r"\{([A-Za-z_][A-Za-z0-9_]*)\}")
_DATE_FORMATS = ("%Y-%m-%d", "%Y%m%d", "%Y_%m_%d", "%Y-%m-%dT%H%M%S", "%Y-%m-%dT%H:%M:%S",
                 "%Y%m%dT%H%M%S", "%Y-%m-%d %H:%M:%S")
_TIME_FORMATS = ("%H%M%S", "%H-%M-%S", "%H:%M:%S", "%H%M")


@dataclass(frozen=True)
class Identity:
    device: str
    device_from: str  # "pattern '...'" or "parent folder"
    recorded_at: datetime | None
    recorded_from: str  # "pattern {date}", "file modification time"
    named: str = ""  # the text the device id was made from (a folder's name, a field)


def compile_pattern(pattern: str) -> re.Pattern[str]:
    """The pattern as a regular expression anchored at the path's end (a component boundary)."""
    names = _FIELD.findall(pattern)
    if "device" not in names:
        raise ImucalError("the pattern needs a {device} field, e.g. '{device}/{date}_*.csv'",
                          source="--device-from", field=pattern)
    if len(set(names)) != len(names):
        raise ImucalError("a field appears twice in the pattern", source="--device-from",
                          field=pattern)
    out, pos = [], 0
    for m in _FIELD.finditer(pattern):
        out.append(_literal(pattern[pos:m.start()]))
        out.append(f"(?P<{m.group(1)}>[^/]+?)")
        pos = m.end()
    out.append(_literal(pattern[pos:]))
    return re.compile(r"(?:^|/)" + "".join(out) + "$")


def _literal(text: str) -> str:
    return ".*".join("[^/]*".join(re.escape(p) for p in part.split("*"))
                     for part in text.split("**"))


def identify(path: Path, pattern: re.Pattern[str] | None, source: str = "") -> Identity:
    """Device and recording time of one file (a path the pattern does not match is an error
    for that file alone: its summary row says so)."""
    if pattern is None:
        folder = path.resolve().parent.name or "unknown"
        return Identity(device=safe_name(folder), device_from="parent folder",
                        recorded_at=_mtime(path), recorded_from="file modification time",
                        named=folder)
    m = pattern.search(path.as_posix())
    if m is None:
        raise ImucalError(f"the path does not match --device-from {source!r}", source=str(path),
                          field="--device-from")
    fields = m.groupdict()
    when, how = _mtime(path), "file modification time"
    if fields.get("date"):
        when = parse_time(fields["date"], fields.get("time"), str(path))
        how = "pattern {date}" + (" {time}" if fields.get("time") else "")
    return Identity(device=safe_name(fields["device"]), device_from=f"pattern {source!r}",
                    recorded_at=when, recorded_from=how, named=fields["device"])


def check_distinct(found: list[tuple[Path, Identity]]) -> None:
    """Refuse two units folded into one device id: folders ``IMU 1`` and ``IMU_1`` both make
    ``IMU_1`` (and ids that differ only in case are one folder on a case-insensitive disk);
    their calibrations would land in one history, and drift would compare two units."""
    first: dict[str, tuple[str, Path]] = {}
    for path, ident in found:
        key = ident.device.casefold()
        named, there = first.setdefault(key, (ident.named, path))
        if ident.named != named:
            raise ImucalError(f"{named!r} (from {there}) and {ident.named!r} would be one device "
                              f"id, {ident.device!r}: two units would be merged; rename one "
                              "folder, or name the devices with --device-from",
                              source=str(path), field="device")


def parse_time(date: str, time: str | None = None, source: str = "--at") -> datetime:
    """'2024-05-01', '20240501', '2024-05-01T12:30:00' (+ an optional separate time) -> UTC.
    A time without a zone is taken as UTC."""
    text = date.strip()
    try:
        when = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        when = None
        for fmt in _DATE_FORMATS:
            try:
                when = datetime.strptime(text, fmt)
                break
            except ValueError:
                continue
    if when is None:
        raise ImucalError(f"cannot read {text!r} as a date (expected e.g. 2024-05-01 or "
                          "20240501)", source=source, field="date")
    if time:
        for fmt in _TIME_FORMATS:
            try:
                t = datetime.strptime(time.strip(), fmt).time()
                when = datetime.combine(when.date(), t)
                break
            except ValueError:
                continue
        else:
            raise ImucalError(f"cannot read {time!r} as a time of day (expected e.g. 123000)",
                              source=source, field="time")
    return when if when.tzinfo else when.replace(tzinfo=timezone.utc)


def _mtime(path: Path) -> datetime | None:
    try:
        return datetime.fromtimestamp(path.stat().st_mtime, tz=timezone.utc)
    except OSError:
        return None


def safe_name(text: str) -> str:
    """A device or session id usable as one folder or file name."""
    name = re.sub(r"[^A-Za-z0-9._+-]+", "_", text.strip()).strip("._")
    return name or "unknown"


def output_names(jobs: list[tuple[str, str, str]]) -> list[str]:
    """``(device, stem, sha256)`` -> a relative ``device/session`` name per job, unique: two
    files with the same stem on one device get the first 8 hex digits of their hash added."""
    seen: dict[tuple[str, str], int] = {}
    for device, stem, _ in jobs:
        seen[(device, stem)] = seen.get((device, stem), 0) + 1
    out = []
    for device, stem, sha in jobs:
        session = stem if seen[(device, stem)] == 1 else f"{stem}-{sha[:8]}"
        out.append(f"{device}/{session}")
    return out
