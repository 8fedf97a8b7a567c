"""The Python form of demo.yaml: the same stages and outputs as plain objects."""

from pathlib import Path

from o3d_terrain.stages import GridQuantize, SyntheticScene
from o3d_terrain.writers import WriteCloud, WriteImage, WriteProduct


def run(output_dir, input_path=None):
    frame = SyntheticScene(scene="offroad", sensor="lidar", seed=0)()
    frame = GridQuantize(cell_size=0.5)(frame)
    out = Path(output_dir)
    WriteImage(product="grid", layer="z", path="grid_height.png").write(frame, out)
    WriteProduct(product="grid", path="grid.npz").write(frame, out)
    WriteCloud(path="cloud.ply").write(frame, out)
    return frame
