"""The Python form of stereo_terrain.yaml."""

from pathlib import Path

from o3d_terrain.stages import (GridQuantize, RationalBSplineTerrain, Segmenter, SlopeEstimator,
                                StereoToCloud)
from o3d_terrain.writers import WriteAttribute, WriteCloud, WriteImage

PAIR = Path(__file__).resolve().parent / "data" / "offroad_pair"


def run(output_dir, input_path=None):
    frame = StereoToCloud(
        left=str(PAIR / "left.png"), right=str(PAIR / "right.png"),
        calibration=str(PAIR / "calibration.yaml"), frame="vehicle", camera_height=1.6,
        pitch_deg=5.0, depth_range=(3.0, 40.0), downscale=2, min_texture=2.0,
    )()
    frame = GridQuantize(cell_size=0.5)(frame)
    frame = RationalBSplineTerrain()(frame)
    frame = SlopeEstimator()(frame)
    frame = Segmenter(threshold=0.2, range_coefficient=0.0005)(frame)
    out = Path(output_dir)
    for writer in (
        WriteImage(product="disparity", path="disparity.png"),
        WriteCloud(path="cloud.ply"),
        WriteCloud(path="labelled.ply", color_by="labels"),
        WriteImage(product="surface", path="terrain_height.png"),
        WriteImage(product="slope_grid", path="slope.png", value_range=(0, 30)),
        WriteAttribute(attribute="labels", path="labels.npy"),
    ):
        writer.write(frame, out)
    return frame
