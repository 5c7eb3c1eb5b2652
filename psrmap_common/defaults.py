"""Every default that more than one entry point shares, defined once.

The CLIs (`psrmap scout`, `server`, `evaluate`, `mission`, `plan`), the component configs and the mission's TOML
read these names instead of repeating literals, and `tests/test_defaults.py` fails if two entry points disagree.
Planner weights live with the planner (`consumer_planner.cost_config.Weights`) and are used unchanged by the
mission.
"""

from __future__ import annotations

__all__ = ["DEFAULT_DELTA_HZ", "DEFAULT_MAP_ID", "DEFAULT_RES_M", "DEFAULT_SEED", "DEFAULT_TILE"]

DEFAULT_MAP_ID = "moon"  # map id of every entry point's map
DEFAULT_RES_M = 0.4  # map cell size [m] (the paper's)
DEFAULT_TILE = 64  # map servers' storage tile [cells per side]; also the unit a shard owns
DEFAULT_SEED = (
    7  # world seed (terrain, friction patches, sensor noise) of `psrmap mission`, `scout`, `evaluate`
)
DEFAULT_DELTA_HZ = 5.0  # cell deltas a scout sends per second of scout time
