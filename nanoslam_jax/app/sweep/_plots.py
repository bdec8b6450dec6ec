"""Figures of a sweep: a metric against each swept parameter (per-seed points and the median),
and a heat map of the median for each pair of grid parameters."""

from __future__ import annotations

import itertools
import math
import re
import textwrap
from pathlib import Path
from typing import Any, NamedTuple, Optional, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nanoslam_jax.eval._scoring import metric_goal, number, seed_summary  # noqa: E402
from nanoslam_jax.app.sweep._spec import ConfigPoint, SweepSpec  # noqa: E402

__all__ = ["plot_sweep", "plot_metric_vs_param", "plot_heatmap", "RunMetric"]


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


class RunMetric(NamedTuple):
    """A metric over a sweep's runs, as :func:`plot_metric_vs_param` draws it.

    Attributes:
        name: the metric's name (axis label).
        values: the metric of each run.
        failed: which runs failed (``None``: none). They are not drawn, but the median counts them
            under the failed-seed rule (:func:`~nanoslam_jax.eval._scoring.seed_summary` with ``goal``):
            a median that reaches them is infinite and left out of the line.
        goal: the metric's goal (``'min'``, ``'max'`` or ``None``).
    """

    name: str
    values: Sequence[float] | np.ndarray
    failed: Optional[Sequence[bool] | np.ndarray] = None
    goal: Optional[str] = "min"


