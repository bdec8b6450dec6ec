"""The study's statistics: per-point summaries over seeds, the paired comparison of one method
against another over the same seeds, and the comparison at equal time.

Every function takes plain rows (mappings, as read from ``runs.csv``: one per run with at least
``method``, ``particles``, ``seed``, ``status`` and the error columns), so the statistics can be
checked by hand on a small table.

**Failed runs** (a non-finite estimate, a landmark capacity overflow, an error) follow the rule
of every summary over seeds (:mod:`nanoslam_jax.eval._scoring`): they are counted and named, and count
as an infinite error: they raise the medians and quartiles they reach, they are the worst seed,
and in a paired comparison a failed run loses to a finished one (two failed runs tie).

**Paired comparison** (:func:`paired_comparison`), at one particle count, of a reference method
A (NANO-SLAM) against another method B over the seeds both ran: the seed selects each filter's
random stream (the methods use it differently, so the pairing is by seed number; the seeds'
runs are independent). ``wins`` are the seeds where A's error is lower, ``losses`` where it is
higher, ``ties`` the rest; ``sign_p`` is the exact two-sided sign test of "A is as likely to win
as to lose" (``scipy.stats.binomtest(wins, wins + losses)``, ties left out); ``median_diff`` is
the median of the paired differences A - B (negative: A lower) over the seeds where both
finished, with a bootstrap percentile interval (``scipy.stats.bootstrap``, seeds resampled with
replacement, a fixed resampling seed).

**Equal time** (:func:`equal_time`): at A's point with ``seconds_per_log`` t, B's median error at
the same t, interpolated linearly in log(seconds per log) between B's two points whose seconds
per log bracket t (B's points sorted by time); NaN when t lies outside B's measured range (no
extrapolation). ``diff`` is A's median minus that value (negative: A is more accurate for the
same time).
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from nanoslam_jax.eval._scoring import number, run_values, summarize_runs, summary_stats

__all__ = ["number", "error_values", "summary_stats", "summarize_points", "paired_comparison", "equal_time"]


def error_values(rows: Sequence[dict], metric: str) -> np.ndarray:
    """One error per row: the metric of a finished run, ``inf`` for a failed one (or a NaN metric)."""
    return run_values(rows, metric, "min")


def _key(r: dict) -> tuple:
    p = number(r.get("particles"))
    return (r["method"], None if math.isnan(p) else int(p))


def summarize_points(rows: Sequence[dict], metrics: Sequence[str], timing: Optional[dict] = None) -> list[dict]:
    """One summary per (method, particles) over its seeds.

    Args:
        rows: run rows.
        metrics: error columns to summarise.
        timing: optional ``(method, particles) -> mapping`` of the point's timing columns
            (``seconds_per_log`` ...), copied into its summary.

    Returns:
        Per point, in order of first appearance: ``method``, ``particles``, ``seeds``, ``n_ok``,
        ``n_failed``, ``failed_seeds``, ``<metric>_median/_q1/_q3/_worst/_best`` and
        ``n_landmarks_median`` (over the finished runs) by
        :func:`~nanoslam_jax.eval._scoring.summarize_runs`, then the timing columns.
    """
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(_key(r), []).append(r)
    out = []
    for (method, particles), rs in groups.items():
        st = summarize_runs(
            rs, metrics, goals={m: "min" for m in metrics}, stats=("median", "q1", "q3", "worst", "best")
        )
        s: dict = {
            "method": method,
            "particles": particles,
            "seeds": st["n_runs"],
            "n_ok": st["n_ok"],
            "n_failed": st["n_failed"],
            "failed_seeds": st["failed_seeds"],
        }
        s.update({f"{m}_{k}": st[f"{m}_{k}"] for m in metrics for k in ("median", "q1", "q3", "worst", "best")})
        s["n_landmarks_median"] = summarize_runs(rs, ["n_landmarks"], stats=("median",))["n_landmarks_median"]
        s.update((timing or {}).get((method, particles), {}))
        out.append(s)
    return out


def paired_comparison(
    rows: Sequence[dict],
    reference: str,
    other: str,
    particles: Optional[int],
    metric: str,
    *,
    n_resamples: int = 10000,
    confidence: float = 0.95,
    seed: int = 0,
) -> dict:
    """The reference method against another at one particle count, over the seeds both ran.

    Returns:
        ``pairs`` (common seeds), ``wins``, ``losses``, ``ties`` (of the reference), ``sign_p``
        (exact two-sided sign test; NaN when every pair ties), ``n_diff`` (pairs where both
        finished), ``median_diff`` and its bootstrap interval ``diff_low``, ``diff_high`` (NaN
        with fewer than 2 such pairs, or when all their differences are equal the interval is that
        value), ``median_ref``, ``median_other`` (over the common seeds, failures as ``inf``) and
        ``ratio`` of the two medians.
    """
    from scipy.stats import binomtest, bootstrap

    def by_seed(label):
        return {int(number(r["seed"])): r for r in rows if _key(r) == (label, particles)}

    a_rows, b_rows = by_seed(reference), by_seed(other)
    seeds = sorted(set(a_rows) & set(b_rows))
    a = error_values([a_rows[s] for s in seeds], metric)
    b = error_values([b_rows[s] for s in seeds], metric)
    wins, losses = int(np.sum(a < b)), int(np.sum(a > b))
    n = wins + losses
    both = np.isfinite(a) & np.isfinite(b)
    d = a[both] - b[both]
    out = {
        "reference": reference,
        "other": other,
        "particles": particles,
        "metric": metric,
        "pairs": len(seeds),
        "wins": wins,
        "losses": losses,
        "ties": len(seeds) - n,
        "sign_p": float(binomtest(wins, n).pvalue) if n else math.nan,
        "n_diff": int(d.size),
        "median_diff": float(np.median(d)) if d.size else math.nan,
        "diff_low": math.nan,
        "diff_high": math.nan,
    }
    if d.size >= 2 and np.ptp(d) == 0:
        out["diff_low"] = out["diff_high"] = float(d[0])
    elif d.size >= 2:
        ci = bootstrap(
            (d,),
            np.median,
            n_resamples=n_resamples,
            confidence_level=confidence,
            method="percentile",
            vectorized=True,
            random_state=np.random.default_rng(seed),
        ).confidence_interval
        out["diff_low"], out["diff_high"] = float(ci.low), float(ci.high)
    ma, mb = summary_stats(a)["median"], summary_stats(b)["median"]
    out.update(
        median_ref=ma, median_other=mb, ratio=ma / mb if mb and math.isfinite(mb) and math.isfinite(ma) else math.nan
    )
    return out


def equal_time(
    summary: Sequence[dict], reference: str, other: str, particles: int, metric: str, time_key: str = "seconds_per_log"
) -> dict:
    """The reference method's median error against the other's at the same seconds per log.

    Args:
        summary: point summaries (:func:`summarize_points`, with ``time_key``).
        reference, other: method labels.
        particles: the reference's particle count.
        metric: the error compared (its ``_median`` column).
        time_key: the seconds-per-log column.

    Returns:
        ``seconds`` (the reference point's), ``median_ref``, ``median_other_at_time`` (see the
        module docstring; NaN outside the other's range), ``diff`` (reference minus other),
        ``bracket`` (the other's two particle counts around that time, e.g. ``"100-300"``).
    """
    ref = next((s for s in summary if s["method"] == reference and s["particles"] == particles), None)
    pts = sorted(
        (
            (number(s.get(time_key)), s[f"{metric}_median"], s["particles"])
            for s in summary
            if s["method"] == other and math.isfinite(number(s.get(time_key))) and number(s.get(time_key)) > 0
        )
    )
    out = {
        "reference": reference,
        "other": other,
        "particles": particles,
        "metric": metric,
        "seconds": math.nan,
        "median_ref": math.nan,
        "median_other_at_time": math.nan,
        "diff": math.nan,
        "bracket": "",
    }
    if ref is None:
        return out
    t = number(ref.get(time_key))
    out.update(seconds=t, median_ref=ref[f"{metric}_median"])
    if not (math.isfinite(t) and t > 0) or not pts or not pts[0][0] <= t <= pts[-1][0]:
        return out
    x = np.log([p[0] for p in pts])
    j = int(np.clip(np.searchsorted(x, math.log(t)), 1, len(pts) - 1)) if len(pts) > 1 else 0
    lo, hi = pts[max(j - 1, 0)], pts[j]
    w = (math.log(t) - math.log(lo[0])) / (math.log(hi[0]) - math.log(lo[0])) if hi[0] > lo[0] else 0.0
    if w <= 0 or w >= 1:
        v = lo[1] if w <= 0 else hi[1]
    else:  # an infinite median (failed runs) on either side makes the interpolated one infinite
        v = lo[1] + w * (hi[1] - lo[1]) if math.isfinite(lo[1]) and math.isfinite(hi[1]) else math.inf
    out.update(median_other_at_time=float(v), diff=float(ref[f"{metric}_median"] - v), bracket=f"{lo[2]}-{hi[2]}")
    return out
