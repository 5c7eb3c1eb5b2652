"""Estimators and map deltas hooked into the scout's run loop.

`Mapper` takes one `ProprioSample` per tick, runs the `EstimatorPipeline`, accumulates per-cell statistics
and every `1/delta_hz` seconds of scout time flushes them as one delta: merged into the scout's own
`LocalMap`, and published to the map service when a `ScoutPublisher` is given. The local map is therefore,
cell for cell, what a server merges from the same deltas.

`open_mapping(...)` (with a `LinkConfig` to publish) is what `scout_agent.component.run` calls; the CLI's
`--map ID --connect ENDPOINT` (`add_mapping_arguments`, `publish_link`) publishes while walking; without
`--connect` the scout keeps a local map, `--save-map PATH.npz` writes it (`psrmap_mapcore.npz` reads it back).
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from protocol.keys import id_arg
from protocol.layers import HAZARD_REASONS
from psrmap_common.defaults import DEFAULT_DELTA_HZ, DEFAULT_RES_M
from psrmap_common.errors import UsageError
from psrmap_common.link import add_link_arguments, link_from_args
from scout_agent.cells import CellAccumulator, LocalMap
from scout_agent.control.reflex import Felt
from scout_agent.errors import ScoutConfigError
from scout_agent.estimators import EstimatorPipeline, PipelineConfig, TickEstimates, record
from scout_agent.estimators.feet import PinocchioFeet
from scout_agent.holding import HeldSamples, HoldConfig, PoseFix
from scout_agent.onboard.software import OnboardSoftware
from scout_agent.outbox import default_outbox_path
from scout_agent.publisher import ScoutPublisher
from scout_agent.signals import ProprioSample

__all__ = [
    "Mapper",
    "MapperConfig",
    "MappingSession",
    "position_variances",
    "LinkConfig",
    "add_mapping_arguments",
    "publish_link",
    "open_mapping",
    "default_pipeline_config",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MapperConfig:
    res: float = DEFAULT_RES_M  # cell size [m]
    delta_hz: float = DEFAULT_DELTA_HZ  # deltas per second of scout time
    pipeline: PipelineConfig | None = None  # None: `default_pipeline_config()`
    hold: HoldConfig = HoldConfig()  # how long samples wait for a pose fix before they leave (holding.py)


def default_pipeline_config(feet: PinocchioFeet, **changes: Any) -> PipelineConfig:
    """Pipeline defaults with the simulated model's mass and CoM (mass declared in robot/constants)."""
    return replace(
        PipelineConfig(
            mass_kg=feet.total_mass_kg,
            com_offset_base=(
                float(feet.com_home_base[0]),
                float(feet.com_home_base[1]),
                float(feet.com_home_base[2]),
            ),
        ),
        **changes,
    )


