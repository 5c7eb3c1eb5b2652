"""Non-foot contacts (trunk, thigh, calf on the ground) are flagged from proprioception alone."""

from __future__ import annotations

from scout_agent.mapping import Mapper, MapperConfig
from scout_agent.run import ScoutRunConfig, run_scout
from scout_agent.sim.terrain import LunarConfig, make_lunar


def test_tumbling_into_a_hazard_crater_is_flagged_as_non_foot_contact():
    crater = max(
        (c for c in make_lunar(LunarConfig(seed=0)).info["craters"] if c["hazard"]), key=lambda c: c["depth"]
    )
    x, y = crater["x"], crater["y"]
    mapper = Mapper(MapperConfig())
    truth_t: list[float] = []
    flagged_t: list[float] = []

    def on_tick(sample, truth, sim):
        est = mapper.update(sample)
        if truth.nonfoot_contacts > 0:
            truth_t.append(truth.t)
        if est.nonfoot:
            flagged_t.append(est.t)

    s = run_scout(
        ScoutRunConfig(scene="lunar", seed=0, start=(x - 2.0, y, 0.0), goal=(x + 2.5, y), sim_seconds=25),
        on_tick=on_tick,
        progress=False,
    )
    assert s["fell"]
    assert truth_t, "the simulator saw no non-foot contact in the fall"
    # flagged no later than 0.2 s after the body first touched the ground, and not while walking normally
    assert flagged_t and min(flagged_t) <= truth_t[0] + 0.2
    assert min(flagged_t) >= truth_t[0] - 1.0


def test_normal_walking_flags_no_non_foot_contact():
    mapper = Mapper(MapperConfig())
    flagged: list[float] = []

    def on_tick(sample, truth, sim):
        if mapper.update(sample).nonfoot:
            flagged.append(sample.t)
        assert truth.nonfoot_contacts == 0

    s = run_scout(
        ScoutRunConfig(scene="ramps", slope_deg=15.0, sim_seconds=12), on_tick=on_tick, progress=False
    )
    assert not s["fell"] and not flagged
