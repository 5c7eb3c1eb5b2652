"""map_server: merges scouts' cell deltas exactly once into a shared, persisted multi-layer map."""