class Mapper:
    """Per tick: estimates → cell statistics → (every 1/delta_hz s) a delta to the local map and publisher.

    The statistics are held (`holding.HeldSamples`) until a pose fix (`fix`) corrects them or they are
    `config.hold.hold_m` behind, and leave in the chunks of one delta period they were gathered in."""

    def __init__(
        self,
        config: MapperConfig = MapperConfig(),
        publisher: Any | None = None,
        feet: PinocchioFeet | None = None,
    ) -> None:
        self.config = config
        self.feet = feet or PinocchioFeet()
        self.pipeline = EstimatorPipeline(self.feet, config.pipeline or default_pipeline_config(self.feet))
        self.acc = CellAccumulator(config.res)
        self.held = HeldSamples(self.acc, config.hold)
        self.local = LocalMap(config.res)
        self.publisher = publisher
        self.deltas = 0
        self.slip_events = 0
        self.hazards = 0
        self._period = 1.0 / config.delta_hz
        self._next_flush: float | None = None
        self._t = 0.0
        self._last_seq: int | None = None

    def update(
        self, sample: ProprioSample, var_xy_m2: float | None = None, var_z_m2: float | None = None
    ) -> TickEstimates:
        """One tick. `var_xy_m2`, `var_z_m2`: the scout's position variance now [m²] (horizontal: the larger
        axis of its estimate's covariance; vertical), recorded with each elevation foothold in the
        `placement` and `height` layers (after any fix's smoothing); None: no σ layers."""
        est = self.pipeline.update(sample)
        pos = sample.base.pos
        self.held.tick(sample.t, float(pos[0]), float(pos[1]), var_xy_m2, var_z_m2)
        record(est, self.held)
        self.slip_events += sum(est.slip.event)
        self._t = sample.t
        if self._next_flush is None:
            self._next_flush = sample.t + self._period
        elif sample.t >= self._next_flush:
            self._next_flush += self._period
            self.held.cut()
            self._send(self.held.chunks() if self.config.hold.hold_m <= 0 else self.held.due())
            if self.acc.pending:  # hazards leave at once; what a full publisher kept back, now
                self._flush_at(self._t)
            if self.publisher is not None:
                self.publisher.poll()
        return est

    def use_accumulator(self, acc: CellAccumulator) -> None:
        """Accumulate into `acc` from now on (e.g. one that also records every sample): the held samples
        leave into it too."""
        self.acc = acc
        self.held.acc = acc

    def fix(self, fix: PoseFix) -> None:
        """A pose fix the localizer fused: spread it back over the held samples and send them; a fix that
        states the walk's datum (`PoseFix.height_profile`) sends only those `hold_m` behind: the next such fix
        revises the rest again with more of the walk behind it (holding.py)."""
        self.held.correct(fix)
        self._send(self.held.chunks() if fix.height_profile is None else self.held.due())

    def _send(self, chunks) -> None:
        """One delta per released chunk, stamped with its newest sample's time."""
        for t in chunks:
            self._flush_at(t)

    def record_hazard(self, x: float, y: float, reasons: tuple[str, ...]) -> None:
        """One hazard report at (x, y) [m] into the `hazard` layer (leaves with the next delta)."""
        bad = set(reasons) - set(HAZARD_REASONS)
        if bad:
            raise ScoutConfigError(
                f"hazard reasons {sorted(bad)} unknown; reasons: {', '.join(HAZARD_REASONS)}"
            )
        self.acc.add("hazard", x, y, n=1.0, **{r: 1.0 for r in reasons})
        self.hazards += 1

    def flush(self) -> int | None:
        """Send everything held and accumulated, one delta per held chunk; returns the last seq sent
        (publishing) or None.

        With a publisher whose unacknowledged buffer is full, the statistics keep accumulating and leave
        with a later delta, so nothing is lost and the local map stays equal to what the server merges.
        """
        self._last_seq = None
        self._send(self.held.chunks())
        if self.acc.pending:  # what was kept back while the publisher was full, and hazards
            self._flush_at(self._t)
        return self._last_seq

    def _flush_at(self, t: float) -> None:
        """What the accumulator holds as one delta stamped `t` [s] (kept for a later one while the
        publisher's unacknowledged buffer is full)."""
        if self.publisher is not None and self.publisher.full:
            return
        layers = self.acc.flush()
        if not layers:
            return
        self.local.merge(layers)
        self.deltas += 1
        if self.publisher is not None:
            self._last_seq = self.publisher.send(layers, t)

    def close(self, ack_timeout_s: float = 10.0) -> dict:
        """Flush the rest, wait for acks (publishing), return a summary."""
        if self.publisher is not None and self.publisher.full:
            self.publisher.wait_acked(ack_timeout_s)
        self.flush()
        out: dict[str, Any] = {
            "deltas": self.deltas,
            "slip_events": int(self.slip_events),
            "hazard_reports": int(self.hazards),
            "res": self.config.res,
            "cells": {k: len(self.local.cells(k)["ix"]) for k in ("elevation", "slip", "cot")},
            "hold": {
                "hold_m": self.config.hold.hold_m,
                "fixes": self.held.fixes,
                "footholds_corrected": self.held.corrected,
                # per fix: height correction, the filter's height σ before and after [m]
                "fix_dz_sigma_before_after_m": [[round(v, 4) for v in f] for f in self.held.fix_log],
            },
        }
        if self.publisher is not None:
            out["all_acked"] = bool(self.publisher.wait_acked(ack_timeout_s))
            out["publisher"] = self.publisher.stats()
        return out


def add_mapping_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("mapping")
    g.add_argument("--map", metavar="ID", type=id_arg("map"), help="map id to publish to (with --connect)")
    add_link_arguments(g)
    g.add_argument(
        "--res",
        type=float,
        default=DEFAULT_RES_M,
        help=f"map cell size [m] (default {DEFAULT_RES_M}; must match the server)",
    )
    g.add_argument("--delta-hz", type=float, default=5.0, help="cell deltas per second (default 5)")
    g.add_argument("--save-map", metavar="PATH.npz", help="save the scout's local map (map_region layout)")
    g.add_argument("--no-map", action="store_true", help="walk without estimators or map")
    g.add_argument(
        "--outbox",
        metavar="PATH.db",
        help="SQLite outbox keeping each delta until acked (default "
        "$XDG_STATE_HOME/psrmap/outbox-<map>-<scout>.db; 'none': memory only)",
    )
    g.add_argument(
        "--resume",
        action="store_true",
        help="first resend the deltas an earlier run of this scout left unacknowledged in the outbox",
    )


def position_variances(robot: OnboardSoftware | None) -> tuple[float, float] | None:
    """(horizontal variance along the larger axis, vertical variance) [m²] of the robot's position estimate;
    None without a robot or on the exact state."""
    if robot is None or robot.on_exact_state:
        return None
    P = robot.estimator.position_covariance()
    return float(max(np.linalg.eigvalsh(P[:2, :2])[-1], 0.0)), float(max(P[2, 2], 0.0))


