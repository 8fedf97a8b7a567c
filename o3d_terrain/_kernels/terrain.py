"""Normal equations of the weighted tensor-product B-spline fit, in symmetric band form.

Control point (a, b) of an (n0, n1) grid has the unknown index k = a * n1 + b; a cell's
(degree + 1)^2 basis functions touch indices at most ``degree * n1 + degree`` apart, so the normal
matrix is banded. Band storage is LAPACK's lower form (``scipy.linalg.solveh_banded(lower=True)``):
``band[d, k] = A[k + d, k]``.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def assemble_band(spans_x, basis_x, spans_y, basis_y, matrix_weights, rhs_values, n0, n1,
                  degree, bandwidth):
    """Band of sum_c w_c b_c b_c^T and the vector sum_c v_c b_c over grid cells c = (i, j).

    ``b_c`` holds the tensor-product basis values N_a(x_i) N_b(y_j); ``matrix_weights[i, j]``
    is w_c and ``rhs_values[i, j]`` is v_c (typically w_c times the sample height). Cells with
    w_c = 0 and v_c = 0 are skipped.
    """
    p = degree
    size = n0 * n1
    band = np.zeros((bandwidth + 1, size))
    rhs = np.zeros(size)
    q = (p + 1) * (p + 1)
    idx = np.empty(q, np.int64)
    val = np.empty(q)
    m0 = spans_x.shape[0]
    m1 = spans_y.shape[0]
    for i in range(m0):
        sx = spans_x[i]
        if sx < 0:
            continue
        for j in range(m1):
            w = matrix_weights[i, j]
            v = rhs_values[i, j]
            if w == 0.0 and v == 0.0:
                continue
            sy = spans_y[j]
            if sy < 0:
                continue
            t = 0
            for a in range(p + 1):
                base = (sx - p + a) * n1 + (sy - p)
                for b in range(p + 1):
                    idx[t] = base + b
                    val[t] = basis_x[i, a] * basis_y[j, b]
                    t += 1
            for u in range(q):
                ku = idx[u]
                vu = val[u]
                rhs[ku] += v * vu
                wu = w * vu
                for s in range(q):
                    ks = idx[s]
                    if ks >= ku:
                        band[ks - ku, ku] += wu * val[s]
    return band, rhs


@numba.njit(cache=True)
def add_thin_plate_band(band, n0, n1, scale, weight_xx, weight_xy, weight_yy):
    """Add ``scale`` times a discrete thin-plate energy of the control points to the band.

    Energy = weight_xx sum (Q[a-1,b] - 2Q[a,b] + Q[a+1,b])^2
           + weight_yy sum (Q[a,b-1] - 2Q[a,b] + Q[a,b+1])^2
           + weight_xy sum (Q[a,b] - Q[a+1,b] - Q[a,b+1] + Q[a+1,b+1])^2.
    Its null space is the planes, so data-free control points continue the surface linearly.
    """
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
                if kind == 0:
                    n = 3
                    idx[0] = (a - 1) * n1 + b
                    idx[1] = a * n1 + b
                    idx[2] = (a + 1) * n1 + b
                    coef[0] = 1.0
                    coef[1] = -2.0
                    coef[2] = 1.0
                elif kind == 1:
                    n = 3
                    idx[0] = a * n1 + b - 1
                    idx[1] = a * n1 + b
                    idx[2] = a * n1 + b + 1
                    coef[0] = 1.0
                    coef[1] = -2.0
                    coef[2] = 1.0
                else:
                    n = 4
                    idx[0] = a * n1 + b
                    idx[1] = a * n1 + b + 1
                    idx[2] = (a + 1) * n1 + b
                    idx[3] = (a + 1) * n1 + b + 1
                    coef[0] = 1.0
                    coef[1] = -1.0
                    coef[2] = -1.0
                    coef[3] = 1.0
                for u in range(n):
                    for s in range(n):
                        d = idx[s] - idx[u]
                        if 0 <= d <= bandwidth:
                            band[d, idx[u]] += w * coef[u] * coef[s]
    return band
