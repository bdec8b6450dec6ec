"""Figures of a run: trajectory and map against GPS (paper Fig. 3), error over time (Fig. 4), ESS; the
second paper's Figures 5 (pose errors over many runs) and 6 (a map of walls and arcs with the track)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple, Optional, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def plot_trajectory(
    path: Path,
    reference: np.ndarray,
    trajectories: Sequence[tuple[str, np.ndarray]],
    landmarks: Optional[np.ndarray] = None,
    true_landmarks: Optional[np.ndarray] = None,
    title: str = "",
    reference_label: str = "GPS",
    confirmed: Optional[np.ndarray] = None,
) -> None:
    """Estimated trajectories (and the best particle's map) against the reference positions.

    Args:
        path: output PNG.
        reference: ``(G, 2)`` GPS (or true) positions in the comparison frame.
        trajectories: ``(label, (T, 2) positions)`` pairs.
        landmarks: ``(L, 2)`` estimated landmarks.
        true_landmarks: ``(L', 2)`` true landmarks (simulated logs).
        confirmed: ``(L,)`` which landmarks are confirmed (drawn dark; tentative ones light);
            None: all are drawn as confirmed.
    """
    fig, ax = plt.subplots(figsize=(8, 8))
    ax.plot(reference[:, 0], reference[:, 1], ".", ms=1.5, color="0.6", label=reference_label)
    for label, xy in trajectories:
        ax.plot(xy[:, 0], xy[:, 1], "-", lw=0.9, label=label)
    if true_landmarks is not None and len(true_landmarks):
        ax.plot(true_landmarks[:, 0], true_landmarks[:, 1], "o", mfc="none", ms=5, color="g", label="true landmarks")
    if landmarks is not None and len(landmarks):
        conf = np.ones(len(landmarks), bool) if confirmed is None else np.asarray(confirmed, bool)
        ax.plot(
            landmarks[conf, 0],
            landmarks[conf, 1],
            "+",
            ms=4,
            color="k",
            label=f"map ({int(conf.sum())} confirmed landmarks)",
        )
        if (~conf).any():
            ax.plot(
                landmarks[~conf, 0],
                landmarks[~conf, 1],
                "+",
                ms=4,
                color="0.75",
                label=f"tentative ({int((~conf).sum())})",
            )
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def plot_series(
    path: Path,
    series: Sequence[tuple[str, np.ndarray, np.ndarray]],
    ylabel: str,
    title: str = "",
    hline: Optional[float] = None,
    logy: bool = False,
    marker: str = "",
) -> None:
    """Time series, e.g. position error (Fig. 4), time per scan (Fig. 5) or ESS.

    Args:
        path: output PNG.
        series: ``(label, t, values)`` triples.
        ylabel: y-axis label.
        hline: optional horizontal reference line (e.g. the resampling threshold).
        logy: logarithmic y axis.
        marker: matplotlib marker for the points.
    """
    fig, ax = plt.subplots(figsize=(9, 3.5))
    for label, t, v in series:
        ax.plot(t, v, lw=0.8, marker=marker, ms=3, label=label)
    if hline is not None:
        ax.axhline(hline, color="0.5", ls="--", lw=0.8)
    if logy:
        ax.set_yscale("log")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if len(series) > 1:
        ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def plot_trajectory_grid(
    path: Path,
    reference: np.ndarray,
    panels: Sequence[tuple[str, np.ndarray, Optional[np.ndarray]]],
    true_landmarks: Optional[np.ndarray] = None,
    reference_label: str = "GPS",
    title: str = "",
) -> None:
    """One panel per method: its trajectory and map against the reference (the paper's Fig. 3).

    Args:
        path: output PNG.
        reference: ``(G, 2)`` GPS (or true) positions in the comparison frame.
        panels: ``(label, (T, 2) trajectory, (L, 2) landmarks or None)`` per method.
        true_landmarks: true landmarks (simulated logs).
        reference_label: legend label of the reference.
        title: figure title.
    """
    n = len(panels)
    cols = min(n, 3)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 4.6 * rows), squeeze=False)
    for ax, (label, xy, lm) in zip(axes.flat, panels):
        ax.plot(reference[:, 0], reference[:, 1], ".", ms=1, color="0.6", label=reference_label)
        if true_landmarks is not None and len(true_landmarks):
            ax.plot(
                true_landmarks[:, 0], true_landmarks[:, 1], "o", mfc="none", ms=4, color="g", label="true landmarks"
            )
        ax.plot(xy[:, 0], xy[:, 1], "-", lw=0.8, color="C0", label="estimate")
        if lm is not None and len(lm):
            ax.plot(lm[:, 0], lm[:, 1], "+", ms=3, color="k", label=f"map ({len(lm)})")
        ax.set_aspect("equal")
        ax.set_title(label, fontsize=10)
        ax.legend(loc="best", fontsize=6)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_error_bands(
    path: Path,
    t: np.ndarray,
    panels: Sequence[tuple[str, Sequence[tuple[str, np.ndarray, np.ndarray, np.ndarray]]]],
    title: str = "",
    logy: bool = False,
) -> None:
    """Errors over time over many runs, one panel per error (the second paper's Figure 5): each
    method's median as a line and a band between two quantiles.

    Args:
        path: output PNG.
        t: ``(T,)`` times (s).
        panels: ``(ylabel, curves)`` per panel, each curve ``(label, median, low, high)`` of ``(T,)``
            values (an infinite value, a failed run's, is not drawn).
        title: the figure's title.
        logy: logarithmic y axes spanning three decades below the highest band (errors of methods
            that differ by orders of magnitude).
    """
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 3.2 * len(panels)), sharex=True, squeeze=False)
    for ax, (ylabel, curves) in zip(axes[:, 0], panels):
        for i, (label, med, lo, hi) in enumerate(curves):
            color = f"C{i}"
            ax.fill_between(t, lo, hi, color=color, alpha=0.2, lw=0)
            ax.plot(t, med, lw=1.0, color=color, label=label)
        ax.set_ylabel(ylabel)
        top = max((float(np.nanmax(c[3])) for c in curves if np.isfinite(c[3]).any()), default=math.nan)
        if logy and math.isfinite(top) and top > 0:  # three decades below the highest band
            ax.set_yscale("log")
            ax.set_ylim(top * 1e-3, top * 1.5)
        ax.grid(alpha=0.3, which="both" if logy else "major")
        ax.legend(fontsize=8, loc="lower right" if logy else "upper right")
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


class FeatureMapDrawing(NamedTuple):
    """A track with its map of walls and arcs, one side of :func:`plot_feature_map`.

    Attributes:
        path: ``(N, 2)`` the positions along the track.
        walls: ``(W, 4)`` the walls as segments ``x0, y0, x1, y1``.
        arcs: ``(P, 3)`` the circles ``xc, yc, R``.
    """

    path: np.ndarray
    walls: np.ndarray
    arcs: np.ndarray


def plot_feature_map(
    path: Path,
    truth: FeatureMapDrawing,
    estimate: FeatureMapDrawing,
    title: str = "",
    label: str = "estimate",
) -> None:
    """A map of walls and arcs with the track, estimate over truth (the second paper's Figure 6).

    Args:
        path: output PNG.
        truth: the true track, walls and circles.
        estimate: the estimated track, walls and circles.
        title: the figure's title.
        label: the estimate's name in the legend.
    """
    true_path, true_walls, true_arcs = truth
    est_path, est_walls, est_arcs = estimate
    fig, ax = plt.subplots(figsize=(8, 8))
    th = np.linspace(0.0, 2.0 * np.pi, 181)

    def walls(segs, style, color, lw, name):
        for i, s in enumerate(np.asarray(segs, float).reshape(-1, 4)):
            ax.plot(s[[0, 2]], s[[1, 3]], style, color=color, lw=lw, label=name if i == 0 else None)

    def circles(arcs, style, color, lw):
        for c in np.asarray(arcs, float).reshape(-1, 3):
            ax.plot(c[0] + c[2] * np.cos(th), c[1] + c[2] * np.sin(th), style, color=color, lw=lw)

    walls(true_walls, "-", "k", 2.0, "true walls and pillar")
    circles(true_arcs, "-", "k", 2.0)
    ax.plot(true_path[:, 0], true_path[:, 1], "-", color="0.5", lw=1.2, label="true track")
    walls(est_walls, "--", "C3", 1.2, f"{label}: walls and arcs")
    circles(est_arcs, "--", "C3", 1.2)
    ax.plot(est_path[:, 0], est_path[:, 1], "--", color="C0", lw=1.0, label=f"{label}: track")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def plot_scan_maps(
    path: Path,
    panels: Sequence[tuple[str, np.ndarray, np.ndarray, Optional[np.ndarray]]],
    title: str = "",
) -> None:
    """The map a laser log gives from a path: every scan's returns drawn from the pose it was taken
    at, one panel per path (for example the estimate beside dead reckoning).

    Args:
        path: output PNG.
        panels: ``(label, (N, 2) scan points in the path's frame, (T, 2) the path, (L, 2, 2)
            landmark line segments or None)`` per panel.
        title: figure title.
    """
    n = max(len(panels), 1)
    fig, axes = plt.subplots(1, n, figsize=(7 * n, 7), squeeze=False)
    for ax, (label, points, xy, segments) in zip(axes[0], panels):
        points = np.asarray(points, float).reshape(-1, 2)
        ax.plot(points[:, 0], points[:, 1], ",", color="0.2", alpha=0.35)
        ax.plot(xy[:, 0], xy[:, 1], "-", lw=0.8, color="C0", label=f"{label}: path")
        if segments is not None and len(segments):
            for i, s in enumerate(np.asarray(segments, float)):
                ax.plot(s[:, 0], s[:, 1], "-", lw=1.4, color="C3", label="landmark lines" if i == 0 else None)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(label, fontsize=10)
        ax.legend(loc="best", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
