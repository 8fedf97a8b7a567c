"""Normal equations of the weighted tensor-product B-spline fit: the thin-plate band, grid
projections and the robust re-weighting passes.

Control point (a, b) of an (n0, n1) grid has the unknown index k = a * n1 + b; a cell's
(degree + 1)^2 basis functions touch indices at most ``degree * n1 + degree`` apart, so the normal
matrix is banded. Band storage is LAPACK's lower form (``scipy.linalg.solveh_banded(lower=True)``):
``band[d, k] = A[k + d, k]``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .bspline import basis_funs_scratch, find_span


@numba.njit(cache=True, inline="always")
def _second_difference(greville, a, h, coef):
    """coef[:3]: h^2 times the second divided difference at abscissa a from its neighbours
    a - 1 and a + 1 (unevenly spaced ``greville``); (1, -2, 1) for uniform spacing h."""
    d0 = greville[a] - greville[a - 1]
    d1 = greville[a + 1] - greville[a]
    f = 2.0 * h * h / (d0 + d1)
    coef[0] = f / d0
    coef[1] = -f * (1.0 / d0 + 1.0 / d1)
    coef[2] = f / d1


@numba.njit(cache=True)
def add_thin_plate_band(band, n0, n1, scale, weight_xx, weight_xy, weight_yy, greville_x,
                        greville_y, relative_x, relative_y):
    """Add ``scale`` times a discrete thin-plate energy of the control points to the band.

    Energy = weight_xx sum (h_x^2 d2Q/dx2)^2 + weight_yy sum (h_y^2 d2Q/dy2)^2
           + weight_xy sum (h_x h_y d2Q/dxdy)^2,
    with divided differences of Q placed at the Greville abscissae (``greville_x``/``_y``,
    unevenly spaced near clamped ends) and h the interior spacing, so that for uniform spacing
    the stencils are (1, -2, 1) and (1, -1, -1, 1). Its null space is exactly the planes
    (a B-spline reproduces a plane with Q = plane at the Greville abscissae), so data-free
    control points continue the surface linearly and planes are fitted without bias.
    On uneven knots h is local: each stencil's term is multiplied by (r_x r_y)^2, r the
    control points' span width relative to the mean (``relative_x``/``_y``, one per control
    point; a mixed stencil takes the mean of its two), so that in units of the local spacing
    the penalty is the uniform one (1 everywhere on uniform knots: the same values).
    """
    hx = greville_x[min(2, n0 - 1)] - greville_x[min(1, n0 - 2)] if n0 > 3 else 1.0
    hy = greville_y[min(2, n1 - 1)] - greville_y[min(1, n1 - 2)] if n1 > 3 else 1.0
    if n0 > 2:
        hx = (greville_x[n0 - 1] - greville_x[0]) / (n0 - 1)
    if n1 > 2:
        hy = (greville_y[n1 - 1] - greville_y[0]) / (n1 - 1)
    idx = np.empty(4, np.int64)
    coef = np.empty(4)
    bandwidth = band.shape[0] - 1
    for kind in range(3):
        if kind == 0:
            w = weight_xx * scale
            a_end = n0 - 1
            b_end = n1
            a_start = 1
            b_start = 0
        elif kind == 1:
            w = weight_yy * scale
            a_end = n0
            b_end = n1 - 1
            a_start = 0
            b_start = 1
        else:
            w = weight_xy * scale
            a_end = n0 - 1
            b_end = n1 - 1
            a_start = 0
            b_start = 0
        if w == 0.0:
            continue
        for a in range(a_start, a_end):
            for b in range(b_start, b_end):
                if kind == 2:
                    rel = 0.25 * (relative_x[a] + relative_x[a + 1]) * \
                        (relative_y[b] + relative_y[b + 1])
                else:
                    rel = relative_x[a] * relative_y[b]
                wr = w * rel * rel
                if kind == 0:
                    n = 3
                    idx[0] = (a - 1) * n1 + b
                    idx[1] = a * n1 + b
                    idx[2] = (a + 1) * n1 + b
                    _second_difference(greville_x, a, hx, coef)
                elif kind == 1:
                    n = 3
                    idx[0] = a * n1 + b - 1
                    idx[1] = a * n1 + b
                    idx[2] = a * n1 + b + 1
                    _second_difference(greville_y, b, hy, coef)
                else:
                    n = 4
                    idx[0] = a * n1 + b
                    idx[1] = a * n1 + b + 1
                    idx[2] = (a + 1) * n1 + b
                    idx[3] = (a + 1) * n1 + b + 1
                    f = hx * hy / ((greville_x[a + 1] - greville_x[a])
                                   * (greville_y[b + 1] - greville_y[b]))
                    coef[0] = f
                    coef[1] = -f
                    coef[2] = -f
                    coef[3] = f
                for u in range(n):
                    for s in range(n):
                        d = idx[s] - idx[u]
                        if 0 <= d <= bandwidth:
                            band[d, idx[u]] += wr * coef[u] * coef[s]
    return band


@numba.njit(cache=True)
def grid_project(spans_x, basis_x, spans_y, basis_y, values, n0, n1):
    """(Bx^T V By)[a, b]: grid values gathered onto the control grid by the basis functions."""
    p = basis_x.shape[1] - 1
    out = np.zeros((n0, n1))
    for i in range(spans_x.shape[0]):
        sx = spans_x[i] - p
        for j in range(spans_y.shape[0]):
            v = values[i, j]
            if v == 0.0:
                continue
            sy = spans_y[j] - p
            for a in range(p + 1):
                va = v * basis_x[i, a]
                for b in range(p + 1):
                    out[sx + a, sy + b] += va * basis_y[j, b]
    return out


# -------------------------------------------------------------------------------------------
# one pass of the robust re-weighting (terrain.py, method "robust"), cell by cell


@numba.njit(cache=True)
def robust_inputs(state, samples, mean, compact, z0, noise_floor, filled_weight, measured,
                  filled):
    """(z, base) of the robust fit over the (m0, m1) grid: z = samples - z0 on valid cells
    (state != 0), 0 elsewhere; with ``mean`` of size > 0, z = max(z, (mean - z0) -
    noise_floor) on the ``compact`` cells; base = 1 on ``measured`` cells, ``filled_weight``
    on ``filled`` ones, 0 elsewhere. One pass instead of the numpy expressions it replaces
    (same operations, so the same values)."""
    m0, m1 = state.shape
    z = np.zeros((m0, m1))
    base = np.zeros((m0, m1))
    use_mean = mean.shape[0] > 0
    for i in range(m0):
        for j in range(m1):
            s = state[i, j]
            if s == 0:
                continue
            v = samples[i, j] - z0
            if use_mean and compact[i, j]:
                v = max(v, (mean[i, j] - z0) - noise_floor)
            z[i, j] = v
            base[i, j] = 1.0 if s == measured else (filled_weight if s == filled else 0.0)
    return z, base


@numba.njit(cache=True)
def grid_project_cells(spans_x, basis_x, spans_y, basis_y, values, cells, n0, n1):
    """(Bx^T V By)[a, b] like :func:`grid_project` over the cells ``cells`` only (increasing
    flat indices into the C-ordered (m0, m1) grid; V = 0 elsewhere), ``values`` holding V of
    those cells (one per entry of ``cells``), contracted
    along y once per grid row (r_i = sum_j V[i, j] By[j, :], then out[a, :] += Bx[i, a] r_i):
    O(cells p + rows n1 p) instead of O(m0 m1 p^2). Same values up to rounding (another
    summation order)."""
    p = basis_x.shape[1] - 1
    m1 = spans_y.shape[0]
    out = np.zeros((n0, n1))
    row = np.zeros(n1)
    # cubic case: row[held .. held + 3] in registers while the cells stay in span ``held``
    # (-1: none), stored back when it changes (the same additions in the same order)
    held = -1
    r0 = r1 = r2 = r3 = 0.0
    count = cells.shape[0]
    k = 0
    while k < count:
        i = cells[k] // m1  # one integer division per grid row
        first = i * m1
        end = first + m1
        lo = n1
        hi = -1
        while k < count and cells[k] < end:
            c = cells[k]
            v = values[k]
            k += 1
            if v == 0.0:
                continue
            j = c - first
            sy = spans_y[j] - p
            if sy < lo:
                lo = sy
            if sy > hi:
                hi = sy
            if p == 3:  # the loop below with a constant length (same operations)
                if sy != held:
                    if held >= 0:
                        row[held] = r0
                        row[held + 1] = r1
                        row[held + 2] = r2
                        row[held + 3] = r3
                    held = sy
                    r0 = row[sy]
                    r1 = row[sy + 1]
                    r2 = row[sy + 2]
                    r3 = row[sy + 3]
                r0 += v * basis_y[j, 0]
                r1 += v * basis_y[j, 1]
                r2 += v * basis_y[j, 2]
                r3 += v * basis_y[j, 3]
                continue
            for b in range(p + 1):
                row[sy + b] += v * basis_y[j, b]
        if held >= 0:
            row[held] = r0
            row[held + 1] = r1
            row[held + 2] = r2
            row[held + 3] = r3
            held = -1
        if hi < 0:
            continue
        sx = spans_x[i] - p
        for a in range(p + 1):
            xa = basis_x[i, a]
            for b in range(lo, hi + p + 1):
                out[sx + a, b] += xa * row[b]
        for b in range(lo, hi + p + 1):
            row[b] = 0.0
    return out


@numba.njit(cache=True)
def residual_scale(z, surface, measured_cells, floor):
    """Noise scale and mean |residual| over the cells ``measured_cells`` (flat indices into
    the C-ordered arrays ``z`` and ``surface``: grids, or the fit's per-cell vectors),
    residual r = z - surface.

    Scale: 1.4826 * median |r| over the residuals r <= 0 (over all of them when fewer than 3
    are <= 0), at least ``floor``. The median is exact (selection over the gathered values),
    the same value as ``numpy.median``. Returns (scale, mean |r|).
    """
    zf = z.ravel()
    sf = surface.ravel()
    n = measured_cells.shape[0]
    gathered = np.empty(n)
    count = 0
    total = 0.0
    for k in range(n):
        c = measured_cells[k]
        r = zf[c] - sf[c]
        a = abs(r)
        total += a
        if r <= 0.0:
            gathered[count] = a
            count += 1
    if count < 3:
        for k in range(n):
            c = measured_cells[k]
            gathered[k] = abs(zf[c] - sf[c])
        count = n
    scale = 1.4826 * np.median(gathered[:count])
    if not scale >= floor:
        scale = floor
    return scale, total / max(n, 1)


@numba.njit(cache=True)
def robust_pass(z, surface, base, valid_cells, compact, use_prior, prior_spread, noise,
                cell_sigma, use_cell_sigma, above_k, below_k, clip_k, previous_samples,
                previous_weights, has_previous, weights, ratios, samples, equalized):
    """Sample weights, control-point weight ratios and equalized samples of one pass, written
    into ``weights``, ``ratios``, ``samples`` and ``equalized`` at the cells ``valid_cells``
    (flat indices, C order, of the cells with base > 0; the caller keeps weight 0, ratio 0,
    sample z and False on every other cell). All arrays are C-contiguous and indexed alike:
    (m0, m1) grids, or (as the fit passes them) vectors of the valid cells' values with
    ``valid_cells`` = 0 .. n - 1, which keeps the cells' data small and contiguous.

    Noise scale of a cell: ``noise``, or with ``use_cell_sigma`` (a range-dependent sensor
    noise model) sqrt(noise^2 + cell_sigma[c]^2), cell_sigma in metres; thresholds
    th_above = above_k * scale, th_below = below_k * scale.
    On a valid cell, r = z - surface: t = r / th_above above the surface, -r / th_below
    below; weight w = base / (1 + t^4) (the bounded form of Broggi et al. eq. 3 with
    alpha = 4). With ``use_prior``, compact cells above the surface get
    t = r / (th_above + prior_spread[c]) (a per-cell widening; read only at compact
    cells). Ratio = w / base.
    Equalization: cells (not compact ones with the prior) with z > surface + clip_k * th_above
    are clipped onto that limit; the others keep z.

    Returns (moved, change): moved = cells whose sample changed by more than 1e-4 from
    ``previous_samples``; change = max |w - previous_weights| (0 when not ``has_previous``).
    """
    zf = z.ravel()
    sf = surface.ravel()
    bf = base.ravel()
    cf = compact.ravel()
    wf = weights.ravel()
    rf = ratios.ravel()
    pf = samples.ravel()
    ef = equalized.ravel()
    ppf = previous_samples.ravel()
    pwf = previous_weights.ravel()
    spf = prior_spread.ravel()
    nf = cell_sigma.ravel()
    noise2 = noise * noise
    moved = 0
    change = 0.0
    for k in range(valid_cells.shape[0]):
        c = valid_cells[k]
        zc = zf[c]
        s = sf[c]
        r = zc - s
        b = bf[c]
        scale = math.sqrt(noise2 + nf[c] * nf[c]) if use_cell_sigma else noise
        th_above = above_k * scale
        if r > 0.0:
            t = r / th_above
        else:
            t = -r / (below_k * scale)
        t2 = t * t
        w = b / (1.0 + t2 * t2)
        keep = use_prior and cf[c]
        if keep and r > 0.0:
            tc = r / (th_above + spf[c])
            tc2 = tc * tc
            w = b / (1.0 + tc2 * tc2)
        wf[c] = w
        rf[c] = w if b == 1.0 else w / max(b, 1e-12)
        limit = s + clip_k * th_above
        value = zc
        if zc > limit and not keep:
            value = limit
            ef[c] = True
        else:
            ef[c] = False
        pf[c] = value
        if abs(value - ppf[c]) > 1e-4:
            moved += 1
        if has_previous:
            d = abs(w - pwf[c])
            if d > change:
                change = d
    return moved, change


@numba.njit(cache=True)
def control_weights_cells(spans_x, basis_x, spans_y, basis_y, ratios, cells, n0, n1, coverage):
    """The rational control-point weights of the robust fit, R = 0.5 + 0.5 * (num / coverage
    where coverage > 1e-9, else 1), with num the projection (:func:`grid_project_cells`) of
    the weight ratios ``ratios`` at the cells ``cells`` and ``coverage`` the projection of the
    valid mask: one call instead of the projection and five numpy expressions (the same
    operations, so the same values)."""
    out = grid_project_cells(spans_x, basis_x, spans_y, basis_y, ratios, cells, n0, n1)
    for a in range(n0):
        for b in range(n1):
            c = coverage[a, b]
            v = out[a, b] / max(c, 1e-12) if c > 1e-9 else 1.0
            out[a, b] = 0.5 + 0.5 * v
    return out


@numba.njit(cache=True)
def scatter_cells(state, cells, weights, samples, equalized, z, surface, threshold, z_start,
                  z0):
    """The robust fit's per-cell vectors (one entry per cell of ``cells``) back onto the
    (m0, m1) grid: sample weights (0 elsewhere), samples in world z (``samples`` + z0 at the
    cells, ``z_start`` + z0 on the other valid cells (state != 0), NaN on empty ones), the
    equalized mask and the outliers (z - surface > threshold); False elsewhere."""
    m0, m1 = state.shape
    weights_grid = np.zeros((m0, m1))
    samples_grid = np.empty((m0, m1))
    equalized_grid = np.zeros((m0, m1), np.bool_)
    outliers = np.zeros((m0, m1), np.bool_)
    for i in range(m0):
        for j in range(m1):
            samples_grid[i, j] = z_start[i, j] + z0 if state[i, j] != 0 else np.nan
    for k in range(cells.shape[0]):
        c = cells[k]
        i = c // m1
        j = c - i * m1
        weights_grid[i, j] = weights[k]
        samples_grid[i, j] = samples[k] + z0
        equalized_grid[i, j] = equalized[k]
        outliers[i, j] = z[k] - surface[k] > threshold
    return weights_grid, samples_grid, equalized_grid, outliers


@numba.njit(cache=True)
def uniform_knot_spans(knots, n_ctrl, degree, tolerance):
    """True when the knot spans under the control polygon (knots degree .. n_ctrl) differ by
    at most ``tolerance`` times their mean width: max - min of the differences of successive
    knots, and the mean as (knots[n_ctrl] - knots[degree]) / their count, as numpy's
    ``ptp(diff(...))`` and that mean compute them."""
    low = math.inf
    high = -math.inf
    for i in range(degree, n_ctrl):
        width = knots[i + 1] - knots[i]
        low = min(low, width)
        high = max(high, width)
    mean = (knots[n_ctrl] - knots[degree]) / (n_ctrl - degree)
    return high - low <= tolerance * mean


@numba.njit(cache=True)
def axis_basis(t, knots, n_ctrl, degree):
    """One axis of a grid basis in one call: the knots (returned as given), the span and the
    degree + 1 non-zero basis values at every parameter of ``t`` (what ``basis_table(t, n_ctrl,
    degree, knots, 0)`` gives, as an (m, degree + 1) table; non-finite t: span -1, values 0)
    and the Greville abscissae (knots a + 1 .. a + degree summed left to right, then divided
    by the degree). The same operations as the separate calls, so the same values."""
    m = t.shape[0]
    spans = np.empty(m, np.int64)
    values = np.zeros((m, degree + 1))
    left = np.empty(degree + 1)
    right = np.empty(degree + 1)
    for i in range(m):
        if not math.isfinite(t[i]):
            spans[i] = -1
            continue
        s = find_span(n_ctrl, degree, t[i], knots)
        spans[i] = s
        basis_funs_scratch(s, t[i], degree, knots, values[i], left, right)
    greville = np.empty(n_ctrl)
    for a in range(n_ctrl):
        g = knots[a + 1]
        for r in range(2, degree + 1):
            g += knots[a + r]
        greville[a] = g / degree
    return knots, spans, values, greville


@numba.njit(cache=True)
def gather_cells(base, z, measured, compact, spread, use_prior):
    """The robust fit's per-cell vectors from flat (C-ordered) grids in one pass: the valid
    cells (flat indices of base > 0, increasing), their samples ``z`` and base weights, the
    positions in those vectors of the ``measured`` cells, and with ``use_prior`` the
    ``compact`` mask and ``spread`` of the valid cells (else one-entry placeholders): what
    ``np.flatnonzero`` and the fancy-indexed gathers give."""
    count = 0
    n_measured = 0
    for c in range(base.shape[0]):
        if base[c] > 0:
            count += 1
            if measured[c]:
                n_measured += 1
    cells = np.empty(count, np.int64)
    z_cells = np.empty(count)
    base_cells = np.empty(count)
    measured_cells = np.empty(n_measured, np.int64)
    size = count if use_prior else 1
    compact_cells = np.zeros(size, np.bool_)
    spread_cells = np.zeros(size)
    k = 0
    m = 0
    for c in range(base.shape[0]):
        if base[c] > 0:
            cells[k] = c
            z_cells[k] = z[c]
            base_cells[k] = base[c]
            if measured[c]:
                measured_cells[m] = k
                m += 1
            if use_prior:
                compact_cells[k] = compact[c]
                spread_cells[k] = spread[c]
            k += 1
    return cells, z_cells, base_cells, measured_cells, compact_cells, spread_cells


@numba.njit(cache=True)
def long_runs(cells, m0, m1, min_span):
    """For each of ``cells`` (distinct flat indices into a C-ordered (m0, m1) grid): whether
    the 8-connected run of ``cells`` it belongs to spans at least ``min_span`` cells along the
    first or the second axis (bounding box). One flood fill over the given cells only, with a
    scratch mark per grid cell: what ``scipy.ndimage.label`` and ``find_objects`` give, at a
    cost that follows the number of cells, not the grid's."""
    n = cells.shape[0]
    slot = np.full(m0 * m1, -1, np.int64)  # position in ``cells`` of a grid cell, -1: none
    for k in range(n):
        slot[cells[k]] = k
    run = np.full(n, -1, np.int64)
    stack = np.empty(n, np.int64)
    members = np.empty(n, np.int64)
    out = np.zeros(n, np.bool_)
    runs = 0
    for start in range(n):
        if run[start] >= 0:
            continue
        run[start] = runs
        stack[0] = start
        top = 1
        size = 0
        lo0 = hi0 = cells[start] // m1
        lo1 = hi1 = cells[start] % m1
        while top > 0:
            top -= 1
            k = stack[top]
            members[size] = k
            size += 1
            i = cells[k] // m1
            j = cells[k] % m1
            lo0 = min(lo0, i)
            hi0 = max(hi0, i)
            lo1 = min(lo1, j)
            hi1 = max(hi1, j)
            for di in range(-1, 2):
                ii = i + di
                if ii < 0 or ii >= m0:
                    continue
                for dj in range(-1, 2):
                    jj = j + dj
                    if jj < 0 or jj >= m1:
                        continue
                    other = slot[ii * m1 + jj]
                    if other >= 0 and run[other] < 0:
                        run[other] = runs
                        stack[top] = other
                        top += 1
        if max(hi0 - lo0, hi1 - lo1) + 1 >= min_span:
            for q in range(size):
                out[members[q]] = True
        runs += 1
    return out


@numba.njit(cache=True)
def supported_count(count, lo_x, hi_x, lo_y, hi_y, n0, n1, degree):
    """How many control points of an (n0, n1) layout of ``degree`` lie under the cells with
    ``count`` > 0 of an (nx, ny) grid: per such cell (ix, iy), the knot spans a .. b of
    ``lo_x[ix]`` .. ``hi_x[ix]`` and ``lo_y[iy]`` .. ``hi_y[iy]`` (a span by its last control
    point), and per span its (degree + 1)^2 control points (last - degree .. last per axis)."""
    spans = np.zeros((n0, n1), np.bool_)
    for ix in range(count.shape[0]):
        for iy in range(count.shape[1]):
            if count[ix, iy] > 0:
                for a in range(lo_x[ix], hi_x[ix] + 1):
                    for b in range(lo_y[iy], hi_y[iy] + 1):
                        spans[a, b] = True
    under = np.zeros((n0, n1), np.bool_)
    for a in range(n0):
        for b in range(n1):
            if spans[a, b]:
                for i in range(max(a - degree, 0), a + 1):
                    for j in range(max(b - degree, 0), b + 1):
                        under[i, j] = True
    total = 0
    for a in range(n0):
        for b in range(n1):
            total += under[a, b]
    return total
