"""The robust re-weighting pass with a per-cell noise scale (range-dependent sensor noise).

Same rule as :func:`o3d_terrain._kernels.terrain.robust_pass`, with the thresholds of each cell
from its own noise scale: th_above[c] = above_k * sqrt(noise^2 + cell_sigma[c]^2), th_below[c]
likewise with below_k, and the equalization band clip_k * th_above[c].
"""

from __future__ import annotations

import math

import numba


@numba.njit(cache=True)
def robust_pass_cells(z, surface, base, valid_cells, compact, use_prior, prior_spread, noise,
                      cell_sigma, above_k, below_k, clip_k, previous_samples, previous_weights,
                      has_previous, weights, ratios, samples, equalized):
    """:func:`o3d_terrain._kernels.terrain.robust_pass` with per-cell thresholds (module
    docstring); ``cell_sigma`` (m0, m1) is the sensor's noise scale per cell (m).
    Returns (moved, change)."""
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
        scale = math.sqrt(noise2 + nf[c] * nf[c])
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
