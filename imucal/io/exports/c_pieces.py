"""A model's pieces of time as C: one ``imucal_piece`` initializer (``{t_start, t_end, A, b}``,
the struct :mod:`imucal.io.exports.c_header` declares) per piece, and a sensor's table of them
(``NAME_pieces``, ``NAME_PIECES``), written alike for the reference triad (c_header.py) and
each other one (:mod:`imucal.io.exports.c_triads`), which both use this module: imports run
one way. The open ends of time (the first piece's start, the last one's end) are +-1e308.
"""

from __future__ import annotations

import numpy as np

from imucal.io.exports.common import fmt_num
from imucal.models import SensorModel


def piece_line(t0: float, t1: float, a: np.ndarray, b: np.ndarray) -> str:
    """One piece ``[t0, t1]`` of ``out = a (raw - b)`` as an initializer line (with its comma)."""
    rows = ", ".join("{" + ", ".join(fmt_num(v) for v in row) + "}" for row in a)
    return (f"    {{{_time(t0)}, {_time(t1)}, {{{rows}}}, "
            f"{{{', '.join(fmt_num(v) for v in b)}}}}},")


def _time(t: float) -> str:
    return fmt_num(t) if np.isfinite(t) else ("-1e308" if t < 0 else "1e308")


def pieces_table(name: str, pieces: list[tuple[str, float, float, SensorModel | None]]
                 ) -> list[str]:
    """``NAME_PIECES`` and the table ``NAME_pieces`` of ``pieces`` (``piece_models``' kind,
    start, end, model), the first reaching back to the start of time, the last on to its end."""
    n = len(pieces)
    lines = [f"#define {name.upper()}_PIECES {n}",
             f"static const imucal_piece {name}_pieces[{n}] = {{"]
    for i, (kind, t0, t1, model) in enumerate(pieces):
        assert model is not None
        if kind == "between":
            # A segment owns its closed interval: the gap starts just after its end.
            t0 = float(np.nextafter(t0, np.inf))
        # The first piece reaches back to the start of time, the last on to its end.
        lines.append(piece_line(-np.inf if i == 0 else t0, np.inf if i == n - 1 else t1,
                                model.matrix, model.b))
    lines.append("};")
    return lines
