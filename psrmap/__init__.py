"""psrmap: the command line and the mission that ties scouts, map server and planner together."""

__all__: list[str] = []
