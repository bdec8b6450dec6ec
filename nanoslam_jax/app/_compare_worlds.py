"""A comparison over worlds: ``nanoslam compare`` of a file with ``seed_keys``.

Each seed is its own log (``seed_keys: [indoor.seed]``: its own simulated room), and every row
runs once on each, the rows of a seed on the same log (simulated once per seed and front end). A
run is :func:`nanoslam_jax.app.experiment.execute`, the run of ``nanoslam run``, scored by the one
scorer (:func:`nanoslam_jax.eval._scoring.score_run`): its numbers in ``runs.csv`` are those of its
``metrics.json``. Over the worlds, under the failed-seed rule (a failed run is an infinite error):

- ``table1.md``: the RMSE table of every comparison, then the feature map's table (the second
  paper's Table 1): position and heading RMSE, line slope and intercept, arc centre and radius,
  corner and break point errors (each run's median over its features; median, IQR and worst over
  the worlds), the walls matched, and the first row paired against each other row;
- ``fig5_pose_error.png``: position and heading error over time, each row's median and IQR over
  the worlds at each time step (the second paper's Figure 5);
- ``fig6_map.png``: the first row's map of walls and arcs and its track over the truth, in the
  world where its position RMSE is the median one (the second paper's Figure 6).
"""

from __future__ import annotations

import math
import sys
import time
import traceback
from pathlib import Path
from typing import Any, NamedTuple, Optional

import numpy as np
import yaml

from nanoslam_jax.app._compare_spec import CompareSpec, seed_config
from nanoslam_jax.eval._feature_metrics import (
    _lines_np,
    break_point_line_errors,
    line_feature_errors,
    line_intersections,
)
from nanoslam_jax.eval._scoring import failure_reason, format_number, metric_goal, number, run_values, seed_summary
from nanoslam_jax._version import __version__
from nanoslam_jax.app.config import config_to_dict

__all__ = ["FEATURE_COLUMNS", "feature_table", "run_worlds", "wall_segments"]

#: The feature table's columns: metric, header, scale, digits.
FEATURE_COLUMNS = (
    ("rmse_fixed", "position RMSE (cm)", 100.0, 2),
    ("rmse_heading_deg", "heading RMSE (deg)", 1.0, 3),
    ("line_slope_median", "line slope", 1.0, 4),
    ("line_intercept_median", "line intercept (cm)", 100.0, 2),
    ("arc_centre_median", "arc centre (cm)", 100.0, 2),
    ("arc_radius_median", "arc radius (cm)", 100.0, 2),
    ("corner_median", "corner points (cm)", 100.0, 2),
    ("break_point_median", "break points (cm)", 100.0, 2),
)


#: The truth's count of each feature type, by the first word of its metrics.
_TRUTH_COUNT = {"line": "n_lines", "arc": "n_arcs", "corner": "n_corners", "break": "n_break_points"}


class _Track(NamedTuple):
    """A run's errors over time: ``t`` (s), ``xy`` (m) and ``heading`` (deg, absolute)."""

    t: np.ndarray
    xy: np.ndarray
    heading: np.ndarray


class _WorldMap(NamedTuple):
    """What Figure 6 draws of one world: the truth and a run's track, lines and arcs."""

    truth: Any  # FeatureTruth
    true_path: np.ndarray
    path: np.ndarray
    lines: np.ndarray
    arcs: np.ndarray


def _numbers(metrics: dict) -> dict:
    return {k: v for k, v in metrics.items() if isinstance(v, (bool, int, float)) and k != "seed"}


def _track(result) -> _Track:
    """The position and heading error of a run at each of its segment times (the truth interpolated)."""
    from nanoslam_jax.eval.metrics import heading_errors

    t, est, truth = result.times, result.trajectory, np.asarray(result.log.raw.truth_poses)
    th, dh = heading_errors(t, est[:, 2], truth)
    inside = (t >= truth[0, 0]) & (t <= truth[-1, 0])
    x, y = (np.interp(t[inside], truth[:, 0], truth[:, k]) for k in (1, 2))
    return _Track(th, np.hypot(est[inside, 0] - x, est[inside, 1] - y), np.abs(dh))


