"""The automatic threshold widened by the surface's local misfit (o3d_terrain.misfit),
checked against the truth of small synthetic clouds."""

import numpy as np

from o3d_terrain.api import segment_terrain
from o3d_terrain.misfit import (
    MISFIT_HIGH,
    OVER_DEPTH,
    OVER_RADIUS,
    local_plane_terrain,
    misfit_thresholds,
    over_terrain,
    widened_thresholds,
)
from o3d_terrain.segment import TerrainLabel, widen_labels


def _flat_with_obstacles(rng):
    """A flat 60 x 60 m tile, 20 points/m², 2 cm noise; a 20 x 20 m field of 0.5 m bushes and
    a 2 x 4 m car 1.5 m tall: everything is at or above the ground, nothing bridges a gully."""
    n = 60 * 60 * 20
    x, y = rng.uniform(0, 60, n), rng.uniform(0, 60, n)
    z = rng.normal(0, 0.02, n)
    bush = (np.abs(x - 20) < 10) & (np.abs(y - 20) < 10) & (rng.uniform(size=n) < 0.7)
    z[bush] += rng.uniform(0.2, 0.6, bush.sum())
    car = (np.abs(x - 45) < 1) & (np.abs(y - 45) < 2)
    z[car] += rng.uniform(0.3, 1.5, car.sum())
    return np.column_stack([x, y, z]), bush | car


def test_no_misfit_keeps_the_global_threshold(rng, monkeypatch):
    """(The tile is top-down, which also measures points against local planes: left out.)"""
    import o3d_terrain.segment as seg
    cloud, obstacle = _flat_with_obstacles(rng)
    heights = cloud[:, 2]  # the exact surface is z = 0
    t = misfit_thresholds(cloud, heights, 0.1, block=10.0)
    assert np.all(t == 0.1)
    assert not seg.sensor_in_cloud(cloud)
    monkeypatch.setattr(seg, "_top_down_planes", lambda *a, **k: 0)
    _, with_misfit = segment_terrain(cloud)
    _, without = segment_terrain(cloud, misfit_threshold=False)
    np.testing.assert_array_equal(with_misfit, without)


def test_gullies_the_surface_bridges_widen_the_threshold(rng, vehicle_scan):
    """A sparse (0.7 points/m²) 240 x 200 m mountain slope (35°) with ridges and gullies 10 m
    apart and 1.2 m deep, which 6 m control spacing cannot follow, and 2.5 m tall blocks;
    read as a vehicle's scan (points around the origin whatever their density), whose layout
    is the vehicle's (a top-down tile's finer refit follows these gullies by itself)."""
    n = int(240 * 200 * 0.7)
    x, y = rng.uniform(0, 240, n), rng.uniform(0, 200, n)
    ground = 0.7 * x + 0.6 * np.sin(2 * np.pi * y / 10.0) + rng.normal(0, 0.03, n)
    z = ground.copy()
    block = ((x % 60) < 4) & ((y % 50) < 4)
    z[block] += 2.5
    cloud = np.column_stack([x, y, z])
    truth = ~block
    _, with_misfit = segment_terrain(cloud)
    _, without = segment_terrain(cloud, misfit_threshold=False)

    def recall(idx):
        mask = np.zeros(n, bool)
        mask[idx] = True
        return (mask & truth).sum() / truth.sum(), (mask & block).sum()

    r_with, fp_with = recall(with_misfit)
    r_without, fp_without = recall(without)
    assert r_with > r_without + 0.05
    assert r_with > 0.95
    # the blocks (2.5 m, above the widest threshold) stay obstacles
    assert 2.5 > MISFIT_HIGH and fp_with == 0 == fp_without


def test_widen_labels_changes_only_the_widened_points():
    heights = np.array([0.3, 0.3, -0.3, -0.3, 2.0, -2.0])
    local = np.array([0.2, 1.0, 0.2, 1.0, 1.5, 1.5])
    O, B, T = TerrainLabel.OBSTACLE, TerrainLabel.BELOW_TERRAIN, TerrainLabel.TERRAIN  # noqa: E741
    labels = np.array([O, O, B, B, O, B], np.uint8)  # as if below_threshold were 0.1
    widen_labels(labels, heights, local, 0.2)
    np.testing.assert_array_equal(labels, [O, T, B, T, O, B])


