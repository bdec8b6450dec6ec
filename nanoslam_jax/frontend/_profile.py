"""A trunk measured from the ranges of the beams that hit it, below the beam spacing.

A trunk of radius ``R`` whose centre lies at range ``D`` and bearing ``b`` subtends the half-angle
``h`` with ``sin h = R / D``; the beam at bearing ``a`` (``|a - b| < h``) meets its near side at the range
``D (cos(a - b) - sqrt(sin^2 h - sin^2(a - b)))`` (a circle seen from outside). The beams of a cluster
hit the trunk and its neighbouring beams miss it, so each of its two edges lies between the cluster's
edge beam and the beam beyond, a beam step ``dphi`` wide. For each pair of edge bearings on a grid over
those two intervals the predicted ranges are linear in ``D``, which least squares gives in closed form
with the residual sum of squares; the pairs are weighted by their likelihood under Gaussian range noise
(uniform prior over the intervals), and the trunk's centre range, bearing and radius are the weighted
means. The smallest residual also says how well a circle of the cluster's angular width explains its
ranges: a bush fragment or a piece of wall does not follow the deep, round profile of a trunk that wide.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int

__all__ = ["TrunkProfile", "fit_trunk_profiles"]

#: Edge bearings tried per edge (cell centres of the beam step beyond each edge beam).
GRID = 8
#: Points handled at once (bounds the (points, grid) work arrays).
_BLOCK = 1 << 12


class TrunkProfile(NamedTuple):
    """Trunks fitted to clusters' ranges (NaN for a cluster without returns).

    Attributes:
        range: range to the centre (m).
        bearing: bearing of the centre (rad).
        radius: radius (m).
        rms: RMS range residual of the best edge pair (m).
    """

    range: Float[np.ndarray, " G"]
    bearing: Float[np.ndarray, " G"]
    radius: Float[np.ndarray, " G"]
    rms: Float[np.ndarray, " G"]


def fit_trunk_profiles(
    r: Float[np.ndarray, " N"],
    a: Float[np.ndarray, " N"],
    starts: Int[np.ndarray, " G"],
    counts: Int[np.ndarray, " G"],
    a_first: Float[np.ndarray, " G"],
    a_last: Float[np.ndarray, " G"],
    dphi: float,
    sigma: float,
) -> TrunkProfile:
    """Fit a trunk to each contiguous group of returns from the ranges and the edge constraints.

    Args:
        r, a: ranges (m) and beam bearings (rad) of the returns, groups contiguous.
        starts, counts: each group's first return and its number of returns (>= 1).
        a_first, a_last: bearings of each group's first and last beams (``a_first < a_last``).
        dphi: the beam step (rad).
        sigma: range noise (m) of the likelihood that weights the edge pairs.
    """
    g = starts.size
    out = TrunkProfile(*(np.full(g, np.nan) for _ in range(4)))
    if g == 0:
        return out
    frac = (np.arange(GRID) + 0.5) / GRID
    f_lo, f_hi = (m.ravel() for m in np.meshgrid(frac, frac, indexing="ij"))
    ends = np.cumsum(counts)
    lo = 0
    while lo < g:
        hi = int(np.searchsorted(ends, ends[lo - 1] + _BLOCK if lo else _BLOCK, "right"))
        hi = max(hi, lo + 1)
        sl = slice(lo, hi)
        e_lo = a_first[sl, None] - f_lo[None] * dphi  # (groups, pairs)
        e_hi = a_last[sl, None] + f_hi[None] * dphi
        centre, half = 0.5 * (e_lo + e_hi), 0.5 * (e_hi - e_lo)
        cnt = counts[sl]
        grp = np.repeat(np.arange(cnt.size), cnt)
        idx = np.repeat(starts[sl] - np.concatenate([[0], np.cumsum(cnt)[:-1]]), cnt) + np.arange(cnt.sum())
        rr, ca, sa = r[idx][:, None], np.cos(a[idx])[:, None], np.sin(a[idx])[:, None]
        cc, sc, s = np.cos(centre), np.sin(centre), np.sin(half)
        cc, sc = cc[grp], sc[grp]
        cos_off, sin_off = ca * cc + sa * sc, sa * cc - ca * sc  # of the beam's bearing from the centre's
        prof = cos_off - np.sqrt(np.maximum((s * s)[grp] - sin_off * sin_off, 0.0))
        first = np.concatenate([[0], np.cumsum(cnt)[:-1]])
        srg = np.add.reduceat(rr * prof, first, axis=0)
        sgg = np.add.reduceat(prof * prof, first, axis=0)
        srr = np.add.reduceat(rr[:, 0] * rr[:, 0], first)
        d = srg / np.maximum(sgg, 1e-300)
        sse = np.maximum(srr[:, None] - srg * d, 0.0)
        best = sse.min(axis=1)
        w = np.exp(-(sse - best[:, None]) / (2.0 * sigma * sigma))
        w /= w.sum(axis=1, keepdims=True)
        out.range[sl] = (w * d).sum(axis=1)
        out.bearing[sl] = (w * centre).sum(axis=1)
        out.radius[sl] = (w * d * s).sum(axis=1)
        out.rms[sl] = np.sqrt(best / cnt)
        lo = hi
    return out
