import numpy as np
import pytest
from naive import grid_layer_statistics as naive_layer_statistics
from naive import grid_quantize as naive_quantize

from o3d_terrain import GridQuantize, InputError, quantize_points
from o3d_terrain.errors import ConfigError
from o3d_terrain.grid import FILLED, INVALID, MEASURED, HeightGrid


def test_kernel_matches_reference_exactly(rng):
    pts = rng.normal(0, 3, size=(3000, 3))
    pts[::97] = np.nan  # non-finite points are skipped
    pts[5, 2] = np.inf
    grid = quantize_points(pts, cell_size=0.7, region=(-6, 6, -5, 5))
    z, count, state, lowest, highest, mean = naive_quantize(pts, -6, -5, 0.7, grid.nx, grid.ny)
    np.testing.assert_array_equal(grid.z, z)
    np.testing.assert_array_equal(grid.count, count)
    np.testing.assert_array_equal(grid.state, state)
    np.testing.assert_array_equal(grid.lowest, lowest)
    np.testing.assert_array_equal(grid.highest, highest)
    np.testing.assert_array_equal(grid.mean, mean)
    assert np.isinf(highest).any() and (highest[np.isfinite(highest)] > z[np.isfinite(highest)]).any()


@pytest.mark.parametrize("layer", [0.24, 1.5])
def test_layer_statistics_match_reference_exactly(rng, layer):
    # heavy-tailed heights: cells hold points within, just above and far above their layer
    pts = np.c_[rng.uniform(-4, 4, (800, 2)), rng.exponential(0.5, 800)]
    pts[::89] = np.nan
    pts[7, 2] = -np.inf
    pts[11, :2] = 50.0  # outside the region
    pts[13] = pts[12] + [0.0, 0.0, layer]  # on the top of the layer if 12 is the lowest
    region = (-4.0, 4.0, -4.0, 4.0)
    for cell in (0.5, 0.7):  # multiplied by 1 / cell and divided by the cell size
        grid = quantize_points(pts, cell_size=cell, region=region, layer=layer)
        x0, _, y0, _ = grid.region
        count, total, above = naive_layer_statistics(pts, x0, y0, cell, grid.nx, grid.ny, layer)
        assert grid.layer == layer
        np.testing.assert_array_equal(grid.layer_count, count)
        np.testing.assert_array_equal(grid.layer_sum, total)
        np.testing.assert_array_equal(grid.layer_above, above)
        assert np.isfinite(above).sum() > 20 and np.isinf(above[grid.count > 1]).any()
        assert np.isinf(above[grid.count == 1]).all()
        assert (above[np.isfinite(above)] > (grid.lowest + layer)[np.isfinite(above)]).all()
    plain = quantize_points(pts, cell_size=0.5, region=region)
    assert plain.layer_count is None and plain.layer_sum is None and plain.layer_above is None


@pytest.mark.parametrize("min_points,fill", [(3, True), (1, False)])
def test_kernel_matches_reference_options(rng, min_points, fill):
    pts = rng.uniform(0, 4, size=(400, 3))
    grid = quantize_points(pts, cell_size=0.5, min_points=min_points, fill_empty=fill)
    x0, _, y0, _ = grid.region
    z, count, state, lowest, highest, mean = naive_quantize(pts, x0, y0, 0.5, grid.nx, grid.ny,
                                                            min_points, fill)
    np.testing.assert_array_equal(grid.z, z)
    np.testing.assert_array_equal(grid.state, state)
    np.testing.assert_array_equal(grid.lowest, lowest)
    np.testing.assert_array_equal(grid.highest, highest)
    np.testing.assert_array_equal(grid.mean, mean)


@pytest.mark.parametrize("cell", [0.25, 0.5, 2.0, 0.7, 0.1])
def test_points_on_cell_edges_match_reference(rng, cell):
    """Power-of-two cell sizes scale the coordinates by a multiplication: points on and next to
    the cell edges (and the far edge of the grid) fall in the cells the division gives."""
    edges = np.arange(0, 41) * cell  # with 0.7 and 0.1, x * (1 / cell) moves some of them
    x = np.r_[edges, np.nextafter(edges, -np.inf), np.nextafter(edges, np.inf),
              rng.uniform(0, 40 * cell, 200)]
    y = rng.permutation(x)
    pts = np.c_[x, y, rng.normal(0, 1, x.size)]
    region = (0.0, 40 * cell, 0.0, 40 * cell)
    grid = quantize_points(pts, cell_size=cell, region=region)
    z, count, state, lowest, highest, mean = naive_quantize(pts, 0.0, 0.0, cell, grid.nx,
                                                            grid.ny)
    np.testing.assert_array_equal(grid.count, count)
    np.testing.assert_array_equal(grid.z, z)
    np.testing.assert_array_equal(grid.lowest, lowest)
    assert grid.skipped_outside > 0 and grid.count.sum() + grid.skipped_outside == x.size



