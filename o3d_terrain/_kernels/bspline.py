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
    # uniform interior knots: guess the span directly, then correct by comparisons
    width = (knots[n + 1] - knots[degree]) / (n + 1 - degree)
    guess = degree + int((t - knots[degree]) / width)
    if guess > n:
        guess = n
    while guess > degree and t < knots[guess]:
        guess -= 1
    while guess < n and t >= knots[guess + 1]:
        guess += 1
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


@numba.njit(cache=True)
def basis_funs(span, t, degree, knots, out):
    """The degree + 1 non-zero basis functions at t (Piegl & Tiller A2.2 BasisFuns).

    ``out[r]`` is N_{span-degree+r, degree}(t).
    """
    left = np.empty(degree + 1)
    right = np.empty(degree + 1)
    out[0] = 1.0
    for j in range(1, degree + 1):
        left[j] = t - knots[span + 1 - j]
        right[j] = knots[span + j] - t
        saved = 0.0
        for r in range(j):
            temp = out[r] / (right[r + 1] + left[j - r])
            out[r] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        out[j] = saved


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
        left[j] = t - knots[span + 1 - j]
        right[j] = knots[span + j] - t
        saved = 0.0
        for r in range(j):
            temp = values[r] / (right[r + 1] + left[j - r])
            values[r] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        values[j] = saved


@numba.njit(cache=True)
def rational_surface(x, y, knots_x, knots_y, degree, control, weights, with_derivatives):
    """Rational tensor-product surface and its first derivatives at points (x[k], y[k]).

    S = A / D with A = sum R_ab N_a(x) N_b(y) Q_ab and D = sum R_ab N_a(x) N_b(y); the
    derivatives follow the quotient rule S_x = (A_x - S D_x) / D (Piegl & Tiller eq. 4.8 in
    homogeneous form). Non-finite coordinates give NaN. Parameters beyond the knot range are
    evaluated on the end span (callers decide what to do outside the region).
    """
    n = x.shape[0]
    n0 = control.shape[0]
    n1 = control.shape[1]
    p = degree
    z = np.empty(n)
    dzdx = np.empty(n) if with_derivatives else np.empty(0)
    dzdy = np.empty(n) if with_derivatives else np.empty(0)
    bx = np.empty(p + 1)
    by = np.empty(p + 1)
    dbx = np.zeros(p + 1)
    dby = np.zeros(p + 1)
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    for k in range(n):
        if not (math.isfinite(x[k]) and math.isfinite(y[k])):
            z[k] = np.nan
            if with_derivatives:
                dzdx[k] = np.nan
                dzdy[k] = np.nan
            continue
        sx = find_span(n0, p, x[k], knots_x)
        sy = find_span(n1, p, y[k], knots_y)
        if with_derivatives:
            basis_funs_first_derivative(sx, x[k], p, knots_x, bx, dbx, left, right)
            basis_funs_first_derivative(sy, y[k], p, knots_y, by, dby, left, right)
        else:
            basis_funs_first_derivative(sx, x[k], p, knots_x, bx, dbx, left, right)
            basis_funs_first_derivative(sy, y[k], p, knots_y, by, dby, left, right)
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
        s = a / d
        z[k] = s
        if with_derivatives:
            dzdx[k] = (ax - s * dx) / d
            dzdy[k] = (ay - s * dy) / d
    return z, dzdx, dzdy
