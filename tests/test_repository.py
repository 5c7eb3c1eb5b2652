"""The repository explains itself: nothing in it points at files a clone does not have."""

from __future__ import annotations

import ast
import graphlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# the team's notes beside the clone (written so that this file does not match a grep for them itself)
_NOTES = "shared" + "/"
OUTSIDE = re.compile(rf"\.\./{_NOTES}|{_NOTES}(DESIGN|REFERENCE|STYLE)\.md|\bREFERENCE\.md\b|\bDESIGN\.md\b")


def test_no_file_refers_outside_the_repository() -> None:
    offenders = []
    for path in ROOT.rglob("*"):
        if path.suffix not in {".py", ".md", ".toml"} or any(
            p in {".git", "runs", "build"} for p in path.parts
        ):
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


def test_benchmarks_run_against_the_installed_package() -> None:
    """No benchmark edits sys.path or forces PYTHONPATH: they import what `pip install -e .` installed."""
    hack = re.compile(r"sys\.path\.(insert|append)|[\"']PYTHONPATH[\"']\s*:")
    offenders = [
        f"{path.relative_to(ROOT)}:{n}: {line.strip()}"
        for path in sorted((ROOT / "benchmarks").glob("*.py"))
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if hack.search(line)
    ]
    assert not offenders, "\n".join(offenders)


def _imports(packages: tuple[str, ...]) -> dict[str, set[str]]:
    """module -> the modules of `packages` it imports anywhere in its file (inside functions too), leaving
    out its own parent packages (a submodule reaching a sibling through its package is not a cycle)."""
    files = {}
    for pkg in packages:
        for path in (ROOT / pkg).rglob("*.py"):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            files[name] = path
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                targets |= {node.module} | {f"{node.module}.{a.name}" for a in node.names}
        graph[name] = set()
        for t in targets:
            while t and t not in files:
                t = t.rpartition(".")[0]
            if t and t != name and not name.startswith(t + "."):
                graph[name].add(t)
    return graph


def test_no_import_cycles_even_through_imports_inside_functions() -> None:
    """An import inside a function can hide a cycle; the graph here counts them (every package, scout_agent
    included since its cli <-> evaluate cycle was broken: the command lives in cli.py, the scoring in
    evaluate.py)."""
    packages = (
        "protocol",
        "scout_agent",
        "psrmap_common",
        "psrmap_mapcore",
        "map_server",
        "consumer_planner",
        "psrmap_interop",
        "psrmap",
    )
    try:
        graphlib.TopologicalSorter(_imports(packages)).prepare()
    except graphlib.CycleError as exc:
        raise AssertionError(f"import cycle: {' -> '.join(exc.args[1])}") from None
