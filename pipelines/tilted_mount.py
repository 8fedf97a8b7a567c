"""The Python form of tilted_mount.yaml."""

from pathlib import Path

from o3d_terrain.io import read_cloud
from o3d_terrain.stages import (GridQuantize, LevelCloud, RationalBSplineTerrain, Segmenter,
                                SlopeEstimator, SyntheticScene)
from o3d_terrain.writers import WriteCloud, WriteImage, WriteProduct


def run(output_dir, input_path=None):
    if input_path is not None:
        cloud = read_cloud(input_path)  # what --input does
    else:
        cloud = SyntheticScene(scene="hills", sensor="lidar", tilt_deg=(0.0, 15.0))()
    frame = LevelCloud(up=(-0.2588, 0.0, 0.9659))(cloud)  # 15 degrees nose down
    frame = GridQuantize(cell_size=0.5)(frame)
    frame = RationalBSplineTerrain()(frame)
    frame = SlopeEstimator()(frame)
    frame = Segmenter()(frame)
    out = Path(output_dir)
    for writer in (
        WriteCloud(path="labelled.ply", color_by="labels"),
        WriteImage(product="slope_grid", path="slope.png", value_range=(0, 30)),
        WriteProduct(product="levelled_from_cloud", path="levelled_from_cloud.npz"),
    ):
        writer.write(frame, out)
    return frame
