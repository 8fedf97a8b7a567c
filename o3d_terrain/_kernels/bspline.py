"""B-spline kernels: knots, basis functions and rational tensor-product surfaces.

Numba kernels, NumPy in and NumPy out, no validation (the public wrappers in
:mod:`o3d_terrain.spline` validate). Algorithms from L. Piegl and W. Tiller, *The NURBS Book*,
2nd ed., Springer 1997. ``degree`` is the polynomial degree p (order = p + 1). A spline with
``n_ctrl`` control points has ``n_ctrl + degree + 1`` knots.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def clamped_uniform_knots(n_ctrl, degree, low, high):
    """Clamped uniform knot vector: ``degree + 1`` copies of each end, uniform interior knots."""
    m = n_ctrl + degree + 1
    knots = np.empty(m)
    n_spans = n_ctrl - degree
    for i in range(m):
        if i <= degree:
            knots[i] = low
        elif i >= n_ctrl:
            knots[i] = high
        else:
            knots[i] = low + (high - low) * (i - degree) / n_spans
    return knots


@numba.njit(cache=True, inline="always")
def _uniform_span(n_ctrl, degree, t, knots, inv_width):
    """Knot span of t on a clamped uniform knot vector (t inside the knot range).

    The span follows from one multiplication; a comparison on each side corrects the rounding
    of t near a knot, so the result equals :func:`find_span`.
    """
    n = n_ctrl - 1
    low = knots[degree]
    if t >= knots[n + 1]:
        return n
    if t <= low:
        return degree
    s = degree + int((t - low) * inv_width)
    if s > n:
        s = n
    if s < degree:
        s = degree
    while s > degree and t < knots[s]:
        s -= 1
    while s < n and t >= knots[s + 1]:
        s += 1
    return s


@numba.njit(cache=True, inline="always")
def _inverse_span_width(n_ctrl, degree, knots):
    """1 / width of the interior knot spans of a clamped uniform knot vector."""
    return (n_ctrl - degree) / (knots[n_ctrl] - knots[degree])


@numba.njit(cache=True)
def find_span(n_ctrl, degree, t, knots):
    """Knot span index of parameter t (Piegl & Tiller A2.1 FindSpan).

    Returns i with knots[i] <= t < knots[i+1], degree <= i <= n_ctrl - 1; t at or beyond the
    right end maps to the last span, t before the left end to the first.
    """
    n = n_ctrl - 1
    if t >= knots[n + 1]:
        return n
    if t <= knots[degree]:
        return degree
    # guess the span as on uniform interior knots, then correct by comparisons
    guess = _uniform_span(n_ctrl, degree, t, knots, _inverse_span_width(n_ctrl, degree, knots))
    if knots[guess] <= t < knots[guess + 1]:
        return guess
    low = degree
    high = n + 1
    mid = (low + high) // 2
    while t < knots[mid] or t >= knots[mid + 1]:
        if t < knots[mid]:
            high = mid
        else:
            low = mid
        mid = (low + high) // 2
    return mid


@numba.njit(cache=True, inline="always")
def _basis_step(j, span, t, knots, out, left, right):
    """Step j of Piegl & Tiller A2.2 BasisFuns, in place: ``out[:j]``, the basis functions of
    degree j - 1 at t, become the j + 1 functions of degree j."""
    left[j] = t - knots[span + 1 - j]
    right[j] = knots[span + j] - t
    saved = 0.0
    for r in range(j):
        temp = out[r] / (right[r + 1] + left[j - r])
        out[r] = saved + right[r + 1] * temp
        saved = left[j - r] * temp
    out[j] = saved


@numba.njit(cache=True, inline="always")
def basis_funs_scratch(span, t, degree, knots, out, left, right):
    """Piegl & Tiller A2.2 BasisFuns with caller-provided scratch ``left``/``right``."""
    out[0] = 1.0
    for j in range(1, degree + 1):
        _basis_step(j, span, t, knots, out, left, right)


@numba.njit(cache=True)
def basis_funs(span, t, degree, knots, out):
    """The degree + 1 non-zero basis functions at t (Piegl & Tiller A2.2 BasisFuns).

    ``out[r]`` is N_{span-degree+r, degree}(t).
    """
    basis_funs_scratch(span, t, degree, knots, out, np.empty(degree + 1), np.empty(degree + 1))


@numba.njit(cache=True)
def ders_basis_funs(span, t, degree, n_ders, knots, ders):
    """Basis functions and their derivatives up to ``n_ders`` (Piegl & Tiller A2.3 DersBasisFuns).

    ``ders[k, r]`` is the k-th derivative of N_{span-degree+r, degree} at t.
    """
    p = degree
    ndu = np.empty((p + 1, p + 1))
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    a = np.empty((2, p + 1))
    ndu[0, 0] = 1.0
    for j in range(1, p + 1):
        left[j] = t - knots[span + 1 - j]
        right[j] = knots[span + j] - t
        saved = 0.0
        for r in range(j):
            ndu[j, r] = right[r + 1] + left[j - r]
            temp = ndu[r, j - 1] / ndu[j, r]
            ndu[r, j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j, j] = saved
    for j in range(p + 1):
        ders[0, j] = ndu[j, p]
    for r in range(p + 1):
        s1 = 0
        s2 = 1
        a[0, 0] = 1.0
        for k in range(1, n_ders + 1):
            d = 0.0
            rk = r - k
            pk = p - k
            if r >= k:
                a[s2, 0] = a[s1, 0] / ndu[pk + 1, rk]
                d = a[s2, 0] * ndu[rk, pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = k - 1 if r - 1 <= pk else p - r
            for j in range(j1, j2 + 1):
                a[s2, j] = (a[s1, j] - a[s1, j - 1]) / ndu[pk + 1, rk + j]
                d += a[s2, j] * ndu[rk + j, pk]
            if r <= pk:
                a[s2, k] = -a[s1, k - 1] / ndu[pk + 1, r]
                d += a[s2, k] * ndu[r, pk]
            ders[k, r] = d
            s1, s2 = s2, s1
    factor = float(p)
    for k in range(1, n_ders + 1):
        for j in range(p + 1):
            ders[k, j] *= factor
        factor *= p - k


@numba.njit(cache=True)
def basis_table(t, n_ctrl, degree, knots, n_ders):
    """Spans and basis values (and derivatives) for many parameters at once.

    Returns ``spans`` (m,) and ``values`` (m, n_ders + 1, degree + 1): ``values[i, k, r]`` is the
    k-th derivative of N_{spans[i]-degree+r} at t[i]. Non-finite t gives span -1.
    """
    m = t.shape[0]
    spans = np.empty(m, np.int64)
    values = np.zeros((m, n_ders + 1, degree + 1))
    ders = np.empty((n_ders + 1, degree + 1))
    for i in range(m):
        if not math.isfinite(t[i]):
            spans[i] = -1
            continue
        s = find_span(n_ctrl, degree, t[i], knots)
        spans[i] = s
        if n_ders == 0:
            basis_funs(s, t[i], degree, knots, ders[0])
        else:
            ders_basis_funs(s, t[i], degree, n_ders, knots, ders)
        for k in range(n_ders + 1):
            for r in range(degree + 1):
                values[i, k, r] = ders[k, r]
    return spans, values


@numba.njit(cache=True)
def basis_funs_first_derivative(span, t, degree, knots, values, derivatives, left, right):
    """Basis functions and first derivatives at t without allocation.

    A2.2 BasisFuns run to degree - 1, then the derivative formula (Piegl & Tiller eq. 2.7)
    N'_{i,p} = p N_{i,p-1} / (u_{i+p} - u_i) - p N_{i+1,p-1} / (u_{i+p+1} - u_{i+1}),
    then the last step of A2.2 to degree p. ``left``/``right`` are scratch of size degree + 1.
    """
    p = degree
    values[0] = 1.0
    for j in range(1, p + 1):
        if j == p:
            # values[k] = N_{span-p+1+k, p-1}, k = 0..p-1
            for r in range(p + 1):
                d = 0.0
                i = span - p + r
                if r >= 1:
                    den = knots[i + p] - knots[i]
                    if den > 0.0:
                        d += values[r - 1] / den
                if r <= p - 1:
                    den = knots[i + p + 1] - knots[i + 1]
                    if den > 0.0:
                        d -= values[r] / den
                derivatives[r] = p * d
        _basis_step(j, span, t, knots, values, left, right)


# -------------------------------------------------------------------------------------------
# fused per-point kernels: span in O(1), basis, rational sum, one pass


@numba.njit(cache=True, inline="always")
def _rational_sums(sx, sy, p, control, weights, bx, by):
    """A = sum R_ab Q_ab N_a N_b and D = sum R_ab N_a N_b over the (p + 1)^2 control points of
    spans (sx, sy), basis values ``bx``/``by``: the numerator and denominator of S = A / D."""
    a = 0.0
    d = 0.0
    for i in range(p + 1):
        ia = sx - p + i
        ra = 0.0
        rd = 0.0
        for j in range(p + 1):
            jb = sy - p + j
            r = weights[ia, jb] * by[j]
            ra += r * control[ia, jb]
            rd += r
        a += bx[i] * ra
        d += bx[i] * rd
    return a, d


@numba.njit(cache=True, inline="always")
def _rational_sums_first_derivatives(sx, sy, p, control, weights, bx, by, dbx, dby):
    """A, D (as :func:`_rational_sums`, another summation order) and their x and y
    derivatives A_x, D_x, A_y, D_y from the basis derivatives ``dbx``/``dby``."""
    a = 0.0
    d = 0.0
    ax = 0.0
    dx = 0.0
    ay = 0.0
    dy = 0.0
    for i in range(p + 1):
        ia = sx - p + i
        ra = 0.0
        rd = 0.0
        ra_y = 0.0
        rd_y = 0.0
        for j in range(p + 1):
            jb = sy - p + j
            r = weights[ia, jb]
            rq = r * control[ia, jb]
            ra += by[j] * rq
            rd += by[j] * r
            ra_y += dby[j] * rq
            rd_y += dby[j] * r
        a += bx[i] * ra
        d += bx[i] * rd
        ax += dbx[i] * ra
        dx += dbx[i] * rd
        ay += bx[i] * ra_y
        dy += bx[i] * rd_y
    return a, d, ax, dx, ay, dy


@numba.njit(cache=True, inline="always")
def quotient_rule(a, d, ax, dx, ay, dy):
    """S = A / D and its derivatives S_x = (A_x - S D_x) / D, S_y = (A_y - S D_y) / D
    (Piegl & Tiller eq. 4.8 in homogeneous form)."""
    s = a / d
    return s, (ax - s * dx) / d, (ay - s * dy) / d


@numba.njit(cache=True)
def span_lookup(knots, n_ctrl, degree):
    """What O(1) span finding needs on any clamped knot vector: ``(table, scale,
    inv_widths)``. [knots[degree], knots[n_ctrl]] is cut into buckets no wider than its
    narrowest non-empty span (at most 64 per span); ``table[b]`` is the span holding the
    start of bucket b, so a parameter's span is its bucket's entry or the next
    (:func:`lookup_span`). ``inv_widths[s]``: 1 / width of span degree + s, 0 for an empty
    span (a repeated interior knot). On uniform knots: one bucket per span."""
    p = degree
    n_spans = n_ctrl - p
    low = knots[p]
    high = knots[n_ctrl]
    inv_widths = np.zeros(n_spans)
    narrowest = high - low
    for s in range(n_spans):
        w = knots[p + s + 1] - knots[p + s]
        if w > 0.0:
            inv_widths[s] = 1.0 / w
            narrowest = min(narrowest, w)
    if not high > low:
        return np.full(1, p, np.int64), 0.0, inv_widths
    n_buckets = max(1, min(int(math.ceil((high - low) / narrowest - 1e-9)), 64 * n_spans))
    scale = n_buckets / (high - low)
    table = np.empty(n_buckets + 1, np.int64)
    s = p
    for b in range(n_buckets + 1):
        t = low + b / scale
        while s < n_ctrl - 1 and t >= knots[s + 1]:
            s += 1
        table[b] = s
    return table, scale, inv_widths


@numba.njit(cache=True, inline="always")
def lookup_span(t, knots, n_ctrl, degree, table, scale):
    """Knot span of t (:func:`find_span`: parameters before or beyond the knot range map to
    the end spans) from the bucket table of :func:`span_lookup`: one multiplication, then
    comparisons with the knots on either side (the bucket's entry is the span or the one
    before it)."""
    f = (t - knots[degree]) * scale
    last = table.shape[0] - 1
    b = 0
    if f >= last:
        b = last
    elif f > 0.0:
        b = int(f)
    s = table[b]
    while s > degree and t < knots[s]:
        s -= 1
    while s < n_ctrl - 1 and t >= knots[s + 1]:
        s += 1
    return s


@numba.njit(cache=True, inline="always")
def _point_value(px, py, kx, ky, p, control, weights, tab_x, sc_x, tab_y, sc_y, bx, by, left,
                 right):
    """S(px, py) - in local coordinates, inside the knot range - as A / D (no derivatives),
    by A2.2 (any degree and knots)."""
    n0 = control.shape[0]
    n1 = control.shape[1]
    sx = lookup_span(px, kx, n0, p, tab_x, sc_x)
    sy = lookup_span(py, ky, n1, p, tab_y, sc_y)
    basis_funs_scratch(sx, px, p, kx, bx, left, right)
    basis_funs_scratch(sy, py, p, ky, by, left, right)
    a, d = _rational_sums(sx, sy, p, control, weights, bx, by)
    return a / d


@numba.njit(cache=True)
def span_power_basis(knots, degree, n_ctrl):
    """The non-zero basis functions of every knot span of a clamped knot vector in power
    form: ``out[s, r, m]`` is the coefficient of u^m in N_{s + r}(t) on span degree + s,
    u = (t - knots[degree + s]) / (knots[degree + s + 1] - knots[degree + s]) (0 to 1 across
    the span; an empty span is left 0). A2.2 run on polynomials: its ``left``/``right`` are
    linear in u and its denominators constant."""
    p = degree
    n_spans = n_ctrl - p
    out = np.zeros((n_spans, p + 1, p + 1))
    left0 = np.zeros(p + 1)  # left[j] = left0[j] + h u, right[j] = right0[j] - h u
    right0 = np.zeros(p + 1)
    temp = np.zeros(p + 1)
    saved = np.zeros(p + 1)
    for s in range(n_spans):
        span = p + s
        h = knots[span + 1] - knots[span]
        if not h > 0.0:
            continue
        cur = out[s]
        cur[0, 0] = 1.0
        for j in range(1, p + 1):
            left0[j] = knots[span] - knots[span + 1 - j]
            right0[j] = knots[span + j] - knots[span]
            saved[:] = 0.0
            for r in range(j):
                den = right0[r + 1] + left0[j - r]
                for m in range(j):
                    temp[m] = cur[r, m] / den
                for m in range(j + 1):
                    below = temp[m - 1] if m > 0 else 0.0
                    own = temp[m] if m < j else 0.0
                    cur[r, m] = saved[m] + right0[r + 1] * own - h * below
                    saved[m] = left0[j - r] * own + h * below
            for m in range(j + 1):
                cur[j, m] = saved[m]
    return out


@numba.njit(cache=True)
def cubic_span_coefficients(knots_x, knots_y, control, weights):
    """The numerator A and the denominator D of a cubic rational surface on every span pair
    as bicubic polynomials in the spans' local (u, v) (:func:`span_power_basis`): flat, 32
    per span pair (sx - 3) * n_spans_y + (sy - 3), the coefficient of u^m v^n of A at
    8 n + m and of D at 8 n + 4 + m (the 8 polynomials in v of a point are then contiguous)."""
    n0, n1 = control.shape
    px = span_power_basis(knots_x, 3, n0)
    py = span_power_basis(knots_y, 3, n1)
    nsx = n0 - 3
    nsy = n1 - 3
    # rows first: per control row ia and y span j, sum_b R Q N_b and sum_b R N_b in v
    rows = np.zeros((n0, nsy, 8))
    for ia in range(n0):
        for j in range(nsy):
            for b in range(4):
                r = weights[ia, j + b]
                rq = r * control[ia, j + b]
                for n in range(4):
                    rows[ia, j, n] += rq * py[j, b, n]
                    rows[ia, j, 4 + n] += r * py[j, b, n]
    out = np.zeros(nsx * nsy * 32)
    for i in range(nsx):
        for j in range(nsy):
            base = (i * nsy + j) * 32
            for a in range(4):
                for m in range(4):
                    c = px[i, a, m]
                    for n in range(4):
                        out[base + 8 * n + m] += c * rows[i + a, j, n]
                        out[base + 8 * n + 4 + m] += c * rows[i + a, j, 4 + n]
    return out


@numba.njit(cache=True, inline="always")
def _knot_range(knots_x, knots_y, tol_x, tol_y):
    """(lo_x, hi_x, lo_y, hi_y): the knot range widened by the tolerances, where the surface
    is evaluated (outside: NaN, or no normal factor)."""
    return (knots_x[0] - tol_x, knots_x[knots_x.shape[0] - 1] + tol_x,
            knots_y[0] - tol_y, knots_y[knots_y.shape[0] - 1] + tol_y)


@numba.njit(cache=True, inline="always")
def _cubic_span_at(px, py, kx, ky, n0, n1, lx, ly):
    """(start of its coefficients, u, v, 1 / width along x, 1 / width along y) of the span
    pair holding local (px, py): the spans by :func:`lookup_span` (``lx``/``ly``: the
    axes' :func:`span_lookup`), clamped to the end spans (which points outside the knot range
    extrapolate); (u, v) local to the span pair (:func:`cubic_span_coefficients`)."""
    ix = lookup_span(px, kx, n0, 3, lx[0], lx[1]) - 3
    iy = lookup_span(py, ky, n1, 3, ly[0], ly[1]) - 3
    wx = lx[2][ix]
    wy = ly[2][iy]
    return (ix * (n1 - 3) + iy) * 32, (px - kx[ix + 3]) * wx, (py - ky[iy + 3]) * wy, wx, wy


@numba.njit(cache=True)
def _held_cubic_span(t, knots, n_ctrl, lookup, i, start, stop, inv_width):
    """(i, start, stop, inv_width) of the cubic span holding t along one axis: span i + 3 of
    ``knots`` (:func:`lookup_span`, ``lookup``: the axis' :func:`span_lookup`), its knots
    start = knots[i + 3] and stop = knots[i + 4] and 1 / its width. The span given (held from
    the previous point) when start <= t < stop: the only non-empty span holding t, the one
    :func:`lookup_span` finds (a parameter outside the knot range, mapped to an end span, is
    in no span's [start, stop) and is looked up). Consecutive points of a scan mostly share
    their spans, and the look-up (a bucket, then comparisons that mispredict) costs more
    than the surface's value. A plain call (LLVM inlines it): with ``inline="always"``
    :func:`heights_above_serial` ran five times slower."""
    if t >= start and t < stop:
        return i, start, stop, inv_width
    i = lookup_span(t, knots, n_ctrl, 3, lookup[0], lookup[1]) - 3
    return i, knots[i + 3], knots[i + 4], lookup[2][i]


@numba.njit(cache=True, inline="always")
def _cubic_span_rows(c, b, v):
    """The 8 polynomials in v of a span pair whose coefficients start at ``c[b]``
    (:func:`cubic_span_coefficients`): A's rows u^0..u^3, then D's, by Horner on contiguous
    coefficients."""
    return (((c[b + 24] * v + c[b + 16]) * v + c[b + 8]) * v + c[b],
            ((c[b + 25] * v + c[b + 17]) * v + c[b + 9]) * v + c[b + 1],
            ((c[b + 26] * v + c[b + 18]) * v + c[b + 10]) * v + c[b + 2],
            ((c[b + 27] * v + c[b + 19]) * v + c[b + 11]) * v + c[b + 3],
            ((c[b + 28] * v + c[b + 20]) * v + c[b + 12]) * v + c[b + 4],
            ((c[b + 29] * v + c[b + 21]) * v + c[b + 13]) * v + c[b + 5],
            ((c[b + 30] * v + c[b + 22]) * v + c[b + 14]) * v + c[b + 6],
            ((c[b + 31] * v + c[b + 23]) * v + c[b + 15]) * v + c[b + 7])


@numba.njit(cache=True, inline="always")
def _cubic_span_ratio(c, b, u, v):
    """A / D at local (u, v) of a span pair whose coefficients start at ``c[b]``
    (:func:`cubic_span_coefficients`): the 8 polynomials in v (:func:`_cubic_span_rows`), then
    A and D in u, all by Horner."""
    r0, r1, r2, r3, d0, d1, d2, d3 = _cubic_span_rows(c, b, v)
    return (((r3 * u + r2) * u + r1) * u + r0) / (((d3 * u + d2) * u + d1) * u + d0)


@numba.njit(cache=True, inline="always")
def _cubic_span_gradient(c, b, u, v):
    """(dS/du, dS/dv) at local (u, v) of a span pair whose coefficients start at ``c[b]``
    (:func:`cubic_span_coefficients`) by the quotient rule S_u = (A_u - S D_u) / D: the 8
    polynomials in v (:func:`_cubic_span_rows`) and their v derivatives, then A, D and their
    derivatives in u, by Horner. Equals the derivative of the B-spline sums up to rounding."""
    r0, r1, r2, r3, d0, d1, d2, d3 = _cubic_span_rows(c, b, v)
    q0 = (3.0 * c[b + 24] * v + 2.0 * c[b + 16]) * v + c[b + 8]
    q1 = (3.0 * c[b + 25] * v + 2.0 * c[b + 17]) * v + c[b + 9]
    q2 = (3.0 * c[b + 26] * v + 2.0 * c[b + 18]) * v + c[b + 10]
    q3 = (3.0 * c[b + 27] * v + 2.0 * c[b + 19]) * v + c[b + 11]
    e0 = (3.0 * c[b + 28] * v + 2.0 * c[b + 20]) * v + c[b + 12]
    e1 = (3.0 * c[b + 29] * v + 2.0 * c[b + 21]) * v + c[b + 13]
    e2 = (3.0 * c[b + 30] * v + 2.0 * c[b + 22]) * v + c[b + 14]
    e3 = (3.0 * c[b + 31] * v + 2.0 * c[b + 23]) * v + c[b + 15]
    a = ((r3 * u + r2) * u + r1) * u + r0
    d = ((d3 * u + d2) * u + d1) * u + d0
    s = a / d
    a_u = (3.0 * r3 * u + 2.0 * r2) * u + r1
    d_u = (3.0 * d3 * u + 2.0 * d2) * u + d1
    a_v = ((q3 * u + q2) * u + q1) * u + q0
    d_v = ((e3 * u + e2) * u + e1) * u + e0
    return (a_u - s * d_u) / d, (a_v - s * d_v) / d


@numba.njit(cache=True, inline="always")
def _heights_range(positions, out, first, last, origin_x, origin_y, origin_z, knots_x,
                   knots_y, p, control, weights, tol_x, tol_y, coef, lx, ly):
    """The heights of :func:`heights_above` of points first to last - 1 into ``out``
    (``coef``: :func:`cubic_span_coefficients` for degree 3, else unused; ``lx``/``ly``: the
    axes' :func:`span_lookup`)."""
    lo_x, hi_x, lo_y, hi_y = _knot_range(knots_x, knots_y, tol_x, tol_y)
    n0 = control.shape[0]
    n1 = control.shape[1]
    bx = np.empty(p + 1)
    by = np.empty(p + 1)
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    # cubic case: the spans of the previous point along x and y (none yet: an empty interval)
    ix = iy = 0
    start_x = start_y = math.inf
    stop_x = stop_y = -math.inf
    wx = wy = 0.0
    for k in range(first, last):
        px = positions[k, 0] - origin_x
        py = positions[k, 1] - origin_y
        z = positions[k, 2]
        if not (px >= lo_x and px <= hi_x and py >= lo_y and py <= hi_y and math.isfinite(z)):
            out[k] = np.nan
            continue
        if p == 3:
            # the span pair and local (u, v) of _cubic_span_at, the spans held while the
            # points stay in them
            ix, start_x, stop_x, wx = _held_cubic_span(px, knots_x, n0, lx, ix, start_x,
                                                       stop_x, wx)
            iy, start_y, stop_y, wy = _held_cubic_span(py, knots_y, n1, ly, iy, start_y,
                                                       stop_y, wy)
            s = _cubic_span_ratio(coef, (ix * (n1 - 3) + iy) * 32, (px - start_x) * wx,
                                  (py - start_y) * wy)
        else:
            s = _point_value(px, py, knots_x, knots_y, p, control, weights, lx[0], lx[1],
                             ly[0], ly[1], bx, by, left, right)
        out[k] = (z - origin_z) - s


@numba.njit(cache=True, inline="always")
def _span_coefficients(knots_x, knots_y, degree, control, weights):
    """:func:`cubic_span_coefficients` of a surface of degree 3, an empty array otherwise."""
    if degree != 3:
        return np.empty(0)
    return cubic_span_coefficients(knots_x, knots_y, control, weights)


@numba.njit(cache=True, parallel=True, error_model="numpy", fastmath={"contract"})
def heights_above(positions, origin_x, origin_y, origin_z, knots_x, knots_y, degree, control,
                  weights, tol_x, tol_y):
    """Signed height z - S(x, y) of each point of an (N, >= 3) array, in one pass.

    ``origin_*``: the surface's local origin (positions are world coordinates). Points with a
    non-finite coordinate or with (x, y) outside the knot range widened by ``tol_x``/``tol_y``
    give NaN. Chunks of points are split over threads; every point is computed alone, so the
    result does not depend on the thread count. Degree 3: A and D of each span pair as
    bicubic polynomials computed once (:func:`cubic_span_coefficients`), then per point the
    span pair (:func:`lookup_span`, clamped to the end spans, which points outside the knot
    range within the tolerance extrapolate; the previous point's spans while the points stay
    in them, :func:`_held_cubic_span`), Horner evaluations (multiply-adds may be fused)
    and one division: the value of the B-spline sums up to rounding (1e-15 relative). The
    per-point code is :func:`_heights_range`, which :func:`heights_above_serial` runs over
    all the points in one thread.
    """
    n = positions.shape[0]
    out = np.empty(n)
    coef = _span_coefficients(knots_x, knots_y, degree, control, weights)
    lx = span_lookup(knots_x, control.shape[0], degree)
    ly = span_lookup(knots_y, control.shape[1], degree)
    chunk = 4096
    n_chunks = (n + chunk - 1) // chunk
    for c in numba.prange(n_chunks):
        _heights_range(positions, out, c * chunk, min(n, (c + 1) * chunk), origin_x,
                       origin_y, origin_z, knots_x, knots_y, degree, control, weights, tol_x,
                       tol_y, coef, lx, ly)
    return out


@numba.njit(cache=True, error_model="numpy", fastmath={"contract"})
def heights_above_serial(positions, origin_x, origin_y, origin_z, knots_x, knots_y, degree,
                         control, weights, tol_x, tol_y):
    """:func:`heights_above` in the calling thread, the same per-point code
    (:func:`_heights_range`) and so the same heights bit for bit: for one numba thread, where
    the parallel loop's machinery costs about a tenth of the time (3.55 against 3.2 ms on a
    124,668-point KITTI frame)."""
    out = np.empty(positions.shape[0])
    _heights_range(positions, out, 0, positions.shape[0], origin_x, origin_y, origin_z,
                   knots_x, knots_y, degree, control, weights, tol_x, tol_y,
                   _span_coefficients(knots_x, knots_y, degree, control, weights),
                   span_lookup(knots_x, control.shape[0], degree),
                   span_lookup(knots_y, control.shape[1], degree))
    return out


@numba.njit(cache=True)
def _range_threshold(positions, k, threshold, range_coefficient, sensor_x, sensor_y,
                     range_high):
    """The obstacle threshold of point k at horizontal range r from the sensor:
    min(threshold + range_coefficient r^2, max(range_high, threshold)), the one rule of
    :func:`label_heights` and :func:`relabel_along_normal`."""
    dx = positions[k, 0] - sensor_x
    dy = positions[k, 1] - sensor_y
    return min(threshold + range_coefficient * (dx * dx + dy * dy), max(range_high, threshold))


@numba.njit(cache=True)
def label_heights(heights, positions, threshold, below_threshold, range_coefficient,
                  sensor_x, sensor_y, range_high, unknown, terrain, obstacle, below):
    """Labels (uint8) from heights above the terrain: ``obstacle`` above t(r) = min(threshold +
    range_coefficient r^2, max(range_high, threshold)), ``below`` under -below_threshold,
    ``terrain`` between, ``unknown`` for NaN heights. r is the horizontal range of
    ``positions[k]`` from the sensor."""
    n = heights.shape[0]
    out = np.empty(n, np.uint8)
    for k in range(n):
        h = heights[k]
        if not math.isfinite(h):
            out[k] = unknown
            continue
        t = threshold
        if range_coefficient != 0.0:
            t = _range_threshold(positions, k, threshold, range_coefficient, sensor_x,
                                 sensor_y, range_high)
        if h > t:
            out[k] = obstacle
        elif h < -below_threshold:
            out[k] = below
        else:
            out[k] = terrain
    return out


@numba.njit(cache=True, parallel=True, error_model="numpy")
def rational_surface_points(x, y, origin_x, origin_y, tol_x, tol_y, knots_x, knots_y, degree,
                            control, weights, with_derivatives):
    """Rational tensor-product surface S = A / D and its first derivatives (quotient rule
    S_x = (A_x - S D_x) / D) at world points (x[k], y[k]) of a surface with local origin
    (origin_x, origin_y), spans found in O(1) (:func:`lookup_span`). Degree 3: from the span
    pairs' bicubic A and D (:func:`cubic_span_coefficients`), as :func:`heights_above`
    evaluates S; other degrees by A2.2 and the derivative formula.

    NaN for non-finite input and for points outside the knot range widened by
    ``tol_x``/``tol_y``; points within the tolerance use the end span. Chunks of points are
    split over threads; every point is computed alone, so the result does not depend on the
    thread count.
    """
    n = x.shape[0]
    p = degree
    n0 = control.shape[0]
    n1 = control.shape[1]
    z = np.empty(n)
    dzdx = np.empty(n) if with_derivatives else np.empty(0)
    dzdy = np.empty(n) if with_derivatives else np.empty(0)
    lo_x, hi_x, lo_y, hi_y = _knot_range(knots_x, knots_y, tol_x, tol_y)
    coef = _span_coefficients(knots_x, knots_y, degree, control, weights)
    lx = span_lookup(knots_x, n0, p)
    ly = span_lookup(knots_y, n1, p)
    chunk = 4096
    n_chunks = (n + chunk - 1) // chunk
    for c in numba.prange(n_chunks):
        bx = np.empty(p + 1)
        by = np.empty(p + 1)
        dbx = np.zeros(p + 1)
        dby = np.zeros(p + 1)
        left = np.empty(p + 1)
        right = np.empty(p + 1)
        for k in range(c * chunk, min(n, (c + 1) * chunk)):
            xk = x[k] - origin_x
            yk = y[k] - origin_y
            if not (xk >= lo_x and xk <= hi_x and yk >= lo_y and yk <= hi_y):
                z[k] = np.nan
                if with_derivatives:
                    dzdx[k] = np.nan
                    dzdy[k] = np.nan
                continue
            if p == 3:
                b, u, v, wx, wy = _cubic_span_at(xk, yk, knots_x, knots_y, n0, n1, lx, ly)
                z[k] = _cubic_span_ratio(coef, b, u, v)
                if with_derivatives:
                    su, sv = _cubic_span_gradient(coef, b, u, v)
                    dzdx[k] = su * wx
                    dzdy[k] = sv * wy
            elif not with_derivatives:
                z[k] = _point_value(xk, yk, knots_x, knots_y, p, control, weights, lx[0],
                                    lx[1], ly[0], ly[1], bx, by, left, right)
            else:
                z[k], dzdx[k], dzdy[k] = _point_first_derivatives(
                    xk, yk, knots_x, knots_y, p, control, weights, lx[0], lx[1], ly[0], ly[1],
                    bx, by, dbx, dby, left, right)
    return z, dzdx, dzdy


@numba.njit(cache=True, inline="always")
def _point_first_derivatives(xk, yk, knots_x, knots_y, p, control, weights, tab_x, sc_x,
                             tab_y, sc_y, bx, by, dbx, dby, left, right):
    """(S, S_x, S_y) at local (xk, yk) inside the knot range (widened by the tolerance):
    spans by :func:`lookup_span`, basis values and derivatives, then the quotient rule.
    ``bx``/``by``/``dbx``/``dby``/``left``/``right``: scratch of size degree + 1."""
    n0 = control.shape[0]
    n1 = control.shape[1]
    sx = lookup_span(xk, knots_x, n0, p, tab_x, sc_x)
    sy = lookup_span(yk, knots_y, n1, p, tab_y, sc_y)
    basis_funs_first_derivative(sx, xk, p, knots_x, bx, dbx, left, right)
    basis_funs_first_derivative(sy, yk, p, knots_y, by, dby, left, right)
    a, d, ax, dx, ay, dy = _rational_sums_first_derivatives(sx, sy, p, control, weights,
                                                            bx, by, dbx, dby)
    return quotient_rule(a, d, ax, dx, ay, dy)


@numba.njit(cache=True)
def _gradient_tools(knots_x, knots_y, degree, control, weights):
    """What a kernel needs to evaluate the surface's gradient point by point, made once per
    surface: the span pairs' bicubic coefficients (degree 3, for :func:`_cubic_span_gradient`),
    the axes' :func:`span_lookup` and scratch of size degree + 1 (for
    :func:`_point_first_derivatives`). The per-point code stays in each kernel's loop: behind
    a helper function numba called it per point, four times slower on the line-of-sight
    kernel (with or without ``inline="always"``)."""
    p = degree
    return (_span_coefficients(knots_x, knots_y, p, control, weights),
            span_lookup(knots_x, control.shape[0], p), span_lookup(knots_y, control.shape[1], p),
            np.empty(p + 1), np.empty(p + 1), np.zeros(p + 1), np.zeros(p + 1), np.empty(p + 1),
            np.empty(p + 1))


@numba.njit(cache=True, error_model="numpy")
def relabel_along_normal(labels, heights, positions, threshold, below_threshold,
                         range_coefficient, sensor_x, sensor_y, range_high, cap, origin_x,
                         origin_y, tol_x, tol_y, knots_x, knots_y, degree, control, weights,
                         terrain, obstacle, below):
    """In place, in one pass: ``obstacle`` points with h <= t(r) f and ``below`` points with
    h >= -below_threshold f become ``terrain``, f = min(sqrt(1 + |grad S|^2), ``cap``) at the
    point (1 where the gradient is not finite or the point lies outside the knot range widened
    by ``tol_x``/``tol_y``), t(r) = min(threshold + range_coefficient r^2, max(range_high,
    threshold)) (r: horizontal range from the sensor). The gradient is evaluated only at the
    points within ``cap`` times their threshold: for degree 3 from the span pairs' bicubic A
    and D (:func:`_cubic_span_gradient`, as :func:`heights_above` evaluates S), else by the
    operations of :func:`rational_surface_points`. Returns how many labels changed."""
    n = heights.shape[0]
    p = degree
    lo_x, hi_x, lo_y, hi_y = _knot_range(knots_x, knots_y, tol_x, tol_y)
    # the candidates, without branches (labels and heights mix at random along a scan)
    candidates = np.empty(n, np.int32)
    count = 0
    obstacle_cap = cap * threshold
    below_cap = -cap * below_threshold
    for k in range(n):
        label = labels[k]
        h = heights[k]
        if range_coefficient != 0.0:
            obstacle_cap = cap * _range_threshold(positions, k, threshold, range_coefficient,
                                                  sensor_x, sensor_y, range_high)
        candidates[count] = k
        count += ((label == obstacle) & (h <= obstacle_cap)) | ((label == below) & (h >= below_cap))
    if count == 0:
        return 0
    coef, lx, ly, bx, by, dbx, dby, left, right = _gradient_tools(knots_x, knots_y, p, control,
                                                                  weights)
    changed = 0
    for c in range(count):
        k = candidates[c]
        label = labels[k]
        h = heights[k]
        t = threshold
        if range_coefficient != 0.0:
            t = _range_threshold(positions, k, threshold, range_coefficient, sensor_x,
                                 sensor_y, range_high)
        xk = positions[k, 0] - origin_x
        yk = positions[k, 1] - origin_y
        factor = 1.0
        if xk >= lo_x and xk <= hi_x and yk >= lo_y and yk <= hi_y:
            if p == 3:
                b, u, v, wx, wy = _cubic_span_at(xk, yk, knots_x, knots_y, control.shape[0],
                                                 control.shape[1], lx, ly)
                su, sv = _cubic_span_gradient(coef, b, u, v)
                gx = su * wx
                gy = sv * wy
            else:
                _, gx, gy = _point_first_derivatives(xk, yk, knots_x, knots_y, p, control,
                                                     weights, lx[0], lx[1], ly[0], ly[1], bx,
                                                     by, dbx, dby, left, right)
            f = math.sqrt(1.0 + gx * gx + gy * gy)
            if math.isfinite(f):
                factor = min(f, cap)
        if (h <= t * factor) if label == obstacle else (h >= -below_threshold * factor):
            labels[k] = terrain
            changed += 1
    return changed


@numba.njit(cache=True, error_model="numpy")
def out_of_sight(positions, labels, terrain, sensor_x, sensor_y, sensor_z, tan_margin, radius,
                 min_points, min_height, step, origin_x, origin_y, tol_x, tol_y, knots_x,
                 knots_y, degree, control, weights):
    """The indices of the ``terrain`` points higher than the sensor where the surface's slope
    along the line of sight, g (rise per metre away from the sensor), is less than
    tan(e - margin), e the point's elevation angle from the sensor (tan_margin = tan margin):
    ground there would be seen through the surface. Empty when fewer than ``min_points``
    terrain points among every ``step``-th point lie within ``radius`` (x/y) of the sensor,
    or when their median height is not at least ``min_height`` below it. Points outside
    the knot range widened by ``tol_x``/``tol_y``, or with a non-finite gradient, are kept.
    The gradient as in :func:`relabel_along_normal`."""
    n = positions.shape[0]
    # the ground around the sensor, from every step-th point
    around = np.empty(n // step + 1)
    m = 0
    r2_max = radius * radius
    for k in range(0, n, step):
        if labels[k] != terrain:
            continue
        dx = positions[k, 0] - sensor_x
        dy = positions[k, 1] - sensor_y
        if dx * dx + dy * dy <= r2_max and math.isfinite(positions[k, 2]):
            around[m] = positions[k, 2]
            m += 1
    if m < min_points or not np.median(around[:m]) <= sensor_z - min_height:
        return np.empty(0, np.int64)
    lo_x, hi_x, lo_y, hi_y = _knot_range(knots_x, knots_y, tol_x, tol_y)
    coef, lx, ly, bx, by, dbx, dby, left, right = _gradient_tools(knots_x, knots_y, degree,
                                                                  control, weights)
    out = np.empty(n, np.int64)
    count = 0
    for k in range(n):
        dz = positions[k, 2] - sensor_z
        if labels[k] != terrain or not dz > 0.0:
            continue
        dx = positions[k, 0] - sensor_x
        dy = positions[k, 1] - sensor_y
        r = math.sqrt(dx * dx + dy * dy)
        xk = positions[k, 0] - origin_x
        yk = positions[k, 1] - origin_y
        if not (r > 0.0 and xk >= lo_x and xk <= hi_x and yk >= lo_y and yk <= hi_y):
            continue
        if degree == 3:
            b, u, v, wx, wy = _cubic_span_at(xk, yk, knots_x, knots_y, control.shape[0],
                                             control.shape[1], lx, ly)
            su, sv = _cubic_span_gradient(coef, b, u, v)
            gx = su * wx
            gy = sv * wy
        else:
            _, gx, gy = _point_first_derivatives(xk, yk, knots_x, knots_y, degree, control,
                                                 weights, lx[0], lx[1], ly[0], ly[1], bx, by,
                                                 dbx, dby, left, right)
        rise = (gx * dx + gy * dy) / r
        tan_e = dz / r
        # rise < tan(e - margin), by the tangent of a difference (e - margin > -90 deg here)
        if rise * (1.0 + tan_e * tan_margin) < tan_e - tan_margin:
            out[count] = k
            count += 1
    return out[:count]


# -------------------------------------------------------------------------------------------
# normal equations of a tensor-product fit on a grid, by rows


@numba.njit(cache=True, inline="always")
def _cell_denominator(basis_x, i, sx, col_d, j, p):
    """D = sum_a Bx[i, a] col_d[j, sx + a] at cell (i, j) (col_d: R contracted along y)."""
    acc = 0.0
    for a in range(p + 1):
        acc += basis_x[i, a] * col_d[j, sx + a]
    return acc


@numba.njit(cache=True, inline="always")
def _store_span_sums(r, t, held, r0, r1, r2, r3, t00, t01, t02, t03, t10, t11, t12, t20, t21,
                     t30):
    """Write the 14 running sums of the cubic span starting at row ``held`` (held in registers
    by :func:`normal_band_cells`) back into ``r`` and ``t``."""
    r[held] = r0
    r[held + 1] = r1
    r[held + 2] = r2
    r[held + 3] = r3
    t[held, 0] = t00
    t[held, 1] = t01
    t[held, 2] = t02
    t[held, 3] = t03
    t[held + 1, 0] = t10
    t[held + 1, 1] = t11
    t[held + 1, 2] = t12
    t[held + 2, 0] = t20
    t[held + 2, 1] = t21
    t[held + 3, 0] = t30


@numba.njit(cache=True, error_model="numpy")
def normal_band_cells(spans_x, basis_x, spans_y, basis_y, z, sample_weights, rational_weights,
                      cells, n0, n1, degree, bandwidth, denominators):
    """Normal equations of the weighted (rational) least-squares fit over the cells ``cells``
    (flat indices into the C-ordered (m0, m1) grid, increasing): ``z`` and ``sample_weights``
    are the samples and weights of those cells, one per entry of ``cells`` (gathered: the
    arrays the loop reads stay small and contiguous).

    Per cell: w = sample weight (cells with w <= 0 or NaN add nothing), v = w z; with
    control-point weights R (``rational_weights`` of size > 0) the rational basis divides by
    D = Bx R By^T at the cell (contracted along y once per column): w / D^2 and w z / D.
    The matrix sum_c w_c b_c b_c^T, b_c[a * n1 + b] = N_a(x_i) N_b(y_j), is built row by row:
    for grid row i, T_i = sum_j w_ij by_j by_j^T (banded, n1 x n1) and r_i = sum_j v_ij by_j
    first, then A[(a, b), (a', b')] += bx_i[a] bx_i[a'] T_i[b, b'] for the degree + 1
    non-zero bx_i[a]: O(cells p^2 + rows n1 p^3) instead of O(cells p^4).

    With R the matrix and right-hand side are those of the rational basis R_ab N_a N_b / D:
    diag(R) A diag(R) and R rhs, scaled in here once the sums are complete. With R and
    ``denominators`` of size > 0, D of every cell is written there (one per entry of
    ``cells``), for :func:`grid_rational_cells` of the solution with the same R.

    Returns ``(lower, rhs, total)``: ``lower[k, d] = A[k + d, k]``, shape
    (n0 n1, bandwidth + 1) (its transpose is LAPACK's lower band storage in Fortran order, so
    ``lower.T`` goes to ``dpbsv`` without a copy), the right-hand side and the sum of the
    weights > 0 (in cell order). Each entry of ``lower`` is updated once per grid row, so the
    loop order within a row does not change the values.
    """
    p = degree
    m1 = spans_y.shape[0]
    rational = rational_weights.shape[0] > 0
    keep = rational and denominators.shape[0] > 0
    size = n0 * n1
    lower = np.zeros((size, bandwidth + 1))
    rhs = np.zeros(size)
    total = 0.0
    col_d = np.zeros((m1, rational_weights.shape[0]))
    if rational:
        for j in range(m1):
            sy = spans_y[j] - p
            for a in range(n0):
                acc = 0.0
                for b in range(p + 1):
                    acc += basis_y[j, b] * rational_weights[a, sy + b]
                col_d[j, a] = acc
    t = np.zeros((n1, p + 1))  # t[b, d] = T_i[b, b + d]
    tf = np.zeros((n1, 2 * p + 1))
    r = np.zeros(n1)
    # cubic case: the sums of the span ``held`` (-1: none) in registers
    held = -1
    r0 = r1 = r2 = r3 = 0.0
    t00 = t01 = t02 = t03 = t10 = t11 = t12 = t20 = t21 = t30 = 0.0
    count = cells.shape[0]
    k = 0
    while k < count:
        i = cells[k] // m1  # one integer division per grid row
        first = i * m1
        end = first + m1
        sx = spans_x[i]
        b_lo = n1
        b_hi = -1
        while k < count and cells[k] < end:
            c = cells[k]
            w = sample_weights[k]
            wz = w * z[k]
            k += 1
            j = c - first
            if not w > 0.0:
                if keep:
                    denominators[k - 1] = _cell_denominator(basis_x, i, sx - p, col_d, j, p)
                continue
            total += w
            if rational:
                acc = _cell_denominator(basis_x, i, sx - p, col_d, j, p)
                if keep:
                    denominators[k - 1] = acc
                w = w / (acc * acc)
                v = wz / acc
            else:
                v = wz
            if sx < 0:
                continue
            sy = spans_y[j]
            if sy < 0:
                continue
            base = sy - p
            if base < b_lo:
                b_lo = base
            if sy > b_hi:
                b_hi = sy
            if p == 3:  # the loop below unrolled for the cubic case (same operations)
                if base != held:
                    # the 14 sums of this span in registers while the next cells of the row
                    # fall in the same span: loaded here, stored back when the span changes
                    # (the same additions in the same order as in place)
                    if held >= 0:
                        _store_span_sums(r, t, held, r0, r1, r2, r3, t00, t01, t02, t03, t10,
                                         t11, t12, t20, t21, t30)
                    held = base
                    r0 = r[base]
                    r1 = r[base + 1]
                    r2 = r[base + 2]
                    r3 = r[base + 3]
                    t00 = t[base, 0]
                    t01 = t[base, 1]
                    t02 = t[base, 2]
                    t03 = t[base, 3]
                    t10 = t[base + 1, 0]
                    t11 = t[base + 1, 1]
                    t12 = t[base + 1, 2]
                    t20 = t[base + 2, 0]
                    t21 = t[base + 2, 1]
                    t30 = t[base + 3, 0]
                y0 = basis_y[j, 0]
                y1 = basis_y[j, 1]
                y2 = basis_y[j, 2]
                y3 = basis_y[j, 3]
                r0 += v * y0
                r1 += v * y1
                r2 += v * y2
                r3 += v * y3
                wb = w * y0
                t00 += wb * y0
                t01 += wb * y1
                t02 += wb * y2
                t03 += wb * y3
                wb = w * y1
                t10 += wb * y1
                t11 += wb * y2
                t12 += wb * y3
                wb = w * y2
                t20 += wb * y2
                t21 += wb * y3
                wb = w * y3
                t30 += wb * y3
                continue
            for b in range(p + 1):
                yb = basis_y[j, b]
                r[base + b] += v * yb
                wb = w * yb
                for d in range(p + 1 - b):
                    t[base + b, d] += wb * basis_y[j, b + d]
        if held >= 0:
            _store_span_sums(r, t, held, r0, r1, r2, r3, t00, t01, t02, t03, t10, t11, t12, t20,
                             t21, t30)
            held = -1
        if b_hi < 0:
            continue
        # the full symmetric band of T_i: tf[b, p + e] = T_i[b, b + e], e = -p .. p (zero
        # outside rows b_lo .. b_hi, so fixed-length loops add only zeros beyond them: each
        # entry of ``lower`` is updated once per grid row, the same sums as entry by entry)
        if p == 3:  # the loop below with a constant length (same assignments)
            for b in range(b_lo, b_hi + 1):
                for d in range(4):
                    tf[b, 3 + d] = t[b, d]
                    if b + d < n1:
                        tf[b + d, 3 - d] = t[b, d]
        else:
            for b in range(b_lo, b_hi + 1):
                for d in range(p + 1):
                    tf[b, p + d] = t[b, d]
                    if b + d < n1:
                        tf[b + d, p - d] = t[b, d]
        for a1 in range(p + 1):
            row1 = (sx - p + a1) * n1
            xa1 = basis_x[i, a1]
            for b in range(b_lo, b_hi + 1):
                rhs[row1 + b] += xa1 * r[b]
            f = xa1 * xa1
            if p == 3:  # the two loops below with constant lengths (unrolled; same operations)
                for b in range(b_lo, b_hi + 1):
                    for d in range(4):
                        lower[row1 + b, d] += f * tf[b, 3 + d]
                for a2 in range(a1 + 1, 4):
                    f = xa1 * basis_x[i, a2]
                    off = (a2 - a1) * n1 - 3
                    for b1 in range(b_lo, b_hi + 1):
                        k1 = row1 + b1
                        for e in range(7):
                            lower[k1, off + e] += f * tf[b1, e]
                continue
            for b in range(b_lo, b_hi + 1):
                for d in range(p + 1):
                    lower[row1 + b, d] += f * tf[b, p + d]
            for a2 in range(a1 + 1, p + 1):
                f = xa1 * basis_x[i, a2]
                off = (a2 - a1) * n1 - p
                for b1 in range(b_lo, b_hi + 1):
                    k1 = row1 + b1
                    for e in range(2 * p + 1):
                        lower[k1, off + e] += f * tf[b1, e]
        for b in range(b_lo, b_hi + 1):
            r[b] = 0.0
            t[b, :] = 0.0
            tf[b, :] = 0.0
    if rational:  # A -> diag(R) A diag(R), rhs -> R rhs (the rational basis R N_a N_b / D)
        rw = rational_weights.ravel()
        for k in range(size):
            rk = rw[k]
            for d in range(min(bandwidth + 1, size - k)):
                lower[k, d] *= rk * rw[k + d]
            rhs[k] *= rk
    return lower, rhs, total


@numba.njit(cache=True, error_model="numpy")
def grid_rational_cells(spans_x, basis_x, spans_y, basis_y, numerator, denominator, cells,
                        out, cell_denominators):
    """:func:`grid_rational` at the cells ``cells`` (increasing flat indices into the C-ordered
    (m0, m1) grid) only, written into ``out`` (one value per entry of ``cells``). Same
    operations per cell as :func:`grid_rational`, so the same values.

    ``cell_denominators`` of size > 0 (with ``denominator``): the denominator at each cell,
    as :func:`normal_band_cells` wrote it for the same weights (the same operations, so the
    same values); only the numerator is then summed here."""
    p = basis_x.shape[1] - 1
    m1 = spans_y.shape[0]
    n0 = numerator.shape[0]
    given = denominator.shape[0] > 0 and cell_denominators.shape[0] > 0
    rational = denominator.shape[0] > 0 and not given
    col_n = np.zeros((m1, n0))
    col_d = np.zeros((m1, n0)) if rational else np.zeros((0, 0))
    for j in range(m1):
        sy = spans_y[j] - p
        for a in range(n0):
            acc_n = 0.0
            acc_d = 0.0
            for b in range(p + 1):
                acc_n += basis_y[j, b] * numerator[a, sy + b]
                if rational:
                    acc_d += basis_y[j, b] * denominator[a, sy + b]
            col_n[j, a] = acc_n
            if rational:
                col_d[j, a] = acc_d
    count = cells.shape[0]
    k = 0
    while k < count:
        i = cells[k] // m1  # one integer division per grid row
        first = i * m1
        end = first + m1
        sx = spans_x[i] - p
        if p == 3 and rational:  # the loop below with a constant length (same operations)
            x0 = basis_x[i, 0]
            x1 = basis_x[i, 1]
            x2 = basis_x[i, 2]
            x3 = basis_x[i, 3]
            while k < count and cells[k] < end:
                c = cells[k]
                k += 1
                j = c - first
                acc_n = 0.0 + x0 * col_n[j, sx]
                acc_d = 0.0 + x0 * col_d[j, sx]
                acc_n += x1 * col_n[j, sx + 1]
                acc_d += x1 * col_d[j, sx + 1]
                acc_n += x2 * col_n[j, sx + 2]
                acc_d += x2 * col_d[j, sx + 2]
                acc_n += x3 * col_n[j, sx + 3]
                acc_d += x3 * col_d[j, sx + 3]
                out[k - 1] = acc_n / acc_d
            continue
        if p == 3 and given:  # the numerator as above, over the given denominators
            x0 = basis_x[i, 0]
            x1 = basis_x[i, 1]
            x2 = basis_x[i, 2]
            x3 = basis_x[i, 3]
            while k < count and cells[k] < end:
                c = cells[k]
                k += 1
                j = c - first
                acc_n = 0.0 + x0 * col_n[j, sx]
                acc_n += x1 * col_n[j, sx + 1]
                acc_n += x2 * col_n[j, sx + 2]
                acc_n += x3 * col_n[j, sx + 3]
                out[k - 1] = acc_n / cell_denominators[k - 1]
            continue
        while k < count and cells[k] < end:
            c = cells[k]
            k += 1
            j = c - first
            acc_n = 0.0
            acc_d = 0.0
            for a in range(p + 1):
                acc_n += basis_x[i, a] * col_n[j, sx + a]
                if rational:
                    acc_d += basis_x[i, a] * col_d[j, sx + a]
            if given:
                out[k - 1] = acc_n / cell_denominators[k - 1]
            else:
                out[k - 1] = acc_n / acc_d if rational else acc_n
    return out


@numba.njit(cache=True, inline="always")
def clamped_basis_first_derivative(t, n_ctrl, degree, knots, tol, values, derivatives, left,
                                   right):
    """Span of t, clamped into the knot range, with the basis values and first derivatives
    there (:func:`basis_funs_first_derivative`); -1 and nothing written where t lies outside
    the knot range widened by ``tol``."""
    low = knots[0]
    high = knots[knots.shape[0] - 1]
    if not (t >= low - tol and t <= high + tol):
        return -1
    t = min(max(t, low), high)
    span = find_span(n_ctrl, degree, t, knots)
    basis_funs_first_derivative(span, t, degree, knots, values, derivatives, left, right)
    return span


@numba.njit(cache=True)
def basis_first_derivative_table(t, n_ctrl, degree, knots, tol):
    """:func:`clamped_basis_first_derivative` at every t[j]: ``spans`` (m,) (-1 outside),
    ``values`` and ``derivatives`` (m, degree + 1) (0 outside)."""
    m = t.shape[0]
    p = degree
    spans = np.full(m, -1, np.int64)
    values = np.zeros((m, p + 1))
    derivatives = np.zeros((m, p + 1))
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    tmp = np.empty(p + 1)
    dtmp = np.empty(p + 1)
    for j in range(m):
        s = clamped_basis_first_derivative(t[j], n_ctrl, p, knots, tol, tmp, dtmp, left, right)
        if s < 0:
            continue
        spans[j] = s
        for b in range(p + 1):
            values[j, b] = tmp[b]
            derivatives[j, b] = dtmp[b]
    return spans, values, derivatives


@numba.njit(cache=True, inline="always")
def contract_row(sx, degree, bx, dbx, weights, weighted_control, a_row, d_row, ax_row, dx_row):
    """The rational surface contracted along x at one grid row (span ``sx``, basis values
    ``bx`` and derivatives ``dbx``): for every control column b, a_row[b] = sum_a N_a R Q,
    d_row[b] = sum_a N_a R, and ax_row, dx_row the same with N'_a (R Q = ``weighted_control``)."""
    p = degree
    for b in range(a_row.shape[0]):
        a = 0.0
        d = 0.0
        ax = 0.0
        dx = 0.0
        for k in range(p + 1):
            r = weights[sx - p + k, b]
            q = weighted_control[sx - p + k, b]
            a += bx[k] * q
            d += bx[k] * r
            ax += dbx[k] * q
            dx += dbx[k] * r
        a_row[b] = a
        d_row[b] = d
        ax_row[b] = ax
        dx_row[b] = dx


@numba.njit(cache=True, inline="always")
def row_node_value(sy, degree, by, dby, j, a_row, d_row, ax_row, dx_row):
    """S, S_x, S_y at grid node j of a row contracted by :func:`contract_row` (span ``sy``,
    basis values ``by[j]`` and derivatives ``dby[j]``): degree + 1 terms per sum, then the
    quotient rule."""
    p = degree
    a = 0.0
    d = 0.0
    ax = 0.0
    dx = 0.0
    ay = 0.0
    dy = 0.0
    for k in range(p + 1):
        b = sy - p + k
        v = by[j, k]
        w = dby[j, k]
        a += v * a_row[b]
        d += v * d_row[b]
        ax += v * ax_row[b]
        dx += v * dx_row[b]
        ay += w * a_row[b]
        dy += w * d_row[b]
    return quotient_rule(a, d, ax, dx, ay, dy)


@numba.njit(cache=True, error_model="numpy")
def rational_surface_grid(x, y, knots_x, knots_y, degree, control, weights, tol_x, tol_y):
    """Rational surface and first derivatives at every grid node (x[i], y[j]) (local
    coordinates): ``z, dz_dx, dz_dy`` shaped (len(x), len(y)), NaN where x[i] or y[j] lies
    outside the knot range widened by ``tol_x``/``tol_y`` (inside it, clamped to the range).

    The tensor product is contracted along x once per grid row (4 (n1,) vectors: sums over a
    of N_a(x_i) R Q, N_a R and their x derivatives), then every node costs 6 sums of
    degree + 1 terms: S = A / D, S_x = (A_x - S D_x) / D, S_y = (A_y - S D_y) / D.
    """
    p = degree
    n0 = control.shape[0]
    n1 = control.shape[1]
    mx = x.shape[0]
    my = y.shape[0]
    z = np.full((mx, my), np.nan)
    gx = np.full((mx, my), np.nan)
    gy = np.full((mx, my), np.nan)
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    span_y, by, dby = basis_first_derivative_table(y, n1, p, knots_y, tol_y)
    rq = weights * control
    a_row = np.empty(n1)
    d_row = np.empty(n1)
    ax_row = np.empty(n1)
    dx_row = np.empty(n1)
    bx = np.empty(p + 1)
    dbx = np.empty(p + 1)
    for i in range(mx):
        sx = clamped_basis_first_derivative(x[i], n0, p, knots_x, tol_x, bx, dbx, left, right)
        if sx < 0:
            continue
        contract_row(sx, p, bx, dbx, weights, rq, a_row, d_row, ax_row, dx_row)
        for j in range(my):
            sy = span_y[j]
            if sy < 0:
                continue
            z[i, j], gx[i, j], gy[i, j] = row_node_value(sy, p, by, dby, j, a_row, d_row,
                                                         ax_row, dx_row)
    return z, gx, gy


@numba.njit(cache=True, error_model="numpy")
def grid_rational(spans_x, basis_x, spans_y, basis_y, numerator, denominator, mask):
    """(Bx N By^T) / (Bx D By^T) at the cells where ``mask`` is true (0 elsewhere): a rational
    tensor-product spline (N = R * Q, D = R) at grid-cell centres.

    The product is contracted along y once per grid column (for every control row a,
    sum_b By[j, b] N[a, b]), then each cell sums degree + 1 terms along x. The operations and
    their order per cell are those of the cell-by-cell sum, so the values are identical to it.
    With ``denominator`` of size 0 the result is the plain spline Bx N By^T.
    """
    p = basis_x.shape[1] - 1
    m0 = spans_x.shape[0]
    m1 = spans_y.shape[0]
    n0 = numerator.shape[0]
    rational = denominator.shape[0] > 0
    out = np.zeros((m0, m1))
    col_n = np.zeros((m1, n0))
    col_d = np.zeros((m1, n0)) if rational else np.zeros((0, 0))
    for j in range(m1):
        used = False
        for i in range(m0):
            if mask[i, j]:
                used = True
                break
        if not used:
            continue
        sy = spans_y[j] - p
        for a in range(n0):
            acc_n = 0.0
            acc_d = 0.0
            for b in range(p + 1):
                acc_n += basis_y[j, b] * numerator[a, sy + b]
                if rational:
                    acc_d += basis_y[j, b] * denominator[a, sy + b]
            col_n[j, a] = acc_n
            if rational:
                col_d[j, a] = acc_d
    for i in range(m0):
        sx = spans_x[i] - p
        for j in range(m1):
            if not mask[i, j]:
                continue
            acc_n = 0.0
            acc_d = 0.0
            for a in range(p + 1):
                acc_n += basis_x[i, a] * col_n[j, sx + a]
                if rational:
                    acc_d += basis_x[i, a] * col_d[j, sx + a]
            out[i, j] = acc_n / acc_d if rational else acc_n
    return out


@numba.njit(cache=True)
def ground_centre_spread(heights, step, low, top):
    """(centre, spread, count) over every ``step``-th height h with low < h <= top: the
    median of those h, and the median of centre - h over those at or below it (the ground's
    noise measured from its own centre, not from the surface:
    :func:`o3d_terrain.segment.auto_threshold`); NaN, NaN, 0 when there is none. The same
    medians numpy.median gives."""
    n = (heights.shape[0] + step - 1) // step
    gathered = np.empty(n)
    count = 0
    for k in range(n):
        h = heights[k * step]
        if h > low and h <= top:
            gathered[count] = h
            count += 1
    if count == 0:
        return np.nan, np.nan, 0
    centre = np.median(gathered[:count])
    depths = np.empty(count)
    below = 0
    for k in range(count):
        if gathered[k] <= centre:
            depths[below] = centre - gathered[k]
            below += 1
    return centre, np.median(depths[:below]), count


@numba.njit(cache=True)
def below_surface_median(heights, step, high):
    """(median of -h, count) over every ``step``-th height h with -high < h <= 0 (the terrain
    noise below the surface, :func:`o3d_terrain.segment.auto_threshold`); median NaN when
    there is none. np.median selects exactly, so it is the value numpy.median gives."""
    n = (heights.shape[0] + step - 1) // step
    gathered = np.empty(n)
    count = 0
    for k in range(n):
        h = heights[k * step]
        if h <= 0.0 and h > -high:
            gathered[count] = -h
            count += 1
    if count == 0:
        return np.nan, 0
    return np.median(gathered[:count]), count
