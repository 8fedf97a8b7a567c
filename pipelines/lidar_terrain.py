"""The Python form of lidar_terrain.yaml."""

from pathlib import Path

from o3d_terrain.io import read_cloud
from o3d_terrain.stages import (GridQuantize, RationalBSplineTerrain, Segmenter, SlopeEstimator,
                                SyntheticScene)
from o3d_terrain.writers import WriteAttribute, WriteCloud, WriteImage, WriteProduct


def run(output_dir, input_path=None):
    if input_path is not None:
        cloud = read_cloud(input_path)  # what --input does
    else:
        cloud = SyntheticScene(scene="hills", sensor="lidar", beams=64, azimuth_steps=1800)()
    frame = GridQuantize(cell_size=0.5)(cloud)
    frame = RationalBSplineTerrain()(frame)
    frame = SlopeEstimator()(frame)
    frame = Segmenter()(frame)
    out = Path(output_dir)
    for writer in (
        WriteCloud(path="labelled.ply", color_by="labels"),
        WriteAttribute(attribute="labels", path="labels.npy"),
        WriteImage(product="surface", path="terrain_height.png"),
        WriteImage(product="slope_grid", path="slope.png", value_range=(0, 30)),
        WriteProduct(product="surface", path="surface.npz"),
    ):
        writer.write(frame, out)
    return frame
