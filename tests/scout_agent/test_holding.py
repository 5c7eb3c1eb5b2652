"""Publish after correcting (scout_agent/holding.py): held samples are moved by a pose fix's smoothed
correction before they leave, in the chunks they were gathered in."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.layers import layer_derived, layer_value
from scout_agent.cells import CellAccumulator, LocalMap
from scout_agent.holding import HeldSamples, HoldConfig, PoseFix

RES = 0.4
SIGMA0_M2 = 0.02  # the launch datum's variance [m²]
Q_M2_PER_M = 0.001  # the filter's height variance grows by this per metre walked [m²/m]


def _walk(held: HeldSamples, local: LocalMap, x0: float, x1: float, err, per_chunk: int = 5) -> int:
    """Ticks every 0.05 m along y = 0.7 from x0 to x1 on flat ground z = 0, a foothold each tick, the estimate's
    height error `err(x)`; a chunk (delta) every `per_chunk` ticks, released chunks merged into `local`.
    Returns the deltas merged."""
    deltas = 0
    for k, x in enumerate(np.arange(x0, x1, 0.05)):
        held.tick(float(x), float(x), 0.7, 0.01, SIGMA0_M2 + Q_M2_PER_M * float(x))
        held.add_elevation(float(x), 0.7, float(err(x)))
        held.append("cot", (float(x), 0.7, 0.1, 0.05, 1.0))
        if k % per_chunk == per_chunk - 1:
            held.cut()
            for _ in held.due():
                local.merge(held.acc.flush())
                deltas += 1
    return deltas


def _heights(local: LocalMap) -> tuple[np.ndarray, np.ndarray]:
    cells = local.cells("elevation")
    x = (cells["ix"] + 0.5) * RES
    return x, layer_value("elevation", cells)


def test_a_fix_moves_the_held_track_onto_the_truth_and_later_samples_are_unaffected() -> None:
    # the height error: the datum's 0.2 m plus 0.01 m per metre walked, consistent with the filter's
    # variance (σ0² / q = e0 / k = 20 m): the smoother's share Δ·P(t)/P⁻(T) undoes it exactly
    def err(x):
        return 0.2 + 0.01 * x

    acc = CellAccumulator(RES)
    held = HeldSamples(acc, HoldConfig(hold_m=30.0))
    local = LocalMap(RES)
    assert _walk(held, local, 0.0, 20.0, err) == 0  # all held: nothing 30 m old yet
    before = SIGMA0_M2 + Q_M2_PER_M * 20.0
    fix = PoseFix(
        np.array([0.0, 0.0, -err(20.0)]), np.array([0.01, 0.01, before]), np.array([0.01, 0.01, 1e-4])
    )
    held.correct(fix)
    chunks = list(held.chunks())
    assert len(chunks) == 80  # 400 ticks, one chunk per 5: one delta each, as without holding
    assert chunks == sorted(chunks) and chunks[-1] == pytest.approx(19.95)
    local.merge(acc.flush())
    x, z = _heights(local)
    assert len(z) == 50 and np.abs(z).max() < 1e-9  # every held foothold landed on the ground
    # the height layer's σ is the smoothed one: far smaller near the fix than the filter's at the time
    cells = local.cells("height")
    sigma = layer_derived("height", "sigma", cells)
    assert sigma[-1] < 0.03 and np.sqrt(before) == pytest.approx(0.2)  # 0.02 m against the filter's 0.2 m
    assert sigma[0] > 2 * sigma[-1]  # the further from the fix, the less it knows
    assert held.corrected == 400 and held.pending == 0
    # after the fix the track continues from the corrected estimate: new samples are published as they are
    _walk(held, local, 20.0, 60.0, lambda x: 0.05)
    local.merge(acc.flush())
    x, z = _heights(local)
    late = x > 22.0
    assert np.allclose(z[late & (x < 29.6)], 0.05)  # released after 30 m without a fix, uncorrected


def test_without_a_fix_samples_leave_after_hold_m_in_their_chunks() -> None:
    acc = CellAccumulator(RES)
    held = HeldSamples(acc, HoldConfig(hold_m=5.0))
    local = LocalMap(RES)
    deltas = _walk(held, local, 0.0, 10.0, lambda x: 0.3)
    assert deltas == 20  # of 40 chunks, those whose last tick is ≥ 5 m behind
    x, z = _heights(local)
    assert x.max() <= 5.0 + 1e-9 and np.allclose(z, 0.3)
    assert sum(1 for _ in held.chunks()) == 20  # the rest leave at close, chunk by chunk
    local.merge(acc.flush())
    assert len(_heights(local)[0]) == 25 and held.pending == 0


def test_hold_zero_publishes_at_once_and_a_bad_hold_is_refused() -> None:
    acc = CellAccumulator(RES)
    held = HeldSamples(acc, HoldConfig(hold_m=0.0))
    local = LocalMap(RES)
    assert _walk(held, local, 0.0, 1.0, lambda x: 0.0) == 4
    with pytest.raises(ValueError, match="hold_m"):
        HoldConfig(hold_m=-1.0)
    with pytest.raises(ValueError, match="hold_m"):
        HoldConfig(hold_m=float("nan"))


def test_horizontal_fix_moves_every_held_layer() -> None:
    acc = CellAccumulator(RES)
    held = HeldSamples(acc, HoldConfig(hold_m=30.0))
    for x in np.arange(0.0, 2.0, 0.05):
        held.tick(float(x), float(x), 0.7, 0.04, 0.01)
        held.add_elevation(float(x), 0.7, 0.0)
        held.append("cot", (float(x), 0.7, 0.1, 0.05, 1.0))
    held.correct(
        PoseFix(np.array([0.0, 0.8, 0.0]), np.array([0.04, 0.04, 0.01]), np.array([0.01, 0.01, 0.01]))
    )
    list(held.chunks())
    layers = acc.flush()
    for name in ("elevation", "cot", "placement", "height"):
        iy = layers[name]["iy"]
        assert set(iy.tolist()) == {3}, name  # y 0.7 + 0.8 = 1.5 m: cell row 3, not 1
    # smoothed horizontal σ: 0.04 − 1²·(0.04 − 0.01) = 0.01 m² → σ 0.1 m
    placement = layers["placement"]
    assert np.allclose(placement["max"], 0.1)


def test_a_fix_that_states_the_walks_datum_revises_the_heights_an_earlier_fix_corrected() -> None:
    """The estimate's height 0.3 m off at launch and drifting 1 cm per metre walked; a first fix at 10 m
    takes off what it sees there but misjudges the datum by 0.2 m, a second at 20 m (the whole walk's DEM
    datum, height_track.py) states the datum along all of it: every held foothold lands on the ground,
    those before the first fix too. Spread by the smoother's gain alone, as a fix that only adds the newest
    evidence, the first fix's misjudged datum stays in them."""

    def err(x):
        return 0.3 + 0.01 * np.asarray(x)

    worst = {}  # the fixes come at the last tick, 9.95 and 19.95 m walked: the profiles' "now"
    c1 = -float(err(10.0)) + 0.2  # the first fix: 0.2 m short of the datum
    c2 = -(float(err(20.0)) + c1)
    for with_profile in (True, False):
        acc = CellAccumulator(RES)
        held = HeldSamples(acc, HoldConfig(hold_m=30.0))
        local = LocalMap(RES)
        _walk(held, local, 0.0, 10.0, err)
        held.correct(PoseFix(np.array([0.0, 0.0, c1]), np.array([0.01, 0.01, SIGMA0_M2 + 0.01]),
                             np.array([0.01, 0.01, 0.01]),
                             (lambda rel: -err(9.95 + rel) + 0.2) if with_profile else None))  # fmt: skip
        _walk(held, local, 10.0, 20.0, lambda x: err(x) + c1)
        held.correct(PoseFix(np.array([0.0, 0.0, c2]), np.array([0.01, 0.01, 0.01 + Q_M2_PER_M * 10.0]),
                             np.array([0.01, 0.01, 1e-4]),
                             (lambda rel: -(err(19.95 + rel) + c1)) if with_profile else None))  # fmt: skip
        list(held.chunks())
        local.merge(acc.flush())
        _, z = _heights(local)
        worst[with_profile] = float(np.abs(z).max())
    assert worst[True] < 1e-9, worst
    assert worst[False] > 0.05, worst


