"""The mission's configuration: `MissionConfig` (map, terrain, scouts, planner), read from TOML and checked.

`load_config(path)` reads `psrmap/mission_default.toml` or a user file (unknown keys and bad values are
`MissionError`s naming what would be valid), `validate` checks a config built in code, `with_scouts(cfg, n)`
keeps or adds scouts.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from protocol.keys import validate_id
from psrmap.errors import PsrmapError
from psrmap_common.defaults import DEFAULT_DELTA_HZ, DEFAULT_MAP_ID, DEFAULT_RES_M, DEFAULT_SEED, DEFAULT_TILE

__all__ = [
    "DRIFT_KEYS",
    "MissionConfig",
    "MissionError",
    "SCENES",
    "ScoutPlan",
    "UNKNOWN_POLICIES",
    "field_scouts",
    "route_seconds",
    "load_config",
    "validate",
    "with_scouts",
]


DRIFT_KEYS = (
    "drift_xy_m",
    "drift_xy_pct",
    "drift_z_m",
    "drift_yaw_deg",
    "state_source",
    "sensors",
    "localization",
    "pos_error_max_m",
    "pos_error_final_m",
    "yaw_error_max_deg",
    "nees_pos_mean",
    "inside_3sigma_frac",
    "height_error_max_m",
    "nees_height_mean",
    "height_inside_3sigma_frac",
)


SCENES = ("lunar", "ramps")


UNKNOWN_POLICIES = ("forbid", "penalty", "infer")


class MissionError(PsrmapError, ValueError):
    """A mission config or flag that cannot run; the message names what would have been valid."""


@dataclass(frozen=True)
class ScoutPlan:
    """One scout: id, start pose (x [m], y [m], yaw [rad]) in the map frame, goal (x, y), waypoints."""

    id: str
    start: tuple[float, float, float]
    goal: tuple[float, float]
    via: tuple[tuple[float, float], ...] = ()

    def route(self) -> list[tuple[float, float]]:
        """The route as map-frame points, start to goal."""
        return [(self.start[0], self.start[1]), *self.via, self.goal]


@dataclass(frozen=True)
class MissionConfig:
    """Everything a mission needs; `load_config` reads it from TOML, flags replace fields once."""

    map: str = DEFAULT_MAP_ID
    res: float = DEFAULT_RES_M  # cell size [m]
    sim_seconds: float = 150.0  # cap on each scout's walk [s]
    field_m: float = (
        20.0  # lunar field side [m] ([mission] field); routes of the default scouts scale with it
    )
    speed: float = 0.2  # [m/s]
    rate_hz: float = DEFAULT_DELTA_HZ  # deltas per second per scout
    out: str = "runs"
    scene: str = "lunar"
    seed: int = DEFAULT_SEED
    slope: float = 15.0  # ramps scene only [deg]
    slippery_patches: int = 4
    holdable_patches: bool = (
        False  # lunar: patches keep μ ≥ tan(slope) + 0.02 (the paper's field); default: regolith draw
    )
    scouts: tuple[ScoutPlan, ...] = ()
    plan_from: tuple[float, float] = (2.0, 2.0)
    plan_to: tuple[float, float] = (18.0, 18.0)
    unknown: str = "penalty"
    weights: dict[str, float] = field(default_factory=dict)
    rrd: bool = True  # write Rerun recordings
    secure: bool = True  # per-run credentials + router ACL (psrmap secure init) for every component
    zenoh_config: str | None = None  # an existing secure folder's router.json5 (agents' files beside it)
    timeout_s: float = 900.0  # the whole mission gives up after this long [s wall clock]
    shards: int = 1  # map-server shards (protocol.partition; 1: one server, contract v1 keys)
    tile: int = (
        DEFAULT_TILE  # the servers' storage tile [cells per side, a power of two]: also the unit a shard owns
    )
    # where the map frame's origin is on the Moon: latitude, longitude [deg], heading of the map's +x axis from
    # the south polar stereographic easting [deg]; exports are then in IAU_2015:30135 (`psrmap export`)
    origin: tuple[float, float, float] | None = None


def _pair(v: Any, what: str) -> tuple[float, float]:
    try:
        if isinstance(v, str) or any(isinstance(c, bool | str) for c in v):
            raise TypeError
        x, y = (float(c) for c in v)
    except (TypeError, ValueError):
        raise MissionError(f"{what} = {v!r}: need [x, y] in metres") from None
    return (x, y)


def _scout(d: dict[str, Any], i: int) -> ScoutPlan:
    where = f"[[scouts]] #{i + 1}"
    try:
        sid = str(d["id"])
        start = tuple(float(c) for c in d["start"])
        goal = _pair(d["goal"], f"{where} goal")
    except KeyError as exc:
        raise MissionError(
            f"{where}: missing {exc.args[0]!r}; a scout needs id, start, goal (via optional)"
        ) from None
    except (TypeError, ValueError):
        raise MissionError(f"{where}: start must be [x, y, yaw]") from None
    if len(start) != 3:
        raise MissionError(f"{where} start = {d['start']!r}: need [x, y, yaw]")
    via = tuple(_pair(p, f"{where} via") for p in d.get("via", []))
    return ScoutPlan(sid, (start[0], start[1], start[2]), goal, via)


_MISSION_KEYS = (
    "map", "res", "sim_seconds", "speed", "rate_hz", "out", "secure", "origin", "shards", "tile", "field",
)  # fmt: skip


def field_scouts(field_m: float) -> tuple[ScoutPlan, ...]:
    """The default scouts of a `field_m` mission: routes that span the field and cross. scout1 walks the
    diagonal south-west → north-east, scout2 the same diagonal the other way (from their meeting in the middle
    on, each walks where the other has just mapped), scout3 the `east` route (along the south, then north:
    it shares the corners' ground with both). Ends are the generator's flattened route ends."""
    from scout_agent.sim.terrain import lunar_routes  # lazy: the terrain generator loads SciPy

    r = lunar_routes(field_m)
    (ax, ay), (bx, by) = r["direct"][0], r["direct"][-1]
    east = r["east"]
    yaw = math.atan2(by - ay, bx - ax)
    e_yaw = math.atan2(east[1][1] - east[0][1], east[1][0] - east[0][0])
    return (
        ScoutPlan("scout1", (ax, ay, yaw), (bx, by)),
        ScoutPlan("scout2", (bx, by, yaw - math.pi), (ax, ay)),
        ScoutPlan("scout3", (east[0][0], east[0][1], e_yaw), east[-1], tuple(east[1:-1])),
    )


def route_seconds(scouts: tuple[ScoutPlan, ...], speed: float) -> float:
    """A walking-time cap that follows the routes: 1.5 × the longest route at `speed`, plus 30 s."""
    longest = max(
        sum(math.dist(a, b) for a, b in zip(s.route()[:-1], s.route()[1:], strict=True)) for s in scouts
    )
    return round(1.5 * longest / speed + 30.0, 1)


_TERRAIN_KEYS = ("scene", "seed", "slope", "slippery_patches", "holdable_patches")


_PLANNER_KEYS = ("from", "to", "unknown", "weights")


_SCOUT_KEYS = ("id", "start", "goal", "via")


def _origin(v: Any, where: str) -> tuple[float, float, float] | None:
    if v is None:
        return None
    try:
        vals = [float(c) for c in v]
        if len(vals) == 2:
            vals.append(0.0)
        lat, lon, heading = vals
    except (TypeError, ValueError):
        raise MissionError(
            f"{where}: [mission] origin = {v!r}: need [lat, lon] or [lat, lon, heading] in degrees"
        ) from None
    if not -90.0 <= lat < -60.0:
        raise MissionError(
            f"{where}: [mission] origin latitude {lat}: the south polar projection needs -90 <= lat < -60"
        )
    return (lat, lon, heading)


MAX_SHARDS = 16


class _Table:
    """One TOML table of the mission file: typed reads that name the key, the section and the file."""

    def __init__(self, table: dict[str, Any], section: str, where: str) -> None:
        self.table, self.section, self.where = table, section, where

    def bad(self, key: str, need: str) -> MissionError:
        return MissionError(f"{self.where}: [{self.section}] {key} = {self.table[key]!r}: need {need}")

    def number(self, key: str, default: float) -> float:
        v = self.table.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise self.bad(key, "a finite number")
        return float(v)

    def integer(self, key: str, default: int, need: str = "an integer") -> int:
        v = self.table.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.bad(key, need)
        return v

    def text(self, key: str, default: str) -> str:
        v = self.table.get(key, default)
        if not isinstance(v, str):
            raise self.bad(key, "a string")
        return v

    def flag(self, key: str, default: bool) -> bool:
        v = self.table.get(key, default)
        if not isinstance(v, bool):
            raise self.bad(key, "true or false")
        return v

    def weights(self) -> dict[str, float]:
        from consumer_planner.cost_config import TERMS  # lazy: the planner package loads its numba kernels

        v = self.table.get("weights", {})
        if not isinstance(v, dict):
            raise self.bad("weights", f"a table {{ name = weight, ... }} with names in: {', '.join(TERMS)}")
        out: dict[str, float] = {}
        for name, w in v.items():
            if name not in TERMS:
                raise MissionError(
                    f"{self.where}: [{self.section}] weights: unknown term {name!r}; terms: {', '.join(TERMS)}"
                )
            if isinstance(w, bool) or not isinstance(w, int | float) or not (math.isfinite(w) and w >= 0):
                raise MissionError(
                    f"{self.where}: [{self.section}] weights.{name} = {w!r}: need a finite number >= 0"
                )
            out[name] = float(w)
        return out


def server_names(cfg: MissionConfig) -> list[str]:
    """The mission's map servers: `server`, or `server0`..`server<K-1>` for a sharded map."""
    return ["server"] if cfg.shards == 1 else [f"server{i}" for i in range(cfg.shards)]


def load_config(path: str | Path | None = None) -> MissionConfig:
    """The mission config from a TOML file (None: the embedded default `mission_default.toml`)."""
    if path is None:
        text = resources.files("psrmap").joinpath("mission_default.toml").read_text()
        where = "the embedded default mission"
    else:
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise MissionError(f"mission config {path}: {exc.strerror}") from None
        where = str(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MissionError(f"{where}: not valid TOML ({exc})") from None
    known = {"mission", "terrain", "scouts", "planner"}
    unknown = set(doc) - known
    if unknown:
        raise MissionError(f"{where}: unknown section(s) {sorted(unknown)}; sections: {sorted(known)}")
    m, t, p = doc.get("mission", {}), doc.get("terrain", {}), doc.get("planner", {})
    for section, table, keys in (
        ("mission", m, _MISSION_KEYS),
        ("terrain", t, _TERRAIN_KEYS),
        ("planner", p, _PLANNER_KEYS),
        *(("scouts", s, _SCOUT_KEYS) for s in doc.get("scouts", [])),
    ):
        if not isinstance(table, dict):
            raise MissionError(f"{where}: [{section}] must be a table")
        extra = set(table) - set(keys)
        if extra:
            raise MissionError(
                f"{where}: unknown key(s) {sorted(extra)} in [{section}]; keys: {', '.join(keys)}"
            )
    base = MissionConfig()
    mt, tt, pt = _Table(m, "mission", where), _Table(t, "terrain", where), _Table(p, "planner", where)
    scouts = doc.get("scouts", [])
    if not isinstance(scouts, list):
        raise MissionError(f"{where}: scouts must be an array of tables ([[scouts]] id, start, goal, via)")
    field_m = mt.number("field", base.field_m)
    if not 5.0 <= field_m <= 400.0:
        raise mt.bad("field", "a lunar field side in metres, 5–400")
    scaled = "field" in m and not scouts  # a field-sized mission with its default scouts
    if scaled:
        # the paper's patches are placed for its routes' walking directions; scout2 walks one backwards
        base = dataclasses.replace(base, slippery_patches=0)
    cfg = dataclasses.replace(
        base,
        map=mt.text("map", base.map),
        res=mt.number("res", base.res),
        sim_seconds=mt.number("sim_seconds", base.sim_seconds),
        speed=mt.number("speed", base.speed),
        rate_hz=mt.number("rate_hz", base.rate_hz),
        out=mt.text("out", base.out),
        secure=mt.flag("secure", base.secure),
        shards=mt.integer("shards", base.shards, f"an integer, 1..{MAX_SHARDS}"),
        tile=mt.integer("tile", base.tile, "an integer, a power of two (cells per tile side)"),
        scene=tt.text("scene", base.scene),
        seed=tt.integer("seed", base.seed),
        slope=tt.number("slope", base.slope),
        slippery_patches=tt.integer("slippery_patches", base.slippery_patches),
        holdable_patches=tt.flag("holdable_patches", base.holdable_patches),
        field_m=field_m,
        scouts=field_scouts(field_m) if scaled else tuple(_scout(s, i) for i, s in enumerate(scouts)),
        plan_from=_pair(
            p.get("from", (2.0, 2.0) if "field" in m else base.plan_from), f"{where}: [planner] from"
        ),
        plan_to=_pair(
            p.get("to", (field_m - 2.0,) * 2 if "field" in m else base.plan_to), f"{where}: [planner] to"
        ),
        unknown=pt.text("unknown", base.unknown),
        weights=pt.weights(),
        origin=_origin(m.get("origin"), where),
    )
    if "field" in m and "sim_seconds" not in m and cfg.scouts:  # the walking time follows the routes
        cfg = dataclasses.replace(cfg, sim_seconds=route_seconds(cfg.scouts, cfg.speed))
    try:
        validate(cfg)
    except MissionError as exc:
        raise MissionError(f"{where}: {exc}") from None
    return cfg


def validate(cfg: MissionConfig) -> None:
    """Raise `MissionError` naming the valid choices when the config cannot run."""
    from consumer_planner.cost_config import TERMS  # lazy: the planner package loads its numba kernels

    try:
        validate_id(cfg.map, "map")
    except ValueError as exc:
        raise MissionError(str(exc)) from None
    bad = {k: v for k, v in cfg.weights.items() if k not in TERMS or not (math.isfinite(v) and v >= 0)}
    if bad:
        raise MissionError(f"[planner] weights {bad}: names in {', '.join(TERMS)}, each a finite number >= 0")
    if cfg.seed < 0:
        raise MissionError(f"seed = {cfg.seed}: need an integer >= 0")
    if cfg.slippery_patches < 0:
        raise MissionError(f"slippery_patches = {cfg.slippery_patches}: need >= 0")
    if cfg.scene not in SCENES:
        raise MissionError(f"scene {cfg.scene!r}; scenes: {', '.join(SCENES)}")
    if cfg.unknown not in UNKNOWN_POLICIES:
        raise MissionError(f"unknown policy {cfg.unknown!r}; policies: {', '.join(UNKNOWN_POLICIES)}")
    if not cfg.scouts:
        raise MissionError("no scouts: give at least one [[scouts]] entry (id, start, goal)")
    ids = [s.id for s in cfg.scouts]
    for sid in ids:
        try:
            validate_id(sid, "scout id")
        except ValueError as exc:
            raise MissionError(str(exc)) from None
    if len(set(ids)) != len(ids):
        raise MissionError(f"scout ids must be unique, got {ids}")
    for name, v in (
        ("res", cfg.res),
        ("sim_seconds", cfg.sim_seconds),
        ("speed", cfg.speed),
        ("rate_hz", cfg.rate_hz),
    ):
        if not (v > 0 and math.isfinite(v)):
            raise MissionError(f"{name} = {v}: must be a finite number > 0")
    if not 1 <= cfg.shards <= MAX_SHARDS:
        raise MissionError(f"shards = {cfg.shards}: need 1 (one server) to {MAX_SHARDS} map-server shards")
    t = cfg.tile
    if t < 1 or t & (t - 1):
        raise MissionError(f"tile = {t}: need a power of two ≥ 1 (cells per tile side; default 64)")
    if cfg.zenoh_config:
        _credential_files(cfg)


def _credential_files(cfg: MissionConfig) -> dict[str, Path]:
    """The secure folder's file of every component, beside `cfg.zenoh_config` (the router's)."""
    router = Path(cfg.zenoh_config or "")
    names = [*server_names(cfg), "planner", *(s.id for s in cfg.scouts)]
    needed = {n: router.with_name(f"{n}.json5") for n in names}
    missing = [str(p) for p in [router, *needed.values()] if not p.is_file()]
    if missing:
        raise MissionError(
            f"--zenoh-config {router}: need the router's file and, beside it, one per component "
            f"(psrmap secure init --scouts <the mission's scout ids> --planners planner, and --servers "
            f"{','.join(server_names(cfg))} for {cfg.shards} shards); missing: "
            f"{', '.join(missing)}"
        )
    return needed


def with_scouts(cfg: MissionConfig, n: int) -> MissionConfig:
    """`cfg` with exactly `n` scouts: the first `n` of its list, more generated around the terrain if needed."""
    if n < 1:
        raise MissionError(f"--scouts {n}: need at least 1")
    scouts = list(cfg.scouts[:n])
    k = 0
    while len(scouts) < n:  # extra scouts start on a ring and walk through the centre
        a = 2 * math.pi * (k + 0.5) / max(n, 1)
        r = 7.0
        sx, sy = r * math.cos(a), r * math.sin(a)
        scouts.append(ScoutPlan(f"scout{len(scouts) + 1}", (sx, sy, a + math.pi), (-0.5 * sx, -0.5 * sy)))
        k += 1
    return dataclasses.replace(cfg, scouts=tuple(scouts))
