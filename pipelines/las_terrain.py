"""The Python form of las_terrain.yaml (the tile is given as input_path)."""

from pathlib import Path

from o3d_terrain.stages import (GridQuantize, RationalBSplineTerrain, ReadCloud, Segmenter,
                                SlopeEstimator)
from o3d_terrain.writers import (WriteAttribute, WriteCloud, WriteImage, WriteLas, WriteProduct,
                                 WriteRaster)


def run(output_dir, input_path=None):
    if input_path is None:
        raise ValueError("las_terrain needs a LAS/LAZ tile: run(output_dir, input_path=tile)")
    # ReadCloud, not read_cloud: the frame keeps the file (product las_source) for WriteLas
    frame = GridQuantize(cell_size=1.0)(ReadCloud(path=str(input_path))())
    frame = RationalBSplineTerrain()(frame)
    frame = SlopeEstimator(cell_size=1.0)(frame)
    frame = Segmenter()(frame)  # automatic threshold and local planes
    out = Path(output_dir)
    for writer in (
        WriteLas(path="classified.laz"),  # ground 2, obstacles 1, below 7, HeightAboveGround
        WriteRaster(path="dtm.tif"),  # the terrain's heights, 1 m cells, the tile's CRS
        WriteRaster(path="slope.tif", layer="slope"),  # degrees
        WriteCloud(path="labelled.ply", color_by="labels"),
        WriteAttribute(attribute="labels", path="labels.npy"),
        WriteImage(product="surface", path="terrain_height.png"),
        WriteImage(product="slope_grid", path="slope.png"),
        WriteProduct(product="surface", path="surface.npz"),
    ):
        writer.write(frame, out)
    return frame