def test_slope_term_widens_only_blocks_the_misfit_widened(rng):
    """The grade term (threshold + reach x tan(slope), at most MISFIT_HIGH) applies only where a
    block's misfit widened the threshold: on a flat cloud the surface follows, a steep grade
    changes nothing; on a 35° slope with ridges the surface bridges (exact heights: the plane
    under the crests), more ground lies within the thresholds and 2.5 m blocks stay above them."""
    cloud, _ = _flat_with_obstacles(rng)
    steep = lambda x, y: np.full(len(x), 1.0)  # noqa: E731
    t = misfit_thresholds(cloud, cloud[:, 2], 0.1, block=10.0, grade=steep)
    assert np.all(t == 0.1)

    n = int(240 * 200 * 0.7)
    x, y = rng.uniform(0, 240, n), rng.uniform(0, 200, n)
    wave = np.sin(2 * np.pi * y / 10.0)  # gullies and sharp crests (up to 1.2 m) 10 m apart
    h = 0.3 * wave + 0.9 * np.maximum(wave, 0.0) ** 8 + rng.normal(0, 0.03, n)  # above z = 0.7 x
    block = ((x % 60) < 4) & ((y % 50) < 4)
    h[block] += 2.5
    positions = np.column_stack([x, y, 0.7 * x + h])
    grade = lambda px, py: np.full(len(px), 0.7)  # noqa: E731
    plain = misfit_thresholds(positions, h, 0.1, block=12.0)
    sloped = misfit_thresholds(positions, h, 0.1, block=12.0, grade=grade)
    wide = plain > 0.1
    assert wide.any() and np.all(sloped[~wide] == 0.1)
    # half a control spacing (3 m) x 0.7 = 2.1 m over the global threshold, capped at MISFIT_HIGH
    np.testing.assert_allclose(sloped[wide], np.maximum(plain[wide], MISFIT_HIGH))
    ground = ~block
    assert (np.abs(h[ground]) <= sloped[ground]).mean() > (np.abs(h[ground]) <= plain[ground]).mean()
    assert np.all(h[block] > sloped[block])


def test_thresholds_equal_the_plain_reference(rng):
    """The kernels give the plain reference's thresholds exactly: widened blocks (a sloped
    field with gullies 1 m deep that a smooth surface bridges), points with non-finite
    coordinates or heights, power-of-two and other cell sizes."""
    import naive

    n = 30_000
    x, y = rng.uniform(0, 120, n), rng.uniform(-40, 60, n)
    heights = 0.5 * np.sin(2 * np.pi * y / 10.0) + rng.normal(0, 0.03, n)
    heights[rng.uniform(size=n) < 0.05] += 2.0  # obstacles, left out above MISFIT_HIGH
    cloud = np.column_stack([x, y, heights + 0.3 * x])
    cloud[::211, 0] = np.nan
    cloud[5::307, 1] = np.inf
    heights[7::401] = np.nan
    widened = 0
    for cell, block in ((1.0, 12.0), (0.5, 7.0), (0.7, 12.0), (1.0, 3.0)):
        for threshold in (0.1, 0.3):
            got = misfit_thresholds(cloud, heights, threshold, block=block, cell=cell)
            expected = naive.misfit_thresholds(cloud, heights, threshold, block=block, cell=cell)
            np.testing.assert_array_equal(got, expected)
            widened += int((got > threshold).sum())
    assert widened > 0


def test_a_fine_control_spacing_still_measures_the_misfit(rng):
    """Blocks of two control spacings at a 1.5 m spacing (a 40 x 40 refit over 60 m) would be
    3 x 3 cells, of which about half lie below a surface that follows the terrain: never the
    20 cells a block needs. Blocks are 7 cells a side at least, so a gully the surface bridges
    widens the threshold at any spacing, and flat ground still keeps the global one."""
    n = 60 * 40 * 20
    cloud = np.c_[rng.uniform(0, 60, n), rng.uniform(0, 40, n), np.zeros(n)]
    flat = rng.normal(0, 0.02, n)
    gully = (cloud[:, 0] >= 20) & (cloud[:, 0] < 24)  # 4 m wide, 0.6 m deep
    for block in (3.0, 10.0):
        assert widened_thresholds(cloud, flat, 0.1, block=block) is None
        got = widened_thresholds(cloud, flat - 0.6 * gully, 0.1, block=block)
        assert got is not None and np.all(got[gully] > 0.5)
        assert np.all(got[cloud[:, 0] > 40] == 0.1)  # far from the gully: the global one


def test_widened_thresholds_is_none_exactly_when_no_point_is_widened():
    rng = np.random.default_rng(11)
    n = 20_000
    cloud = np.c_[rng.uniform(0, 60, n), rng.uniform(0, 40, n), np.zeros(n)]
    flat = rng.normal(0, 0.02, n)
    gully = flat - 0.8 * ((cloud[:, 0] >= 20) & (cloud[:, 0] < 30))  # a gully it bridges
    for heights, widened in ((flat, False), (gully, True)):
        full = misfit_thresholds(cloud, heights, 0.1, block=10.0)
        got = widened_thresholds(cloud, heights, 0.1, block=10.0)
        assert (got is not None) == widened == bool((full > 0.1).any())
        if got is not None:
            np.testing.assert_array_equal(got, full)