@pytest.mark.parametrize("cell", [0.5, 0.7])
def test_scan_order_runs_and_odd_values_match_reference(rng, cell):
    """Points in runs of one cell (a scan's order, summed in registers by the kernel) with
    non-finite x, y or z, values far outside and on the far edges among them: the cells,
    the sums and the skipped counts of the plain reference."""
    pts = rng.uniform(0, 6 * cell, size=(600, 3))
    pts = pts[np.lexsort((np.floor(pts[:, 1] / cell), np.floor(pts[:, 0] / cell)))]
    odd = np.array([np.nan, np.inf, -np.inf, 1e308, -1e308, -1e-300, 6 * cell, -0.0])
    for column in range(3):
        rows = rng.choice(len(pts), 40, replace=False)
        # z: non-finite values only (huge ones would overflow the cells' sums, in both)
        pts[rows, column] = rng.choice(odd if column < 2 else odd[[0, 1, 2, 7]], 40)
    region = (0.0, 6 * cell, 0.0, 6 * cell)
    grid = quantize_points(pts, cell_size=cell, region=region)
    z, count, state, lowest, highest, mean = naive_quantize(pts, 0.0, 0.0, cell, grid.nx,
                                                            grid.ny)
    for name, expected in (("z", z), ("count", count), ("state", state), ("lowest", lowest),
                           ("highest", highest), ("mean", mean)):
        np.testing.assert_array_equal(getattr(grid, name), expected, err_msg=name)
    finite = np.isfinite(pts).all(axis=1)
    # a finite x whose distance from the region overflows counts as non-finite, as in _cell
    with np.errstate(over="ignore", invalid="ignore"):
        scaled = np.abs(pts[:, :2] - np.array(region)[[0, 2]]) / cell
    nonfinite = ~finite | ~np.isfinite(scaled).all(axis=1)
    assert grid.skipped_nonfinite == nonfinite.sum()
    assert grid.skipped_nonfinite + grid.skipped_outside + count.sum() == len(pts)

@pytest.mark.parametrize("order", ["scan", "random"])
def test_cell_sums_in_place_and_side_by_side_agree(rng, order):
    """The two ways of summing the cells (straight into the four arrays for points in runs
    of one cell, side by side in one array for points one to a run) give the same values bit
    for bit, with points outside the grid and non-finite ones among them; the kernel takes
    the first for a scan's order and the second for random order."""
    from o3d_terrain._kernels import grid as kernels
    cell, n = 0.5, 4000
    pts = rng.uniform(-0.5, 10.5, size=(n, 3))
    if order == "scan":
        pts = pts[np.lexsort((np.floor(pts[:, 1] / cell), np.floor(pts[:, 0] / cell)))]
    pts[rng.choice(n, 30, replace=False), 2] = np.nan
    flat = np.ascontiguousarray(pts).reshape(-1)
    cells = np.empty(n, np.int32)
    kernels._cells_of(flat, 0.0, 0.0, cell, 2.0, 20, 20, cells)
    assert (cells == -1).any() and (cells == -2).any()
    assert (2 * kernels._run_count(cells) > n) == (order == "random")
    got = kernels._cell_sums(flat, cells, 400)
    side = kernels._cell_sums_side_by_side(flat, cells, 400)
    for a, b in zip(got, side):
        np.testing.assert_array_equal(a, b)
        assert np.asarray(a).dtype == np.asarray(b).dtype
    assert got[-2] == 30 and got[0].sum() + got[-2] + got[-1] == n


def test_equation_one_on_a_single_cell():
    z = np.array([1.0, 2.0, 3.0, 10.0])
    pts = np.column_stack([np.full(4, 0.1), np.full(4, 0.1), z])
    grid = quantize_points(pts, cell_size=1.0, region=(0, 1, 0, 1))
    expected = max(z.min(), z.mean() - z.std())
    assert grid.z[0, 0] == pytest.approx(expected)
    assert grid.state[0, 0] == MEASURED and grid.count[0, 0] == 4


