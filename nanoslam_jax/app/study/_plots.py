"""The study's figure: error against seconds per log, one line per method with IQR bands."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_accuracy_vs_compute"]


def plot_accuracy_vs_compute(
    path: Path,
    summary: Sequence[dict],
    metrics: Sequence[str] = ("rmse_fixed", "rmse_aligned"),
    floor: Optional[dict] = None,
    title: str = "",
) -> None:
    """One panel per error: the median over seeds against the seconds per log (log axis), a line
    through each method's particle counts (labelled at each point) with the interquartile range
    shaded; a deterministic method (no particle count) is one point with its value. The GPS floor
    (:class:`~nanoslam_jax.eval.gps_floor.GpsFloor` as a mapping), when given, is drawn as a band
    (``rmse_fixed``) or a line (``rmse_aligned``).

    Args:
        path: output PNG.
        summary: point summaries with ``seconds_per_log`` (points without it are left out).
        metrics: the errors, one panel each.
        floor: the GPS floor, or None.
        title: figure title.
    """
    fig, axes = plt.subplots(1, len(metrics), figsize=(6.5 * len(metrics), 5.2), squeeze=False)
    methods = list(dict.fromkeys(s["method"] for s in summary))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, m in zip(axes[0], metrics):
        for i, method in enumerate(methods):
            pts = sorted(
                (s for s in summary if s["method"] == method and math.isfinite(s.get("seconds_per_log", math.nan))),
                key=lambda s: s["particles"] or 0,
            )
            if not pts:
                continue
            c = colors[i % len(colors)]
            x = np.array([s["seconds_per_log"] for s in pts])
            med, q1, q3 = (np.array([s[f"{m}_{k}"] for s in pts], float) for k in ("median", "q1", "q3"))
            if pts[0]["particles"] is None:  # deterministic: one run
                ax.plot(x, med, "*", ms=12, color=c, label=method)
                continue
            ax.plot(x, med, "o-", color=c, label=method)
            ax.fill_between(x, q1, np.minimum(q3, 1e6), color=c, alpha=0.18, lw=0)
            for s, xi, yi in zip(pts, x, med):
                if math.isfinite(yi):
                    ax.annotate(
                        str(s["particles"]), (xi, yi), textcoords="offset points", xytext=(4, 4), fontsize=7, color=c
                    )
        if floor is not None and m.startswith("rmse_fixed"):
            ax.axhspan(
                floor["fixed_floor_low"],
                floor["fixed_floor_high"],
                color="0.5",
                alpha=0.2,
                label="GPS floor (frame + GPS error)",
            )
        elif floor is not None:
            ax.axhline(floor["aligned_floor"], color="0.4", ls="--", lw=1, label="GPS floor (GPS error)")
        ax.set_xscale("log")
        ax.set_xlabel("seconds per log (one run alone, after compilation)")
        ax.set_ylabel(f"{m} [m]: median over seeds, IQR shaded")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(title + " (labels: particles)")
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
