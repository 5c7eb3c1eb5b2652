"""The one root exception of consumer_planner; its messages name what would have been valid."""

from __future__ import annotations

__all__ = ["PlannerError"]


class PlannerError(Exception):
    """A planning request that cannot be served (bad input, no server, no such layer, ...)."""