class MappingSession:
    """What `open_mapping` returns: a context manager whose `on_tick` feeds `run_scout` (after any other
    callback it chains), and whose exit flushes the last delta, waits for acks, saves the map and closes
    the Zenoh link; `summary` then holds the mapping figures (None without a map)."""

    def __init__(
        self,
        mapper: Mapper | None,
        publisher: Any | None,
        save_path: str | None,
        chained: Any | None = None,
        on_estimates: Any | None = None,
    ) -> None:
        self.mapper = mapper
        self.publisher = publisher
        self.save_path = save_path
        self.chained = chained
        self.on_estimates = on_estimates  # called with each tick's TickEstimates (e.g. the Rerun logger)
        self.summary: dict | None = None

    def on_tick(
        self, sample: ProprioSample, truth: object = None, robot: OnboardSoftware | None = None
    ) -> TickEstimates | None:
        """Feed one tick; returns its estimates (the pilot feels them), None without a map. `robot`: the
        software that made the sample; its estimator's position variances go with the tick's footholds into
        the placement and height layers (none without it, or on the exact state)."""
        if self.chained is not None:
            self.chained(sample, truth, robot)
        if self.mapper is None:
            return None
        var = position_variances(robot)
        est = self.mapper.update(sample, *var) if var is not None else self.mapper.update(sample)
        if self.on_estimates is not None:
            self.on_estimates(est)
        return est

    def on_fix(self, fix: PoseFix) -> None:
        """A pose fix the localizer fused (`run.run_scout`'s `on_fix`): the held samples are corrected."""
        if self.mapper is not None:
            self.mapper.fix(fix)

    def on_hazard(self, felt: Felt) -> None:
        """A hazard the pilot's reflex felt (`control.reflex.Felt`): into the map's `hazard` layer."""
        if self.mapper is not None:
            self.mapper.record_hazard(felt.x, felt.y, felt.reasons)

    def finish(self) -> dict | None:
        if self.mapper is None or self.summary is not None:
            return self.summary
        try:
            out = self.mapper.close()
            if self.save_path:
                out["saved"] = str(self.mapper.local.save_npz(Path(self.save_path)))
            self.summary = out
        finally:
            if self.publisher is not None:
                self.publisher.close()
        return self.summary

    def __enter__(self) -> MappingSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()


@dataclass(frozen=True)
class LinkConfig:
    """Publishing to the map service: map id, router endpoints, the SQLite outbox (a path, "none" for
    memory only, None for the default path), resend what an earlier run left unacked, credentials."""

    map_id: str
    connect: tuple[str, ...]
    outbox: str | None = None
    resume: bool = False
    zenoh_config: str | None = None


def open_mapping(
    scout_id: str,
    res: float,
    delta_hz: float,
    link: LinkConfig | None = None,
    save_map: str | None = None,
    on_tick: Any | None = None,
    on_estimates: Any | None = None,
) -> MappingSession:
    """The scout's mapping: estimators, cell deltas every 1/delta_hz s into the local map, published
    when `link` is given; `on_tick` (optional) is an existing per-tick callback to chain, `on_estimates`
    receives each tick's estimates. Raises ScoutConfigError / ScoutLinkError naming what would work."""
    if not res > 0:
        raise ScoutConfigError(f"res {res}: need a cell size > 0 [m]")
    if not delta_hz > 0:
        raise ScoutConfigError(f"delta_hz {delta_hz}: need > 0")
    publisher = None
    if link is not None:
        if not link.connect:
            raise ScoutConfigError(
                f"map {link.map_id!r} needs an endpoint of the map service's router, e.g. tcp/127.0.0.1:7447"
            )

        outbox = (
            None if link.outbox == "none" else (link.outbox or default_outbox_path(link.map_id, scout_id))
        )
        publisher = ScoutPublisher(link.map_id, scout_id, res, link.connect, outbox=outbox, resume=link.resume,
                                   zenoh_config_file=link.zenoh_config)  # fmt: skip
    mapper = Mapper(MapperConfig(res=res, delta_hz=delta_hz), publisher=publisher)
    return MappingSession(mapper, publisher, save_map, on_tick, on_estimates)


def publish_link(args: argparse.Namespace) -> LinkConfig | None:
    """The `--map/--connect/--outbox/--resume/--zenoh-config` options as a LinkConfig (None: no --connect and no
    router in --zenoh-config); raises UsageError when they do not go together."""
    link = link_from_args(args, required=False)
    if link.connect and not args.map:
        raise UsageError("--connect needs --map ID (the map to publish to)")
    if args.map and not link.connect:
        raise UsageError("--map needs --connect ENDPOINT (the map service's router), e.g. tcp/127.0.0.1:7447")
    if not link.connect:
        return None
    return LinkConfig(args.map, link.connect, getattr(args, "outbox", None), getattr(args, "resume", False),
                      link.zenoh_config)  # fmt: skip
