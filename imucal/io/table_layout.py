"""Which columns of a table hold time, the accelerometer and the gyroscope (method.md §0):
by name, by position, or as the user maps them with ``--columns``."""

from __future__ import annotations

from imucal.errors import ImucalError
from imucal.io.column_guess import guess_hint, paste_name
from imucal.io.column_names import AXES, EXTRA_AXES, EXTRA_ROLES, LABELS, classify_name
from imucal.io.file_contents import Table
from imucal.io.parts import LoadOptions, Part, columns_for


def widths(sensors: tuple[str, ...]) -> tuple[int, ...]:
    return (3, 4, 6, 7) if len(sensors) == 2 else (3, 4)


def expected(sensors: tuple[str, ...]) -> str:
    if len(sensors) == 2:
        return ("6 columns (ax ay az gx gy gz), 7 (t + 6), or 3/4 for an accelerometer-only "
                "session")
    xyz = "x y z"
    return f"3 columns ({xyz} of the {LABELS[sensors[0]]}) or 4 (t {xyz})"



def from_positions(table: Table, sensors: tuple[str, ...], opts: LoadOptions) -> dict[str, Part]:
    """Headerless text or one matrix: columns [t] ax ay az [gx gy gz] by position."""
    source = table.source
    columns = columns_for(opts, sensors, source)
    if columns:
        mapping = {}
        for role, col in columns.items():
            if not isinstance(col, int):
                raise ImucalError(f"the file has no header, so {role!r} must be a 0-based "
                                  f"column position, got {col!r}", source=source,
                                  field="columns")
            if col >= table.n_cols:
                raise ImucalError(f"{role!r} -> position {col}, but the file has only "
                                  f"{table.n_cols} columns", source=source,
                                  field="columns")
            mapping[role] = col
        return _parts_from_mapping(table, mapping, sensors, opts, counter=None)
    n = table.n_cols
    if n not in widths(sensors):
        raise ImucalError(f"found {n} column(s); expected {expected(sensors)}"
                          f"{guess_hint(table, sensors)}", source=source, field="columns")
    offset = 1 if n in (4, 7) else 0
    mapping = {"t": 0} if offset else {}
    roles = AXES[sensors[0]] + (AXES["gyro"] if n >= 6 else ())
    mapping.update({role: offset + i for i, role in enumerate(roles)})
    return _parts_from_mapping(table, mapping, sensors, opts, counter=None)


def from_names(table: Table, sensors: tuple[str, ...], opts: LoadOptions) -> dict[str, Part]:
    """A table with a header: map column names to roles, then let ``columns`` override."""
    assert table.names is not None
    single = sensors[0] if len(sensors) == 1 else None
    wanted = {"t", *(r for s in sensors for r in AXES[s])}
    mapping: dict[str, int] = {}
    units: dict[str, str | None] = {}
    ranks: dict[str, int] = {}
    counter = None
    explicit = _explicit_columns(table, columns_for(opts, sensors, table.source))
    taken = set(explicit.values())
    for i, name in enumerate(table.names):
        if i in taken:
            continue
        meaning = classify_name(name, single)
        if meaning.role == "counter":
            counter = counter or table.label(i)
        elif meaning.role in wanted and meaning.role not in explicit:
            role = meaning.role
            if role in mapping and ranks[role] <= meaning.rank:
                if ranks[role] < meaning.rank:
                    continue  # a better name holds this role ("time" beside "header.stamp")
                other = table.names[mapping[role]]
                raise ImucalError(f"columns {other!r} and {name!r} both look like {role!r}; "
                                  f"choose one with --columns {role}={paste_name(table, i)}",
                                  source=table.source, field="columns")
            mapping[role], units[role], ranks[role] = i, meaning.unit, meaning.rank
    for role, i in explicit.items():  # a unit in an explicitly mapped name still counts
        meaning = classify_name(table.names[i], single)
        units[role] = meaning.unit if meaning.role == role else None
    mapping.update(explicit)
    used = set(mapping.values())
    if len(sensors) == 2:
        used |= _extra_parts(table, mapping, used, opts)
    ignored = [n for i, n in enumerate(table.names) if i not in used and n]
    parts = _parts_from_mapping(table, mapping, sensors, opts, counter)
    if ignored and parts:
        opts.notes.append(f"ignored columns in {table.source}: {', '.join(ignored)}")
    for sensor, part in parts.items():
        hints = {units.get(role) for role in AXES[sensor]}
        part.unit_hint = hints.pop() if len(hints) == 1 else None
        if "t" in mapping and units.get("t"):
            part.time_unit = units["t"]
    for _, part in opts.extras:
        if "t" in mapping and units.get("t"):
            part.time_unit = units["t"]
    return parts


