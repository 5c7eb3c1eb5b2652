"""protocol: the msgpack wire contract v1 shared by scouts, map servers and planners."""
