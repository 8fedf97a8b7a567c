"""SyntheticScene: a source stage that samples a synthetic off-road scene with exact truth."""

from __future__ import annotations

from ..frame import Frame
from ..options import NON_NEGATIVE, POSITIVE, Range, option
from ..synthetic import SCENES, make_scene, sample_lidar, sample_solid_state, sample_stereo
from .base import SourceStage, stage
from .grid_quantize import check_region


@stage
class SyntheticScene(SourceStage):
    """Sample a synthetic off-road scene (exact terrain and obstacles) with a lidar, stereo or
    solid-state lidar model.

    The cloud is in the sensor frame (x forward, y left, z up), so a tilted sensor gives tilted
    data. Each point carries ``ground_truth`` (1 terrain, 2 obstacle, 3 spurious return) and ``obstacle_ids``
    (-1 terrain). The products ``truth`` (the scene: exact height, gradient, slope, obstacles)
    and ``sensor_truth`` (the sampled cloud with its pose, noise-free points and the exact
    terrain in the sensor frame) let later steps score the result. See docs/synthetic.md.
    """

    writes = ("truth", "sensor_truth")
    writes_attributes = ("ground_truth", "obstacle_ids")

    scene: str = option("offroad", choices=tuple(SCENES), help="which scene to generate")
    sensor: str = option("lidar", choices=("lidar", "stereo", "solid_state"),
                         help="lidar: spinning multi-beam; stereo: one point per pixel, depth "
                              "noise from disparity noise (grows with range²); solid_state: "
                              "forward-looking lidar with a non-repetitive (rosette) scan")
    seed: int = option(0, rule=Range(0, None), help="seed of the scene's random parts and of the noise")
    obstacles: bool = option(True, help="place the scene's obstacles (false: bare terrain)")
    region: tuple = option(
        None, kind=float, length=4, nullable=True, unit="m", check=check_region,
        help="x_min, x_max, y_min, y_max of the scene (world); null = the scene's own "
             "(40 m x 30 m; 26 m x 22 m for section6)",
    )
    tilt_deg: tuple = option((0.0, 0.0), kind=float, length=2, unit="deg",
                             rule=Range(-45, 45),
                             help="sensor roll and pitch (pitch positive = nose down)")
    yaw_deg: float = option(0.0, unit="deg", help="sensor heading, counter-clockwise from +x")
    sensor_height: float = option(1.8, unit="m", rule=POSITIVE,
                                  help="sensor height above the terrain")
    range_noise: float = option(0.02, unit="m", rule=NON_NEGATIVE,
                                help="lidar, solid_state: standard deviation of the range noise")
    beams: int = option(32, rule=Range(1, 1024), help="lidar: number of beams")
    azimuth_steps: int = option(900, rule=Range(1, 100_000),
                                help="lidar: firings per revolution")
    outlier_fraction: float = option(
        0.0, rule=Range(0, 1),
        help="fraction of spurious returns (dust, multipath, mismatches), moved along their ray "
             "to 0.5-1.5 times the true range; ground_truth 3")
    disparity_noise_px: float = option(0.25, unit="px", rule=NON_NEGATIVE,
                                       help="stereo: standard deviation of the disparity noise")
    image_size: tuple = option((320, 240), kind=int, length=2, unit="px", rule=Range(8, 8192),
                               help="stereo: image width and height")
    baseline: float = option(0.3, unit="m", rule=POSITIVE, help="stereo: camera baseline")
    points: int = option(100_000, rule=Range(1, 10_000_000),
                         help="solid_state: firings in the frame (100,000: about half a second "
                              "of a 200 kHz unit)")
    fov_deg: float = option(70.0, unit="deg", rule=Range(1, 170),
                            help="solid_state: diameter of the circular field of view")

    def read(self) -> Frame:
        scene = make_scene(self.scene, seed=self.seed, obstacles=self.obstacles,
                           region=self.region)
        if self.sensor == "lidar":
            cloud = sample_lidar(scene, sensor_height=self.sensor_height, yaw_deg=self.yaw_deg,
                                 tilt_deg=self.tilt_deg, beams=self.beams,
                                 azimuth_steps=self.azimuth_steps, range_noise=self.range_noise,
                                 outlier_fraction=self.outlier_fraction,
                                 seed=self.seed)
        elif self.sensor == "solid_state":
            cloud = sample_solid_state(scene, sensor_height=self.sensor_height,
                                       yaw_deg=self.yaw_deg, tilt_deg=self.tilt_deg,
                                       fov_deg=self.fov_deg, points=self.points,
                                       range_noise=self.range_noise,
                                       outlier_fraction=self.outlier_fraction, seed=self.seed)
        else:
            cloud = sample_stereo(scene, camera_height=self.sensor_height, yaw_deg=self.yaw_deg,
                                  tilt_deg=self.tilt_deg, width=self.image_size[0],
                                  height=self.image_size[1], baseline=self.baseline,
                                  disparity_noise_px=self.disparity_noise_px,
                                  outlier_fraction=self.outlier_fraction, seed=self.seed)
        frame = Frame(cloud.to_pointcloud()).with_products(truth=scene, sensor_truth=cloud)
        return frame.with_note(
            f"{self.type_name}: scene '{self.scene}' (seed {self.seed}), {self.sensor}, "
            f"{len(cloud)} points, {int(cloud.is_obstacle.sum())} on obstacles"
        )
