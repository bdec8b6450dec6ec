"""Figures of a run: trajectory and map against GPS (paper Fig. 3), error over time (Fig. 4), ESS."""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

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
) -> None:
    """Estimated trajectories (and the best particle's map) against the reference positions.

    Args:
        path: output PNG.
        reference: ``(G, 2)`` GPS (or true) positions in the comparison frame.
        trajectories: ``(label, (T, 2) positions)`` pairs.
        landmarks: ``(L, 2)`` estimated landmarks.
        true_landmarks: ``(L', 2)`` true landmarks (simulated logs).
    """
    fig, ax = plt.subplots(figsize=(8, 8))
    ax.plot(reference[:, 0], reference[:, 1], ".", ms=1.5, color="0.6", label=reference_label)
    for label, xy in trajectories:
        ax.plot(xy[:, 0], xy[:, 1], "-", lw=0.9, label=label)
    if true_landmarks is not None and len(true_landmarks):
        ax.plot(true_landmarks[:, 0], true_landmarks[:, 1], "o", mfc="none", ms=5, color="g", label="true landmarks")
    if landmarks is not None and len(landmarks):
        ax.plot(landmarks[:, 0], landmarks[:, 1], "+", ms=4, color="k", label=f"map ({len(landmarks)} landmarks)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def plot_series(path: Path, series: Sequence[tuple[str, np.ndarray, np.ndarray]], ylabel: str, title: str = "",
                hline: Optional[float] = None) -> None:
    """Time series, e.g. position error (Fig. 4) or ESS.

    Args:
        path: output PNG.
        series: ``(label, t, values)`` triples.
        ylabel: y-axis label.
        hline: optional horizontal reference line (e.g. the resampling threshold).
    """
    fig, ax = plt.subplots(figsize=(9, 3.5))
    for label, t, v in series:
        ax.plot(t, v, lw=0.8, label=label)
    if hline is not None:
        ax.axhline(hline, color="0.5", ls="--", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if len(series) > 1:
        ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
