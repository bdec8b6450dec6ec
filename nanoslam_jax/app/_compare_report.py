"""The results of a comparison: each method's result over seeds, their summary (Table I) and the
files a comparison writes (tables, per-seed rows, the resolved comparison file)."""

from __future__ import annotations
import dataclasses
import datetime as _dt
import json
import math
from pathlib import Path
from typing import Any, Optional
import numpy as np
import yaml
from nanoslam_jax.app._compare_spec import (
    CompareSpec,
    MethodSpec,
)
from nanoslam_jax._version import __version__
from nanoslam_jax.eval._scoring import (
    format_number,
    summarize_runs,
    write_rows_csv,
)
from nanoslam_jax.app.config import Config, config_to_dict


RMSE_KEYS = ("rmse_fixed", "rmse_aligned", "rmse_fixed_clean", "rmse_aligned_clean", "final_error")


@dataclasses.dataclass
class MethodResult:
    """Everything measured for one method (host arrays)."""

    spec: MethodSpec
    method: str
    rows: list[dict]
    status: str = "ok"
    reason: str = ""
    ms_per_scan: float = math.nan
    compile_s: float = math.nan
    batch_run_s: float = math.nan
    trajectory: Optional[np.ndarray] = None  # first seed's reported estimate (T, 3)
    landmarks: Optional[np.ndarray] = None  # first seed's map (L, 2)
    chunk_ms: Optional[np.ndarray] = None  # ms per scan of each timed chunk
    chunk_t: Optional[np.ndarray] = None  # log time at the middle of each chunk
    trajectories: Optional[list] = None  # every seed's scored trajectory (run_method's keep_trajectories)


#: The columns a comparison summarises over seeds (those its runs report).
SUMMARY_KEYS = (
    "rmse_fixed",
    "rmse_aligned",
    "rmse_fixed_clean",
    "rmse_aligned_clean",
    "rmse_fixed_path",
    "rmse_aligned_path",
    "rmse_fixed_best",
    "rmse_aligned_best",
    "n_landmarks",
    "n_confirmed",
    "smoother_s",
)


#: The columns against a reference path (``data.reference``), summarised where runs report them.
REFERENCE_KEYS = ("ref_rmse", "ref_max", "ref_rel_trans", "ref_rel_rot_deg")

#: The heading and the feature map's columns (the second paper's Table 1), summarised where runs report them.
FEATURE_KEYS = (
    "rmse_heading_deg",
    *(
        f"{k}_{s}"
        for k in ("line_slope", "line_intercept", "arc_centre", "arc_radius", "corner", "break_point")
        for s in ("median", "worst")
    ),
    *(
        f"n_{k}"
        for k in (
            "lines",
            "lines_matched",
            "lines_est",
            "arcs",
            "arcs_matched",
            "arcs_est",
            "corners",
            "corners_matched",
            "break_points",
            "break_points_matched",
        )
    ),
)


def summarise(res: MethodResult) -> dict:
    """One table row: median, quartiles and worst seed over the seeds, failed seeds counted
    (:func:`~nanoslam_jax.eval._scoring.summarize_runs`)."""
    keys = [k for k in SUMMARY_KEYS if k in RMSE_KEYS or k.startswith("n_") or any(k in r for r in res.rows)]
    keys += [k for k in (*REFERENCE_KEYS, *FEATURE_KEYS) if any(k in r for r in res.rows)]
    st = summarize_runs(res.rows, keys, stats=("median", "q1", "q3", "worst"))
    out: dict[str, Any] = {
        "method": res.spec.label,
        "filter_method": res.method,
        "status": res.status,
        "reason": res.reason,
        "seeds": len(res.rows),
        "n_failed": st["n_failed"],
        "failed_seeds": st["failed_seeds"],
    }
    out.update({k: v for k, v in st.items() if k.endswith(("_median", "_q1", "_q3", "_worst"))})
    out.update(
        ms_per_scan=res.ms_per_scan,
        compile_s=res.compile_s,
        batch_run_s=res.batch_run_s,
        paper_rmse=res.spec.paper_rmse,
        paper_ms=res.spec.paper_ms,
    )
    return out