def test_slope_term_measures_slope_from_the_ground_under_the_sensor(rng):
    """segment_points' slope term takes level from the surface under the sensor: on a plane
    pitched 10° around the sensor (a tilted sensor on level ground) the grade is ~0 and the
    gradient found is the tilt; a sensor outside the cloud (an airborne tile) or without
    enough ground around it keeps the cloud's z axis as level."""
    from o3d_terrain.api import fit_terrain
    from o3d_terrain.segment import _grade_from_sensor_ground, sensor_ground_gradient

    n = 40_000
    x, y = rng.uniform(-40, 40, n), rng.uniform(-30, 30, n)
    tilt = np.tan(np.radians(10.0))
    z = tilt * x + 0.05 * np.sin(x / 3.0) * np.cos(y / 4.0) + rng.normal(0, 0.02, n)
    positions = np.column_stack([x, y, z])
    surface = fit_terrain(positions)
    h = surface.heights_above(positions)
    gx, gy = sensor_ground_gradient(surface, positions, h, 0.2)
    assert abs(gx - tilt) < 0.01 and abs(gy) < 0.01
    grade = _grade_from_sensor_ground(surface, positions, h, 0.2, (0.0, 0.0, 0.0))
    assert np.all(grade(x[:1000], y[:1000]) < 0.05)
    # outside the cloud, or fewer than the least number of ground points within the radius
    assert sensor_ground_gradient(surface, positions, h, 0.2, (500.0, 0.0, 0.0)) == (0.0, 0.0)
    assert sensor_ground_gradient(surface, positions, h, 0.2, min_points=n + 1) == (0.0, 0.0)
    far = _grade_from_sensor_ground(surface, positions, h, 0.2, (500.0, 0.0, 0.0))
    np.testing.assert_allclose(far(x[:1000], y[:1000]),
                               np.hypot(*surface.gradient(x[:1000], y[:1000])))


def test_local_planes_take_ground_the_surface_undercuts_not_objects():
    """local_plane_terrain: on a 30° plane 1 m above the surface (a ridge the surface
    undercuts), a point on the plane between terrain points becomes terrain; a point 0.5 m
    above the plane (a bush) does not, nor does one beyond the terrain (not surrounded)."""
    g = np.arange(-3.0, 3.01, 0.5)
    gx, gy = np.meshgrid(g, g)
    gx, gy = gx.ravel(), gy.ravel()
    off = (gx != 0) | (gy != 0)
    gx, gy = gx[off], gy[off]
    slope = np.tan(np.radians(30))
    # terrain points: the plane's points left of x = 1 (already labelled terrain)
    keep = gx < 1.0
    x = np.concatenate([gx[keep], [0.0, 0.25, 2.5]])
    y = np.concatenate([gy[keep], [0.0, 0.25, 0.0]])
    h = 1.0 + slope * x
    h[-2] += 0.5  # a bush
    cloud = np.column_stack([x, y, np.zeros_like(x)])
    terrain = np.ones(x.size, bool)
    terrain[-3:] = False
    candidates = np.arange(x.size - 3, x.size)
    n = local_plane_terrain(cloud, h, terrain, candidates, radius=3.0, threshold=0.2)
    assert n == 1
    assert terrain[-3] and not terrain[-2] and not terrain[-1]


def _local_planes_reference(p, h, terrain, candidates, radius, threshold, min_points=4,
                            rounds=20, lends=None):
    """local_plane_terrain point by point (scipy's k-d tree for the neighbours, numpy's
    solver for the plane), each round from the terrain of the round before; ``lends``: the
    points the planes may read (None = all)."""
    from scipy.spatial import cKDTree
    terrain = terrain.copy()
    for _ in range(rounds):
        ground = np.flatnonzero(terrain if lends is None else terrain & lends)
        tree = cKDTree(p[ground, :2])
        new = []
        for i in candidates[~terrain[candidates]]:
            near = ground[tree.query_ball_point(p[i, :2], radius)]
            d = p[near, :2] - p[i, :2]
            d2 = (d * d).sum(axis=1)
            near, d = near[d2 <= radius * radius], d[d2 <= radius * radius]
            if (near.size < min_points or not (d[:, 0] > 0).any() or not (d[:, 0] < 0).any()
                    or not (d[:, 1] > 0).any() or not (d[:, 1] < 0).any()):
                continue
            a = np.column_stack([np.ones(near.size), d])
            intercept = np.linalg.solve(a.T @ a, a.T @ h[near])[0]
            if h[i] - intercept <= threshold:
                new.append(i)
        if not new:
            break
        terrain[new] = True
    return terrain


