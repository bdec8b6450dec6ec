"""Scoring: the metrics of one run, and their summary over seeds with one rule for failed seeds.

Every command that runs a filter (``run``, ``compare``, ``sweep``, ``study``) and the scripts in
``experiments/`` score a run with :func:`score_run` and summarise seeds with
:func:`summarize_runs` (or, for one column of numbers, :func:`seed_summary`).

**One run** (:func:`score_run`): the reported trajectory against the log's GPS (or a simulated
log's truth) by :func:`nanoslam_jax.eval.metrics.evaluate` (``rmse_fixed``, ``rmse_aligned``, their
``*_clean`` variants, ...); the reported map against the true trees of a simulated log
(:func:`~nanoslam_jax.eval.metrics.map_summary`, also after the trajectory's alignment) or against a
real log's survey (:func:`~nanoslam_jax.eval.metrics.survey_summary`); other trajectories of the same
run (the filter's own estimate beside a smoothed path) as ``rmse_fixed_<tag>``,
``rmse_aligned_<tag>``. A trajectory that is not finite everywhere is not scored (``finite`` is
false; :func:`failure_reason` says where it broke).

**Failed seeds.** A seed *fails* when its run raised an exception, its estimate became
non-finite, a check of the caller failed it (a sweep's landmark capacity overflow with
``run.fail_on_overflow``), or, for one metric, that metric is not a finite number although the
run finished. A failed seed is never dropped from a summary:

* it is counted (``n_failed``) and named (``failed_seeds``);
* for a metric where lower is better (every error: ``rmse_*``, ``final_error``, map errors) it
  counts as ``+inf``, the worst possible value: it is the worst seed, a quartile that reaches it
  is ``+inf``, and the median is ``+inf`` when more than half the seeds failed; for a metric where
  higher is better (found fractions, ``dr_over_slam``; :data:`HIGHER_IS_BETTER`) it counts as
  ``-inf``;
* a descriptive column that is neither better nor worse when larger (landmark counts, ESS,
  iterations, times; :func:`metric_goal` gives ``None``) has no worst value to stand for a failure:
  it is summarised over the seeds that did not fail, and ``n_failed`` beside it says how many that
  leaves out.

A metric that no seed reports (``rmse_*`` of a log without GPS) is not applicable: its summary is
NaN. Quantiles are linear interpolations between order statistics (``numpy.percentile``).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Mapping, NamedTuple, Optional, Sequence

import numpy as np

from nanoslam_jax.eval._reference_metrics import score_reference
from nanoslam_jax.eval.metrics import evaluate, feature_map_errors, map_summary, rmse_heading_deg, survey_summary
from nanoslam_jax.methods import AbstractEstimate, BestParticle

__all__ = [
    "HIGHER_IS_BETTER",
    "MapEstimate",
    "companion_tracks",
    "failure_reason",
    "format_number",
    "metric_goal",
    "number",
    "run_values",
    "score_run",
    "seed_summary",
    "summarize_runs",
    "summary_stats",
    "with_arcs",
    "write_rows_csv",
]

#: Metrics where a higher value is better (a failed seed counts as ``-inf`` in their summary).
HIGHER_IS_BETTER = frozenset(
    {
        "map_n_found",
        "map_found_fraction",
        "map_n_found_aligned",
        "map_found_fraction_aligned",
        "survey_found",
        "survey_found_by_id",
        "dr_over_slam",
        "survey_dr_over_slam",
        "n_lines_matched",
        "n_corners_matched",
        "n_arcs_matched",
        "n_break_points_matched",
    }
)
#: Prefixes and names of the errors (lower is better; a failed seed counts as ``+inf``).
_ERROR_PREFIXES = (
    "rmse_",
    "dr_rmse_",
    "map_rmse",
    "map_median_est_to_true",
    "map_spurious",
    "map_n_spurious",
    "survey_rmse",
    "survey_spurious",
    "dr_survey_rmse",
    "line_slope_",
    "line_intercept_",
    "line_rho_",
    "line_alpha_",
    "corner_",
    "arc_centre_",
    "arc_radius_",
    "break_point_",
)
_ERRORS = frozenset({"mean_error", "max_error", "final_error"})

#: Stand-in for an infinite value inside ``np.quantile`` (interpolating towards ``inf`` can give NaN).
_BIG = 1e300


def metric_goal(metric: str) -> Optional[str]:
    """``'min'`` for an error (lower is better), ``'max'`` for :data:`HIGHER_IS_BETTER`, ``None``
    for a descriptive column (counts, ESS, iterations, times)."""
    if metric in HIGHER_IS_BETTER:
        return "max"
    if metric in _ERRORS or metric.startswith(_ERROR_PREFIXES):
        return "min"
    return None


# --------------------------------------------------------------------------- one run


class MapEstimate(NamedTuple):
    """A run's reported map, for :func:`score_run`.

    Attributes:
        xy: ``(L, l)`` its active landmarks (tentative and confirmed): their states, of which
            the first two are a point's or a circle's position (a line's ``(rho, alpha)``).
        confirmed: ``(L,)`` which of them are confirmed (only those are scored).
        ids: ``(L,)`` the detection id each landmark carries (known association), or None.
        kinds: ``(L,)`` each landmark's type name (``'line'``, ``'circle'``: a map of several
            types), or None (one type).
    """

    xy: np.ndarray
    confirmed: np.ndarray
    ids: Optional[np.ndarray] = None
    kinds: Optional[np.ndarray] = None


def with_arcs(lines: MapEstimate, arcs: np.ndarray, active: np.ndarray) -> MapEstimate:
    """A map of lines (NASRUKF's per-beam features) with the filter's arcs beside them, as one map
    of several types (``kinds`` ``'line'`` and ``'circle'``) for :func:`score_run`.

    Args:
        lines: the lines ``(rho, alpha)`` (``kinds`` None).
        arcs: ``(A, 3)`` the arc slots ``(xc, yc, R)``.
        active: ``(A,)`` which slots hold an arc (all of them scored as confirmed).
    """
    act = np.asarray(active, bool)
    a = np.asarray(arcs, float).reshape(-1, 3)[act]
    xy = np.asarray(lines.xy, float).reshape(len(lines.confirmed), -1)[:, :2]
    ids = None if lines.ids is None else np.r_[np.asarray(lines.ids, float), np.full(len(a), -1.0)]
    return MapEstimate(
        np.r_[np.c_[xy, np.zeros(len(xy))], a],
        np.r_[np.asarray(lines.confirmed, bool), np.ones(len(a), bool)],
        ids,
        np.array(["line"] * len(xy) + ["circle"] * len(a)),
    )


def _gps(log) -> np.ndarray:
    raw = getattr(log, "raw", None)
    return np.asarray(raw.gps if raw is not None else log.gps)


def _truth_poses(log) -> Optional[np.ndarray]:
    """The log's true path ``time, x, y, phi`` (simulated logs), or None."""
    raw = getattr(log, "raw", None)
    return raw.truth_poses if raw is not None else getattr(log, "truth_poses", None)


def failure_reason(times: np.ndarray, est: np.ndarray) -> str:
    """Where a trajectory stops being finite (``''`` when it is finite everywhere)."""
    finite = np.isfinite(np.asarray(est)).reshape(len(est), -1).all(axis=1)
    if finite.all():
        return ""
    j = int(np.argmin(finite))
    return f"non-finite estimate from segment {j} (t = {float(times[j]):.2f} s)"


def companion_tracks(
    estimate: AbstractEstimate,
    best_pose: np.ndarray,
    mean_pose: np.ndarray,
    before_smoother: Optional[np.ndarray] = None,
) -> dict[str, np.ndarray]:
    """The trajectories a run reports beside its estimate, for :func:`score_run`'s ``others``:
    the filter's other per-segment estimate (``wmean``, the weighted mean, when ``filter.estimate``
    is ``best``; else ``best``, the best particle's pose) and, after the smoother, the ``path`` it
    started from."""
    out = {"wmean": mean_pose} if isinstance(estimate, BestParticle) else {"best": best_pose}
    if before_smoother is not None:
        out["path"] = before_smoother
    return out


def score_run(
    log,
    est: np.ndarray,
    metrics,
    landmarks: Optional[MapEstimate] = None,
    others: Optional[Mapping[str, np.ndarray]] = None,
) -> dict:
    """The metrics of one run.

    Args:
        log: the log the run scored (a :class:`~nanoslam_jax.app.experiment.LoadedLog` or a sweep's
            :class:`~nanoslam_jax.app.sweep.LogData`): its segment times, GPS, metrics frame, map
            truth and survey.
        est: ``(segments, >= 2)`` the reported trajectory (x, y first).
        metrics: the config's ``metrics`` section (``gps_rotation_deg``, ``jump_speed``,
            ``map_radius``).
        landmarks: the reported map (None: no map, e.g. dead reckoning).
        others: more trajectories of the same run, by tag: each adds ``rmse_fixed_<tag>`` and
            ``rmse_aligned_<tag>`` (a non-finite one is left out).

    Returns:
        ``finite`` (whether ``est`` is finite everywhere); with a finite ``est`` and GPS, every
        figure of :func:`~nanoslam_jax.eval.metrics.evaluate`; with a finite ``est`` that has headings
        and a log with a true path, ``rmse_heading_deg`` (:func:`~nanoslam_jax.eval.metrics.rmse_heading_deg`);
        with ``landmarks``, ``n_landmarks``,
        ``n_confirmed`` and the map figures the log supports (``map_*`` against a simulated log's
        true trees, ``survey_*`` against a survey; for a map of lines against an indoor log's true
        walls, the ``summary`` of :func:`~nanoslam_jax.eval.metrics.feature_map_errors` over the
        confirmed lines: ``line_slope_*``, ``line_intercept_*``, ``line_rho_*``, ``line_alpha_*``,
        ``corner_*``, ``break_point_*`` (median and worst), ``n_lines``, ``n_lines_matched``,
        ``n_corners``, ``n_corners_matched``, ``n_break_points``, ``n_break_points_matched`` and
        ``n_lines_est``; with arcs in the map (:func:`with_arcs`) or in the truth also the arcs'
        figures below; for a map of circles against its true pillars,
        ``arc_centre_*``, ``arc_radius_*``, ``n_arcs``, ``n_arcs_matched`` and ``n_arcs_est``); with a
        finite ``est`` that has headings and a log with a reference path (``log.reference``, a
        :class:`~nanoslam_jax.eval.ReferencePath`), the ``ref_*`` figures of
        :func:`~nanoslam_jax.eval.score_reference`.
    """
    t = np.asarray(log.segments.time)
    gps = _gps(log)
    est = np.asarray(est)
    finite = bool(np.all(np.isfinite(est)))
    out: dict = {"finite": finite}
    mk = dict(rotation_deg=metrics.gps_rotation_deg, jump_speed=metrics.jump_speed, frame=log.frame)
    alignment = None
    if finite and len(gps):
        alignment = evaluate(t, est[:, :2], gps, **mk)
        out.update(alignment)
        for tag, other in (others or {}).items():
            other = np.asarray(other)
            if np.all(np.isfinite(other)):
                o = evaluate(t, other[:, :2], gps, **mk)
                out.update({f"rmse_fixed_{tag}": o["rmse_fixed"], f"rmse_aligned_{tag}": o["rmse_aligned"]})
    reference = getattr(log, "reference", None)
    if finite and reference is not None and est.ndim == 2 and est.shape[1] >= 3:
        out.update(score_reference(reference, t, est))
    truth = _truth_poses(log)
    if finite and truth is not None and est.ndim == 2 and est.shape[1] >= 3:
        out["rmse_heading_deg"] = rmse_heading_deg(t, est[:, 2], truth)
    if landmarks is not None:
        conf = np.asarray(landmarks.confirmed, bool)
        states = np.asarray(landmarks.xy, float)
        states = states.reshape(conf.shape[0], -1) if states.size else np.zeros((conf.shape[0], 2))
        xy = states[:, :2]
        out.update(map_summary(xy, conf, log.map_truth, metrics.map_radius, alignment))
        if log.survey is not None:
            out.update(survey_summary(xy, conf, log.survey.xy, metrics.map_radius, landmarks.ids, log.survey.ids))
        features = getattr(log, "feature_truth", None)
        if features is not None and landmarks.kinds is not None:  # lines and circles: Table 1's lines and arcs
            kinds = np.asarray(landmarks.kinds)
            lines, arcs = states[conf & (kinds == "line"), :2], states[conf & (kinds == "circle"), :3]
            table = feature_map_errors(
                lines,
                features.lines,
                est_arcs=arcs,
                true_arcs=features.arcs,
                corners=features.corners,
                true_break_points=features.break_points,
            )["summary"]
            out.update(table, n_lines_est=len(lines), n_arcs_est=len(arcs))
        elif features is not None and states.shape[1] == 3:  # a map of circles (xc, yc, R): Table 1's arcs
            none = np.zeros((0, 2))
            table = feature_map_errors(none, none, est_arcs=states[conf], true_arcs=features.arcs)["summary"]
            out.update({k: v for k, v in table.items() if "arc" in k}, n_arcs_est=int(conf.sum()))
        elif features is not None:  # a map of lines (rho, alpha): the second paper's Table 1
            table = feature_map_errors(
                xy[conf], features.lines, corners=features.corners, true_break_points=features.break_points
            )["summary"]
            out.update(table, n_lines_est=int(conf.sum()))
    return out


# --------------------------------------------------------------------------- over seeds


def number(v: Any) -> float:
    """A CSV cell or a Python value as a float (empty or unparsable: NaN; ``inf`` is kept)."""
    if v is None or v == "":
        return math.nan
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def summary_stats(values: np.ndarray) -> dict:
    """``median``, ``q1``, ``q3`` (linear interpolation, as ``numpy.percentile``), ``worst`` (max)
    and ``best`` (min) of errors that may hold ``inf``; a quantile that reaches an ``inf`` is
    ``inf``. All NaN for no values."""
    v = np.asarray(values, float)
    if v.size == 0:
        return dict(median=math.nan, q1=math.nan, q3=math.nan, worst=math.nan, best=math.nan)
    q = np.quantile(np.minimum(v, _BIG), [0.5, 0.25, 0.75])
    top = np.max(v[np.isfinite(v)], initial=-math.inf)
    q = [math.inf if x > top else float(x) for x in q]
    return dict(median=q[0], q1=q[1], q3=q[2], worst=float(np.max(v)), best=float(np.min(v)))


def seed_summary(
    values: Sequence[float],
    failed: Optional[Sequence[bool]] = None,
    goal: Optional[str] = "min",
    seeds: Optional[Sequence[int]] = None,
) -> dict:
    """One metric over seeds under the failed-seed rule (module docstring).

    Args:
        values: the metric of each seed (anything for a failed one).
        failed: which seeds failed (default: none); a NaN value also fails its seed, unless no
            seed has a value (the metric does not apply: all NaN).
        goal: ``'min'`` (an error: a failure is ``+inf``), ``'max'`` (a failure is ``-inf``) or
            ``None`` (descriptive: failed seeds left out).
        seeds: the seed of each value, for ``failed_seeds`` (default: their positions).

    Returns:
        ``median``, ``q1``, ``q3``, ``min``, ``max``, ``best`` and ``worst`` (by ``goal``; for
        ``None`` the min and the max), ``n`` (seeds), ``n_failed`` and ``failed_seeds`` (a list).
    """
    v = np.array([number(x) for x in values], float)
    bad = np.zeros(v.shape, bool) if failed is None else np.asarray(failed, bool).copy()
    ids = list(range(len(v))) if seeds is None else [int(s) for s in seeds]
    applicable = bool(np.any(~np.isnan(v)))
    if applicable:
        bad |= np.isnan(v)
    out: dict = {"n": int(v.size), "n_failed": int(bad.sum()), "failed_seeds": [s for s, b in zip(ids, bad) if b]}
    nan = dict(median=math.nan, q1=math.nan, q3=math.nan, min=math.nan, max=math.nan, best=math.nan, worst=math.nan)
    if not applicable and not bad.all():
        return {**nan, **out}
    if goal is None:
        v = v[~bad & np.isfinite(v)]
    else:
        v = np.where(bad, math.inf if goal == "min" else -math.inf, v)
    if v.size == 0:
        return {**nan, **out}
    sign = 1.0 if goal != "max" else -1.0  # quantiles of -v where -inf is the bad end
    st = summary_stats(sign * v)
    q1, q3 = (st["q1"], st["q3"]) if sign > 0 else (-st["q3"], -st["q1"])
    lo, hi = float(np.min(v)), float(np.max(v))
    best, worst = (lo, hi) if goal != "max" else (hi, lo)
    return {
        "median": sign * st["median"],
        "q1": q1,
        "q3": q3,
        "min": lo,
        "max": hi,
        "best": best,
        "worst": worst,
        **out,
    }


def run_values(rows: Sequence[Mapping], metric: str, goal: Optional[str] = "min") -> np.ndarray:
    """One value per run row under the failed-seed rule: the metric of a run with status ``ok``,
    ``+inf`` (``goal='max'``: ``-inf``) for a failed run or a non-finite metric."""
    bad = math.inf if goal != "max" else -math.inf
    out = np.array([number(r.get(metric)) if r.get("status", "ok") == "ok" else bad for r in rows], float)
    return np.where(np.isnan(out), bad, out)


def summarize_runs(
    rows: Sequence[Mapping],
    metrics: Sequence[str],
    goals: Optional[Mapping[str, Optional[str]]] = None,
    stats: Sequence[str] = ("median", "q1", "q3", "min", "max"),
) -> dict:
    """Runs of one setting (one row per seed) summarised under the failed-seed rule.

    Args:
        rows: one mapping per seed: ``seed``, ``status`` (``'ok'`` or not; missing: ok), ``reason``
            and the metrics (numbers or CSV strings).
        metrics: the columns to summarise.
        goals: a column's goal where it differs from :func:`metric_goal`'s.
        stats: the statistics of :func:`seed_summary` to report per column.

    Returns:
        ``n_runs``, ``n_ok``, ``n_failed`` (runs whose status is not ok), ``failed_seeds`` (their
        seeds, ``;``-separated), ``reasons`` (their distinct reasons, ``;``-separated) and
        ``<metric>_<stat>`` for each column and statistic.
    """
    goals = dict(goals or {})
    failed = [r.get("status", "ok") != "ok" for r in rows]
    seeds = [int(x) if math.isfinite(x := number(r.get("seed", i))) else i for i, r in enumerate(rows)]
    out: dict = {
        "n_runs": len(rows),
        "n_ok": len(rows) - sum(failed),
        "n_failed": sum(failed),
        "failed_seeds": ";".join(str(s) for s, f in zip(seeds, failed) if f),
        "reasons": "; ".join(sorted({str(r.get("reason", "")) for r, f in zip(rows, failed) if f} - {""})),
    }
    for m in metrics:
        st = seed_summary([r.get(m) for r in rows], failed, goals.get(m, metric_goal(m)), seeds)
        out.update({f"{m}_{k}": st[k] for k in stats})
    return out


# --------------------------------------------------------------------------- tables


def format_number(v: Any, nd: int = 3) -> str:
    """A table cell: floats with ``nd`` decimals (``inf``, ``nan`` as such), None empty."""
    if v is None:
        return ""
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        return ("inf" if v > 0 else "-inf") if math.isinf(v) else f"{v:.{nd}f}"
    return str(v)


def write_rows_csv(path: str | Path, rows: Sequence[Mapping]) -> None:
    """Rows (mappings) as a CSV file: the columns in order of first appearance, None empty."""
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in keys})