def test_low_outlier_bounded_by_min():
    # eq. 1 stays within [min, max] of the cell
    z = np.array([0.0, 0.0, 0.0, -5.0])
    pts = np.column_stack([np.full(4, 0.5), np.full(4, 0.5), z])
    grid = quantize_points(pts, cell_size=1.0, region=(0, 1, 0, 1))
    assert z.min() <= grid.z[0, 0] <= z.max()


def test_fill_and_invalid_states():
    # one measured cell in a 5 x 1 strip: its neighbour is filled, the rest invalid
    pts = np.array([[0.5, 0.5, 2.0]])
    grid = quantize_points(pts, cell_size=1.0, region=(0, 5, 0, 1))
    assert list(grid.state[:, 0]) == [MEASURED, FILLED, INVALID, INVALID, INVALID]
    assert grid.z[1, 0] == 2.0 and grid.z[2, 0] == 0.0


def test_far_edge_point_lands_in_last_cell():
    pts = np.array([[0.0, 0.0, 1.0], [2.0, 2.0, 3.0]])
    grid = quantize_points(pts, cell_size=1.0)
    assert grid.shape == (2, 2)
    assert grid.count.sum() == 2 and grid.count[1, 1] == 1


def test_utm_coordinates_keep_precision():
    base = np.array([500_000.0, 4_500_000.0, 300.0])
    pts = base + np.array([[0.1, 0.1, 0.0], [0.3, 0.2, 0.001]])
    grid = quantize_points(pts, cell_size=0.5)
    assert grid.x_min == pytest.approx(500_000.1, abs=1e-9)
    assert grid.z[0, 0] == pytest.approx(300.0, abs=1e-6)


def test_bad_inputs_have_clear_errors():
    with pytest.raises(InputError, match="empty"):
        quantize_points(np.zeros((0, 3)), cell_size=1.0)
    with pytest.raises(InputError, match="no finite point"):
        quantize_points(np.full((4, 3), np.nan), cell_size=1.0)
    with pytest.raises(InputError, match="cells") as error:
        quantize_points(np.array([[0, 0, 0], [1e3, 1e3, 0.0]]), cell_size=0.01)
    assert "millimetres" not in str(error.value)
    # a 60 m scan in millimetres spans 60 km: the error says how to scale it
    with pytest.raises(InputError, match=r"spans 60 km: if the coordinates are millimetres"):
        quantize_points(np.array([[-30e3, -20e3, 0], [30e3, 20e3, 0.0]]), cell_size=0.5)
    with pytest.raises(ConfigError, match="x_max > x_min"):
        GridQuantize(region=(1, 0, 0, 1))


def test_stage_counts_skipped_points(rng):
    pts = rng.uniform(0, 10, size=(100, 3))
    pts[:3] = np.nan
    frame = GridQuantize(cell_size=1.0, region=(0, 5, 0, 10))(pts)
    notes = " ".join(frame.notes)
    assert "3 non-finite" in notes and "outside the region" in notes
    grid = frame.products["grid"]
    assert grid.count.sum() == ((pts[3:, 0] <= 5)).sum()


def test_save_load_keeps_lowest_highest_and_mean(rng, tmp_path):
    pts = rng.uniform(0, 3, size=(200, 3))
    grid = quantize_points(pts, cell_size=0.5)
    grid.save(tmp_path / "g.npz")
    back = HeightGrid.load(tmp_path / "g.npz")
    for name in ("z", "count", "state", "lowest", "highest", "mean"):
        np.testing.assert_array_equal(getattr(back, name), getattr(grid, name))


