"""psrmap's map, cost grid and paths as ROS 2 messages: `grid_map_msgs/msg/GridMap`, `nav_msgs/msg/OccupancyGrid`,
`nav_msgs/msg/Path`.

Definitions, CDR serialisation and RIHS01 type hashes come from `rosbags` (its ROS 2 Jazzy type store for the
standard messages; grid_map_msgs from the `.msg` files shipped in `psrmap_interop/msg/`), not hand-written encoders.

Index conventions (what RViz and grid_map expect):
- GridMap: `info.pose` is the map's centre; cell (i, j) of a layer lies at x = centre_x + length_x/2 − (i + ½)·res,
  y = centre_y + length_y/2 − (j + ½)·res (index (0, 0) at the +x, +y corner); each layer is a
  Float32MultiArray, column-major, dim[0] "column_index" (size = cells along y), dim[1] "row_index" (size =
  cells along x). NaN marks a cell without data.
- OccupancyGrid: row-major from `info.origin` (the lower-left corner), 0..100 cost, -1 unknown.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from importlib import resources

import numpy as np

__all__ = ["GRID_MAP", "OCCUPANCY_GRID", "PATH", "dds_type_name", "grid_map_layers", "grid_map_msg", "occupancy_grid_msg",
           "path_msg", "serialize", "type_hash", "typestore"]  # fmt: skip

GRID_MAP = "grid_map_msgs/msg/GridMap"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
PATH = "nav_msgs/msg/Path"


@functools.cache
def typestore():  # -> rosbags Typestore
    """ROS 2 Jazzy's standard messages plus psrmap's shipped grid_map_msgs definitions."""
    from rosbags.typesys import (  # lazy: rosbags only for ROS messages
        Stores,
        get_types_from_msg,
        get_typestore,
    )

    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    pkg = resources.files("psrmap_interop") / "msg" / "grid_map_msgs" / "msg"
    for name in ("GridMapInfo", "GridMap"):
        types.update(get_types_from_msg((pkg / f"{name}.msg").read_text(), f"grid_map_msgs/msg/{name}"))
    store.register(types)
    return store


def type_hash(typename: str) -> str:
    """`RIHS01_<64 hex>`: the ROS 2 type hash of `typename` (REP 2011), as rmw_zenoh puts it in key expressions."""
    return typestore().hash_rihs01(typename)


def dds_type_name(typename: str) -> str:
    """`pkg/msg/Name` -> `pkg::msg::dds_::Name_` (the DDS-mangled name rmw_zenoh uses)."""
    pkg, kind, name = typename.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def serialize(msg, typename: str) -> bytes:
    """CDR, little endian, with the 4-byte encapsulation header."""
    return bytes(typestore().serialize_cdr(msg, typename))


def _header(frame: str, stamp_ns: int):
    T = typestore().types
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 1_000_000_000),
                                    nanosec=int(stamp_ns % 1_000_000_000)), frame_id=frame)  # fmt: skip


def _pose(x: float, y: float, z: float = 0.0):
    T = typestore().types
    return T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )


def grid_map_msg(layers: Mapping[str, np.ndarray], res: float, x0: float, y0: float, frame: str = "map",
                 stamp_ns: int = 0):  # fmt: skip
    """A GridMap of `layers[name]` ((h, w), row iy along y from y0, column ix along x from x0: our map arrays)."""
    T = typestore().types
    names = list(layers)
    h, w = layers[names[0]].shape if names else (0, 0)
    dim = T["std_msgs/msg/MultiArrayDimension"]
    layout = T["std_msgs/msg/MultiArrayLayout"](
        dim=[dim(label="column_index", size=h, stride=h * w), dim(label="row_index", size=w, stride=w)],
        data_offset=0,
    )
    data = [
        T["std_msgs/msg/Float32MultiArray"](layout=layout,
                                            data=np.ascontiguousarray(np.asarray(layers[n], np.float32)[::-1, ::-1]).ravel())
        for n in names
    ]  # fmt: skip
    info = T["grid_map_msgs/msg/GridMapInfo"](resolution=float(res), length_x=w * res, length_y=h * res,
                                              pose=_pose(x0 + w * res / 2, y0 + h * res / 2))  # fmt: skip
    return T[GRID_MAP](header=_header(frame, stamp_ns), info=info, layers=names, basic_layers=[], data=data,
                       outer_start_index=0, inner_start_index=0)  # fmt: skip


def grid_map_layers(msg) -> dict[str, np.ndarray]:
    """The inverse of `grid_map_msg`: layer -> (h, w) array in our orientation (row iy along y)."""
    out = {}
    for name, arr in zip(msg.layers, msg.data, strict=True):
        h, w = arr.layout.dim[0].size, arr.layout.dim[1].size
        out[name] = np.asarray(arr.data, dtype=np.float32).reshape(h, w)[::-1, ::-1]
    return out


def occupancy_grid_msg(cost: np.ndarray, known: np.ndarray, res: float, x0: float, y0: float, frame: str = "map",
                       stamp_ns: int = 0):  # fmt: skip
    """`cost` (h, w) [1/m, +inf impassable] as 0..99 over its passable range, 100 impassable, -1 where `known` is
    False (and passable)."""
    T = typestore().types
    c = np.asarray(cost, dtype=np.float64)
    ok = np.isfinite(c)
    lo, hi = (float(c[ok].min()), float(c[ok].max())) if ok.any() else (0.0, 1.0)
    occ = np.full(c.shape, 100, dtype=np.int8)
    occ[ok] = np.round(99 * (c[ok] - lo) / (hi - lo if hi > lo else 1.0)).astype(np.int8)
    occ[ok & ~np.asarray(known, bool)] = -1
    h, w = c.shape
    info = T["nav_msgs/msg/MapMetaData"](map_load_time=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
                                         resolution=float(res), width=w, height=h, origin=_pose(x0, y0))  # fmt: skip
    return T[OCCUPANCY_GRID](header=_header(frame, stamp_ns), info=info, data=occ.ravel())


def path_msg(points: Sequence[Sequence[float]], frame: str = "map", stamp_ns: int = 0):
    """(k, 2 or 3) map-frame points as a Path."""
    T = typestore().types
    poses = [
        T["geometry_msgs/msg/PoseStamped"](header=_header(frame, stamp_ns), pose=_pose(*p)) for p in points
    ]
    return T[PATH](header=_header(frame, stamp_ns), poses=poses)
