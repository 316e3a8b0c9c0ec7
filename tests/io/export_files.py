"""Every one-file export of a calibration, as bytes: the tests that an added section leaves
the other formats unchanged compare two of these."""

from pathlib import Path

from imucal.io.exports import FORMATS, export

# The formats that write one file (c_runtime writes a directory of C, tested on its own in
# tests/io/test_c_runtime.py)
FILE_FORMATS = [f for f in FORMATS if not FORMATS[f].directory]


def export_all(path: Path, out: Path) -> dict[str, bytes]:
    """Each of FILE_FORMATS of the calibration ``path`` written into the new folder ``out``."""
    out.mkdir()
    for fmt in FILE_FORMATS:
        export(path, fmt, out / f"x.{fmt}")
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())}
