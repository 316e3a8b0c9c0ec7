"""A warning about a run, as data: what kind (a stable code), where (a segment or the whole
session) and what a person should read.

Readers decide how to show it: the CLI and the viewer print :attr:`RunWarning.text`, the
calibration file writes :meth:`RunWarning.to_dict`; a script can test ``w.code`` instead of
searching the message, whose wording may change.
"""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class RunWarning:
    code: str  # short and stable, e.g. "few_orientations" (the list: docs in each stage)
    message: str  # one sentence for a person, without the segment
    # The segment it concerns, by its number from 1 (as printed everywhere, and as
    # ``imucal export --segment`` takes it); None: the whole session.
    segment: int | None = None

    @property
    def text(self) -> str:
        """The message with its segment in front ("segment 1: ...") when it has one."""
        return self.message if self.segment is None else f"segment {self.segment}: {self.message}"

    def in_segment(self, segment: int | None) -> RunWarning:
        return replace(self, segment=segment)

    def to_dict(self) -> dict[str, str | int | None]:
        return {"code": self.code, "segment": self.segment, "message": self.message}
