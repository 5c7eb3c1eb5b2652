"""The README is tested: every shell command in its ```bash blocks runs here, in document order, so a command that
stops working as written fails CI.

How each command runs (`_plan` decides; a command it cannot place fails the test, so a new README command must be
given a way to run here):
- psrmap commands run as written, in a fresh folder per README section, with only these changes:
  * endpoints: `tcp/0.0.0.0:7447` and `tcp/base:7447` (the base station) and `tcp/127.0.0.1:7447` (this host's
    router) become free loopback ports; a section that starts its own network (a `router` or `secure init`)
    gets new ports, and a second router on "another host" (`--connect tcp/base:7447`) a port of its own;
  * time, where unavoidable: a scout or evaluate walks `--sim-seconds 2` instead of its whole route, a mission
    runs `--scouts 1 --sim-seconds 2`, the ROS 2 bridge (which runs until stopped) publishes `--once`; on such a
    small map a `plan` may answer that its goal cell is impassable (exit 1 with that message: the planner ran);
  * `router` and `server` lines (and any line ending in `&`) start in the background; the test waits for their
    "up" line and stops them when their group of sections is done;
  * a group — a section that starts its own network (or uses none) and the sections after it that use that
    network — runs in document order; independent groups run side by side in two lanes, and the mission beside
    them (most of the time here is waiting on subprocesses, not computing); `export VAR=...` lines hold for
    every later group as they would in one shell;
  * `runs/<ts>` is the run folder of the mission run before; the DEM `LDEM_875S_5M.tif` is a small GeoTIFF the
    test writes at the window the README names (the real LOLA tile is a 1 GB download);
  * `--viewer` and `--connect-viewer` run with no display and nothing at the viewer's port (as on CI): they must
    fail at once with their one-line message; the live path is `tests/integration/test_live_viewer.py`.
- The install, test-suite and lint lines are what CI's own script runs: the test checks `.ci/run` runs them.
- Benchmarks are long measurements: the test checks each script exists and accepts the README's flags (`--help`).
- Tools of other stacks (`ros2`, `rviz2`, `rerun`) are not run; `gdalinfo moon.tif` is checked with rasterio
  (GDAL's Python binding): the file opens, on the Moon's south polar stereographic projection.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from psrmap_common.session import free_port

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PSRMAP = [sys.executable, "-m", "psrmap"]
EXTERNAL = ("ros2", "rviz2", "rerun")  # another stack's tools: not installed here, not run


@dataclass(frozen=True)
class Command:
    section: str  # the README heading the command is under
    text: str  # as written (continuations joined, comment dropped)
    argv: tuple[str, ...]
    background: bool  # ends with `&`


def readme_commands(text: str) -> list[Command]:
    """Every command of the README's ```bash blocks, `&&` chains split, in document order."""
    out: list[Command] = []
    section, block = "", None
    for line in text.splitlines():
        if block is None and line.startswith("#"):
            section = line.lstrip("#").strip()
        if line.startswith("```"):
            if block is None and line.strip() == "```bash":
                block = []
            elif block is not None:
                out.extend(_block_commands(section, block))
                block = None
            continue
        if block is not None:
            block.append(line)
    return out


def _block_commands(section: str, lines: list[str]) -> list[Command]:
    joined = re.sub(r"\\\n\s*", " ", "\n".join(lines))
    out = []
    for line in joined.splitlines():
        lex = shlex.shlex(line, posix=True, punctuation_chars="&")
        lex.whitespace_split = True
        lex.commenters = "#"
        words, part = [], []
        for tok in lex:
            if tok in ("&&", "&"):
                words.append((part, tok == "&"))
                part = []
            else:
                part.append(tok)
        if part:
            words.append((part, False))
        for argv, background in words:
            if argv:
                out.append(Command(section, line.split(" #")[0].strip(), tuple(argv), background))
    return out


@dataclass
class Network:
    """The loopback ports standing in for the README's endpoints in one section."""

    base: int = 0
    local: int = 0

    def fresh(self) -> None:
        self.base = self.local = free_port()

    def sub(self, word: str) -> str:
        for host in ("0.0.0.0", "base"):
            word = word.replace(f"tcp/{host}:7447", f"tcp/127.0.0.1:{self.base}")
        return word.replace("tcp/127.0.0.1:7447", f"tcp/127.0.0.1:{self.local}")


