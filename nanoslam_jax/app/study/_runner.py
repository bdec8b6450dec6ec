"""Runs a study: each point's seeds through the sweep runner, each point timed alone, then the
tables, the paired comparison and the figure.

For each point (:func:`~nanoslam_jax.app.study.expand_study`, cheapest particle counts first):

1. **Accuracy**: the point's seeds are a sweep of one configuration (:func:`nanoslam_jax.app.sweep.run_sweep`
   into ``DIR/runs/<point>/``: batches of seeds vmapped in one compiled program, split over the
   cores, appended to that sweep's ``results.csv`` as each batch finishes). An interrupted study
   resumes there (``--resume``): finished points are skipped, a partial one continues.
2. **Seconds per log**: the point's first seed alone, in a fresh process set up as ``nanoslam
   run`` is (:mod:`nanoslam_jax.app.study._timing`), after compilation, the median of up to
   ``timing.repeats`` runs; one row per point in ``DIR/timing.csv``.
3. The study's tables are rewritten, so an interrupted study keeps what it finished.

``DIR`` gets ``study.yaml`` (the resolved study and the versions), ``configs/<point>.yaml`` (each
point's config, its first seed), ``runs/`` (one sweep directory per point), ``timing.csv``,
``runs.csv`` (one row per run: ``point_id, method, filter_method, particles, seed, status,
reason``, every metric of the sweep runner, ``batch_s_per_run`` = the vmapped batch's time divided
by its runs, which is *not* a run's cost, and the point's timing columns ``seconds_per_log``,
``seconds_per_log_min``, ``timing_runs``, ``ms_per_scan``, ``scans``, ``devices``),
``summary.csv`` / ``summary.md`` (per point: median, IQR, worst and best seed of each error, and
the seconds per log), ``paired.csv`` / ``paired.md`` (the paired comparison at each particle count
and at equal time), ``accuracy_vs_compute.png`` and, on the real log, ``gps_floor.md`` /
``gps_floor.json``.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import yaml

from nanoslam_jax._version import __version__
from nanoslam_jax.eval._scoring import format_number, write_rows_csv
from nanoslam_jax.app.config import ConfigError, config_to_dict
from nanoslam_jax.app.study._spec import STUDY_METRICS, StudyPoint, StudySpec, expand_study, point_sweep_dict
from nanoslam_jax.app.study._stats import equal_time, number, paired_comparison, summarize_points
from nanoslam_jax.lib._precision import in_float64

if TYPE_CHECKING:
    from nanoslam_jax.app.sweep import ResultsFile

__all__ = ["run_study", "StudyResult", "TIMING_FIELDS"]

#: The timing columns of a point (``timing.csv``), copied into its runs and its summary.
TIMING_FIELDS = (
    "seconds_per_log",
    "seconds_per_log_min",
    "timing_runs",
    "ms_per_scan",
    "scans",
    "devices",
    "compile_s",
    "peak_rss_mb",
)
_TIMING_COLUMNS = ("point_id", "method", "particles", "seed", "status", "reason", *TIMING_FIELDS, "runs_s")


@dataclasses.dataclass(frozen=True)
class StudyResult:
    """What :func:`run_study` wrote.

    Attributes:
        out_dir: the study directory.
        summary: the per-point summaries (``summary.csv``).
        paired: the paired comparisons (``paired.csv``).
        n_failed: failed runs and failed timings.
    """

    out_dir: Path
    summary: list
    paired: list
    n_failed: int


def _say(stream, text: str) -> None:
    if stream is not None:
        stream.write(text + "\n")
        stream.flush()


def _sweep_done(sweep_dir: Path, sweep, pt: StudyPoint) -> bool:
    """Whether the point's sweep directory holds every seed of this very point (an error if it
    holds another point's runs)."""
    from nanoslam_jax.app.sweep import read_results, spec_identity, stored_identity

    if not (sweep_dir / "sweep.yaml").is_file():
        return False
    old = stored_identity((yaml.safe_load((sweep_dir / "sweep.yaml").read_text()) or {}).get("identity"))
    if old != spec_identity(sweep):
        raise ConfigError(
            f"{sweep_dir}: holds the runs of other settings of point {pt.point_id} than {sweep.source}'s; "
            f"choose another --out"
        )
    rows = read_results(sweep_dir / "results.csv")
    return {f"c0000-s{s}" for s in pt.seeds} <= {r["run_id"] for r in rows}


