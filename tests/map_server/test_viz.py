from __future__ import annotations

import threading

from map_server.tiles import TiledMap
from map_server.viz import MapViz
from protocol.testing import layer_cells


def test_logs_only_touched_tiles(tmp_path):
    m = TiledMap(0.4)
    m.merge({"slip": layer_cells("slip", [1, 200], [1, 1])})
    viz = MapViz(str(tmp_path / "map.rrd"), "m1", interval_s=0.0)
    assert viz.log_tiles(m, m.take_touched(), threading.Lock(), 1) == 2
    m.merge({"slip": layer_cells("slip", [2], [2])})
    assert viz.log_tiles(m, m.take_touched(), threading.Lock(), 2) == 1
    viz.close()
    assert (tmp_path / "map.rrd").stat().st_size > 0
