"""The robot's software as it would run on the Aliengo's own computer: `lowlevel.LowState` in, `lowlevel.LowCmd`
out (`software.OnboardSoftware`), with the drivers' processing of the readings (`drivers`).

It composes the robot-software packages beside it — `state_estimation`, `control`, and, in the run loop,
`localization`, `estimators`, `mapping`, `publisher` — none of which imports `scout_agent.sim` (the simulated
hardware and world); tests/scout_agent/test_structure.py fails if one does. This package imports nothing at
package level, so `from scout_agent.onboard.drivers import …` never drags the controller in.
"""