@pytest.mark.parametrize("cell,tilt_spread", [(0.5, 0.0), (0.7, 0.0), (0.5, 0.03)])
def test_cell_planes_match_reference(rng, cell, tilt_spread):
    """Eq. 1 with the in-cell slope removed: the kernel's sums in the grid's two passes give
    the plane a plain per-cell least-squares fit gives (tilted planes, steep ones capped,
    noise, cells of every count, points on one line)."""
    from naive import grid_cell_planes

    from o3d_terrain._kernels.grid import PLANE_MIN_POINTS

    xy = rng.uniform(0, 6, (1500, 2))
    z = 0.4 * xy[:, 0] - 0.9 * xy[:, 1] + np.where(xy[:, 0] > 4, 1.5 * xy[:, 0], 0.0)
    z = z + rng.normal(0, 0.02, len(z)) + np.where(rng.random(len(z)) < 0.05, 1.0, 0.0)
    level_ground = xy[:, 1] > 4.5  # noise only: tilts that do not pass the F test
    z[level_ground] = rng.normal(0, 0.05, level_ground.sum())
    line = np.c_[np.linspace(0.01, 5.99, 120), np.full(120, 3.3), np.zeros(120)]
    line[:, 2] = 0.5 * line[:, 0]
    pts = np.r_[np.c_[xy, z], line]
    pts[::101] = np.nan
    grid = quantize_points(pts, cell_size=cell, region=(0, 6, 0, 6), plane=True,
                           tilt_spread=tilt_spread)
    level, sample = grid_cell_planes(pts, 0.0, 0.0, cell, grid.nx, grid.ny,
                                     min_points=PLANE_MIN_POINTS, tilt_spread=tilt_spread)
    has = grid.count > 0
    np.testing.assert_allclose(grid.level[has], level[has], rtol=0, atol=1e-9)
    np.testing.assert_allclose(grid.plane_sample[grid.valid], sample[grid.valid], rtol=0,
                               atol=1e-9)
    dense = grid.valid & (grid.count >= PLANE_MIN_POINTS)
    kept = dense & (grid.plane_sample == grid.z) & (grid.level == grid.mean)
    assert kept.sum() >= 5 and (dense & ~kept).sum() >= 20  # both sides of the F test
    plain = quantize_points(pts, cell_size=cell, region=(0, 6, 0, 6))
    np.testing.assert_array_equal(grid.z, plain.z)  # eq. 1 itself is unchanged
    assert plain.level is None and plain.plane_sample is None


def test_cell_plane_sample_on_a_slope():
    """A dense cell on a 30 degree plane: eq. 1 sits rise / sqrt(12) low (points spread evenly),
    the plane's sample is the plane's height at the cell centre; points on one line through
    the cell (a single scan ring) give the line's height there, not a tilt across it."""
    g = np.tan(np.radians(30.0))
    u = (np.arange(20) + 0.5) / 20
    x, y = np.meshgrid(u, u, indexing="ij")
    pts = np.c_[x.ravel(), y.ravel(), g * x.ravel() + 0.1 * y.ravel()]
    grid = quantize_points(pts, cell_size=1.0, region=(0, 1, 0, 1), plane=True)
    centre = g * 0.5 + 0.05
    rise = np.hypot(g, 0.1)  # the plane's rise across the 1 m cell, along its gradient
    assert grid.z[0, 0] == pytest.approx(centre - rise / np.sqrt(12), abs=0.01)
    assert grid.level[0, 0] == pytest.approx(centre, abs=1e-9)
    assert grid.plane_sample[0, 0] == pytest.approx(centre, abs=1e-9)
    ring = np.c_[u, np.full(20, 0.2), g * u + 0.02]  # along x at y = 0.2, 0.3 off the centre
    grid = quantize_points(ring, cell_size=1.0, region=(0, 1, 0, 1), plane=True)
    assert grid.plane_sample[0, 0] == pytest.approx(g * 0.5 + 0.02, abs=1e-9)