def _time_point(spec: StudySpec, pt: StudyPoint, out: Path, data_dir: Optional[str], cache: Optional[str]) -> dict:
    """One timing row: the point's first seed alone in a fresh process (see ``_timing``)."""
    js = out / "configs" / f"{pt.point_id}.timing.json"
    cmd = [
        sys.executable,
        "-m",
        "nanoslam_jax.app.study._timing",
        str(out / "configs" / f"{pt.point_id}.yaml"),
        "--json",
        str(js),
        "--repeats",
        str(spec.timing.repeats),
        "--budget-s",
        str(spec.timing.budget_s),
    ]
    cmd += ["--data", data_dir] if data_dir else []
    cmd += ["--segments", str(spec.segments)] if spec.segments else []
    cmd += ["--cache", cache] if cache else []
    row = {"point_id": pt.point_id, "method": pt.label, "particles": pt.particles, "seed": pt.seeds[0]}
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    if proc.returncode != 0 or not js.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()
        return {
            **row,
            "status": "failed",
            "reason": f"timing process exit {proc.returncode}: {tail[-1] if tail else ''}",
        }
    t = json.loads(js.read_text())
    return {
        **row,
        "status": "ok",
        "reason": "",
        **{k: t[k] for k in TIMING_FIELDS},
        "runs_s": ";".join(f"{x:.4f}" for x in t["runs_s"]),
    }


def _write_study_yaml(out: Path, spec: StudySpec, points: list[StudyPoint], resume: bool) -> list[dict]:
    """Write ``study.yaml``; returns the points the directory holds (a resumed study keeps the
    points of its earlier runs that this one does not name, e.g. with ``--methods``)."""
    from nanoslam_jax.app.experiment import versions

    now = [
        {
            "point_id": p.point_id,
            "method": p.label,
            "filter_method": p.method,
            "particles": p.particles,
            "first_seed": p.seeds[0],
            "n_seeds": len(p.seeds),
        }
        for p in points
    ]
    old = ((yaml.safe_load((out / "study.yaml").read_text()) or {}).get("points") or []) if resume else []
    ids = {p["point_id"] for p in now}
    held = [p for p in old if p["point_id"] not in ids] + now
    d = {
        "name": spec.name,
        "source": spec.source,
        "quick": spec.quick,
        "base": spec.base,
        "set": list(spec.set),
        "first_seed": spec.first_seed,
        "segments": spec.segments,
        "timing": dataclasses.asdict(spec.timing),
        "run": dict(spec.run),
        "paired": None if spec.paired is None else dataclasses.asdict(spec.paired),
        "points": held,
        "versions": versions(),
        "command": " ".join(sys.argv),
        "written": _dt.datetime.now().isoformat(timespec="seconds"),
    }
    (out / "study.yaml").write_text(f"# nanoslam-jax {__version__} study\n" + yaml.safe_dump(d, sort_keys=False))
    return held