def _explicit_columns(table: Table, columns: dict[str, str | int]) -> dict[str, int]:
    """Column indices of the roles the user mapped by name (any case) or position."""
    assert table.names is not None
    lowered = [n.strip().lower() for n in table.names]
    result = {}
    for role, col in columns.items():
        if isinstance(col, int):
            if col >= table.n_cols:
                raise ImucalError(f"{role!r} -> position {col}, but the file has only "
                                  f"{table.n_cols} columns", source=table.source,
                                  field="columns")
            result[role] = col
        elif col in table.names:
            result[role] = table.names.index(col)
        elif col.strip().lower() in lowered:
            result[role] = lowered.index(col.strip().lower())
        else:
            raise ImucalError(f"{role!r} -> {col!r}, but there is no such column; the file has "
                              f"{', '.join(table.names)}", source=table.source,
                              field="columns")
    return result


def _parts_from_mapping(table: Table, mapping: dict[str, int], sensors: tuple[str, ...],
                        opts: LoadOptions, counter: str | None) -> dict[str, Part]:
    parts = {}
    for sensor in sensors:
        roles = AXES[sensor]
        present = [r for r in roles if r in mapping]
        if not present:
            if sensor == "acc" or len(sensors) == 1:
                have = ", ".join(table.names) if table.names else f"{table.n_cols} unnamed"
                example = "x, y, z or " if len(sensors) == 1 else ""
                raise ImucalError(
                    f"no {LABELS[sensor]} columns found (columns: {have}); expected names like "
                    f"{example}{roles[0]}/{'acc_x' if sensor == 'acc' else 'gyr_x'}, or map "
                    f"them with --columns{guess_hint(table, sensors)}", source=table.source,
                    field="columns")
            continue
        if len(present) < 3:
            missing = [r for r in roles if r not in mapping]
            raise ImucalError(f"{LABELS[sensor]} columns incomplete: missing {', '.join(missing)}"
                              f"; map them with --columns{guess_hint(table, sensors)}",
                              source=table.source, field="columns")
        values = table.columns([mapping[r] for r in roles])
        part = Part(sensor, table.source, values, counter_label=counter)
        if "t" in mapping:
            ti = mapping["t"]
            part.time = table.column(ti)
            part.time_label = table.label(ti)
            part.time_is_datetime = ti in table.seconds_cols
        elif table.shared_time is not None:
            part.time, part.time_label = table.shared_time, f"variable {table.shared_time_name!r}"
            if part.time.size != len(values):
                raise ImucalError(f"{part.time_label} has {part.time.size} values but the matrix "
                                  f"has {len(values)} samples", source=table.source,
                                  field="time")
        parts[sensor] = part
    return parts


def _extra_parts(table: Table, mapping: dict[str, int], used: set[int],
                 opts: LoadOptions) -> set[int]:
    """The streams a table holds beside the pair, found by the same naming rule (a2x…, g2x…,
    mx…, temp, or --columns): each complete one becomes a part in ``opts.extras``; the columns
    taken are returned. An incomplete triad stays among the ignored columns."""
    assert table.names is not None
    explicit = _explicit_columns(table, {r: c for r, c in (opts.columns or {}).items()
                                         if r in EXTRA_ROLES})
    found: dict[str, tuple[int, str | None]] = {}
    for i, name in enumerate(table.names):
        if i in used or i in explicit.values():
            continue
        meaning = classify_name(name, None)
        if meaning.role in EXTRA_ROLES and meaning.role not in found:
            found[meaning.role] = (i, meaning.unit)
    found.update({r: (i, None) for r, i in explicit.items()})
    taken: set[int] = set()
    for (kind, instance), roles in EXTRA_AXES.items():
        if not all(r in found for r in roles):
            continue
        cols = [found[r][0] for r in roles]
        units = {found[r][1] for r in roles}
        part = Part(instance, table.source, table.columns(cols),
                    unit_hint=units.pop() if len(units) == 1 else None)
        if "t" in mapping:
            ti = mapping["t"]
            part.time, part.time_label = table.column(ti), table.label(ti)
            part.time_is_datetime = ti in table.seconds_cols
        opts.extras.append((kind, part))
        taken.update(cols)
    return taken
