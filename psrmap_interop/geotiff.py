"""A map region as a multi-band GeoTIFF: one band per layer value and one per layer's observation count.

Bands are float32 with NaN as nodata, each described (`layer value`, `layer count`), with its unit as the band's
unit type (GDAL's `GetUnitType`: `gdalinfo` prints it) and its unit, statistic and meaning as band tags.
Georeferencing:

- with a `MoonOrigin` (latitude, longitude of the map frame's origin, heading of its +x axis), the file is in
  `IAU_2015:30135` (Moon south polar stereographic, sphere R = 1737.4 km, the CRS of the LOLA south-pole
  DEMs): the affine transform carries the map's heading as a rotation and the projection's scale at that
  latitude, so every pixel lands where the map cell lies. GeoTIFF keys can name only EPSG codes, so the
  keys hold the projection itself (user-defined: GDAL reads it back as IAU_2015:30135's polar stereographic,
  variant A, which PROJ identifies at 100 %), and a GDAL side-car `<file>.aux.xml` holds the CRS as WKT2 with
  its identifier `ID["IAU",30135,2015]` (GDAL reads the side-car first: `gdalinfo` prints the ID).
  rasterio 1.4 takes a dataset's CRS through WKT1 (`GDALGetProjectionRef`), which turns variant A into B and
  drops the identifier's version, so its `crs.to_authority()` is None for any IAU CRS (even an in-memory
  dataset made from `IAU_2015:30135`) unless GDAL exports WKT2: `rasterio.Env(OSR_WKT_FORMAT="WKT2_2019")`;
- without one, a local engineering CRS (`LOCAL_CS`, metres, x east, y north of the launch site), and the
  file's `PSRMAP_CRS` tag says that it is not georeferenced.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from protocol.layers import LAYERS
from psrmap_interop.errors import InteropError

__all__ = ["MOON_GEOGRAPHIC", "MOON_SOUTH_POLAR", "MoonOrigin", "map_affine", "pam_path", "write_geotiff"]

MOON_SOUTH_POLAR = "IAU_2015:30135"  # Moon (2015) sphere, south polar stereographic
MOON_GEOGRAPHIC = "IAU_2015:30100"  # Moon (2015) sphere, planetocentric latitude / longitude
MOON_RADIUS_M = 1_737_400.0
COUNT_UNIT = "observations"  # the unit type of a count band
LOCAL_WKT = ('LOCAL_CS["psrmap map frame: metres east (x) and north (y) of the mission origin, not georeferenced",'
             'LOCAL_DATUM["psrmap mission origin",0],UNIT["metre",1],AXIS["X",EAST],AXIS["Y",NORTH]]')  # fmt: skip


@dataclass(frozen=True)
class MoonOrigin:
    """Where the map frame's origin (x = y = 0) is on the Moon, and which way its +x axis points: `heading_deg`
    counter-clockwise from the projection's +easting axis (0: map x along easting, y along northing)."""

    lat_deg: float
    lon_deg: float
    heading_deg: float = 0.0

    def __post_init__(self) -> None:
        if not -90.0 <= self.lat_deg < -60.0:
            raise InteropError(
                f"origin latitude {self.lat_deg}: the south polar projection needs -90 <= lat < -60"
            )
        if not -360.0 <= self.lon_deg <= 360.0:
            raise InteropError(f"origin longitude {self.lon_deg}: need -360..360 degrees")

    @classmethod
    def parse(cls, text: str) -> MoonOrigin:
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            vals = []
        if len(vals) not in (2, 3):
            raise InteropError(f"origin {text!r}: need LAT,LON[,HEADING] in degrees, e.g. -89.45,222.7,30")
        return cls(*vals)

    def projected(self) -> tuple[float, float, float]:
        """(easting, northing) [m] of the origin in IAU_2015:30135 and the projection's scale there (projected
        metres per metre on the ground)."""
        from rasterio.crs import CRS  # lazy here and below: rasterio (GDAL) only when a CRS or file is made
        from rasterio.warp import transform

        src, dst = CRS.from_string(MOON_GEOGRAPHIC), CRS.from_string(MOON_SOUTH_POLAR)
        dlat = 1e-4
        (e0, e1), (n0, n1) = transform(src, dst, [self.lon_deg] * 2, [self.lat_deg, self.lat_deg + dlat])
        ground = MOON_RADIUS_M * math.radians(dlat)
        return e0, n0, math.hypot(e1 - e0, n1 - n0) / ground