def test_a_fix_that_states_the_walks_datum_keeps_the_samples_younger_than_hold_m_for_the_next() -> None:
    """The mapper releases everything it holds at a fix that adds only the newest evidence; at a fix that
    states the walk's datum (`PoseFix.height_profile`) only what is `hold_m` behind, so the next such fix revises
    the rest with more of the walk behind it."""
    from scout_agent.mapping import Mapper, MapperConfig

    left = {}
    for with_profile in (False, True):
        mapper = Mapper(MapperConfig(res=RES, hold=HoldConfig(hold_m=30.0)))
        _walk(mapper.held, mapper.local, 0.0, 40.0, lambda x: 0.1)  # 40 m: the first 10 m already left
        mapper.held.cut()
        held_before = mapper.held.pending
        profile = (lambda rel: np.full(np.shape(rel), -0.1)) if with_profile else None
        mapper.fix(PoseFix(np.array([0.0, 0.0, -0.1]), np.array([0.01, 0.01, 0.05]), np.array([0.01, 0.01, 0.01]),
                           profile))  # fmt: skip
        left[with_profile] = (held_before, mapper.held.pending)
    assert left[False][0] > 0 and left[False][1] == 0, left
    assert left[True][1] == left[True][0], left  # nothing 30 m old: all stay for the next fix


def test_a_fix_that_states_the_walks_datum_variance_sets_the_held_footholds_vertical_sigma() -> None:
    """With `PoseFix.height_profile_var` the held footholds' vertical σ (the `height` layer's) is that datum's
    posterior σ at each one's distance walked, not the filter's σ when it stood there smoothed by the fix's
    gain; without it the smoothed σ stays (here 0.10 m at the walk's start, where the profile states 0.05 m)."""
    sig = {}
    for with_var in (False, True):
        acc = CellAccumulator(RES)
        held = HeldSamples(acc, HoldConfig(hold_m=30.0))
        local = LocalMap(RES)
        _walk(held, local, 0.0, 20.0, lambda x: 0.1)
        profile_var = (lambda rel: 0.03**2 + 0.002**2 * np.asarray(rel) ** 2) if with_var else None
        held.correct(PoseFix(np.array([0.0, 0.0, -0.1]), np.array([0.01, 0.01, SIGMA0_M2 + Q_M2_PER_M * 20.0]),
                             np.array([0.01, 0.01, 0.03**2]), lambda rel: np.full(np.shape(rel), -0.1),
                             profile_var))  # fmt: skip
        list(held.chunks())
        local.merge(acc.flush())
        cells = local.cells("height")
        x = (cells["ix"] + 0.5) * RES
        sig[with_var] = (x, layer_derived("height", "sigma", cells))
    x, s = sig[True]
    want = np.sqrt(0.03**2 + 0.002**2 * (x - 19.95) ** 2)
    assert np.allclose(s, want, atol=0.004), np.c_[x, s, want][::10]
    assert np.abs(sig[False][1] - want).max() > 0.04, np.c_[x, sig[False][1], want][::10]
