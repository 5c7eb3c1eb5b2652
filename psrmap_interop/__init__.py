"""interop: psrmap's map in the formats the field already uses — ROS 2 messages over rmw_zenoh, rosbag2
(MCAP) recordings, GeoTIFF for GIS.

Like `protocol`, a library the services and the CLI import (never the other way round); it imports only
`protocol` and third-party packages (`rosbags` for ROS message definitions, CDR and type hashes; `rasterio` —
GDAL and PROJ — for GeoTIFF and the Moon's coordinate systems).
"""