@dataclass
class Readme:
    tmp: Path
    net: Network = field(default_factory=Network)
    env: dict[str, str] = field(default_factory=dict)
    procs: list[subprocess.Popen] = field(default_factory=list)
    section: str = ""
    started_network: bool = False
    log: list[str] = field(default_factory=list)
    pool: ThreadPoolExecutor = field(default_factory=lambda: ThreadPoolExecutor(1))
    mission: Future[Path] = field(default_factory=Future)  # shared by the groups: the mission's run folder

    def cwd(self) -> Path:
        d = self.tmp / (re.sub(r"[^A-Za-z0-9]+", "-", self.section).strip("-").lower() or "top")
        d.mkdir(exist_ok=True)
        return d

    def environ(self, **extra: str) -> dict[str, str]:
        env = {**os.environ, **self.env, **extra}
        env["XDG_STATE_HOME"] = str(self.cwd() / "state")  # each section's scout outboxes apart
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])
        env.pop("DISPLAY", None)
        env.pop("WAYLAND_DISPLAY", None)
        return env

    # -- running -----------------------------------------------------------------------------------------
    def run(self, cmd: Command) -> None:
        if cmd.section != self.section:
            self.section, self.started_network = cmd.section, False
        argv = list(cmd.argv)
        if argv[0] == "export" and "=" in argv[1]:
            k, v = argv[1].split("=", 1)
            self.env[k] = v
            self.log.append(f"{cmd.text}  -> set")
            return
        if argv[0] in EXTERNAL:
            self.log.append(f"{cmd.text}  -> not run (another stack's tool)")
            return
        if argv[0] == "gdalinfo":
            return self._gdalinfo(argv[1])
        if argv[:3] == ["python3", "-m", "pip"] or argv[:3] == ["python3", "-m", "pytest"]:
            return self._ci(cmd)
        if argv[0] in ("ruff", "mypy"):
            return self._ci(cmd)
        if argv[0] == "python3" and argv[1].startswith("benchmarks/"):
            return self._benchmark(cmd)
        if argv[:3] == ["python3", "-m", "psrmap"]:
            argv = ["psrmap", *argv[3:]]
        if argv[0] != "psrmap":
            pytest.fail(f"README command the test does not know how to run: {cmd.text!r} ({cmd.section})")
        self._psrmap(cmd, argv[1:])

    def _psrmap(self, cmd: Command, args: list[str]) -> None:
        sub = args[0]
        starts_network = sub == "router" and "--connect" not in args or args[:2] == ["secure", "init"]
        if starts_network and not self.started_network:
            self.net.fresh()
            self.started_network = True
        elif sub == "router":  # a router on another host, meshed to the base
            self.net.local = free_port()
        args = [self.net.sub(a) for a in args]
        if "runs/<ts>" in args:  # the mission's group sets it, or says why it never ran (_run_group)
            run_dir = self.mission.result(timeout=900)
            args = [str(run_dir) if a == "runs/<ts>" else a for a in args]
        if "--viewer" in args or "--connect-viewer" in args:
            return self._viewer(cmd, args)
        if sub in ("scout", "evaluate") and "--sim-seconds" not in args:
            args += ["--sim-seconds", "2"]
        if sub == "mission":
            args += ["--scouts", "1", "--sim-seconds", "2"]
        if sub == "ros2":
            args += ["--once"]
        if "--dem" in args:
            _write_dem(self.cwd() / args[args.index("--dem") + 1])
        if cmd.background or sub in ("router", "server"):
            return self._background(cmd, args)
        if sub == "mission":  # the longest command: it runs beside the others, `runs/<ts>` waits for it
            assert self.mission.set_running_or_notify_cancel(), "the README runs one mission"
            self.pool.submit(self._mission, cmd, args, self.cwd(), self.environ())
            return
        self._foreground(cmd, args, self.cwd(), self.environ())

    def _foreground(self, cmd: Command, args: list[str], cwd: Path, env: dict[str, str]) -> Path:
        sub = args[0]
        t0 = time.monotonic()
        res = subprocess.run([*PSRMAP, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
                             check=False)  # fmt: skip
        took = time.monotonic() - t0
        if res.returncode == 1 and sub == "plan" and "is impassable" in res.stderr:  # the 2 s map's answer
            self.log.append(f"{cmd.text}  -> exit 1 in {took:.1f} s (2 s map): {_last_line(res.stderr)}")
            return cwd
        assert res.returncode == 0, f"`{cmd.text}` ({cmd.section}) as `psrmap {' '.join(args)}` failed:\n" + (
            res.stdout[-1500:] + res.stderr[-3000:]
        )
        self.log.append(f"{cmd.text}  -> exit 0 in {took:.1f} s: {_last_line(res.stdout)}")
        return max((cwd / "runs").iterdir()) if sub == "mission" else cwd

    def _mission(self, cmd: Command, args: list[str], cwd: Path, env: dict[str, str]) -> None:
        try:
            self.mission.set_result(self._foreground(cmd, args, cwd, env))
        except BaseException as exc:  # handed to whoever waits for the run folder
            self.mission.set_exception(exc)

    def _background(self, cmd: Command, args: list[str]) -> None:
        log = self.cwd() / f"bg{len(self.procs)}.log"
        with log.open("w") as out:  # a file, not a pipe: a chatty server never blocks on a full pipe
            p = subprocess.Popen([*PSRMAP, *args], cwd=self.cwd(), env=self.environ(), stdout=out,
                                 stderr=subprocess.STDOUT, start_new_session=True)  # fmt: skip
        self.procs.append(p)
        deadline = time.monotonic() + 120  # a loaded machine: starting a server takes a while
        while time.monotonic() < deadline and p.poll() is None:
            up = [ln for ln in log.read_text().splitlines() if '"up"' in ln]
            if up:
                self.log.append(f"{cmd.text}  -> up: {up[0].strip()}")
                return
            time.sleep(0.1)
        pytest.fail(f"`{cmd.text}` ({cmd.section}) never said it was up:\n{log.read_text()[-3000:]}")

    def _viewer(self, cmd: Command, args: list[str]) -> None:
        args = [re.sub(r":9876/", f":{free_port()}/", a) for a in args]  # nothing listens there
        t0 = time.monotonic()
        res = subprocess.run([*PSRMAP, *args], cwd=self.cwd(), env=self.environ(), capture_output=True,
                             text=True, timeout=60, check=False)  # fmt: skip
        took = time.monotonic() - t0
        want = "--viewer: no display here" if "--viewer" in args else "no Rerun viewer answers at"
        assert res.returncode == 2 and want in res.stderr, f"`{cmd.text}`: {res.stderr[-2000:]}"
        assert res.stderr.count("\n") == 1, res.stderr  # one line, no traceback
        # how fast the check itself is (no 25 s gRPC wait): tests/integration/test_cli_errors.py, in-process;
        # here the wall time is mostly importing the simulator on a shared machine
        self.log.append(f"{cmd.text}  -> (no display) exit 2 in {took:.1f} s: {res.stderr.strip()[:100]}…")

    def _ci(self, cmd: Command) -> None:
        def norm(argv: tuple[str, ...]) -> tuple[str, ...]:
            argv = argv[2:] if argv[:2] == ("python3", "-m") else argv
            # `pip install -e .` is covered by CI's `pip install -e ".[test]"` (the same package, plus extras)
            return ("pip", "install", "-e", ".") if argv[:3] == ("pip", "install", "-e") else argv

        ci = {norm(c.argv) for c in _block_commands("ci", (ROOT / ".ci" / "run").read_text().splitlines())}
        assert norm(cmd.argv) in ci, f"README's `{shlex.join(cmd.argv)}` is not what CI runs (.ci/run)"
        self.log.append(f"{shlex.join(cmd.argv)}  -> run by .ci/run")

    def _benchmark(self, cmd: Command) -> None:
        script, flags = cmd.argv[1], [a for a in cmd.argv[2:] if a.startswith("--")]
        res = subprocess.run([sys.executable, script, "--help"], cwd=ROOT, env=self.environ(),
                             capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
        assert res.returncode == 0, f"{script} --help: {res.stderr[-2000:]}"
        missing = [f for f in flags if f not in res.stdout]
        assert not missing, f"{script} does not take {missing} (README: `{cmd.text}`)"
        self.log.append(f"{cmd.text}  -> not run (a long measurement); --help takes {flags}")

    def _gdalinfo(self, path: str) -> None:
        import rasterio

        with rasterio.open(self.cwd() / path) as ds:
            crs, bands = ds.crs.to_wkt(), ds.count
        assert "Moon" in crs and "Polar_Stereographic" in crs, crs  # (its identifier: tests/psrmap_interop)
        self.log.append(
            f"gdalinfo {path}  -> checked with rasterio: {bands} bands, Moon south polar stereographic"
        )

    def stop(self) -> None:
        """Stop this group's background processes (SIGINT, then SIGKILL after 10 s)."""
        for p in self.procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGINT)
        for p in self.procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def _last_line(out: str) -> str:
    lines = [ln for ln in out.strip().splitlines() if ln.strip()]
    return (lines[-1][:120] + ("…" if len(lines[-1]) > 120 else "")) if lines else "(no output)"


def _write_dem(path: Path) -> None:
    """A small Moon polar-stereographic GeoTIFF (5 m/px, a gentle slope) around the README's window
    `--dem-window=12000,-8000` (the scene's south-west corner; the scene is 20 m on a side)."""
    import numpy as np
    import rasterio
    from rasterio.crs import CRS
    from rasterio.transform import Affine

    x0, y0, px, n = 11_900.0, -7_900.0, 5.0, 40  # upper-left corner [m], pixel [m], pixels per side
    cols, _ = np.meshgrid(np.arange(n), np.arange(n))
    z = 1500.0 + np.tan(np.radians(3.0)) * (cols + 0.5) * px
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32",
                       crs=CRS.from_string("IAU_2015:30135"), transform=Affine(px, 0.0, x0, 0.0, -px, y0),
                       nodata=-9999.0) as ds:  # fmt: skip
        ds.write(z.astype("float32"), 1)


