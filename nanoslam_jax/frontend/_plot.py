"""Figures of single scans with their features (``nanoslam detect --plot``)."""

from __future__ import annotations

import os

import numpy as np

from nanoslam_jax.data import LaserScans
from nanoslam_jax.frontend._types import Features

__all__ = ["parse_scan_list", "plot_scan"]


def parse_scan_list(text: str, n_scans: int) -> list[int]:
    """Scan indices from ``"100,250-252"`` (0-based, inclusive ranges); raises ValueError naming a bad item."""
    out = []
    for item in text.split(","):
        item = item.strip()
        lo, sep, hi = item.partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise ValueError(f"--plot {text!r}: expected scan indices like 100,250-252, got {item!r}") from None
        if not 0 <= a <= b < n_scans:
            raise ValueError(f"--plot {text!r}: scan {item!r} outside 0..{n_scans - 1}")
        out += list(range(a, b + 1))
    return out


def plot_scan(
    scans: LaserScans, feats: Features, scan: int, path: str | os.PathLike, window: float | None = 40.0, ax=None
) -> None:
    """Draw one scan: its returns coloured by cluster, line segments, circles, corners, break points
    and trees (centre and trunk), in the vehicle frame.

    Args:
        scans: the scans.
        feats: their features (:func:`~nanoslam_jax.frontend.extract_features`).
        scan: the scan index.
        path: the image file to write (ignored when ``ax`` is given).
        window: half-width of the drawn area (m); None: all returns.
        ax: a matplotlib axes to draw on instead of a new figure.
    """
    import matplotlib

    if ax is None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(8, 6))
    P, C = feats.points, feats.clusters
    sel = P.scan == scan
    cid = np.repeat(np.arange(C.scan.size), C.n)[sel]
    ax.scatter(P.x[sel], P.y[sel], c=cid % 10, cmap="tab10", s=6, label="returns (by cluster)")
    L = feats.lines
    for i, k in enumerate(np.flatnonzero(L.scan == scan)):
        ax.plot([L.x0[k], L.x1[k]], [L.y0[k], L.y1[k]], "k-", lw=2, label=None if i else "line segments")
    Ci = feats.circles
    for k in np.flatnonzero(Ci.scan == scan):
        ax.add_patch(plt.Circle((Ci.cx[k], Ci.cy[k]), Ci.radius[k], fill=False, ec="tab:purple", lw=1, ls="--"))
    Q = feats.corners
    q = Q.scan == scan
    ax.plot(Q.x[q], Q.y[q], "rs", ms=7, mfc="none", label="corners")
    B = feats.breakpoints
    b = B.scan == scan
    ax.plot(B.x[b], B.y[b], "b^", ms=6, mfc="none", label="break points")
    T = feats.trees
    t = np.flatnonzero(T.scan == scan)
    cx, cy = T.range[t] * np.cos(T.bearing[t]), T.range[t] * np.sin(T.bearing[t])
    for x, y, d in zip(cx, cy, T.diameter[t]):
        ax.add_patch(plt.Circle((x, y), d / 2, fill=False, ec="tab:green", lw=2))
    ax.plot(cx, cy, "g+", ms=10, label="trees (centre, trunk)")
    ax.plot([0], [0], "k>", ms=10, label="laser")
    ax.set_aspect("equal")
    if window is not None:
        ax.set_xlim(-window / 4, window)
        ax.set_ylim(-window * 0.75, window * 0.75)
    ax.set_xlabel("x ahead (m)")
    ax.set_ylabel("y left (m)")
    ax.set_title(
        f"scan {scan} (t = {scans.time[scan]:.3f} s): {t.size} trees, "
        f"{int((L.scan == scan).sum())} lines, {int(q.sum())} corners, {int(b.sum())} break points"
    )
    ax.legend(loc="upper left", fontsize=7)
    if own:
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
