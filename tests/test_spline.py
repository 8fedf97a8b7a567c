"""Spline math: oracles (scipy NdBSpline, naive Cox-de Boor, central differences) and properties."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline, NdBSpline

from o3d_terrain._kernels import bspline as kb
from o3d_terrain.errors import InputError
from o3d_terrain.spline import TerrainSurface, clamped_uniform_knots, make_lsq_surface

import naive_spline


def random_surface(rng, n0=7, n1=6, degree=3, rational=True, origin=(0.0, 0.0, 0.0)):
    kx = clamped_uniform_knots(n0, degree, -5.0, 7.0)
    ky = clamped_uniform_knots(n1, degree, -3.0, 4.0)
    q = rng.normal(size=(n0, n1))
    r = rng.uniform(0.5, 2.0, size=(n0, n1)) if rational else np.ones((n0, n1))
    return TerrainSurface(degree, kx, ky, q, r, origin)


def test_knots_are_clamped_and_uniform():
    k = clamped_uniform_knots(6, 3, 0.0, 3.0)
    assert k.size == 10
    np.testing.assert_allclose(k, [0, 0, 0, 0, 1, 2, 3, 3, 3, 3])


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_basis_partition_of_unity_and_derivatives_match_scipy(degree):
    n = 9
    knots = clamped_uniform_knots(n, degree, 0.0, 5.0)
    t = np.linspace(0.0, 5.0, 101)
    spans, values = kb.basis_table(t, n, degree, knots, 1)
    np.testing.assert_allclose(values[:, 0, :].sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(values[:, 1, :].sum(axis=1), 0.0, atol=1e-10)
    for a in range(n):
        c = np.zeros(n)
        c[a] = 1.0
        ref = BSpline(knots, c, degree)
        ours = np.zeros_like(t)
        dours = np.zeros_like(t)
        for r in range(degree + 1):
            hit = spans - degree + r == a
            ours[hit] = values[hit, 0, r]
            dours[hit] = values[hit, 1, r]
        np.testing.assert_allclose(ours, ref(t), atol=1e-12)
        np.testing.assert_allclose(dours, ref.derivative()(t), atol=1e-9)


def test_unit_weights_equal_scipy_ndbspline():
    rng = np.random.default_rng(0)
    s = random_surface(rng, rational=False)
    ref = NdBSpline((s.knots_x, s.knots_y), s.control_points, s.degree)
    x = rng.uniform(-5, 7, 500)
    y = rng.uniform(-3, 4, 500)
    np.testing.assert_allclose(s(x, y), ref(np.stack([x, y], 1)), atol=1e-9)
    gx, gy = s.gradient(x, y)
    np.testing.assert_allclose(gx, ref(np.stack([x, y], 1), nu=(1, 0)), atol=1e-9)
    np.testing.assert_allclose(gy, ref(np.stack([x, y], 1), nu=(0, 1)), atol=1e-9)


def test_many_control_points_equal_scipy_ndbspline():
    """Cubic surfaces with uniform interior spans (evaluated in closed form) and the clamped
    end spans, through __call__ and heights_above."""
    rng = np.random.default_rng(11)
    for degree, (n0, n1) in ((3, (20, 14)), (3, (32, 9)), (2, (15, 12))):
        s = TerrainSurface(degree, clamped_uniform_knots(n0, degree, -3.0, 41.0),
                           clamped_uniform_knots(n1, degree, 2.0, 17.5),
                           rng.normal(size=(n0, n1)), np.ones((n0, n1)))
        ref = NdBSpline((s.knots_x, s.knots_y), s.control_points, s.degree)
        x = np.r_[rng.uniform(-3, 41, 3000), -3.0, 41.0, s.knots_x]  # knots: span edges
        y = np.r_[rng.uniform(2, 17.5, 3000), 17.5, 2.0, rng.uniform(2, 17.5, s.knots_x.size)]
        expected = ref(np.stack([x, y], 1))
        np.testing.assert_allclose(s(x, y), expected, atol=1e-9)
        z = rng.normal(size=x.size)
        np.testing.assert_allclose(s.heights_above(np.c_[x, y, z]), z - expected, atol=1e-9)


def test_rational_surface_equals_naive_double_sum():
    rng = np.random.default_rng(1)
    s = random_surface(rng, n0=5, n1=6, degree=2)
    for x, y in rng.uniform([-5, -3], [7, 4], size=(30, 2)):
        ref = naive_spline.rational_surface(x, y, s.knots_x, s.knots_y, s.degree,
                                            s.control_points, s.weights)
        assert s(x, y) == pytest.approx(ref, abs=1e-12)
    # the right and top edges belong to the last span
    ref = naive_spline.rational_surface(7.0, 4.0, s.knots_x, s.knots_y, s.degree,
                                        s.control_points, s.weights)
    assert s(7.0, 4.0) == pytest.approx(ref, abs=1e-12)


def test_rational_derivatives_equal_central_differences():
    rng = np.random.default_rng(2)
    s = random_surface(rng)
    x = rng.uniform(-4.9, 6.9, 200)
    y = rng.uniform(-2.9, 3.9, 200)
    h = 1e-5
    gx, gy = s.gradient(x, y)
    np.testing.assert_allclose(gx, (s(x + h, y) - s(x - h, y)) / (2 * h), atol=1e-6)
    np.testing.assert_allclose(gy, (s(x, y + h) - s(x, y - h)) / (2 * h), atol=1e-6)


def test_weights_scale_invariance_and_convex_hull():
    rng = np.random.default_rng(3)
    s = random_surface(rng)
    s2 = TerrainSurface(s.degree, s.knots_x, s.knots_y, s.control_points, 7.5 * s.weights)
    x = rng.uniform(-5, 7, 100)
    y = rng.uniform(-3, 4, 100)
    np.testing.assert_allclose(s(x, y), s2(x, y), atol=1e-12)
    assert np.all(s(x, y) <= s.control_points.max() + 1e-12)
    assert np.all(s(x, y) >= s.control_points.min() - 1e-12)


def test_slope_of_tilted_plane():
    x = np.linspace(0, 10, 21)
    y = np.linspace(-5, 5, 21)
    z = 0.2 * x[:, None] + 0 * y[None, :]
    s = make_lsq_surface(x, y, z, control_points=(6, 6), degree=3)
    px = np.array([1.3, 5.0, 9.7])
    py = np.array([-4.0, 0.1, 4.9])
    np.testing.assert_allclose(s(px, py), 0.2 * px, atol=1e-9)
    np.testing.assert_allclose(s.slope_deg(px, py), np.degrees(np.arctan(0.2)), atol=1e-9)
    n = s.normals(px, py)
    np.testing.assert_allclose(n, np.tile([-0.2, 0, 1] / np.sqrt(1.04), (3, 1)), atol=1e-9)


def test_evaluation_of_bad_coordinates_is_a_clear_error():
    s = random_surface(np.random.default_rng(6))
    with pytest.raises(InputError, match=r"shape \(3,\) and y of shape \(4,\) do not broadcast"):
        s(np.zeros(3), np.zeros(4))
    with pytest.raises(InputError, match="numbers or arrays of numbers"):
        s.slope_deg("a", 0.0)
    assert s(np.zeros((2, 1)), np.zeros((1, 5))).shape == (2, 5)  # a grid still broadcasts


@pytest.mark.parametrize("step", [0.5, 0.7, 1.3])
def test_slope_grid_is_slope_deg_at_the_centres(step):
    # the grid kernel (one contraction per row of centres) against the per-point evaluation,
    # with a last partial row and column (centres outside the region: NaN in both)
    s = random_surface(np.random.default_rng(5), origin=(500_000.0, 4_000_000.0, 300.0))
    grid = s.slope_grid(step)
    reference = s.slope_deg(grid.x_centers[:, None], grid.y_centers[None, :])
    np.testing.assert_array_equal(np.isnan(grid.slope_deg), np.isnan(reference))
    np.testing.assert_allclose(grid.slope_deg, reference, atol=1e-10, equal_nan=True)


@pytest.mark.parametrize("method", ["tensor", "two_pass"])
def test_fit_reproduces_a_spline_exactly(method):
    rng = np.random.default_rng(4)
    s = random_surface(rng, n0=6, n1=5, rational=False)
    x = np.linspace(-5, 7, 40)
    y = np.linspace(-3, 4, 30)
    z = s(x[:, None], y[None, :])
    w = rng.uniform(0.2, 3.0, z.shape)
    fit = make_lsq_surface(x, y, z, w, control_points=(6, 5), region=(-5, 7, -3, 4),
                           method=method)
    np.testing.assert_allclose(fit.control_points + fit.origin[2], s.control_points, atol=1e-7)


def test_tensor_fit_equals_dense_weighted_least_squares():
    rng = np.random.default_rng(5)
    x = np.linspace(0, 10, 25)
    y = np.linspace(0, 8, 20)
    z = rng.normal(size=(25, 20))
    w = rng.uniform(0, 2, z.shape)
    r = rng.uniform(0.5, 2, (6, 5))
    fit = make_lsq_surface(x, y, z, w, control_points=(6, 5), rational_weights=r,
                           origin=(0, 0, 0))
    # dense reference: design matrix of the rational basis, row per sample
    xx, yy = np.meshgrid(x, y, indexing="ij")
    rows = []
    for a in range(6):
        for b in range(5):
            q = np.zeros((6, 5))
            q[a, b] = 1.0
            basis_s = TerrainSurface(3, fit.knots_x, fit.knots_y, q, r)
            rows.append(basis_s(xx, yy).ravel())
    design = np.array(rows).T
    sw = np.sqrt(w.ravel())
    ref = np.linalg.lstsq(design * sw[:, None], z.ravel() * sw, rcond=None)[0]
    np.testing.assert_allclose(fit.control_points.ravel(), ref, atol=1e-6)


def test_tensor_fit_over_sparse_cells_equals_dense_weighted_least_squares():
    # most cells without weight (as on a lidar grid): the fit over the listed cells only, and
    # the surface written at those cells, against the dense rational design matrix
    from o3d_terrain.spline import GridBasis

    rng = np.random.default_rng(8)
    x = np.linspace(0, 12, 31)
    y = np.linspace(0, 9, 23)
    z = rng.normal(size=(31, 23))
    w = np.where(rng.uniform(size=z.shape) < 0.3, rng.uniform(0.1, 2, z.shape), 0.0)
    r = rng.uniform(0.5, 2, (7, 6))
    basis = GridBasis(x, y, (7, 6), 3, (0, 12, 0, 9))
    cells = np.flatnonzero(w > 0)
    q = basis.solve_tensor(z, w, r, ridge=1e-14, cells=cells)
    np.testing.assert_array_equal(q, basis.solve_tensor(z, w, r, ridge=1e-14))
    xx, yy = np.meshgrid(x, y, indexing="ij")
    rows = []
    for a in range(7):
        for b in range(6):
            e = np.zeros((7, 6))
            e[a, b] = 1.0
            rows.append(TerrainSurface(3, basis.knots_x, basis.knots_y, e, r)(xx, yy).ravel())
    design = np.array(rows).T[cells]
    sw = np.sqrt(w.ravel()[cells])
    ref = np.linalg.lstsq(design * sw[:, None], z.ravel()[cells] * sw, rcond=None)[0]
    np.testing.assert_allclose(q.ravel(), ref, atol=1e-6)
    out = np.full(z.shape, -7.0)
    basis.evaluate_cells(q, r, cells, out)
    full = basis.evaluate(q, r)
    np.testing.assert_array_equal(out.ravel()[cells], full.ravel()[cells])
    assert np.all(np.delete(out.ravel(), cells) == -7.0)
    # the per-cell forms the robust fit uses: gathered samples and weights, values per cell
    np.testing.assert_array_equal(
        basis.solve_cells(cells, z.ravel()[cells], w.ravel()[cells], r, ridge=1e-14), q)
    np.testing.assert_array_equal(basis.evaluate_at_cells(q, r, cells), full.ravel()[cells])
    # the denominators the assembly wrote, reused by the evaluation with the same R
    denominators = np.full(cells.size, np.nan)
    basis.solve_cells(cells, z.ravel()[cells], w.ravel()[cells], r, ridge=1e-14,
                      denominators=denominators)
    np.testing.assert_array_equal(basis.evaluate_at_cells(q, r, cells, None, denominators),
                                  full.ravel()[cells])
    np.testing.assert_allclose(full, TerrainSurface(3, basis.knots_x, basis.knots_y, q, r)(xx, yy),
                               atol=1e-9)


def test_grid_basis_tables_match_the_cox_de_boor_recursion():
    # the per-axis tables of a grid basis (one kernel per axis): clamped uniform knots, the
    # span and non-zero basis values at every cell centre, Greville abscissae; a non-finite
    # centre gets span -1 and zero values
    from o3d_terrain.spline import GridBasis

    rng = np.random.default_rng(12)
    for degree in (1, 2, 3, 4):
        x = np.sort(rng.uniform(-3.0, 9.0, 29))
        x[[0, -1]] = (-3.0, 9.0)  # both ends of the knot range
        x[11] = np.nan
        y = np.linspace(-1.0, 4.0, 17)
        n0, n1 = degree + 4, degree + 2
        basis = GridBasis(x, y, (n0, n1), degree, (-3.0, 9.0, -1.0, 4.0))
        for axis, t, n, low, high in (("x", x, n0, -3.0, 9.0), ("y", y, n1, -1.0, 4.0)):
            knots = getattr(basis, f"knots_{axis}")
            spans = getattr(basis, f"spans_{axis}")
            values = getattr(basis, f"basis_{axis}")
            inner = np.linspace(low, high, n - degree + 1)
            np.testing.assert_allclose(knots, np.r_[[low] * degree, inner, [high] * degree],
                                       rtol=0, atol=1e-12)
            assert values.shape == (t.size, degree + 1) and values.flags.c_contiguous
            for i, ti in enumerate(t):
                if not np.isfinite(ti):
                    assert spans[i] == -1 and np.all(values[i] == 0.0)
                    continue
                full = np.array([naive_spline.basis(a, degree, ti, knots) for a in range(n)])
                first = spans[i] - degree
                np.testing.assert_allclose(values[i], full[first:first + degree + 1], atol=1e-12)
                assert np.all(np.delete(full, np.arange(first, first + degree + 1)) == 0.0)
            greville = np.array([knots[a + 1:a + degree + 1].mean() for a in range(n)])
            np.testing.assert_allclose(getattr(basis, f"greville_{axis}"), greville,
                                       rtol=0, atol=1e-12)


def test_outside_region_is_nan_and_nonfinite_input_is_nan():
    rng = np.random.default_rng(6)
    s = random_surface(rng)
    out = s(np.array([-5.1, 7.1, 0.0, np.nan, 0.0]), np.array([0.0, 0.0, 4.2, 0.0, np.inf]))
    assert np.isnan(out).all()
    assert np.isfinite(s(-5.0, -3.0)) and np.isfinite(s(7.0, 4.0))


def test_large_projected_coordinates_keep_precision():
    x0, y0 = 637_000.0, 4_850_000.0
    x = x0 + np.linspace(0, 50, 51)
    y = y0 + np.linspace(0, 30, 31)
    z = 200.0 + 0.1 * (x[:, None] - x0) - 0.05 * (y[None, :] - y0)
    s = make_lsq_surface(x, y, z, control_points=(8, 8))
    px, py = x0 + 12.345, y0 + 6.789
    assert s(px, py) == pytest.approx(200.0 + 1.2345 - 0.33945, abs=1e-8)


def test_save_load_round_trip(tmp_path):
    rng = np.random.default_rng(7)
    s = random_surface(rng, origin=(1e6, 2e6, 300.0))
    s.save(tmp_path / "s.npz")
    t = TerrainSurface.load(tmp_path / "s.npz")
    x = 1e6 + rng.uniform(-5, 7, 50)
    y = 2e6 + rng.uniform(-3, 4, 50)
    np.testing.assert_array_equal(s(x, y), t(x, y))
    assert t.origin == s.origin and t.degree == s.degree
    assert t.cell_size is None
    assert repr(t) == repr(s)
    np.save(tmp_path / "other.npy", np.zeros(3))
    with pytest.raises(InputError, match="TerrainSurface"):
        TerrainSurface.load(tmp_path / "other.npy")
    u = TerrainSurface(s.degree, s.knots_x, s.knots_y, s.control_points, s.weights, s.origin,
                       cell_size=0.25)
    u.save(tmp_path / "u.npz")
    assert TerrainSurface.load(tmp_path / "u.npz").cell_size == 0.25


def test_load_takes_the_path_save_was_given_and_names_wrong_files(tmp_path):
    """save("x") writes x.npz (numpy's rule); load("x") reads it back. A text file, a missing
    file and another product's archive each get an InputError naming the file and why."""
    from o3d_terrain.grid import HeightGrid
    from o3d_terrain.spline import SlopeGrid

    s = random_surface(np.random.default_rng(3))
    s.save(tmp_path / "surface")
    assert (tmp_path / "surface.npz").exists()
    assert repr(TerrainSurface.load(tmp_path / "surface")) == repr(s)
    (tmp_path / "notes.txt").write_text("not an archive\n")
    with pytest.raises(InputError, match="notes.txt: not a TerrainSurface file"):
        TerrainSurface.load(tmp_path / "notes.txt")
    with pytest.raises(InputError, match="missing: no such file"):
        TerrainSurface.load(tmp_path / "missing")
    SlopeGrid(np.zeros((2, 2)), np.arange(2.0), np.arange(2.0), 1.0).save(tmp_path / "slope")
    with pytest.raises(InputError, match="not a TerrainSurface file .it holds a SlopeGrid"):
        TerrainSurface.load(tmp_path / "slope.npz")
    with pytest.raises(InputError, match="not a HeightGrid file .it holds a TerrainSurface"):
        HeightGrid.load(tmp_path / "surface")


@pytest.mark.parametrize("uneven", [False, True])
@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
def test_span_power_basis_equals_scipy_basis_functions(degree, uneven):
    """The power form of each span's basis functions (clamped end spans included) gives the
    B-spline basis at points of the span and at its two knots."""
    n_ctrl = degree + 6
    knots = clamped_uniform_knots(n_ctrl, degree, -2.0, 9.0)
    if uneven:
        knots[degree + 1:n_ctrl] += np.linspace(-0.4, 0.7, n_ctrl - degree - 1)
    power = kb.span_power_basis(knots, degree, n_ctrl)
    rng = np.random.default_rng(degree)
    for s in range(n_ctrl - degree):
        span = degree + s
        t = np.r_[knots[span], rng.uniform(knots[span], knots[span + 1], 20), knots[span + 1]]
        u = (t - knots[span]) / (knots[span + 1] - knots[span])
        for r in range(degree + 1):
            coefficients = np.zeros(n_ctrl)
            coefficients[span - degree + r] = 1.0
            expected = BSpline(knots, coefficients, degree)(t)
            got = np.polynomial.polynomial.polyval(u, power[s, r])
            np.testing.assert_allclose(got, expected, atol=1e-13)


def test_heights_above_extrapolate_the_end_spans_within_the_tolerance():
    """Points just outside the knot range (within the rounding tolerance) take the end spans'
    polynomials, like the surface itself; farther out they are NaN."""
    rng = np.random.default_rng(12)
    s = random_surface(rng, n0=9, n1=8)
    x0, x1, y0, y1 = s.region
    tol_x, tol_y = s._tolerances()
    x = np.r_[x0 - 0.5 * tol_x, x1 + 0.5 * tol_x, x0 - 2 * tol_x, 0.3]
    y = np.r_[y1 + 0.5 * tol_y, y0 - 0.5 * tol_y, 0.1, y1 + 2 * tol_y]
    h = s.heights_above(np.c_[x, y, np.zeros(4)])
    np.testing.assert_allclose(h[:2], -s(x[:2], y[:2]), atol=1e-12)
    corner = NdBSpline((s.knots_x, s.knots_y), s.control_points * s.weights, s.degree)
    denominator = NdBSpline((s.knots_x, s.knots_y), s.weights, s.degree)
    ends = np.stack([np.clip(x[:2], x0, x1), np.clip(y[:2], y0, y1)], 1)
    np.testing.assert_allclose(h[:2], -corner(ends) / denominator(ends), atol=1e-6)
    assert np.isnan(h[2:]).all()


def test_heights_above_equal_z_minus_surface_and_are_nan_outside():
    rng = np.random.default_rng(8)
    s = random_surface(rng, origin=(5e5, 4e6, 200.0))
    x0, x1, y0, y1 = s.region
    pts = np.c_[rng.uniform(x0 - 1, x1 + 1, 2000), rng.uniform(y0 - 1, y1 + 1, 2000),
                200 + rng.normal(0, 3, 2000)]
    pts[::97] = np.nan
    pts[5, 2] = np.inf
    pts[6, :2] = (x1, y1)  # the far corner is inside
    h = s.heights_above(pts)
    expected = pts[:, 2] - s(pts[:, 0], pts[:, 1])
    expected[~np.isfinite(expected)] = np.nan  # any non-finite coordinate: undefined
    np.testing.assert_allclose(h, expected, atol=1e-9)
    assert np.array_equal(np.isnan(h), np.isnan(expected))
    assert np.isfinite(h[6]) and np.isnan(h[5])


def test_heights_above_of_points_in_sequence_equal_each_point_alone():
    """The cubic heights hold the previous point's spans while the points stay in them: points
    in order along a line (consecutive ones sharing spans), on the knots, on a repeated knot,
    outside the knot range (within the tolerance and beyond) and non-finite between them give
    each point's height alone, bit for bit, serial and parallel."""
    rng = np.random.default_rng(21)
    kx = np.r_[[0.0] * 4, 0.6, 1.5, 4.0, 7.0, 7.0, 8.5, [10.0] * 4]
    ky = np.r_[[-3.0] * 4, -1.0, 0.2, 0.5, 3.6, [6.0] * 4]
    n0, n1 = kx.size - 4, ky.size - 4
    s = TerrainSurface(3, kx, ky, rng.normal(size=(n0, n1)), rng.uniform(0.5, 2.0, (n0, n1)),
                       (100.0, -50.0, 3.0))
    t = np.linspace(0.0, 1.0, 4001)
    x = np.r_[-1e-10, 10.0 * t, kx, 10.0 + 1e-10, 7.0, 7.0, 10.0 * t[::-1], 11.0, 5.0]
    y = np.r_[6.0, -3.0 + 9.0 * t ** 2, np.resize(ky, kx.size), -3.0 - 1e-10, 0.2, 0.5, 6.0 * t, 0.0, 1.0]
    points = np.c_[x + 100.0, y - 50.0, rng.normal(3.0, 1.0, x.size)]
    points[7] = np.nan
    points[-1, 2] = np.inf
    alone = np.array([kb.heights_above_serial(points[k:k + 1], 100.0, -50.0, 3.0, kx, ky, 3,
                                              s.control_points, s.weights, 1e-9, 1e-9)[0]
                      for k in range(x.size)])
    serial = kb.heights_above_serial(points, 100.0, -50.0, 3.0, kx, ky, 3, s.control_points,
                                     s.weights, 1e-9, 1e-9)
    parallel = kb.heights_above(points, 100.0, -50.0, 3.0, kx, ky, 3, s.control_points,
                                s.weights, 1e-9, 1e-9)
    assert np.array_equal(serial, alone, equal_nan=True)
    assert np.array_equal(parallel, alone, equal_nan=True)
    assert np.isnan(alone[[7, -2, -1]]).all() and np.isfinite(alone[[0, 1, -3]]).all()


def test_raster_and_mesh_export():
    rng = np.random.default_rng(8)
    s = random_surface(rng)
    z, xc, yc = s.to_raster(0.5)
    assert z.shape == (xc.size, yc.size) == (24, 14)
    np.testing.assert_allclose(z, s(xc[:, None], yc[None, :]))
    mesh = s.to_mesh(1.0)
    v = np.asarray(mesh.vertices)
    np.testing.assert_allclose(v[:, 2], s(v[:, 0], v[:, 1]), atol=1e-12)
    assert len(mesh.triangles) == 2 * 12 * 7
    assert v[:, 0].max() == pytest.approx(7.0) and v[:, 1].min() == pytest.approx(-3.0)


def test_invalid_surfaces_are_rejected_with_reasons():
    kx = clamped_uniform_knots(5, 3, 0, 1)
    with pytest.raises(InputError, match="weights"):
        TerrainSurface(3, kx, kx, np.zeros((5, 5)), -np.ones((5, 5)))
    with pytest.raises(InputError, match="knots"):
        TerrainSurface(3, kx[:-1], kx, np.zeros((5, 5)), np.ones((5, 5)))
    with pytest.raises(InputError, match="at least 4 control points"):
        clamped_uniform_knots(3, 3, 0, 1)
    with pytest.raises(InputError, match="degenerate"):
        make_lsq_surface([0, 1, 2], [0, 1, 2], np.zeros((3, 3)), control_points=(4, 4),
                         region=(0, 0, 0, 2))


@pytest.mark.parametrize("degree", [2, 3])
def test_surface_on_uneven_knots_equals_the_b_spline_sums(degree):
    """A surface on clamped knots that are not evenly spaced (and with a repeated interior
    knot) evaluates as the rational B-spline sums: values, heights (parallel and serial) and
    gradients."""
    rng = np.random.default_rng(degree)
    kx = np.r_[[0.0] * (degree + 1), 0.6, 1.5, 4.0, 7.0, 7.0, 8.5, [10.0] * (degree + 1)]
    ky = np.r_[[-3.0] * (degree + 1), -1.0, 0.2, 0.5, 3.6, [6.0] * (degree + 1)]
    n0, n1 = kx.size - degree - 1, ky.size - degree - 1
    q = rng.normal(size=(n0, n1))
    r = rng.uniform(0.5, 2.0, (n0, n1))
    origin = (500_000.0, 4_000_000.0, 120.0)
    s = TerrainSurface(degree, kx, ky, q, r, origin)
    x = np.r_[rng.uniform(0, 10, 3000), kx[degree + 1:-degree - 1], 0.0, 10.0]
    y = np.r_[rng.uniform(-3, 6, 3000), np.resize(ky[degree + 1:-degree - 1], 6), -3.0, 6.0]

    def rational(xx, yy):
        bx = BSpline.design_matrix(np.clip(xx, 0, 10), kx, degree).toarray()
        by = BSpline.design_matrix(np.clip(yy, -3, 6), ky, degree).toarray()
        return np.einsum("ia,ab,ib->i", bx, r * q, by) / np.einsum("ia,ab,ib->i", bx, r, by)

    expected = rational(x, y) + origin[2]
    np.testing.assert_allclose(s(x + origin[0], y + origin[1]), expected, atol=1e-11)
    points = np.c_[x + origin[0], y + origin[1], np.full(x.size, 125.0)]
    np.testing.assert_allclose(s.heights_above(points), 125.0 - expected, atol=1e-11)
    serial = kb.heights_above_serial(points, *origin, s.knots_x, s.knots_y, degree,
                                     s.control_points, s.weights, 1e-9, 1e-9)
    np.testing.assert_allclose(serial, 125.0 - expected, atol=1e-11)
    # away from the ends and from the double knot at x = 7 (where degree 2 has a kink)
    inside = (x > 1e-3) & (x < 10 - 1e-3) & (y > -3 + 1e-3) & (y < 6 - 1e-3) & \
        (np.abs(x - 7.0) > 1e-3)
    h = 1e-6
    gx, gy = s.gradient(x[inside] + origin[0], y[inside] + origin[1])
    xi, yi = x[inside], y[inside]
    np.testing.assert_allclose(gx, (rational(xi + h, yi) - rational(xi - h, yi)) / (2 * h),
                               atol=2e-5)
    np.testing.assert_allclose(gy, (rational(xi, yi + h) - rational(xi, yi - h)) / (2 * h),
                               atol=2e-5)