def _features(result) -> tuple[np.ndarray, np.ndarray]:
    """A run's confirmed lines ``(rho, alpha)`` and arcs ``(xc, yc, R)``, as :func:`score_run` scores them."""
    from nanoslam_jax.app.experiment import _map_layout, map_columns

    none2, none3 = np.zeros((0, 2)), np.zeros((0, 3))
    lm = result.landmarks
    if lm is None:
        return none2, none3
    dim, names = _map_layout(result.config)
    conf = lm[:, map_columns(dim, names is not None).index("confirmed")] > 0
    vals = lm[conf, :dim]
    if names is not None:  # several types in one map
        kind = np.asarray(names)[lm[conf, dim].astype(int)]
        return vals[kind == "line", :2], vals[kind == "circle", :3]
    if hasattr(result.state, "arc_table"):  # NASRUKF's per-beam lines and arcs
        arcs, active = (np.asarray(a) for a in result.state.arc_table())
        return vals[:, :2], arcs[np.asarray(active, bool)]
    return (none2, vals[:, :3]) if dim == 3 else (vals[:, :2], none3)


def _clip(line: np.ndarray, box: np.ndarray) -> np.ndarray:
    """The part ``x0, y0, x1, y1`` of a line ``(rho, alpha)`` inside ``box`` ``(xmin, ymin, xmax, ymax)``
    (NaN where it misses the box)."""
    n = np.array([math.cos(line[1]), math.sin(line[1])])
    foot, d = line[0] * n, np.array([-n[1], n[0]])
    lo, hi = -np.inf, np.inf
    for k in (0, 1):
        if abs(d[k]) < 1e-12:
            if not box[k] <= foot[k] <= box[k + 2]:
                return np.full(4, np.nan)
            continue
        a, b = sorted(((box[k] - foot[k]) / d[k], (box[k + 2] - foot[k]) / d[k]))
        lo, hi = max(lo, a), min(hi, b)
    return np.r_[foot + lo * d, foot + hi * d] if lo < hi else np.full(4, np.nan)


def wall_segments(truth, est_lines: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray]:
    """The walls of an indoor world's true lines as segments, and estimated lines drawn as walls.

    A true line's wall runs between the outermost of its corners (where it meets its neighbours)
    and break points (its door jambs and free ends). An estimated line matched to a true one
    (:func:`~nanoslam_jax.eval._feature_metrics.line_feature_errors`) is drawn between the points of
    the estimated line nearest that wall's ends; an unmatched one is clipped to the box of the
    true walls, 0.5 m larger.

    Args:
        truth: the world's :class:`~nanoslam_jax.sim._indoor_types.FeatureTruth`.
        est_lines: ``(E, 2)`` estimated lines ``(rho, alpha)``, or None.

    Returns:
        ``(L, 4)`` the true walls ``x0, y0, x1, y1`` (NaN for a line with fewer than two such
        points) and ``(E, 4)`` the estimated ones.
    """
    tru = _lines_np(truth.lines)
    n_lines = tru.shape[0]
    points: list[list[np.ndarray]] = [[] for _ in range(n_lines)]
    pairs = np.asarray(truth.corners, np.int64).reshape(-1, 2)
    for (a, b), p in zip(pairs, line_intersections(tru[pairs[:, 0]], tru[pairs[:, 1]])):
        if np.all(np.isfinite(p)):
            points[a].append(p)
            points[b].append(p)
    bp = np.asarray(truth.break_points, float).reshape(-1, 2)
    for k, line in enumerate(break_point_line_errors(tru, tru, np.arange(n_lines), bp)["line"]):
        if line >= 0:
            points[line].append(bp[k])
    walls = np.full((n_lines, 4), np.nan)
    for i, pts in enumerate(points):
        if len(pts) >= 2:
            n = np.array([math.cos(tru[i, 1]), math.sin(tru[i, 1])])
            d = np.array([-n[1], n[0]])
            s = np.asarray(pts) @ d
            walls[i] = np.r_[tru[i, 0] * n + s.min() * d, tru[i, 0] * n + s.max() * d]
    est = _lines_np(np.zeros((0, 2)) if est_lines is None else est_lines)
    out = np.full((est.shape[0], 4), np.nan)
    ends = walls[np.all(np.isfinite(walls), axis=1)].reshape(-1, 2)
    box = np.r_[ends.min(axis=0) - 0.5, ends.max(axis=0) + 0.5] if len(ends) else np.array([-10.0, -10, 10, 10])
    match = line_feature_errors(est, tru)["match"]
    for e in range(est.shape[0]):
        out[e] = _clip(est[e], box)
    for j in np.flatnonzero((match >= 0) & np.all(np.isfinite(walls), axis=1)):
        k = int(match[j])
        n = np.array([math.cos(est[k, 1]), math.sin(est[k, 1])])
        w = walls[j].reshape(2, 2)
        out[k] = (w - np.outer(w @ n - est[k, 0], n)).reshape(4)  # the wall's ends moved onto the estimate
    return walls, out


