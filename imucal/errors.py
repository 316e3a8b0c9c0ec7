"""The product's one error type: every problem a user can cause ends up here.

The CLI turns an :class:`ImucalError` into a single line on stderr and exit code 1; anything
else escaping the core is a bug in imucal, not in the user's data.
"""

from __future__ import annotations


class ImucalError(Exception):
    """A problem with the user's input or settings, explained in one line.

    ``source`` names the file (or setting) at fault, ``field`` the part of it, and the message
    says what was expected. ``str(err)`` is the one-line message shown to the user.
    """

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None):
        self.source = source
        self.field = field
        self.problem = message
        parts = [p for p in (source, field) if p]
        text = ": ".join([*parts, message])
        super().__init__(" ".join(text.split()))


def plural(n: int, noun: str) -> str:
    """``"1 gap"``, ``"3 gaps"``: counts in messages."""
    return f"{n} {noun}{'' if n == 1 else 's'}"