def markdown_table(rows: list[dict]) -> str:
    """The Table I layout: RMSE (median, IQR and worst seed over seeds; a failed seed counts as an
    infinite error), ms per scan, landmarks, paper's figures. A smoothed method is followed by a
    row of the filter's own estimate of the same runs (``rmse_*_best``)."""
    if (
        rows
        and all("ref_rmse_median" in r or r["status"] != "ok" for r in rows)
        and any("ref_rmse_median" in r for r in rows)
    ):
        return reference_table(rows)
    lines = [
        "| method | seeds | RMSE fixed [m] median (IQR) | worst | RMSE aligned [m] median (IQR) | worst | "
        "ms per scan | confirmed landmarks | paper RMSE [m] | paper ms per step |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    fmt = format_number
    for r in rows:
        seeds = f"{r['seeds']}" + (f" ({r['n_failed']} failed: {r['failed_seeds']})" if r.get("n_failed") else "")
        if r["status"] != "ok" and not math.isfinite(r.get("rmse_fixed_median", math.nan)):
            lines.append(
                f"| {r['method']} | {seeds} | failed: {r['reason']} | | | | | | {fmt(r['paper_rmse'])} | "
                f"{fmt(r['paper_ms'], 2)} |"
            )
            continue
        iqr = lambda k: f"{fmt(r[k + '_median'])} ({fmt(r[k + '_q1'])}-{fmt(r[k + '_q3'])})"  # noqa: E731
        lines.append(
            f"| {r['method']} | {seeds} | {iqr('rmse_fixed')} | {fmt(r['rmse_fixed_worst'], 2)} | "
            f"{iqr('rmse_aligned')} | {fmt(r['rmse_aligned_worst'], 2)} | {fmt(r['ms_per_scan'], 2)} | "
            f"{fmt(r['n_confirmed_median'], 0)} | {fmt(r['paper_rmse'])} | {fmt(r['paper_ms'], 2)} |"
        )
        if "rmse_fixed_path_median" in r and "rmse_fixed_best_median" in r:  # smoothed: the filter's own estimate
            lines.append(
                f"| {r['method']}: the filter's own estimate, same runs | {seeds} | {iqr('rmse_fixed_best')} | "
                f"{fmt(r['rmse_fixed_best_worst'], 2)} | {iqr('rmse_aligned_best')} | "
                f"{fmt(r['rmse_aligned_best_worst'], 2)} | | | | |"
            )
    return "\n".join(lines) + "\n"


def reference_table(rows: list[dict]) -> str:
    """The table of a comparison scored against a reference path: the trajectory error after the
    SE(2) alignment (median, IQR and worst seed), the mean error of the relative motion between
    consecutive reference poses, ms per scan and landmarks."""
    lines = [
        "| method | seeds | path error [m] median (IQR) | worst | relative motion [m] median | worst | "
        "relative rotation [deg] median | worst | ms per scan | confirmed landmarks |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    fmt = format_number
    for r in rows:
        seeds = f"{r['seeds']}" + (f" ({r['n_failed']} failed: {r['failed_seeds']})" if r.get("n_failed") else "")
        if "ref_rmse_median" not in r:
            lines.append(f"| {r['method']} | {seeds} | failed: {r['reason']} | | | | | | | |")
            continue
        lines.append(
            f"| {r['method']} | {seeds} | {fmt(r['ref_rmse_median'])} ({fmt(r['ref_rmse_q1'])}-"
            f"{fmt(r['ref_rmse_q3'])}) | {fmt(r['ref_rmse_worst'])} | {fmt(r['ref_rel_trans_median'], 3)} | "
            f"{fmt(r['ref_rel_trans_worst'], 3)} | {fmt(r['ref_rel_rot_deg_median'], 2)} | "
            f"{fmt(r['ref_rel_rot_deg_worst'], 2)} | {fmt(r['ms_per_scan'], 2)} | {fmt(r['n_confirmed_median'], 0)} |"
        )
    return "\n".join(lines) + "\n"


def log_key(cfg: Config) -> str:
    """What a config's log depends on: configs with the same key run on the same log."""
    d = config_to_dict(cfg)
    return json.dumps(
        [d[k] for k in ("data", "sim", "city", "indoor", "vehicle", "detector")] + [cfg.model.measurement],
        sort_keys=True,
    )


def write_resolved(out: Path, spec: CompareSpec) -> None:
    """Create the comparison directory and write ``compare.yaml``: the resolved comparison with the versions."""
    from nanoslam_jax.app.experiment import versions

    out.mkdir(parents=True, exist_ok=True)
    (out / "configs").mkdir(exist_ok=True)
    resolved = {
        "name": spec.name,
        "base": spec.base,
        "seeds": spec.seeds,
        "first_seed": spec.first_seed,
        "seed_keys": list(spec.seed_keys),
        "timing_chunk": spec.timing_chunk,
        "set": list(spec.set),
        "methods": [dataclasses.asdict(m) | {"set": list(m.set)} for m in spec.methods],
        "version": __version__,
        "versions": versions(),
        "source": spec.source,
        "written": _dt.datetime.now().isoformat(timespec="seconds"),
    }
    (out / "compare.yaml").write_text(yaml.safe_dump(resolved, sort_keys=False))


def _write_outputs(
    out: Path, spec: CompareSpec, results: list[MethodResult], header: str = "", extra: str = ""
) -> None:
    """``table1.csv``, ``runs.csv``, ``table1.md`` (``header``, the RMSE table, then ``extra``) and ``summary.json``."""
    table = [summarise(r) for r in results]
    write_rows_csv(out / "table1.csv", table)
    runs = [{"method": r.spec.label, "filter_method": r.method, **row} for r in results for row in r.rows]
    if runs:
        write_rows_csv(out / "runs.csv", runs)
    header = header or (
        f"# {spec.name}: {len(spec.methods)} methods, {spec.seeds} seeds "
        f"({spec.first_seed}..{spec.first_seed + spec.seeds - 1}; EKF-SLAM, NASRUKF and dead reckoning are deterministic: one run)\n\n"
    )
    (out / "table1.md").write_text(header + markdown_table(table) + extra)
    # JSON has no inf: an infinite median (failed seeds) is written as the string "inf", NaN as null.
    safe = lambda v: (None if math.isnan(v) else str(v)) if isinstance(v, float) and not math.isfinite(v) else v  # noqa: E731
    (out / "summary.json").write_text(
        json.dumps([{k: safe(v) for k, v in row.items()} for row in table], indent=2) + "\n"
    )
