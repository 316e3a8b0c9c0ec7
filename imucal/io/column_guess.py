"""Which column is which by the values, where the names say nothing (method.md §0).

Only to help a user write ``--columns``: the guess is never used to load, only printed, ready
to paste. A column that increases throughout is time (a counter where it goes up in steps of
1); three adjacent columns whose norm is near-constant at a plausible magnitude (~1 g,
~9.81 m/s^2, or thousands of raw counts) are the accelerometer (it reads gravity while still
and turning); of the other adjacent triples, the one that is quiet most of the time and bursts
in the turns is the gyroscope.
"""

from __future__ import annotations

import shlex

import numpy as np

from imucal.errors import ImucalError
from imucal.io.column_names import AXES, LABELS
from imucal.io.file_contents import Table

_HEAD_ROWS = 20_000  # enough rows to judge a column by
_MAX_NORM_SPREAD = 0.2  # relative median deviation of |a| above which no triple is gravity


def paste_name(table: Table, i: int) -> str:
    """Column ``i`` as a ``--columns`` value takes it: its name, or its 0-based position where
    there is no name or one that cannot be pasted (digits alone read as a position; a comma or
    an equals sign would split the option)."""
    name = table.names[i].strip() if table.names else ""
    if not name or name.isdigit() or "," in name or "=" in name:
        return str(i)
    return name


def guess_hint(table: Table, sensors: tuple[str, ...]) -> str:
    """"; by their values, ...: --columns t=...,ax=..." for an error message, or "" where the
    values do not tell."""
    try:
        columns = _numeric_columns(table)
        roles, why = _guess(table, columns, sensors)
    except (ImucalError, ValueError, MemoryError):
        return ""
    primary = AXES[sensors[0]]
    if not all(r in roles for r in primary):
        return ""
    order = [r for r in ("t", "ax", "ay", "az", "gx", "gy", "gz") if r in roles]
    value = ",".join(f"{r}={paste_name(table, roles[r])}" for r in order)
    return f"; by their values, {'; '.join(why)}: --columns {shlex.quote(value)}"


def _named(table: Table, cols: list[int] | tuple[int, ...]) -> str:
    """Columns as a message names them: by name, else "column(s)" and 0-based positions."""
    text = ", ".join(paste_name(table, j) for j in cols)
    return text if table.names else f"column{'s' if len(cols) > 1 else ''} {text}"


def _numeric_columns(table: Table) -> dict[int, np.ndarray]:
    found = {}
    for i in range(table.n_cols):
        try:
            values = table.column(i)[:_HEAD_ROWS]
        except ImucalError:
            continue  # text
        if values.size >= 3 and np.isfinite(values).mean() > 0.9:
            found[i] = values
    return found


def _guess(table: Table, columns: dict[int, np.ndarray], sensors: tuple[str, ...]
           ) -> tuple[dict[str, int], list[str]]:
    roles: dict[str, int] = {}
    why: list[str] = []
    taken: set[int] = set()
    with np.errstate(invalid="ignore", over="ignore"):
        for i, values in columns.items():
            step = np.diff(values)
            if np.isfinite(values).all() and np.all(step > 0):
                taken.add(i)
                if np.all(step == 1):
                    why.append(f"{_named(table, [i])} counts samples (use --rate)")
                elif "t" not in roles:
                    roles["t"] = i
                    why.append(f"{_named(table, [i])} increases (time)")
        triples = [(i, i + 1, i + 2) for i in columns
                   if all(j in columns and j not in taken for j in (i, i + 1, i + 2))]
        order = sensors if sensors[0] == "acc" else ("gyro",)
        for sensor in order:
            triples = [tr for tr in triples if not taken & set(tr)]
            pick = _acc_triple(columns, triples) if sensor == "acc" else _gyro_triple(columns,
                                                                                     triples)
            if pick is None:
                continue
            (cols, said) = pick
            taken |= set(cols)
            roles.update(zip(AXES[sensor], cols, strict=True))
            why.append(f"{_named(table, cols)} look like the {LABELS[sensor]} ({said})")
    return roles, why


def _acc_triple(columns: dict[int, np.ndarray], triples: list[tuple[int, int, int]]
                ) -> tuple[tuple[int, int, int], str] | None:
    """The adjacent triple whose norm is nearest to constant, at a magnitude gravity has."""
    best = None
    for tr in triples:
        norm = np.linalg.norm(np.column_stack([columns[j] for j in tr]), axis=1)
        norm = norm[np.isfinite(norm)]
        med = float(np.median(norm)) if norm.size else 0.0
        if med <= 0:
            continue
        spread = float(np.median(np.abs(norm - med))) / med
        plausible = 0.5 <= med <= 2.0 or 5.0 <= med <= 20.0 or med > 100
        key = (not plausible, spread)
        if spread < _MAX_NORM_SPREAD and (best is None or key < best[0]):
            best = (key, tr, f"norm {med:.3g} within {spread:.1%}")
    return None if best is None else (best[1], best[2])


def _gyro_triple(columns: dict[int, np.ndarray], triples: list[tuple[int, int, int]]
                 ) -> tuple[tuple[int, int, int], str] | None:
    """The adjacent triple that is quiet most of the time and bursts now and then: its 99th
    percentile deviation is many times its median one."""
    best = None
    for tr in triples:
        scores = []
        for j in tr:
            x = columns[j][np.isfinite(columns[j])]
            dev = np.abs(x - np.median(x))
            scores.append(float(np.percentile(dev, 99)) / (float(np.median(dev)) + 1e-12))
        score = float(np.mean(scores))
        if best is None or score > best[0]:
            best = (score, tr)
    return None if best is None else (best[1], "quiet, with bursts")