def test_the_readme_parser_finds_the_commands() -> None:
    cmds = readme_commands(README.read_text())
    texts = [" ".join(c.argv) for c in cmds]
    assert "python3 -m psrmap mission" in texts  # the first of the two commands, after its `&&`
    assert any(c.background for c in cmds)
    assert any("--route 1.5,1.5 18.5,18.5" in t for t in texts)  # quoted words and a continuation line


def _uses_network(cmd: Command) -> bool:
    return any("tcp/" in a or a == "--zenoh-config" for a in cmd.argv)


def _starts_network(cmd: Command) -> bool:
    a = cmd.argv[cmd.argv.index("psrmap") + 1 :] if "psrmap" in cmd.argv else ()
    return a[:1] == ("router",) and "--connect" not in a or a[:2] == ("secure", "init")


def readme_groups(cmds: list[Command]) -> list[list[Command]]:
    """The commands in groups that can run side by side: a section that starts its own network or uses none
    opens a group; a section that uses a network without starting one joins the group before it."""
    groups: list[list[Command]] = []
    by_section: dict[str, list[Command]] = {}
    for c in cmds:
        by_section.setdefault(c.section, []).append(c)
    for section in by_section.values():
        own = any(_starts_network(c) for c in section) or not any(_uses_network(c) for c in section)
        if own or not groups:
            groups.append([])
        groups[-1].extend(section)
    return groups