def map_affine(x_left: float, y_top: float, res: float, origin: MoonOrigin | None):
    """The GeoTIFF affine transform of a grid whose top-left corner is (x_left, y_top) in the map frame."""
    from rasterio.transform import Affine

    if origin is None:
        return Affine(res, 0.0, x_left, 0.0, -res, y_top)
    e0, n0, k = origin.projected()
    c, s = math.cos(math.radians(origin.heading_deg)), math.sin(math.radians(origin.heading_deg))
    # map (x, y) -> projected: E = e0 + k (c x - s y), N = n0 + k (s x + c y); pixel (col, row) -> map
    # (x_left + col res, y_top - row res)
    return Affine(k * c * res, k * s * res, e0 + k * (c * x_left - s * y_top),
                  k * s * res, -k * c * res, n0 + k * (s * x_left + c * y_top))  # fmt: skip


def write_geotiff(
    path: str | Path,
    values: Mapping[str, np.ndarray],
    counts: Mapping[str, np.ndarray],
    res: float,
    x0: float,
    y0: float,
    origin: MoonOrigin | None = None,
    tags: Mapping[str, str] | None = None,
) -> Path:
    """Write `values[layer]` and `counts[layer]` ((h, w), row 0 = the southmost cells, whose lower-left corner
    is (x0, y0) in the map frame) as bands: for each layer its value, then its count. Returns the path."""
    import rasterio
    from rasterio.crs import CRS

    names = list(values)
    if not names:
        raise InteropError("nothing to write: the region holds no layer")
    h, w = values[names[0]].shape
    bands: list[tuple[np.ndarray, str, dict[str, str]]] = []  # array, description, tags (with its unit)
    for name in names:
        spec = LAYERS.get(name)
        unit = spec.unit if spec else ""
        doc = spec.doc if spec else ""
        bands.append(
            (values[name], f"{name} value", {"layer": name, "stat": "value", "unit": unit, "meaning": doc})
        )
        if name in counts:
            bands.append((counts[name], f"{name} count", {"layer": name, "stat": "n", "unit": COUNT_UNIT,
                                                           "meaning": f"observations behind {name}"}))  # fmt: skip
    transform = map_affine(x0, y0 + h * res, res, origin)
    crs = CRS.from_string(MOON_SOUTH_POLAR) if origin else CRS.from_wkt(LOCAL_WKT)
    out = Path(path)
    pam_path(out).unlink(missing_ok=True)  # an overwritten file's side-car would override its new CRS
    profile = dict(driver="GTiff", width=w, height=h, count=len(bands), dtype="float32", crs=crs,
                   transform=transform, nodata=float("nan"), compress="deflate", tiled=w >= 256 and h >= 256)  # fmt: skip
    with rasterio.open(out, "w", **profile) as ds:
        file_tags = {"PSRMAP_CRS": (f"{MOON_SOUTH_POLAR}, origin lat {origin.lat_deg} lon {origin.lon_deg} "
                                    f"heading {origin.heading_deg} deg") if origin else
                     "local engineering frame (metres east/north of the mission origin); not georeferenced",
                     "PSRMAP_RES_M": f"{res:g}", "PSRMAP_MAP_X0_M": f"{x0:g}", "PSRMAP_MAP_Y0_M": f"{y0:g}"}  # fmt: skip
        ds.update_tags(**file_tags, **dict(tags or {}))
        for i, (arr, desc, btags) in enumerate(bands, start=1):
            a = np.asarray(arr, dtype=np.float32)
            if a.shape != (h, w):
                raise InteropError(f"band {desc!r} is {a.shape}; every band must be {(h, w)}")
            ds.write(a[::-1], i)  # GeoTIFF row 0 is the top (north) edge
            ds.set_band_description(i, desc)
            if btags["unit"]:
                ds.set_band_unit(i, btags["unit"])
            ds.update_tags(i, **btags)
    if origin:
        _write_pam_crs(out, crs)
    return out


def pam_path(path: str | Path) -> Path:
    """The GDAL side-car (`<file>.aux.xml`) that holds a georeferenced GeoTIFF's identified CRS."""
    return Path(f"{path}.aux.xml")


def _write_pam_crs(path: Path, crs) -> None:
    """Put `crs` as WKT2 (with its authority ID) in the GDAL side-car of `path`, keeping whatever else GDAL
    wrote there."""
    side = pam_path(path)
    root = (
        ET.parse(side).getroot() if side.exists() else ET.Element("PAMDataset")
    )  # GDAL may have written one
    for old in root.findall("SRS"):
        root.remove(old)
    srs = ET.Element("SRS", {"dataAxisToSRSAxisMapping": "1,2"})  # easting, northing: the transform's order
    srs.text = crs.to_wkt(version="WKT2_2019")
    root.insert(0, srs)
    ET.ElementTree(root).write(side, encoding="unicode")
