"""docs/method.md holds every section and equation the code cites ("method.md §3", "(M2)"), and
nothing points at a method document outside the repository."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "method.md"
CITING = ("imucal", "viewer", "tests", "bench")
# "§N" of another document: the thesis's own sections, NIST SP 1065's.
OTHER = re.compile(r"(thesis|\"thesis\"|1065)\s*$")


def _sources() -> list[Path]:
    files = [p for d in CITING for p in (ROOT / d).rglob("*.py")]
    return [*files, ROOT / "README.md"]


def cited() -> tuple[dict[int, set[str]], dict[int, set[str]]]:
    """Section and equation numbers cited, each with the files that cite it."""
    sections: dict[int, set[str]] = {}
    equations: dict[int, set[str]] = {}
    for path in _sources():
        text = path.read_text(encoding="utf-8")
        if "method.md" not in text:
            continue  # a module that cites nothing of the method (M1 there is something else)
        name = path.relative_to(ROOT).as_posix()
        for m in re.finditer(r"§\s?(\d+)(?:\s?-\s?§?(\d+))?", text):
            if OTHER.search(text[max(0, m.start() - 12):m.start()]):
                continue
            lo = int(m.group(1))
            hi = int(m.group(2)) if m.group(2) else lo
            for n in range(lo, hi + 1):
                sections.setdefault(n, set()).add(name)
        for m in re.finditer(r"\bM(\d+)\b", text):
            equations.setdefault(int(m.group(1)), set()).add(name)
    return sections, equations


def test_every_cited_section_and_equation_is_in_docs_method_md():
    doc = DOC.read_text(encoding="utf-8")
    headings = {int(n) for n in re.findall(r"^## (\d+)\. ", doc, re.M)}
    labels = {int(n) for n in re.findall(r"\(M(\d+)\)\s*$", doc, re.M)}
    sections, equations = cited()
    assert {1, 3, 5} <= set(sections) and {1, 2, 3, 4, 5} <= set(equations)  # the parse works
    missing = {f"§{n}": sorted(w) for n, w in sections.items() if n not in headings}
    missing |= {f"M{n}": sorted(w) for n, w in equations.items() if n not in labels}
    assert not missing, missing
    # Each equation labelled once, at the end of the line that states it.
    assert len(re.findall(r"\(M\d+\)\s*$", doc, re.M)) == len(labels)


def test_nothing_points_outside_the_repository_for_the_method():
    outside = "../shared/" + "method.md"  # spelled apart: this file is among the sources
    for path in _sources():
        text = path.read_text(encoding="utf-8")
        assert outside not in text, path
    assert "(docs/method.md)" in (ROOT / "README.md").read_text(encoding="utf-8")