def test_local_planes_equal_the_point_by_point_reference(rng):
    """local_plane_terrain reads dense neighbour cells as sums over sub-cells (each sub-cell
    whose terrain lies wholly within the radius) and sparse ones point by point: both give
    the labels of the point-by-point reference, over several rounds (a 3 x 3 m patch of
    candidates on a 20° slope taken up from its edges, with 0.4 m bushes among them)."""
    for density, radius in ((400.0, 0.5), (3.0, 2.0)):  # 4 sub-cells a side / 1
        n = int(12 * 12 * density)
        x, y = rng.uniform(0, 12, n), rng.uniform(0, 12, n)
        h = 1.0 + np.tan(np.radians(20)) * x + rng.normal(0, 0.02, n)
        patch = (np.abs(x - 6) < 1.5) & (np.abs(y - 6) < 1.5)
        bush = patch & (rng.uniform(size=n) < 0.1)
        h[bush] += 0.4
        p = np.column_stack([x, y, np.zeros(n)])
        terrain = ~patch
        candidates = np.flatnonzero(patch)
        expected = _local_planes_reference(p, h, terrain, candidates, radius, 0.1)
        got = terrain.copy()
        taken = local_plane_terrain(p, h, got, candidates, radius=radius, threshold=0.1,
                                    cell_points=2**62)
        np.testing.assert_array_equal(got, expected)
        assert taken == int(expected[patch].sum()) > 0.8 * (patch & ~bush).sum()
        assert not got[bush].any()


def test_local_planes_later_rounds_equal_the_reference_round_for_round(rng):
    """After the first round each candidate's neighbour sums are kept and the terrain taken
    in the round before is added to them (its sub-cells read again where much was taken):
    after every round the labels equal the point-by-point reference's, on a dense cloud (sums
    over sub-cells) and a sparse one (every point read), candidates in a patch with a little
    terrain among them taken up over several rounds, 0.4 m bushes left out."""
    for density, radius, side, patch_side, kept in ((400.0, 0.3, 12.0, 4.0, 0.02),
                                                    (1.0, 2.0, 40.0, 20.0, 0.3)):
        n = int(side * side * density)
        x, y = rng.uniform(0, side, n), rng.uniform(0, side, n)
        h = 1.0 + np.tan(np.radians(20)) * x + 0.3 * np.sin(y) + rng.normal(0, 0.02, n)
        patch = (np.abs(x - side / 2) < patch_side / 2) & (np.abs(y - side / 2) < patch_side / 2)
        bush = patch & (rng.uniform(size=n) < 0.1)
        h[bush] += 0.4
        p = np.column_stack([x, y, np.zeros(n)])
        terrain = ~patch | (~bush & (rng.uniform(size=n) < kept))
        candidates = np.flatnonzero(~terrain)
        expected = terrain
        changed = 0
        for rounds in range(1, 21):
            before = expected
            expected = _local_planes_reference(p, h, before, candidates, radius, 0.05, rounds=1)
            got = terrain.copy()
            taken = local_plane_terrain(p, h, got, candidates, radius=radius, threshold=0.05,
                                        rounds=rounds, cell_points=2**62)
            np.testing.assert_array_equal(got, expected)
            assert taken == int((got & ~terrain).sum())
            if (expected == before).all():
                break
            changed += 1
        assert changed >= 3
        assert not got[bush].any() and got[patch & ~bush].mean() > 0.7