def plot_metric_vs_param(
    path: Path,
    key: str,
    xs: Sequence[Any],
    metric: RunMetric,
    *,
    title: str = "",
    log_x: bool | None = None,
) -> None:
    """Scatter of per-run values of ``metric`` against ``key`` and the median per distinct value.

    Args:
        path: output PNG.
        key: the swept parameter.
        xs: its value in each run (numbers, or anything else drawn as categories).
        metric: the metric of each run, which runs failed and the metric's goal.
        title: figure title.
        log_x: logarithmic x axis (default: positive values spanning more than a factor 20).
    """
    ys, failed, goal = metric.values, metric.failed, metric.goal
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    numeric = all(_is_number(x) for x in xs)
    distinct = sorted(set(xs), key=lambda v: v if numeric else str(v))
    if numeric:
        pos = {v: float(v) for v in distinct}
    else:
        pos = {v: float(i) for i, v in enumerate(distinct)}
        ax.set_xticks(list(pos.values()), [str(v) for v in distinct])
    x = np.array([pos[v] for v in xs], float)
    y = np.asarray(ys, float)
    bad = np.zeros(y.shape, bool) if failed is None else np.asarray(failed, bool)
    shown = ~bad & np.isfinite(y)
    jitter = 0.0 if numeric else 0.08
    rng = np.random.default_rng(0)
    ax.scatter((x + jitter * rng.uniform(-1, 1, x.shape))[shown], y[shown], s=14, alpha=0.5, label="runs (each seed)")
    med = [
        seed_summary(y[x == pos[v]], bad[x == pos[v]], goal)["median"] if np.any(x == pos[v]) else np.nan
        for v in distinct
    ]
    med = [m if np.isfinite(m) else np.nan for m in med]
    ax.plot([pos[v] for v in distinct], med, "-o", color="C3", ms=4, label="median")
    if log_x is None:
        vals = [pos[v] for v in distinct]
        log_x = numeric and min(vals) > 0 and max(vals) / min(vals) > 20
    if log_x:
        ax.set_xscale("log")
    ax.set_xlabel(key)
    ax.set_ylabel(metric.name)
    ax.set_title(textwrap.fill(title or f"{metric.name} against {key}", 70), fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_heatmap(
    path: Path,
    kx: str,
    ky: str,
    xvals: Sequence[Any],
    yvals: Sequence[Any],
    table: np.ndarray,
    metric: str,
    title: str = "",
) -> None:
    """Heat map of ``table[iy, ix]`` (the metric's median) over two grid parameters, annotated."""
    fig, ax = plt.subplots(figsize=(1.2 * len(xvals) + 2.5, 0.7 * len(yvals) + 2.0))
    masked = np.ma.masked_invalid(table)
    im = ax.imshow(masked, origin="lower", aspect="auto", cmap="viridis_r")
    ax.set_xticks(range(len(xvals)), [f"{v:.4g}" if _is_number(v) else str(v) for v in xvals])
    ax.set_yticks(range(len(yvals)), [f"{v:.4g}" if _is_number(v) else str(v) for v in yvals])
    ax.set_xlabel(kx)
    ax.set_ylabel(ky)
    finite = table[np.isfinite(table)]
    mid = (finite.min() + finite.max()) / 2 if finite.size else 0.0
    for iy in range(len(yvals)):
        for ix in range(len(xvals)):
            v = table[iy, ix]
            ax.text(
                ix,
                iy,
                "failed" if not np.isfinite(v) else f"{v:.3g}",
                ha="center",
                va="center",
                fontsize=8,
                color="white" if np.isfinite(v) and v > mid else "black",
            )
    fig.colorbar(im, ax=ax, label=f"median {metric}")
    ax.set_title(textwrap.fill(title or f"median {metric}", 60), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_sweep(
    out: Path, spec: SweepSpec, points: Sequence[ConfigPoint], rows: Sequence[dict], metrics: Sequence[str]
) -> list[Path]:
    """All figures of a sweep in ``out`` (created); returns the files written.

    ``<metric>_vs_<key>.png`` for every swept key with more than one value, and
    ``heatmap_<metric>_<key1>_<key2>.png`` for every pair of grid keys (median over seeds and
    over the other swept keys). Failed runs are not drawn as points; the medians count them under
    the failed-seed rule (:mod:`nanoslam_jax.eval._scoring`), a median they make infinite is marked
    ``failed``.
    """
    out.mkdir(parents=True, exist_ok=True)
    values = {p.config_id: p.values for p in points}
    runs = [r for r in rows if r["config_id"] in values]
    written = []
    for metric in metrics:
        ys = np.array([number(r.get(metric, "")) for r in runs], float)
        failed = np.array([r["status"] != "ok" for r in runs], bool)
        goal = spec.goal if metric == spec.metric else metric_goal(metric)
        if not np.any(~failed & np.isfinite(ys)):
            continue
        log_keys = {p.key for p in spec.random.params if p.log} if spec.random else set()
        run_metric = RunMetric(metric, ys, failed, goal)
        for key in spec.swept_keys:
            xs = [values[r["config_id"]][key] for r in runs]
            if len(set(map(repr, xs))) < 2:
                continue
            path = out / f"{_safe(metric)}_vs_{_safe(key)}.png"
            plot_metric_vs_param(
                path,
                key,
                xs,
                run_metric,
                title=f"{spec.name}: {metric} against {key}",
                log_x=True if key in log_keys else None,
            )
            written.append(path)
        grid = [(k, list(v)) for k, v in spec.grid if len(v) > 1]
        for (kx, vx), (ky, vy) in itertools.combinations(grid, 2):
            cfgx = {p.config_id: p for p in points}
            table = np.full((len(vy), len(vx)), np.nan)
            for iy, yv in enumerate(vy):
                for ix, xv in enumerate(vx):
                    sel = np.array(
                        [
                            _match(cfgx[r["config_id"]].values[kx], xv) and _match(cfgx[r["config_id"]].values[ky], yv)
                            for r in runs
                        ],
                        bool,
                    )
                    if sel.any():
                        table[iy, ix] = seed_summary(ys[sel], failed[sel], goal)["median"]
            path = out / f"heatmap_{_safe(metric)}_{_safe(kx)}_{_safe(ky)}.png"
            others = [k for k in spec.swept_keys if k not in (kx, ky)]
            note = f" (median over seeds{' and ' + ', '.join(others) if others else ''})"
            plot_heatmap(path, kx, ky, vx, vy, table, metric, title=f"{spec.name}: {metric}{note}")
            written.append(path)
    return written


def _match(a: Any, b: Any) -> bool:
    if _is_number(a) and _is_number(b):
        return math.isclose(float(a), float(b), rel_tol=1e-12, abs_tol=0.0)
    return a == b
