"""The Python form of demo.yaml: the same stages and outputs as plain objects."""

from pathlib import Path

from o3d_terrain.stages import (GridQuantize, ObstacleDetector, RationalBSplineTerrain,
                                Segmenter, SlopeEstimator, SyntheticScene, TraversabilityCost)
from o3d_terrain.stages.obstacles import WriteCostMap, WriteObstacles
from o3d_terrain.writers import WriteCloud, WriteImage, WriteProduct


def run(output_dir, input_path=None):
    frame = SyntheticScene(scene="offroad", sensor="lidar", seed=0, beams=64, azimuth_steps=1800)()
    frame = GridQuantize(cell_size=0.5)(frame)  # 2.5-D height grid (eq. 1)
    frame = RationalBSplineTerrain()(frame)  # terrain surface
    frame = SlopeEstimator()(frame)  # slope by derivation
    frame = Segmenter()(frame)  # terrain / obstacle / below-terrain labels
    frame = ObstacleDetector()(frame)  # obstacle clusters
    frame = TraversabilityCost(vehicle="offroad_suv")(frame)  # cost map
    out = Path(output_dir)
    for writer in (
        WriteImage(product="grid", layer="z", path="grid_height.png"),
        WriteImage(product="surface", path="terrain_height.png"),
        WriteImage(product="slope_grid", path="slope.png", value_range=(0, 30)),
        WriteCostMap(path="cost_map.png"),
        WriteObstacles(path="obstacles.json"),
        WriteProduct(product="surface", path="surface.npz"),
        WriteCloud(path="cloud_labels.ply", color_by="labels"),
    ):
        writer.write(frame, out)
    return frame