def _prepare_study_dir(out: Path, spec: StudySpec, points: list[StudyPoint], resume: bool) -> list[dict]:
    """Create the study directory, write ``study.yaml`` and the config of each point's timing
    process (its first seed); returns the points the directory holds (see ``_write_study_yaml``)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "configs").mkdir(exist_ok=True)
    held = _write_study_yaml(out, spec, points, resume)
    for pt in points:
        cfg = config_to_dict(pt.config) | {"seed": pt.seeds[0]}
        (out / "configs" / f"{pt.point_id}.yaml").write_text(
            f"# study {spec.name}: {pt.label}, {pt.particles or 'no'} particles, seeds {pt.seeds[0]}..{pt.seeds[-1]}\n"
            + yaml.safe_dump(cfg, sort_keys=False)
        )
    return held


def _open_timing_file(out: Path) -> ResultsFile:
    """``timing.csv`` of the study, created, or repaired when it exists (a resumed study)."""
    from nanoslam_jax.app.sweep import ResultsFile

    timing_file = ResultsFile(out / "timing.csv", _TIMING_COLUMNS)
    if (out / "timing.csv").exists():
        timing_file.repair()
    else:
        timing_file.create()
    return timing_file


def _setup_sweep_devices(spec: StudySpec, first: StudyPoint, parallel: Optional[str]) -> None:
    """Set up the JAX CPU devices of the sweep runner's ``devices`` mode, when the study uses it
    (the ``run`` options of the point ``first``, and ``parallel``)."""
    from nanoslam_jax.app._devices import SWEEP_DEVICES_PER_CORE, setup_devices
    from nanoslam_jax.app.sweep import resolve_parallel, sweep_from_dict

    opts = sweep_from_dict(point_sweep_dict(spec, first), source=spec.source).run
    mode, workers = resolve_parallel(parallel or opts.parallel, opts.workers)
    if mode == "devices" and opts.backend == "local":
        setup_devices(workers * SWEEP_DEVICES_PER_CORE)


def _plot_study(out: Path, spec: StudySpec, summary: list, floor: Optional[dict], say) -> None:
    """Draw ``accuracy_vs_compute.png``; a failure is reported with ``say``, never raised."""
    from nanoslam_jax.app.study._plots import plot_accuracy_vs_compute

    try:
        plot_accuracy_vs_compute(
            out / "accuracy_vs_compute.png", summary, floor=floor, title=f"{spec.name}: {Path(spec.source).name}"
        )
    except Exception as e:  # the figure must never lose a study
        say(f"figure failed: {type(e).__name__}: {e}")


@in_float64
def run_study(
    spec: StudySpec,
    out_dir: str | Path,
    *,
    resume: bool = False,
    data_dir: Optional[str] = None,
    plots: bool = True,
    progress: bool = True,
    stream=sys.stderr,
    parallel: Optional[str] = None,
) -> StudyResult:
    """Run (or resume) a study and write its directory (see the module docstring).

    Args:
        spec: the study (:func:`~nanoslam_jax.app.study.load_study`).
        out_dir: the study directory (created).
        resume: continue the study in ``out_dir``: finished points are reused, unfinished ones
            continue, new points (a method added to the file) run. A point whose settings changed
            is an error naming it.
        data_dir: log directory overriding ``data.path``.
        plots: write the figure.
        progress: report progress on ``stream``.
        stream: where progress goes.
        parallel: the sweep runner's ``parallel`` option (default: the study's ``run.parallel``).

    Raises:
        ConfigError: ``out_dir`` holds a study already (without ``resume``), or none (with it).
    """
    from nanoslam_jax.lib._cache import enable_compile_cache
    from nanoslam_jax.app.sweep import SweepOverrides, read_results, run_sweep, sweep_from_dict

    out = Path(out_dir)
    if resume and not (out / "study.yaml").is_file():
        raise ConfigError(f"{out}: no study to resume here (study.yaml not found)")
    if not resume and (out / "study.yaml").exists():
        raise ConfigError(f"{out}: holds a study already; pass --resume to continue it, or choose another --out")
    points = expand_study(spec)
    held = _prepare_study_dir(out, spec, points, resume)
    # The cache the command set up (the user's, or $NANOSLAM_CACHE_DIR; none with --no-cache) serves
    # the timing processes too; without one, the study keeps its programs in OUT/jax_cache.
    cache = enable_compile_cache(out / "jax_cache") if dict(spec.run).get("compile_cache", True) else None
    timing_file = _open_timing_file(out)
    say = (lambda text: _say(stream, text)) if progress else (lambda text: None)  # noqa: E731

    if points:  # the sweep runner's JAX devices, set up before any point (some run as one process)
        _setup_sweep_devices(spec, points[0], parallel)

    t_start = time.perf_counter()
    for k, pt in enumerate(points):
        what = f"{pt.label}, " + (
            f"{pt.particles} particles, {len(pt.seeds)} seeds" if pt.particles else "deterministic"
        )
        sweep_dir = out / "runs" / pt.point_id
        sweep = sweep_from_dict(point_sweep_dict(spec, pt), source=f"{spec.source}: {pt.point_id}")
        if _sweep_done(sweep_dir, sweep, pt):
            say(f"[{k + 1}/{len(points)}] {what}: runs finished before")
        else:
            say(f"[{k + 1}/{len(points)}] {what}: accuracy runs")
            # One run (a deterministic method) in one process: a batch split over the devices
            # would be padded with copies of it.
            run_sweep(
                sweep,
                sweep_dir,
                resume=(sweep_dir / "sweep.yaml").is_file(),
                data_dir=data_dir,
                progress=progress,
                stream=stream,
                overrides=SweepOverrides(parallel=parallel or ("single" if len(pt.seeds) == 1 else None)),
            )
        timed = {r["point_id"]: r for r in read_results(out / "timing.csv", key="point_id")}
        if timed.get(pt.point_id, {}).get("status") == "ok":
            say(f"    seconds per log measured before: {number(timed[pt.point_id]['seconds_per_log']):.3f}")
        else:
            row = _time_point(spec, pt, out, data_dir, cache)
            timing_file.append([row])
            say(
                f"    seconds per log: {format_number(row.get('seconds_per_log'))} ({row.get('timing_runs', 0)} timed runs)"
                if row["status"] == "ok"
                else f"    timing failed: {row['reason']}"
            )
        write_tables(out, spec, held)
        say(f"    {time.perf_counter() - t_start:.0f} s elapsed")

    summary, paired = write_tables(out, spec, held)
    floor = _gps_floor(out, spec, points, data_dir, say)
    if plots:
        _plot_study(out, spec, summary, floor, say)
    runs = _collect_runs(out, held)
    timing_rows = read_results(out / "timing.csv", key="point_id")
    n_failed = sum(r["status"] != "ok" for r in runs) + sum(r["status"] != "ok" for r in timing_rows)
    return StudyResult(out, summary, paired, n_failed)


def _collect_runs(out: Path, points: list[dict]) -> list[dict]:
    """Every run's row (from the points' sweeps) with the point's identity and timing columns."""
    from nanoslam_jax.app.sweep import METRIC_KEYS, read_results

    timed = {r["point_id"]: r for r in read_results(out / "timing.csv", key="point_id") if r["status"] == "ok"}
    rows = []
    for pt in points:
        for r in read_results(out / "runs" / pt["point_id"] / "results.csv"):
            row = {
                "point_id": pt["point_id"],
                "method": pt["method"],
                "filter_method": pt["filter_method"],
                "particles": pt["particles"],
                "seed": int(r["seed"]),
                "status": r["status"],
                "reason": r["reason"],
                **{m: r.get(m, "") for m in METRIC_KEYS},
                "batch_s_per_run": r.get("run_s", ""),
            }
            t = timed.get(pt["point_id"], {})
            row.update({k: t.get(k, "") for k in TIMING_FIELDS if k not in ("compile_s", "peak_rss_mb")})
            rows.append(row)
    return rows


