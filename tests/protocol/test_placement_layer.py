"""The placement layer (contract extension of issue 23): each foothold carries the scout's horizontal σ; the
map keeps n, Σσ², max σ under the generic merge rule; the value is the RMS σ, `worst` the largest."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.layers import LAYERS, layer_derived, layer_value, merge_op
from scout_agent.cells import CellAccumulator, LocalMap


def test_placement_merges_by_the_generic_rule_and_reads_as_rms_sigma() -> None:
    layer = LAYERS["placement"]
    assert layer.stats == ("n", "var", "max") and layer.unit == "m"
    assert [merge_op(s) for s in layer.stats] == ["add", "add", "max"]
    local = LocalMap(0.4)
    for sigmas in ([0.1, 0.1], [0.5]):  # two deltas from two moments of one scout (or two scouts)
        acc = CellAccumulator(0.4)
        for s in sigmas:
            acc.append("placement", (1.0, 1.0, 1.0, s * s, s))
        local.merge(acc.flush())
    cells = local.cells("placement")
    stats = {k: cells[k] for k in layer.stats}
    assert layer_value("placement", stats)[0] == pytest.approx(np.sqrt((0.01 + 0.01 + 0.25) / 3))
    assert layer_derived("placement", "worst", stats)[0] == pytest.approx(0.5)
    empty = {k: np.zeros(1) for k in layer.stats}
    assert np.isnan(layer_value("placement", empty)[0])
