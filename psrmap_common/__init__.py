"""common: what the services share that is not the wire contract.

`session` (the Zenoh session configuration every process opens: endpoints, mode, credentials, TLS),
`pathsearch` (optimal paths on cost grids: the planner's routes and the scout's detours) and `recording`
(the Rerun conventions: the `sim_time` timeline, colour scales, scout colours, viewer streaming). The contract itself (keys, messages, codec, layers, errors) is `protocol`, which imports
neither Zenoh nor Rerun.
"""
