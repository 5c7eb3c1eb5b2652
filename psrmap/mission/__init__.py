"""`psrmap mission`: a whole mission on one machine — router, map server, N scouts, a rover planner.

- `config.py`: `MissionConfig` from `mission_default.toml` or a user file, checked;
- `components.py`: what each component gets (a scout's `ScoutConfig`; the plan and the comparison);
- `processes.py`: a component's `run(config)` in a spawned process, its typed summary back through a pipe;
- `run.py`: `run_mission` — the router in-process, then server, scouts, planner; the run folder;
- `recording.py`: the components' recordings merged into `mission.rrd`;
- `report.py`: the summary as JSON and the printed report; `cli.py`: the command.

`run_mission` and `scout_config` are imported from their modules (`psrmap.mission.run`, `.components`):
they bring in every component, which `psrmap mission --help` does not need.
"""

from __future__ import annotations

from psrmap.mission.cli import register
from psrmap.mission.config import MissionConfig, MissionError, ScoutPlan, load_config, validate, with_scouts
from psrmap.mission.recording import merge_recordings, rerun_exe
from psrmap.mission.report import deltas_sent

__all__ = [
    "MissionConfig",
    "MissionError",
    "ScoutPlan",
    "deltas_sent",
    "load_config",
    "merge_recordings",
    "register",
    "rerun_exe",
    "validate",
    "with_scouts",
]