def _exports(cmds: list[Command]) -> dict[str, str]:
    return dict(c.argv[1].split("=", 1) for c in cmds if c.argv[0] == "export" and "=" in c.argv[1])


def _runs_the_mission(cmd: Command) -> bool:
    a = cmd.argv[cmd.argv.index("psrmap") + 1 :] if "psrmap" in cmd.argv else ()
    return a[:1] == ("mission",) and "--viewer" not in a and "--connect-viewer" not in a


def _run_group(r: Readme, cmds: list[Command]) -> Readme:
    try:
        for cmd in cmds:
            r.run(cmd)
    finally:
        r.stop()
        started = r.mission.running() or r.mission.done()
        if any(_runs_the_mission(c) for c in cmds) and not started:  # it stopped before its mission started
            r.mission.set_running_or_notify_cancel()
            r.mission.set_exception(RuntimeError("the README's mission never ran (its section failed first)"))
    return r


@pytest.mark.slow
def test_every_readme_command_runs(tmp_path: Path) -> None:
    cmds = readme_commands(README.read_text())
    assert len(cmds) > 30
    groups = readme_groups(cmds)
    assert [c for g in groups for c in g] == cmds  # every command, in document order within its group
    mission: Future[Path] = Future()
    t0 = time.monotonic()
    env: dict[str, str] = {}
    runners = []
    with ThreadPoolExecutor(1) as mission_lane, ThreadPoolExecutor(2) as lanes:
        for g in groups:
            r = Readme(tmp_path, env=dict(env), pool=mission_lane, mission=mission)
            env |= _exports(g)
            runners.append((r, lanes.submit(_run_group, r, g)))
        try:
            for _, fut in runners:
                fut.result()  # a group's failure fails the test (the others still finish and stop)
            if mission.running() or mission.done():
                mission.result()
        finally:
            print(f"\nREADME: {len(cmds)} commands in {len(groups)} groups in {time.monotonic() - t0:.0f} s")
            print("\n".join(line for r, _ in runners for line in r.log))
