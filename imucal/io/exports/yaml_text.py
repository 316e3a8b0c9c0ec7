"""A tiny YAML emitter for the exports (no YAML library is a dependency).

Block mappings, lists of numbers in flow style (``[1.0, 2.0]``, nested for matrices), lists of
mappings as block sequences, double-quoted strings (JSON escapes, valid YAML), ``null``,
``true``/``false``, and comments (:class:`Commented`). Floats are written so that YAML 1.1
readers (PyYAML, which Kalibr uses) read them as floats: always a dot in the mantissa
(``1.0e-05``, not ``1e-05``, which YAML 1.1 reads as a string), ``.inf``/``.nan``.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any

_PLAIN_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class Commented:
    """A value with a comment written after it on its line."""

    value: Any
    comment: str


@dataclass(frozen=True)
class Comment:
    """A comment line in a mapping (its key is ignored)."""

    text: str


def scalar(x: Any) -> str:
    if x is None:
        return "null"
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, int):
        return str(x)
    if isinstance(x, float):
        if math.isnan(x):
            return ".nan"
        if math.isinf(x):
            return ".inf" if x > 0 else "-.inf"
        text = repr(x + 0.0)  # -0.0 + 0.0 is 0.0: no signed zeros in the output
        mantissa, _, exp = text.partition("e")
        if "." not in mantissa:
            mantissa += ".0"
        return mantissa + (f"e{'+' if not exp.startswith('-') else ''}{exp.lstrip('+')}"
                           if exp else "")
    if isinstance(x, str):
        return json.dumps(x)
    if hasattr(x, "item"):  # numpy scalar
        return scalar(x.item())
    raise TypeError(f"cannot write {type(x).__name__} as a YAML scalar")


def _flow(x: Any) -> str | None:
    """A list of scalars (or of such lists) in flow style; None if it is not one."""
    if isinstance(x, (list, tuple)) or hasattr(x, "tolist"):
        items = x.tolist() if hasattr(x, "tolist") else list(x)
        parts = []
        for v in items:
            if isinstance(v, (list, tuple)):
                inner = _flow(v)
                if inner is None:
                    return None
                parts.append(inner)
            elif isinstance(v, dict):
                return None
            else:
                parts.append(scalar(v))
        return "[" + ", ".join(parts) + "]"
    return None


def _key(k: str) -> str:
    return k if _PLAIN_KEY.match(k) else json.dumps(k)


def dump(obj: dict, indent: int = 0) -> str:
    """A mapping as block-style YAML text."""
    pad = " " * indent
    lines: list[str] = []
    for k, v in obj.items():
        comment = ""
        if isinstance(v, Comment):
            lines.append(f"{pad}# {v.text}")
            continue
        if isinstance(v, Commented):
            v, comment = v.value, f"  # {v.comment}"
        if isinstance(v, dict):
            lines.append(f"{pad}{_key(k)}:{comment}")
            lines.append(dump(v, indent + 2).rstrip("\n"))
            continue
        flow = _flow(v)
        if flow is not None:
            lines.append(f"{pad}{_key(k)}: {flow}{comment}")
        elif isinstance(v, (list, tuple)):  # a list of mappings
            lines.append(f"{pad}{_key(k)}:{comment}")
            for item in v:
                text = dump(item, indent + 4).rstrip("\n")
                lines.append(f"{pad}  - {text.lstrip()}")
        else:
            lines.append(f"{pad}{_key(k)}: {scalar(v)}{comment}")
    return "\n".join(line for line in lines if line) + "\n"


def comment_block(lines: list[str]) -> str:
    return "".join(f"# {line}\n" for line in lines)