@pytest.mark.parametrize("tilt_spread", [0.02, 0.05, 0.1])
def test_cell_planes_only_where_they_can_pass_match_reference(rng, tilt_spread):
    """The kernel fits planes only in the cells whose heights spread enough for the tilt to
    pass the tilt_spread test: cells whose tilt spreads their heights by 0.5-2 times
    tilt_spread (little noise: the F test passes) give the plain per-cell fit's level and
    sample on both sides of the test, with the sums of several cells interleaved in point
    order (consecutive points mostly in one cell, as a scanner gives them)."""
    from naive import grid_cell_planes

    nx = ny = 8
    cells = []
    for ix in range(nx):
        for iy in range(ny):
            k = int(rng.integers(4, 30))
            u = rng.uniform(0, 1, (k, 2))
            spread = tilt_spread * rng.uniform(0.5, 2.0)  # RMS of the tilt over the points
            direction = rng.normal(size=2)
            slope = direction / np.linalg.norm(direction)
            tilt = (u - u.mean(axis=0)) @ slope
            z = 3.0 + 0.1 * ix + tilt * spread / tilt.std() + rng.normal(0, 1e-4, k)
            cells.append(np.c_[ix + u[:, 0], iy + u[:, 1], z])
    pts = np.concatenate(cells)
    runs = np.split(np.arange(len(pts)), np.sort(rng.choice(len(pts), len(pts) // 4)))
    pts = pts[np.concatenate([runs[i] for i in rng.permutation(len(runs))])]
    grid = quantize_points(pts, cell_size=1.0, region=(0, nx, 0, ny), plane=True,
                           tilt_spread=tilt_spread)
    level, sample = grid_cell_planes(pts, 0.0, 0.0, 1.0, nx, ny, tilt_spread=tilt_spread)
    np.testing.assert_allclose(grid.level, level, rtol=0, atol=1e-9)
    np.testing.assert_allclose(grid.plane_sample, sample, rtol=0, atol=1e-9)
    used = grid.level != grid.mean
    assert 5 <= used.sum() <= used.size - 5  # both sides of the tilt_spread test


def test_cell_plane_level_of_cells_below_min_points(rng):
    """A cell with fewer than min_points points (not MEASURED) keeps its plane's level
    whatever the tests (they apply to MEASURED cells only): the kernel fits its plane even
    where its heights spread too little for the tilt_spread test."""
    u = rng.uniform(0, 1, (5, 2))
    pts = np.c_[u, 0.2 * u[:, 0] + 0.1 * u[:, 1]]
    tilted = quantize_points(pts, cell_size=1.0, region=(0, 1, 0, 1), plane=True)
    assert tilted.level[0, 0] != tilted.mean[0, 0]
    sparse = quantize_points(pts, cell_size=1.0, region=(0, 1, 0, 1), plane=True,
                             tilt_spread=1.0, min_points=6, fill_empty=False)
    assert sparse.state[0, 0] == INVALID
    assert sparse.level[0, 0] == tilted.level[0, 0]
    assert sparse.plane_sample[0, 0] == sparse.z[0, 0]


def test_repr_is_a_summary_not_the_arrays(rng):
    grid = quantize_points(rng.uniform(0, 20, (5000, 3)), cell_size=1.0)
    text = repr(grid)
    assert text.startswith("HeightGrid(cells=(20, 20), cell_size=1.0, region=(")
    assert "points=5000" in text and "array" not in text and len(text) < 200


def test_cell_planes_kernel_equals_the_covariance_of_each_cells_points(rng):
    """The per-slot plane of the cell_planes kernel (the face cells' planes) against each
    wanted cell's points' covariance by numpy: points in runs of one cell as a scan gives
    them, some cells' points scattered, non-finite coordinates, points outside the grid and
    on its far edge; cells not wanted and with fewer than 3 points give nothing."""
    from o3d_terrain._kernels.grid import cell_planes

    nx, ny, cell = 6, 5, 0.5
    centres = rng.integers(0, nx * ny, 300)
    runs = np.repeat(centres, rng.integers(1, 8, centres.size))
    ix, iy = np.divmod(runs, ny)
    x = (ix + rng.uniform(0, 1, runs.size)) * cell
    y = (iy + rng.uniform(0, 1, runs.size)) * cell
    z = 0.3 * x - 0.2 * y + rng.normal(0, 0.05, runs.size)
    pts = np.c_[x, y, z]
    pts[::37, 2] = np.nan
    pts[::41, 0] = np.inf
    pts[5] = (-0.1, 1.0, 0.0)  # outside
    pts[6] = (nx * cell, ny * cell, 0.0)  # the far corner: the last cell
    slot = np.full(nx * ny, -1, np.int64)
    wanted = rng.permutation(nx * ny)[:20]
    slot[wanted] = np.arange(wanted.size)
    base = rng.normal(0, 1, nx * ny)
    normal, thickness, width = cell_planes(pts, 0.0, 0.0, cell, nx, ny, slot, wanted.size, base)
    finite = np.isfinite(pts).all(axis=1) & (pts[:, 0] >= 0)
    cx = np.minimum((np.where(finite, pts[:, 0], 0) / cell).astype(int), nx - 1)
    cy = np.minimum((np.where(finite, pts[:, 1], 0) / cell).astype(int), ny - 1)
    for s, c in enumerate(wanted):
        mine = pts[finite & (cx * ny + cy == c)]
        if len(mine) < 3:
            assert np.isnan(normal[s]).all() and np.isnan(thickness[s]) and np.isnan(width[s])
            continue
        values, vectors = np.linalg.eigh(np.cov(mine.T, bias=True))
        expected = vectors[:, 0] * np.sign(vectors[2, 0])
        np.testing.assert_allclose(normal[s], expected, atol=1e-7)
        np.testing.assert_allclose(thickness[s], np.sqrt(max(values[0], 0.0)), atol=1e-7)
        np.testing.assert_allclose(width[s], np.sqrt(max(values[1], 0.0)), atol=1e-7)
