"""Earlier returns of a pulse are never terrain (Segmenter ground_returns, LAS return numbers)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from o3d_terrain import read_cloud, segment_terrain
from o3d_terrain.errors import InputError
from o3d_terrain.evaluation.datasets import LabelledFrame, read_las_frame
from o3d_terrain.evaluation.segmentation import evaluate_frame, ours, run_method
from o3d_terrain.frame import LABELS, NUMBER_OF_RETURNS, RETURN_NUMBERS, cloud_from_numpy
from o3d_terrain.segment import TerrainLabel, earlier_returns
from o3d_terrain.stages import GridQuantize, RationalBSplineTerrain, Segmenter


def test_earlier_returns_are_those_the_pulse_went_past():
    r = np.array([1, 2, 1, 0, 3, 1, 2])
    n = np.array([2, 2, 1, 0, 2, 3, 3])
    np.testing.assert_array_equal(earlier_returns(r, n),
                                  [True, False, False, False, False, True, True])
    with pytest.raises(InputError, match="one value per point"):
        earlier_returns(r, n[:3])


def _tile(seed=0):
    """A 40 m sloped tile seen from the air: ground (last returns), tree crowns 6 m up (first
    of two returns), and the ground-level first returns of low cover (first of two returns,
    within the noise of the ground: only their return numbers tell them apart). Returns
    (positions, return numbers, numbers of returns, is_ground, low_cover)."""
    rng = np.random.default_rng(seed)
    n = 16_000
    x, y = rng.uniform(0.0, 40.0, (2, n))
    z = 0.1 * x + 0.3 * np.sin(y / 5.0) + rng.normal(0.0, 0.02, n)
    crown = rng.random(n) < 0.15
    z[crown] += 6.0 + rng.normal(0.0, 0.5, crown.sum())
    low = ~crown & (rng.random(n) < 0.05)
    z[low] += 0.05
    r = np.ones(n, np.int32)
    count = np.ones(n, np.int32)
    count[crown | low] = 2
    return np.column_stack([x, y, z]), r, count, ~crown & ~low, low


def test_segmenter_keeps_earlier_returns_out_of_the_terrain():
    p, r, count, ground, low = _tile()
    cloud = cloud_from_numpy(p, **{RETURN_NUMBERS: r, NUMBER_OF_RETURNS: count})
    fitted = RationalBSplineTerrain()(GridQuantize(cell_size=0.5)(cloud))
    last = Segmenter()(fitted)
    every = Segmenter(ground_returns="all")(fitted)
    terrain_last = last.attribute(LABELS) == TerrainLabel.TERRAIN
    terrain_all = every.attribute(LABELS) == TerrainLabel.TERRAIN
    assert terrain_all[low].mean() > 0.9  # at ground level: terrain by height alone
    assert not terrain_last[low].any()
    np.testing.assert_array_equal(terrain_last[~low], terrain_all[~low])
    assert terrain_last[ground].mean() > 0.98
    assert any("earlier return" in note for note in last.notes)
    # the function: a tensor cloud carrying the numbers, as read_cloud gives a LAS file's
    _, inliers = segment_terrain(cloud)
    np.testing.assert_array_equal(inliers, np.flatnonzero(terrain_last))
    _, inliers_all = segment_terrain(cloud, ground_returns="all")
    np.testing.assert_array_equal(inliers_all, np.flatnonzero(terrain_all))
    # numbers that say nothing (0) test nothing; a cloud without them neither
    unknown = cloud_from_numpy(p, **{RETURN_NUMBERS: np.zeros_like(r),
                                     NUMBER_OF_RETURNS: np.zeros_like(count)})
    np.testing.assert_array_equal(segment_terrain(unknown)[1], inliers_all)
    np.testing.assert_array_equal(segment_terrain(p)[1], inliers_all)


def test_ground_returns_option_is_checked():
    p, *_ = _tile()
    with pytest.raises(InputError, match="did you mean 'last'"):
        segment_terrain(p, ground_returns="lsat")


def test_las_tile_returns_reach_the_labels_and_the_evaluation(tmp_path):
    laspy = pytest.importorskip("laspy")
    p, r, count, ground, low = _tile(seed=1)
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([500000.0, 4500000.0, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = 500000.0 + p[:, 0], 4500000.0 + p[:, 1], p[:, 2]
    las.return_number = r
    las.number_of_returns = count
    las.classification = np.where(ground, 2, 1).astype(np.uint8)
    path = tmp_path / "tile.las"
    las.write(str(path))

    cloud = read_cloud(path)
    assert isinstance(cloud, o3d.t.geometry.PointCloud)
    _, inliers = segment_terrain(cloud)
    assert not np.isin(np.flatnonzero(low), inliers).any()

    frame = read_las_frame(path)
    np.testing.assert_array_equal(frame.returns[0], r)
    np.testing.assert_array_equal(frame.returns[1], count)
    method = ours()
    np.testing.assert_array_equal(np.flatnonzero(run_method(method, frame)), inliers)
    with_numbers = evaluate_frame(method, frame).counts
    without = evaluate_frame(ours(ground_returns="all"), frame).counts
    assert with_numbers.f1 > without.f1
    # a method that does not take the numbers gets the points alone
    np.testing.assert_array_equal(run_method(lambda positions: positions[:, 2] < 5.0, frame),
                                  frame.positions[:, 2] < 5.0)
    with pytest.raises(InputError, match="returns must be"):
        LabelledFrame(name="bad", positions=frame.positions, is_ground=frame.is_ground,
                      scored=frame.scored, returns=(r, count[:5]))


def test_pdal_return_fields_of_a_ply_file_count_too(tmp_path):
    p, r, count, _, low = _tile(seed=2)
    cloud = o3d.t.geometry.PointCloud(o3d.core.Tensor(p))
    cloud.point["ReturnNumber"] = o3d.core.Tensor(r[:, None])
    cloud.point["NumberOfReturns"] = o3d.core.Tensor(count[:, None])
    path = tmp_path / "tile.ply"
    o3d.t.io.write_point_cloud(str(path), cloud)
    _, inliers = segment_terrain(read_cloud(path))
    assert not np.isin(np.flatnonzero(low), inliers).any()
    _, inliers_all = segment_terrain(read_cloud(path), ground_returns="all")
    assert np.isin(np.flatnonzero(low), inliers_all).mean() > 0.9