def write_tables(out: Path, spec: StudySpec, points: list[dict]) -> tuple[list, list]:
    """Write ``runs.csv``, ``summary.csv/.md`` and ``paired.csv/.md`` from what ``out`` holds.

    Args:
        out: the study directory.
        spec: the study (titles, timing rule, paired comparison).
        points: the points to tabulate: ``point_id``, ``method`` (label), ``filter_method`` and
            ``particles`` of each (the ``points`` of ``study.yaml``).
    """
    from nanoslam_jax.app.sweep import read_results

    runs = _collect_runs(out, points)
    timing = {}
    for r in read_results(out / "timing.csv", key="point_id"):
        if r["status"] == "ok":
            timing[(r["method"], None if r["particles"] == "" else int(r["particles"]))] = {
                k: number(r[k]) for k in TIMING_FIELDS
            }
    if runs:
        write_rows_csv(out / "runs.csv", runs)
    summary = summarize_points(runs, STUDY_METRICS, timing)
    if summary:
        write_rows_csv(out / "summary.csv", summary)
    (out / "summary.md").write_text(_summary_markdown(spec, points, summary))
    paired = _paired_rows(spec, runs, summary)
    if paired:
        write_rows_csv(out / "paired.csv", paired)
    else:
        (out / "paired.csv").unlink(missing_ok=True)  # never one left from an earlier state of the study
    (out / "paired.md").write_text(_paired_markdown(spec, paired))
    return summary, paired


def _paired_rows(spec: StudySpec, runs: list[dict], summary: list[dict]) -> list[dict]:
    p = spec.paired
    if p is None:
        return []
    counts = sorted({s["particles"] for s in summary if s["method"] == p.reference and s["particles"] is not None})
    rows = []
    for n in counts:
        for other in p.against:
            if not any(s["method"] == other and s["particles"] == n for s in summary):
                continue
            for m in p.metrics:
                row = paired_comparison(
                    runs,
                    p.reference,
                    other,
                    n,
                    m,
                    n_resamples=p.bootstrap,
                    confidence=p.confidence,
                    seed=p.bootstrap_seed,
                )
                eq = equal_time(summary, p.reference, other, n, m)
                row.update(
                    seconds_ref=eq["seconds"],
                    median_other_at_time=eq["median_other_at_time"],
                    diff_at_time=eq["diff"],
                    bracket_at_time=eq["bracket"],
                )
                rows.append(row)
    return rows


