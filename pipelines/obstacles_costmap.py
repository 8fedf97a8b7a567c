"""The Python form of obstacles_costmap.yaml: the same stages and outputs as plain objects."""

from pathlib import Path

from o3d_terrain.stages import (GridQuantize, ObstacleDetector, SyntheticScene,
                                TraversabilityCost)
from o3d_terrain.stages.obstacles import WriteCostMap, WriteObstacles
from o3d_terrain.writers import WriteCloud, WriteImage, WriteProduct


def run(output_dir, input_path=None):
    from o3d_terrain.stages import RationalBSplineTerrain, Segmenter, SlopeEstimator

    frame = SyntheticScene(scene="offroad", sensor="lidar", seed=0, beams=64,
                           azimuth_steps=1800)()
    frame = GridQuantize(cell_size=0.5)(frame)  # 2.5-D height grid
    frame = RationalBSplineTerrain()(frame)  # terrain surface
    frame = SlopeEstimator()(frame)  # slope by derivation
    frame = Segmenter()(frame)  # terrain / obstacle labels
    frame = ObstacleDetector(cell_size=0.3, min_points=5, min_height=0.3)(frame)
    frame = TraversabilityCost(vehicle="offroad_suv", cell_size=0.25)(frame)
    out = Path(output_dir)
    WriteProduct(product="cost_map", path="cost_map.npz").write(frame, out)
    WriteCostMap(path="cost_map.png").write(frame, out)
    WriteImage(product="cost_map", layer="slope_deg", path="cost_map_slope.png").write(frame, out)
    WriteObstacles(path="obstacles.json").write(frame, out)
    WriteCloud(path="cloud_labels.ply", color_by="labels").write(frame, out)
    WriteCloud(path="cloud_costs.ply", color_by="costs").write(frame, out)
    return frame