def _strided_share(p, cells_of, listed, most):
    """The points a cell lends when it lends every k-th of its ``listed`` points in index
    order, k the smallest stride leaving at most ``most`` (cells: ``cells_of``)."""
    lends = np.zeros(len(p), bool)
    for c in np.unique(cells_of[listed]):
        members = np.flatnonzero(listed & (cells_of == c))
        lends[members[::-(-members.size // most)]] = True
    return lends


def test_local_planes_read_a_regular_share_of_a_dense_cell(rng):
    """A neighbour cell (``radius`` wide, from the candidates' box grown by ``radius``)
    holding more than ``cell_points`` points lends every k-th of them in index order to the
    planes: the labels equal the point-by-point reference's on that share, every
    candidate still decided; and the share changes which points the planes read."""
    n, radius, cap = 20000, 0.5, 10
    x, y = rng.uniform(0, 12, n), rng.uniform(0, 12, n)
    h = 1.0 + np.tan(np.radians(20)) * x + 0.3 * np.sin(y) + rng.normal(0, 0.03, n)
    patch = (np.abs(x - 6) < 3) & (np.abs(y - 6) < 3)
    bush = patch & (rng.uniform(size=n) < 0.1)
    h[bush] += 0.4
    p = np.column_stack([x, y, np.zeros(n)])
    terrain = ~patch | (~bush & (rng.uniform(size=n) < 0.05))
    candidates = np.flatnonzero(~terrain)
    x0, y0 = x[candidates].min() - radius, y[candidates].min() - radius
    x1, y1 = x[candidates].max() + radius, y[candidates].max() + radius
    inside = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    cells = np.floor((x - x0) / radius) * 10**6 + np.floor((y - y0) / radius)
    lends = _strided_share(p, cells, inside, cap)
    assert lends[inside].mean() < 0.5
    expected = _local_planes_reference(p, h, terrain, candidates, radius, 0.05, lends=lends)
    got = terrain.copy()
    taken = local_plane_terrain(p, h, got, candidates, radius=radius, threshold=0.05,
                                cell_points=cap)
    np.testing.assert_array_equal(got, expected)
    assert taken == int((got & ~terrain).sum()) > 0
    assert not got[bush].any()


def test_local_planes_recover_ridges_in_widened_blocks(rng, monkeypatch, vehicle_scan):
    """A sparse 35° mountain slope with 2 m ridges 16 m apart (the 6 m control spacing
    undercuts them beyond the widened threshold): the local planes recover ridge ground, and
    no more of the 2.5 m blocks become terrain. Read as a vehicle's scan, as above."""
    import o3d_terrain.segment as seg
    n = int(240 * 200 * 0.7)
    x, y = rng.uniform(0, 240, n), rng.uniform(0, 200, n)
    z = 0.7 * x + 2.0 * np.sin(2 * np.pi * y / 16.0) + rng.normal(0, 0.03, n)
    block = ((x % 60) < 4) & ((y % 50) < 4)
    z[block] += 2.5
    cloud = np.column_stack([x, y, z])

    def scores():
        mask = np.zeros(n, bool)
        mask[segment_terrain(cloud)[1]] = True
        return (mask & ~block).sum() / (~block).sum(), (mask & block).sum()

    r_with, fp_with = scores()
    monkeypatch.setattr(seg, "local_plane_terrain", lambda *a, **k: 0)
    r_without, fp_without = scores()
    assert r_with > r_without + 0.015
    assert fp_with <= fp_without


def _airborne_mounds():
    """An airborne strip (6 pulses/m2 from 300 m, projected coordinates) over the gravel
    mounds with the default obstacles and a 0.4 m rock: no point lies near the origin."""
    from o3d_terrain.synthetic import Obstacle, default_obstacles, make_scene, sample_airborne
    scene = make_scene("mounds", seed=0, obstacles=False).with_obstacles(
        default_obstacles(0) + (Obstacle("rock", (5.0, 8.0), (1.0, 1.0), 0.4),))
    return sample_airborne(scene, seed=0)


def _ground_scores(cloud):
    mask = np.zeros(len(cloud), bool)
    # the vehicle's layout (a top-down scan's finer one follows more of the mounds itself)
    mask[segment_terrain(cloud.positions, control_points=(32, 32))[1]] = True
    truth = ~cloud.is_obstacle
    tp, fp, fn = (mask & truth).sum(), (mask & ~truth).sum(), (~mask & truth).sum()
    h = cloud.true_height_above_terrain
    tall = cloud.is_obstacle & (h > 0.3)
    return 2 * tp / (2 * tp + fp + fn), float(np.mean(~mask[tall]))


def test_top_down_scans_measure_points_against_local_planes(monkeypatch):
    """From the air the 0.5 m cells' surface undercuts the mounds' tops (narrower than the
    control spacing) and their ground was labelled obstacle (F1 0.989 without the local
    planes, 0.997 with them); measured against the plane of the terrain around them it is
    terrain, while every obstacle point more than 0.3 m up stays an obstacle."""
    import o3d_terrain.segment as seg
    cloud = _airborne_mounds()
    assert not seg.sensor_in_cloud(cloud.positions)
    f1_with, recall_with = _ground_scores(cloud)
    monkeypatch.setattr(seg, "_top_down_planes", lambda *a, **k: 0)
    f1_without, recall_without = _ground_scores(cloud)
    assert f1_with > 0.995 and f1_with > f1_without + 0.005
    assert recall_with == recall_without == 1.0


def test_a_vehicle_scan_is_not_top_down(rng):
    """sensor_in_cloud: a lidar frame around its sensor is a vehicle's scan; the same points
    moved 1 km away, or an airborne strip, are not (their labels then use the local planes)."""
    from o3d_terrain.segment import sensor_in_cloud
    from o3d_terrain.synthetic import make_scene, sample_lidar
    frame = sample_lidar(make_scene("flat", seed=0), seed=0).positions
    assert sensor_in_cloud(frame)
    assert not sensor_in_cloud(frame + [1000.0, 0.0, 0.0])
    assert sensor_in_cloud(frame + [1000.0, 0.0, 0.0], (1000.0, 0.0, 0.0))
    assert not sensor_in_cloud(_airborne_mounds().positions)


def test_plane_radius_holds_the_planes_points_at_the_scans_density(rng):
    """plane_radius: 4 terrain points/m2 give the radius of a disc of PLANE_POINTS of them;
    obstacle points do not count; ``most`` caps it; no terrain gives 0."""
    from o3d_terrain.misfit import PLANE_POINTS, plane_radius
    n = 40 * 40 * 4
    cloud = np.column_stack([rng.uniform(0, 40, 2 * n), rng.uniform(0, 40, 2 * n),
                             np.zeros(2 * n)])
    terrain = np.arange(2 * n) < n
    expected = np.sqrt(PLANE_POINTS / (np.pi * 4.0))
    assert abs(plane_radius(cloud, terrain, most=10.0) - expected) < 0.03 * expected
    assert plane_radius(cloud, terrain, most=0.5) == 0.5
    assert plane_radius(cloud, np.zeros(2 * n, bool), most=10.0) == 0.0


def test_top_down_labels_drop_bad_points_and_keep_the_rest():
    """An airborne strip with 5 % NaN rows and a few infinite coordinates: the bad points are
    never inliers, and the others get the labels they get without the bad rows."""
    cloud = _airborne_mounds()
    p = cloud.positions.copy()
    clean = segment_terrain(p)[1]
    noisy = np.vstack([p, np.full((len(p) // 20, 3), np.nan), [[np.inf, 0.0, 0.0]] * 3])
    inliers = segment_terrain(noisy)[1]
    assert inliers.max() < len(p)
    np.testing.assert_array_equal(inliers, clean)


def test_face_points_are_the_vertical_stacks_above_the_bound():
    """A column of returns stacked up a wall is a face; the same heights spread along a
    35-degree ridge (one point per column) are not; points below MISFIT_FACE_LOW never are."""
    from o3d_terrain.misfit import MISFIT_FACE_LOW, face_points
    wall = np.column_stack([np.full(6, 5.02), np.full(6, 3.01), np.linspace(0.6, 1.4, 6)])
    ridge = np.column_stack([np.linspace(10, 12, 6), np.full(6, 3.0),
                             0.6 + 0.7 * np.linspace(0, 2, 6) * 0.4])
    low = np.column_stack([np.full(3, 20.05), np.full(3, 1.0), [0.1, 0.3, 0.45]])
    p = np.vstack([wall, ridge, low])
    h = p[:, 2].copy()  # a level surface at z = 0
    faces = face_points(p, h, np.arange(len(p)))
    np.testing.assert_array_equal(faces, np.arange(6))
    assert low[:, 2].max() < MISFIT_FACE_LOW


def test_widened_blocks_keep_the_sides_of_objects_beside_rough_ground(monkeypatch):
    """A 64-channel lidar 5 m up over the 120 m offroad frame: the surface misfits the bumps
    30-35 m out and the misfit widens the threshold there to 0.6-1.5 m, which took the lower
    part of the car and the pedestrian standing there (obstacle recall 0.747 measured); the
    returns of their sides stack in one column and stay obstacles (0.946)."""
    from o3d_terrain import segment
    from o3d_terrain.synthetic import Obstacle, default_obstacles, make_scene, sample_lidar
    obstacles = tuple(Obstacle(o.kind, (o.center[0] + 20.0, o.center[1]), o.size, o.height,
                               o.yaw_deg) for o in default_obstacles(0))
    scene = make_scene("offroad", seed=0, obstacles=False,
                       region=(-60.0, 60.0, -60.0, 60.0)).with_obstacles(obstacles)
    cloud = sample_lidar(scene, seed=0, sensor_height=5.0, fov_deg=(-20.0, 10.0), beams=64,
                         azimuth_steps=1800)
    p = cloud.positions
    tall = cloud.is_obstacle & (p[:, 2] - cloud.terrain_height(p[:, 0], p[:, 1]) > 0.3)

    def recall():
        # on the robust fit's layout: the default refit's finer one (o3d_terrain.refine)
        # follows these bumps, and the misfit no longer widens the threshold there
        _, inliers = segment_terrain(p, control_points=(32, 32))
        terrain = np.zeros(len(p), bool)
        terrain[inliers] = True
        return float(np.mean(~terrain[tall]))

    with_faces = recall()
    monkeypatch.setattr(segment, "face_points", lambda *a, **k: np.zeros(0, np.int64))
    without = recall()
    assert with_faces > 0.9
    assert without < with_faces - 0.1


def test_depth_below_slope_equals_the_point_by_point_reference(rng):
    from o3d_terrain._kernels.local_plane import depth_below_slope
    p = np.column_stack([rng.uniform(0, 20, 3000), rng.uniform(0, 20, 3000),
                         rng.normal(0, 0.5, 3000)])
    terrain = rng.uniform(size=3000) < 0.6
    idx = rng.choice(3000, 300, replace=False)
    gx, gy = rng.normal(0, 0.5, 300), rng.normal(0, 0.5, 300)
    alone = depth_below_slope(p, terrain, idx, gx, gy, 0.9, 10**9, 10**9)
    both = depth_below_slope(p, terrain, idx, gx, gy, 0.9, 6, 10**9)
    planes = 0
    for k, i in enumerate(idx):
        d = p[:, :2] - p[i, :2]
        near = terrain & (np.hypot(d[:, 0], d[:, 1]) <= 0.9)
        near[i] = False
        e = p[near, 2] - p[i, 2] - (gx[k] * d[near, 0] + gy[k] * d[near, 1])
        assert alone[k] == (e.min() if e.size else np.inf)
        if e.size + 1 < 6 or e.min() >= 0:
            assert both[k] == alone[k]
            continue
        q = np.vstack([p[i], p[near]])
        normal = np.linalg.eigh(np.cov(q.T, bias=True))[1][:, 0]
        if abs(normal[2]) < 0.1:
            assert both[k] == max(e.min(), 0.0)
            continue
        own = p[near, 2] - p[i, 2] + (normal[0] * d[near, 0] + normal[1] * d[near, 1]) / normal[2]
        np.testing.assert_allclose(both[k], max(e.min(), own.min()), atol=1e-9)
        planes += 1
    assert planes > 100


def test_depth_below_slope_reads_a_regular_share_of_a_dense_cell(rng):
    """A cell of the neighbour grid (cells ``radius`` wide from the candidates' box grown by
    ``radius``) holding more than ``cell_points`` terrain points gives every k-th of them in
    index order, k the smallest stride leaving at most ``cell_points``; other cells all."""
    from o3d_terrain._kernels.local_plane import depth_below_slope
    n, radius, cap = 4000, 0.9, 20
    p = np.column_stack([rng.uniform(0, 6, n), rng.uniform(0, 6, n), rng.normal(0, 0.5, n)])
    p[:1000, :2] = rng.uniform(2.0, 2.8, (1000, 2))  # one dense patch: strided cells
    terrain = rng.uniform(size=n) < 0.7
    idx = rng.choice(n, 200, replace=False)
    gx, gy = rng.normal(0, 0.5, 200), rng.normal(0, 0.5, 200)
    got = depth_below_slope(p, terrain, idx, gx, gy, radius, 10**9, cap)
    x0, y0 = p[idx, 0].min() - radius, p[idx, 1].min() - radius
    cell = np.floor((p[:, 0] - x0) / radius) * 10**6 + np.floor((p[:, 1] - y0) / radius)
    kept = np.zeros(n, bool)
    strided = 0
    for c in np.unique(cell[terrain]):
        members = np.flatnonzero(terrain & (cell == c))
        stride = -(-members.size // cap)
        kept[members[::stride]] = True
        strided += stride > 1
    assert strided > 0
    for k, i in enumerate(idx):
        d = p[:, :2] - p[i, :2]
        near = kept & (np.hypot(d[:, 0], d[:, 1]) <= radius)
        near[i] = False
        e = p[near, 2] - p[i, 2] - (gx[k] * d[near, 0] + gy[k] * d[near, 1])
        assert got[k] == (e.min() if e.size else np.inf)


def test_points_over_terrain_are_those_with_terrain_beneath_them_beyond_the_slope():
    """On a 50° slope (terrain points every 0.25 m) a point 0.8 m above the slope stands over
    the terrain; a point on the slope, and one above the terrain's edge with nothing within
    reach beneath it, do not, even where the surface's slope is wrong (level)."""
    g = np.arange(0.0, 10.0, 0.25)
    x, y = np.meshgrid(g, g, indexing="ij")
    slope = np.tan(np.radians(50.0))
    ground = np.column_stack([x.ravel(), y.ravel(), slope * x.ravel()])
    extra = np.array([[5.1, 5.1, slope * 5.1 + 0.8],   # a bush's top over the slope
                      [5.1, 5.1, slope * 5.1 + 0.01],  # on the slope
                      [12.0, 5.0, slope * 12.0 + 0.8]])  # beyond the terrain's edge
    p = np.vstack([ground, extra])
    terrain = np.ones(len(p), bool)
    candidates = np.arange(len(ground), len(p))

    def gradient(px, py):
        return np.full(len(px), slope), np.zeros(len(px))

    over = over_terrain(p, candidates, terrain, gradient)
    assert over.tolist() == [len(ground)]
    assert OVER_DEPTH < 0.8 and OVER_RADIUS > 0.25 * np.sqrt(2)
    # a face steeper than the surface: measured against a level surface the slope's points
    # lie below each other, but along their own plane
    level = over_terrain(p, candidates, terrain, lambda px, py: (0 * px, 0 * py))
    assert level.tolist() == [len(ground)]
    alone = over_terrain(p, candidates, terrain, lambda px, py: (0 * px, 0 * py),
                         plane_points=10**9)
    assert len(ground) + 1 in alone.tolist()


def _shrubs_on_a_mountain(rng, share=0.35, corner=(1000.0, 2000.0)):
    """The sparse 35° mountain slope of the gullies test (0.7 points/m², ridges and gullies
    10 m apart) from the air, a 60 m band of it under shrubs: ``share`` of the band's returns
    from the shrubs 0.3-1.2 m up, the rest from the ground under them."""
    n = int(240 * 200 * 0.7)
    x, y = rng.uniform(0, 240, n), rng.uniform(0, 200, n)
    z = 0.7 * x + 0.6 * np.sin(2 * np.pi * y / 10.0) + rng.normal(0, 0.03, n)
    shrub = (x > 100) & (x < 160) & (rng.uniform(size=n) < share)
    z[shrub] += rng.uniform(0.3, 1.2, shrub.sum())
    return np.column_stack([x + corner[0], y + corner[1], z]), shrub


def test_top_down_scans_keep_shrubs_over_the_ground_obstacles(rng, monkeypatch):
    """The widened threshold and the local planes take shrubs up to 1.2 m over a steep sparse
    slope the surface cannot follow (1,419 of 3,015 without the rule, 413 with it); the
    ground keeps its recall (the ridges the surface undercuts have no terrain beneath them).
    With the tile's corner at the origin too: a tile in local coordinates is not a scan."""
    import o3d_terrain.segment as seg
    for corner in ((1000.0, 2000.0), (0.0, 0.0)):
        cloud, shrub = _shrubs_on_a_mountain(np.random.default_rng(0), corner=corner)
        assert not seg.sensor_in_cloud(cloud)
        scores = []
        for rule in (True, False):
            if not rule:
                monkeypatch.setattr(seg, "over_terrain", lambda *a, **k: np.zeros(0, np.int64))
            mask = np.zeros(len(cloud), bool)
            mask[segment_terrain(cloud)[1]] = True
            scores.append(((mask & ~shrub).sum() / (~shrub).sum(), (mask & shrub).sum()))
            monkeypatch.undo()
        (recall_with, shrubs_with), (recall_without, shrubs_without) = scores
        assert shrubs_with < 0.2 * shrub.sum() and shrubs_with < 0.5 * shrubs_without
        assert recall_with >= recall_without - 0.0005 and recall_with > 0.999


def test_a_tile_around_the_origin_is_not_a_vehicle_scan(rng):
    """A top-down tile moved to local coordinates (centred at the origin, or its corner on
    it) has as many points per square metre near the origin as far from it; a lidar frame
    has many more near its sensor, and keeps being a scan when cropped to its forward 60°.
    A tile too small to fill the far ring (the 40 m synthetic strip) still reads as a scan."""
    from o3d_terrain.segment import sensor_in_cloud
    from o3d_terrain.synthetic import make_scene, sample_lidar
    tile = np.column_stack([rng.uniform(-60, 60, 60_000), rng.uniform(-50, 50, 60_000),
                            rng.normal(0, 0.05, 60_000)])
    assert not sensor_in_cloud(tile)
    assert not sensor_in_cloud(tile - [-60.0, -50.0, 0.0])
    assert not sensor_in_cloud(tile + [1000.0, 0.0, 0.0])
    strip = _airborne_mounds().positions
    assert not sensor_in_cloud(strip)
    assert sensor_in_cloud(strip - [*strip[:, :2].mean(axis=0), 0.0])
    frame = sample_lidar(make_scene("hills", seed=0), seed=0).positions
    assert sensor_in_cloud(frame)
    ahead = frame[np.abs(np.arctan2(frame[:, 1], frame[:, 0])) < np.radians(30.0)]
    assert sensor_in_cloud(ahead)
