"""LAS tiles for the tests of the LAS/LAZ writers: a small sloped tile with a building."""

import numpy as np

import laspy

BOX = (12.0, 16.0, 12.0, 16.0)  # a 4 m building, 3 m tall, on the slope


def terrain_height(x, y):
    """The tile's terrain (metres)."""
    return 0.1 * x + 0.5 * np.sin(y / 6.0)


def write_tile(path, *, feet=False, point_format=3, seed=0, wkt=None):
    """A 40 m x 40 m tile (metres, or US feet with the GeoTIFF unit keys), 8 points/m2 of
    ground in class 2 and a building's roof in class 6, with GPS times and intensities;
    ``wkt``: a WKT coordinate system record (LAS 1.4, point format 6 or more) instead of keys.
    Returns the roof's mask."""
    rng = np.random.default_rng(seed)
    n = 12_800
    x = rng.uniform(0.0, 40.0, n)
    y = rng.uniform(0.0, 40.0, n)
    z = terrain_height(x, y) + rng.normal(0.0, 0.02, n)
    roof = (x > BOX[0]) & (x < BOX[1]) & (y > BOX[2]) & (y < BOX[3])
    z[roof] += 3.0
    unit = 0.3048 if feet else 1.0
    version = "1.2" if point_format < 6 else "1.4"
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([500000.0, 4500000.0, 0.0])
    if feet:
        from laspy.vlrs.known import GeoKeyDirectoryVlr, GeoKeyEntryStruct

        vlr = GeoKeyDirectoryVlr()
        vlr.geo_keys_header = GeoKeyEntryStruct(1, 1, 0, 2)
        vlr.geo_keys = [GeoKeyEntryStruct(3076, 0, 1, 9002), GeoKeyEntryStruct(4099, 0, 1, 9002)]
        header.vlrs.append(vlr)
    if wkt is not None:
        from laspy.vlrs.known import WktCoordinateSystemVlr

        header.vlrs.append(WktCoordinateSystemVlr(wkt))
    las = laspy.LasData(header)
    las.x = 500000.0 + x / unit
    las.y = 4500000.0 + y / unit
    las.z = z / unit
    las.classification = np.where(roof, 6, 2).astype(np.uint8)
    las.gps_time = np.arange(n, dtype=np.float64) * 1e-4
    las.intensity = rng.integers(0, 4000, n).astype(np.uint16)
    las.write(str(path))
    return roof
