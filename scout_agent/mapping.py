"""Estimators and map deltas hooked into the scout's run loop.

`Mapper` takes one `ProprioSample` per tick, runs the `EstimatorPipeline`, accumulates per-cell statistics
and every `1/delta_hz` seconds of scout time flushes them as one delta: merged into the scout's own
`LocalMap`, and published to the map service when a `ScoutPublisher` is given. The local map is therefore,
cell for cell, what a server merges from the same deltas.

`add_mapping_arguments(parser)` and `attach_mapping(args, run_config)` are what `psrmap scout` calls:
`--map ID --connect ENDPOINT` publishes while walking; without `--connect` the scout keeps a local map,
`--save-map PATH.npz` writes it (map_region layout, `scout_agent.cells.load_npz` reads it back).
"""

from __future__ import annotations

import argparse
import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from protocol.keys import id_arg
from scout_agent.cells import CellAccumulator, LocalMap
from scout_agent.estimators import EstimatorPipeline, PipelineConfig, TickEstimates, record
from scout_agent.estimators.feet import PinocchioFeet
from scout_agent.signals import ProprioSample

__all__ = [
    "Mapper",
    "MapperConfig",
    "MappingSession",
    "add_mapping_arguments",
    "attach_mapping",
    "default_pipeline_config",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MapperConfig:
    res: float = 0.4  # cell size [m]
    delta_hz: float = 5.0  # deltas per second of scout time
    pipeline: PipelineConfig | None = None  # None: `default_pipeline_config()`


def default_pipeline_config(feet: PinocchioFeet, **changes: Any) -> PipelineConfig:
    """Pipeline defaults with the simulated model's mass and CoM (mass declared in robot/constants)."""
    return replace(
        PipelineConfig(
            mass_kg=feet.total_mass_kg, com_offset_base=(float(feet.com_home_base[0]), float(feet.com_home_base[1]), float(feet.com_home_base[2]))
        ),
        **changes,
    )


class Mapper:
    """Per tick: estimates → cell statistics → (every 1/delta_hz s) a delta to the local map and publisher."""

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
        self.local = LocalMap(config.res)
        self.publisher = publisher
        self.deltas = 0
        self.slip_events = 0
        self._period = 1.0 / config.delta_hz
        self._next_flush: float | None = None
        self._t = 0.0

    def update(self, sample: ProprioSample) -> TickEstimates:
        est = self.pipeline.update(sample)
        record(est, self.acc)
        self.slip_events += sum(est.slip.event)
        self._t = sample.t
        if self._next_flush is None:
            self._next_flush = sample.t + self._period
        elif sample.t >= self._next_flush:
            self._next_flush += self._period
            self.flush()
            if self.publisher is not None:
                self.publisher.poll()
        return est

    def flush(self) -> int | None:
        """Send what accumulated as one delta; returns its seq (publishing) or None.

        With a publisher whose unacknowledged buffer is full, the statistics keep accumulating and leave
        with a later delta, so nothing is lost and the local map stays equal to what the server merges.
        """
        if self.publisher is not None and self.publisher.full:
            return None
        layers = self.acc.flush()
        if not layers:
            return None
        self.local.merge(layers)
        self.deltas += 1
        if self.publisher is not None:
            return self.publisher.send(layers, self._t)
        return None

    def close(self, ack_timeout_s: float = 10.0) -> dict:
        """Flush the rest, wait for acks (publishing), return a summary."""
        if self.publisher is not None and self.publisher.full:
            self.publisher.wait_acked(ack_timeout_s)
        self.flush()
        out: dict[str, Any] = {
            "deltas": self.deltas,
            "slip_events": int(self.slip_events),
            "res": self.config.res,
            "cells": {k: len(self.local.cells(k)["ix"]) for k in ("elevation", "slip", "cot")},
        }
        if self.publisher is not None:
            out["all_acked"] = bool(self.publisher.wait_acked(ack_timeout_s))
            out["publisher"] = self.publisher.stats()
        return out


def add_mapping_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("mapping")
    g.add_argument("--map", metavar="ID", type=id_arg("map"), help="map id to publish to (with --connect)")
    g.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint of the map service's router, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    g.add_argument(
        "--res", type=float, default=0.4, help="map cell size [m] (default 0.4; must match the server)"
    )
    g.add_argument("--delta-hz", type=float, default=5.0, help="cell deltas per second (default 5)")
    g.add_argument("--save-map", metavar="PATH.npz", help="save the scout's local map (map_region layout)")
    g.add_argument("--no-map", action="store_true", help="walk without estimators or map")
    g.add_argument("--outbox", metavar="PATH.db",
                   help="SQLite outbox keeping each delta until acked (default "
                        "$XDG_STATE_HOME/psrmap/outbox-<map>-<scout>.db; 'none': memory only)")
    g.add_argument("--zenoh-config", metavar="FILE",
                   help="Zenoh config with this scout's credentials (`psrmap secure init`)")
    g.add_argument("--resume", action="store_true",
                   help="first resend the deltas an earlier run of this scout left unacknowledged in the outbox")


class MappingSession:
    """What `attach_mapping` returns: a context manager whose `on_tick` feeds `run_scout` (after any other
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

    def on_tick(self, sample: ProprioSample, truth: object = None, sim: object = None) -> None:
        if self.chained is not None:
            self.chained(sample, truth, sim)
        if self.mapper is not None:
            est = self.mapper.update(sample)
            if self.on_estimates is not None:
                self.on_estimates(est)

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


def attach_mapping(
    args: argparse.Namespace, run_config: Any, on_tick: Any | None = None, on_estimates: Any | None = None
) -> MappingSession:
    """Build the scout's mapping from parsed `add_mapping_arguments` options; `on_tick` (optional) is an
    existing per-tick callback to chain, `on_estimates` receives each tick's estimates. With `--no-map` the
    session only forwards to `on_tick`."""
    if getattr(args, "no_map", False):
        return MappingSession(None, None, None, on_tick)
    parser = getattr(args, "_parser", None)

    def err(msg: str) -> None:
        if parser is not None:
            parser.error(msg)
        raise SystemExit(f"error: {msg}")

    if args.connect and not args.map:
        err("--connect needs --map ID (the map to publish to)")
    if args.map and not args.connect:
        err("--map needs --connect ENDPOINT (the map service's router), e.g. tcp/127.0.0.1:7447")
    if not args.res > 0:
        err(f"--res {args.res}: need a cell size > 0 [m]")
    if not args.delta_hz > 0:
        err(f"--delta-hz {args.delta_hz}: need > 0")
    publisher = None
    if args.connect:
        from scout_agent.outbox import default_outbox_path
        from scout_agent.publisher import ScoutPublisher

        box = getattr(args, "outbox", None)
        outbox = None if box == "none" else (box or default_outbox_path(args.map, run_config.scout_id))
        try:
            publisher = ScoutPublisher(args.map, run_config.scout_id, args.res, args.connect, outbox=outbox,
                                       resume=getattr(args, "resume", False),
                                       zenoh_config_file=getattr(args, "zenoh_config", None))
        except (ConnectionError, ValueError) as exc:
            err(str(exc))
    mapper = Mapper(MapperConfig(res=args.res, delta_hz=args.delta_hz), publisher=publisher)
    return MappingSession(mapper, publisher, args.save_map, on_tick, on_estimates)
