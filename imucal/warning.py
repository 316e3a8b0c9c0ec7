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


# A loader's note for a stream a table holds beside the calibrated pair (a2x…, g2x…, temp):
# what it says until a later step calibrates the stream (calibrate --all-imus, --triad,
# --temperature), which then says so in its place (:func:`calibrated_beside`).
NOT_CALIBRATED = "recorded, not calibrated"


def beside_note(label: str, roles: str, samples: int, what: str = NOT_CALIBRATED) -> str:
    """The loader's note for a stream found beside the pair (columns ``roles``)."""
    return f"{label} found beside the pair ({roles}: {samples} samples); {what}"


def calibrated_note(note: str, name: str, what: str) -> str:
    """The loader's note ``note`` saying ``what`` calibrated the stream ``name`` (a table's a2,
    g2, temp) instead of :data:`NOT_CALIBRATED`; any other note as it is."""
    roles = "temp" if name == "temp" else f"{name}x, {name}y, {name}z"
    if f" found beside the pair ({roles}: " in note and note.endswith(f"; {NOT_CALIBRATED}"):
        return note[:-len(NOT_CALIBRATED)] + what
    return note


def calibrated_beside(warnings: list[RunWarning], name: str, what: str) -> list[RunWarning]:
    """``warnings`` with the loader's note for the stream ``name`` saying ``what`` calibrated
    it (:func:`calibrated_note`)."""
    return [replace(w, message=calibrated_note(w.message, name, what)) if w.code == "input"
            else w for w in warnings]