def _cell(st: dict, scale: float, digits: int) -> str:
    if not math.isfinite(st["median"]) and math.isnan(st["median"]):
        return "n/a"
    fmt = lambda v: format_number(v * scale if math.isfinite(v) else v, digits)  # noqa: E731
    cell = f"{fmt(st['median'])} ({fmt(st['q1'])}-{fmt(st['q3'])}), worst {fmt(st['worst'])}"
    return cell + (f", {st['n_failed']} failed" if st["n_failed"] else "")


def feature_table(results: list) -> str:
    """The feature map's table (the second paper's Table 1) of a comparison over worlds, Markdown.

    Args:
        results: the rows' :class:`~nanoslam_jax.app.compare.MethodResult`, one run row per world.
    """
    head = " | ".join(h for _, h, _, _ in FEATURE_COLUMNS)
    lines = [
        "\n## The feature map (the second paper's Table 1)\n",
        "Each run's median error over its walls, corners, break points and pillars; median (IQR) and worst "
        "over the worlds, a failed run (or a feature type it did not map) counted as an infinite error. "
        "Break points: the distance of a wall's end to its wall's estimated line.\n",
        f"| method | worlds | {head} | walls matched | lines in map |",
        "|---|---|" + "---|" * (len(FEATURE_COLUMNS) + 2),
    ]
    for res in results:
        rows = res.rows
        failed = [r.get("status") != "ok" for r in rows]
        seeds = [r["seed"] for r in rows]
        cells = []
        for key, _, scale, digits in FEATURE_COLUMNS:
            count = _TRUTH_COUNT.get(key.split("_")[0])
            # a feature the world holds and the run did not map fails the run for that column
            bad = [
                f or (count is not None and number(r.get(count)) > 0 and not math.isfinite(number(r.get(key))))
                for r, f in zip(rows, failed)
            ]
            cells.append(_cell(seed_summary([r.get(key) for r in rows], bad, metric_goal(key), seeds), scale, digits))
        ok = [r for r, f in zip(rows, failed) if not f]
        matched = f"{sum(int(r.get('n_lines_matched', 0)) for r in ok)} / {sum(int(r.get('n_lines', 0)) for r in ok)}"
        n_est = [float(r["n_lines_est"]) for r in ok if "n_lines_est" in r]
        est = format_number(float(np.median(n_est)), 0) if n_est else ""
        lines.append(f"| {res.spec.label} | {len(rows)} | " + " | ".join(cells) + f" | {matched} | {est} |")
    if len(results) > 1:
        first = results[0]
        lines.append("")
        for other in results[1:]:
            n = min(len(first.rows), len(other.rows))
            wins = [
                int(np.sum(run_values(first.rows[:n], k) < run_values(other.rows[:n], k)))
                for k in ("rmse_fixed", "rmse_heading_deg")
            ]
            lines.append(
                f"- {first.spec.label} against {other.spec.label}, paired over the worlds: the smaller position "
                f"RMSE in {wins[0]} of {n}, the smaller heading RMSE in {wins[1]} of {n}."
            )
    return "\n".join(lines) + "\n"


def _bands(tracks: list[Optional[_Track]], t: np.ndarray, field: str, scale: float):
    """Median, first and third quartile over the worlds at each time of ``t`` (a failed run: infinite)."""
    v = np.array([np.full(t.shape, np.inf) if tr is None else np.interp(t, tr.t, getattr(tr, field)) for tr in tracks])
    q = np.quantile(np.minimum(v, 1e300), [0.5, 0.25, 0.75], axis=0)
    return [np.where(x > 1e299, np.nan, x * scale) for x in q]


