"""The robot apart from the world, by structure: the robot's software never imports the simulator, and the
simulator never imports the robot's software (issue 27). Imports are read from the source (inside functions and
`TYPE_CHECKING` blocks too, relative ones resolved), so a hidden import fails here as much as a top-level one."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "scout_agent"

# the parts of scout_agent; every module belongs to exactly one (a new module must say where it stands)
SIMULATOR = ("scout_agent.sim",)  # the world and the simulated hardware, sensor models included
ROBOT_SOFTWARE = (  # what would run on the Aliengo's own computer
    "scout_agent.onboard",
    "scout_agent.state_estimation",
    "scout_agent.control",
    "scout_agent.estimators",
    "scout_agent.localization",
    "scout_agent.mapping",
    "scout_agent.cells",
    "scout_agent.holding",
    "scout_agent.publisher",
    "scout_agent.delivery",
    "scout_agent.outbox",
)
SHARED = (  # what both sides may import: the interface, the records, the robot's description, file readers
    "scout_agent.lowlevel",
    "scout_agent.signals",
    "scout_agent.robot",
    "scout_agent.errors",
    "scout_agent.dem_reader",
    "scout_agent.ccall",  # C routines of loaded libraries (quadprog, MuJoCo) called from compiled code
)
HARNESS = (  # joins the two and evaluates: the loop, the run, the command line
    "scout_agent.loop",
    "scout_agent.run",
    "scout_agent.evaluate",
    "scout_agent.component",
    "scout_agent.cli",
    "scout_agent.viz",
    "scout_agent.__main__",
)
PARTS = {"simulator": SIMULATOR, "robot software": ROBOT_SOFTWARE, "shared": SHARED, "harness": HARNESS}


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        out[".".join(parts).removesuffix(".__init__")] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The scout_agent modules `name` imports anywhere in its file."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the module's package, up level - 1
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*anchor, *([base] if base else [])])
            targets = [f"{base}.{a.name}" for a in node.names] + [base]
        else:
            continue
        for t in targets:
            while t and t not in modules:
                t = t.rpartition(".")[0]
            if t.startswith("scout_agent") and t != name and t != "scout_agent":
                found.add(t)
    return found


def _part(module: str) -> str | None:
    for part, prefixes in PARTS.items():
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            return part
    return None


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _offenders(part: str, allowed: tuple[str, ...]) -> list[str]:
    return sorted(
        f"{m} imports {t} ({_part(t)})"
        for m, targets in _graph().items()
        if _part(m) == part
        for t in targets
        if _part(t) not in allowed
    )


def test_every_module_belongs_to_one_part() -> None:
    unplaced = [m for m in _modules() if m != "scout_agent" and _part(m) is None]
    assert not unplaced, f"say which part these belong to (tests/scout_agent/test_structure.py): {unplaced}"


def test_the_robot_software_never_imports_the_simulator() -> None:
    """Nor the harness (the loop imports the simulator): so it could run against a real Aliengo."""
    offenders = _offenders("robot software", ("robot software", "shared"))
    assert not offenders, "\n".join(offenders)


def test_the_simulator_never_imports_the_robot_software() -> None:
    offenders = _offenders("simulator", ("simulator", "shared"))
    assert not offenders, "\n".join(offenders)


def test_the_shared_modules_import_only_shared_modules() -> None:
    offenders = _offenders("shared", ("shared",))
    assert not offenders, "\n".join(offenders)


def test_the_import_reader_sees_both_kinds_of_import() -> None:
    """The checks above are only as good as the reader: the loop joins both sides, a sensor model imports its
    siblings relatively, and an import inside a function counts."""
    g = _graph()
    assert {"scout_agent.sim.aliengo", "scout_agent.onboard.software"} <= g["scout_agent.loop"]
    assert "scout_agent.sim.sensors.imu" in g["scout_agent.sim.sensors.suite"]  # `from .imu import …`
    assert "scout_agent.localization.shared_map" in g["scout_agent.component"]  # inside a function


def _loaded_after_import(module: str) -> list[str]:
    """The scout_agent modules a fresh interpreter has loaded after importing `module` alone."""
    code = f"import sys, {module}; print(' '.join(m for m in sys.modules if m.startswith('scout_agent')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return out.stdout.split()


def test_importing_either_side_loads_none_of_the_other():
    """The same at run time: the robot's software loads without the simulator, the simulator without it."""
    robot = _loaded_after_import("scout_agent.onboard.software")
    assert "scout_agent.state_estimation.estimator" in robot
    assert not [m for m in robot if _part(m) == "simulator"]
    hardware = _loaded_after_import("scout_agent.sim.aliengo")
    assert "scout_agent.sim.sensors.suite" in hardware
    assert not [m for m in hardware if _part(m) == "robot software"]
