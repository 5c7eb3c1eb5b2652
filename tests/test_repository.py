"""The repository explains itself: nothing in it points at files a clone does not have."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUTSIDE = re.compile(r"\.\./shared|shared/(DESIGN|REFERENCE|STYLE)\.md|\bREFERENCE\.md\b|\bDESIGN\.md\b")


def test_no_file_refers_outside_the_repository() -> None:
    offenders = []
    for path in ROOT.rglob("*"):
        if path.suffix not in {".py", ".md", ".toml"} or any(
            p in {".git", "runs", "build"} for p in path.parts
        ):
            continue
        if path == Path(__file__).resolve():
            continue
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if OUTSIDE.search(line):
                offenders.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not offenders, "\n".join(offenders)


def test_the_design_documents_exist_and_are_linked_from_the_readme() -> None:
    readme = (ROOT / "README.md").read_text()
    for doc in ("docs/design.md", "docs/physics.md", "docs/interfaces.md", "docs/results.md"):
        assert (ROOT / doc).is_file(), doc
        assert doc in readme, f"README does not point at {doc}"