def _summary_markdown(spec: StudySpec, points: list[dict], summary: list[dict]) -> str:
    seg = f"the first {spec.segments} segments of the log" if spec.segments else "the whole log"
    lines = [
        f"# {spec.name}",
        "",
        f"{len(points)} points over {seg}. Errors in metres against GPS: median [q1, q3], worst seed (a failed "
        f"run counts as inf). `s/log` is the median time of one run of the point's first seed alone over "
        f"{seg}, after compilation, in a fresh process set up as `nanoslam run` is ({spec.timing.repeats} runs at "
        f"most, none started past {spec.timing.budget_s:g} s), not a batch's time per run.",
        "",
        "| method | particles | seeds (ok) | rmse_fixed median [IQR] | worst | rmse_aligned median [IQR] | worst | "
        "landmarks | s/log |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in sorted(summary, key=lambda s: (s["method"], s["particles"] or 0)):

        def cell(m):
            return f"{format_number(s[m + '_median'])} [{format_number(s[m + '_q1'])}, {format_number(s[m + '_q3'])}]"

        lines.append(
            f"| {s['method']} | {s['particles'] or '-'} | {s['seeds']} ({s['n_ok']}) | {cell('rmse_fixed')} | "
            f"{format_number(s['rmse_fixed_worst'])} | {cell('rmse_aligned')} | {format_number(s['rmse_aligned_worst'])} | "
            f"{format_number(s['n_landmarks_median'], 0)} | {format_number(s.get('seconds_per_log'), 2)} |"
        )
    return "\n".join(lines) + "\n"


def _paired_markdown(spec: StudySpec, rows: list[dict]) -> str:
    if not rows:
        return f"# {spec.name}: paired comparison\n\nNone configured (or the compared points have not run yet).\n"
    p = spec.paired
    assert p is not None  # rows come only from a paired spec
    lines = [
        f"# {spec.name}: {p.reference} against the others",
        "",
        f"Same particle count, same seeds: wins / losses / ties of {p.reference} (lower error), the exact "
        f"two-sided sign test's p, the median of the paired differences {p.reference} - other with its "
        f"{100 * p.confidence:g} % bootstrap interval ({p.bootstrap} resamples), and the two medians. "
        f"Equal time: the other's median error interpolated in log(seconds per log) at {p.reference}'s seconds "
        f"per log (blank outside the other's measured range), and the difference.",
        "",
        "| particles | against | metric | W/L/T | sign p | median diff [CI] | medians | s/log | other at equal time | diff at equal time |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        at = math.isfinite(r["median_other_at_time"])
        other_at = f"{format_number(r['median_other_at_time'])} (N {r['bracket_at_time']})" if at else ""
        lines.append(
            f"| {r['particles']} | {r['other']} | {r['metric']} | {r['wins']}/{r['losses']}/{r['ties']} | "
            f"{format_number(r['sign_p'])} | {format_number(r['median_diff'])} [{format_number(r['diff_low'])}, {format_number(r['diff_high'])}] | "
            f"{format_number(r['median_ref'])} vs {format_number(r['median_other'])} | {format_number(r['seconds_ref'], 2)} | {other_at} | "
            f"{format_number(r['diff_at_time']) if at else ''} |"
        )
    return "\n".join(lines) + "\n"


def _gps_floor(out: Path, spec: StudySpec, points: list[StudyPoint], data_dir: Optional[str], say) -> Optional[dict]:
    """The GPS floor over the study's span (real logs only: a simulated log's GPS is the truth)."""
    from nanoslam_jax.eval.gps_floor import floor_markdown, gps_floor_of_log
    from nanoslam_jax.app._models import motion_model_from_config
    from nanoslam_jax.app.sweep import load_log_data

    cfg = points[0].config
    if cfg.data.kind in ("simulated", "city"):
        return None
    try:
        log = load_log_data(cfg, data_dir, spec.segments)
        if log.frame != "relative":
            return None
        f = gps_floor_of_log(motion_model_from_config(cfg), cfg.metrics, log)
    except Exception as e:  # the floor must never lose a study
        say(f"gps floor failed: {type(e).__name__}: {e}")
        return None
    (out / "gps_floor.md").write_text(floor_markdown(f))
    d = dataclasses.asdict(f)
    (out / "gps_floor.json").write_text(json.dumps(d, indent=2) + "\n")
    return d