def _figures(out: Path, spec: CompareSpec, results: list, tracks: list, maps: dict) -> None:
    from nanoslam_jax.eval.plotting import FeatureMapDrawing, plot_error_bands, plot_feature_map

    ok = [tr for trs in tracks for tr in trs if tr is not None]
    if ok:
        t = min((tr.t for tr in ok), key=len)
        panels: list[tuple[str, list]] = [("x-y error [cm]", []), ("heading error [deg]", [])]
        for res, trs in zip(results, tracks):
            bad = sum(tr is None for tr in trs)
            label = f"{res.spec.label}" + (f" ({bad} failed)" if bad else "")
            panels[0][1].append((label, *_bands(trs, t, "xy", 100.0)))
            panels[1][1].append((label, *_bands(trs, t, "heading", 1.0)))
        plot_error_bands(
            out / "fig5_pose_error.png",
            t,
            panels,
            f"{spec.name}: median and IQR over {len(tracks[0])} worlds at each time",
            logy=True,
        )
    if maps:
        values = run_values(results[0].rows, "rmse_fixed")
        order = [results[0].rows[i]["seed"] for i in np.argsort(values, kind="stable")]
        order = [s for s in order if s in maps]
        seed = order[(len(order) - 1) // 2]
        m = maps[seed]
        true_walls, est_walls = wall_segments(m.truth, m.lines)
        plot_feature_map(
            out / "fig6_map.png",
            FeatureMapDrawing(m.true_path, true_walls[np.all(np.isfinite(true_walls), axis=1)], m.truth.arcs),
            FeatureMapDrawing(m.path, est_walls[np.all(np.isfinite(est_walls), axis=1)], m.arcs),
            title=f"{spec.name}: {results[0].spec.label}, world {seed} (the median position RMSE)",
            label=results[0].spec.label,
        )


def run_worlds(spec: CompareSpec, out: Path, plots: bool = True, stream=sys.stderr) -> list[dict]:
    """Run every row of ``spec`` on every seed's own log and write the comparison directory (the
    module docstring).

    Args:
        spec: a comparison with ``seed_keys``.
        out: result directory (created).
        plots: draw Figures 5 and 6.
        stream: where progress lines go.

    Returns:
        The table rows (also in ``table1.csv``).
    """
    from nanoslam_jax.app._compare_report import MethodResult, _write_outputs, log_key, summarise, write_resolved
    from nanoslam_jax.app.experiment import execute, load_log

    write_resolved(out, spec)
    seeds = spec.seed_list
    safe = ["".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in m.label) for m in spec.methods]
    results = []
    for m, name in zip(spec.methods, safe):
        cfg = seed_config(spec, m, spec.first_seed)
        results.append(MethodResult(m, cfg.filter.method, rows=[]))
        (out / "configs" / f"{name}.yaml").write_text(
            f"# nanoslam-jax {__version__}, seed {spec.first_seed}; for seed s: seed and {', '.join(spec.seed_keys)} = s\n"
            + yaml.safe_dump(config_to_dict(cfg), sort_keys=False)
        )
    tracks: list[list[Optional[_Track]]] = [[] for _ in spec.methods]
    maps: dict[int, _WorldMap] = {}
    header = (
        f"# {spec.name}: {len(spec.methods)} methods on {len(seeds)} worlds (seeds {seeds[0]}..{seeds[-1]}; "
        f"seed and {', '.join(spec.seed_keys)} = the seed): one run per world and method\n\n"
    )
    for j, s in enumerate(seeds):
        logs: dict[str, Any] = {}
        for i, m in enumerate(spec.methods):
            t0 = time.perf_counter()
            cfg = seed_config(spec, m, s)
            try:
                key = log_key(cfg)
                if key not in logs:
                    logs[key] = load_log(cfg)
                r = execute(cfg, progress=False, log=logs[key])
                reason = failure_reason(r.times, r.trajectory)
                row = {"seed": s, "status": "failed" if reason else "ok", "reason": reason, **_numbers(r.metrics)}
                track = None if reason else _track(r)
                if i == 0 and not reason and r.log.feature_truth is not None:
                    lines, arcs = _features(r)
                    truth = np.asarray(r.log.raw.truth_poses)[:, 1:3]
                    maps[s] = _WorldMap(r.log.feature_truth, truth, r.trajectory[:, :2], lines, arcs)
            except Exception as e:  # recorded, the comparison goes on
                reason = f"{type(e).__name__}: {e}"
                row, track = {"seed": s, "status": "failed", "reason": reason}, None
                (out / f"error-{safe[i]}-{s}.txt").write_text(traceback.format_exc())
            results[i].rows.append(row)
            tracks[i].append(track)
            stream.write(
                f"[world {j + 1}/{len(seeds)}, seed {s}] {m.label}: {row['status']} in {time.perf_counter() - t0:.1f} s, "
                f"rmse_fixed {format_number(row.get('rmse_fixed', math.nan), 4)}, "
                f"heading {format_number(row.get('rmse_heading_deg', math.nan), 3)} deg\n"
            )
            stream.flush()
        for res in results:
            ok = [r for r in res.rows if r["status"] == "ok"]
            bad = [r["seed"] for r in res.rows if r["status"] != "ok"]
            res.status, res.reason = ("failed", f"failed for seed(s) {bad}") if bad else ("ok", "")
            res.ms_per_scan = float(np.median([r["ms_per_scan"] for r in ok])) if ok else math.nan
            res.compile_s = res.rows[0].get("compile_s", math.nan)
            res.batch_run_s = float(sum(r.get("run_s", 0.0) for r in res.rows))
        # Written after every world: an interrupted comparison keeps what it finished.
        _write_outputs(out, spec, results, header, feature_table(results))
    if plots:
        _figures(out, spec, results, tracks, maps)
    return [summarise(r) for r in results]
