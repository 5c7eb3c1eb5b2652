from __future__ import annotations

import threading

from map_server.viz import MapViz
from protocol.testing import layer_cells
from psrmap_mapcore import TiledMap


def test_logs_only_touched_tiles(tmp_path):
    m = TiledMap(0.4)
    m.merge({"slip": layer_cells("slip", [1, 200], [1, 1])})
    viz = MapViz(str(tmp_path / "map.rrd"), "m1", interval_s=0.0)
    assert viz.log_tiles(m, m.take_touched(), threading.Lock(), 1) == 2
    m.merge({"slip": layer_cells("slip", [2], [2])})
    assert viz.log_tiles(m, m.take_touched(), threading.Lock(), 2) == 1
    viz.close()
    assert (tmp_path / "map.rrd").stat().st_size > 0


def test_recording_holds_values_counts_and_status(tmp_path):
    from rerun.chunk import RrdReader

    m = TiledMap(0.4)
    m.merge({"slip": layer_cells("slip", [1, 200], [1, 1]), "cot": layer_cells("cot", [3], [4])})
    viz = MapViz(str(tmp_path / "map.rrd"), "m1", interval_s=0.0)
    viz.log_tiles(m, m.take_touched(), threading.Lock(), 1)
    viz.close()
    entities = {c.entity_path for c in RrdReader(tmp_path / "map.rrd").stream()}
    assert {"/map/slip/0_0", "/map/slip/3_0", "/map/cot/0_0"} <= entities
    assert {"/map/counts/slip/0_0", "/map/counts/slip/3_0", "/map/counts/cot/0_0"} <= entities
    assert {"/map/status/cells", "/map/status/version"} <= entities
