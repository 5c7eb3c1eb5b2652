"""consumer_planner: rover-side queries of the shared map, costed paths and route comparison."""
