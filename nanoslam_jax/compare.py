"""Method comparison over seeds: the paper's Table I and Figures 3-5.

A comparison file names a base config, the methods (each a label and ``key=value`` overrides
of the base, at least ``filter.method``), the number of seeds and optionally the paper's
figures to print beside ours::

    name: table1
    base: victoria_park_nano.yaml     # relative to this file; null: the embedded default
    seeds: 8
    first_seed: 0
    timing_chunk: 250                 # segments per timed chunk (Fig. 5 resolution)
    set: []                           # overrides applied to every method
    methods:
      - label: NANO-SLAM
        set: [filter.method=nano]
        paper_rmse: 2.538
        paper_ms: 17.692

For each method the seeds run vmapped in one compiled program (:func:`filter.run_batch`); a
separate single run of the first seed, timed chunk by chunk, gives the computation time per
scan (the table's ms per scan and Fig. 5). EKF-SLAM, NASRUKF and dead reckoning are deterministic
and run once. A method that fails (bad config, non-finite estimate, exception) is recorded with its
reason; the others still run.

Writes ``table1.md``, ``table1.csv`` (one row per method), ``runs.csv`` (one row per method and
seed), ``summary.json``, ``compare.yaml`` (the resolved comparison with the version), the resolved
config of each method under ``configs/``, and ``fig3_trajectories.png``, ``fig4_error.png``,
``fig5_time.png``.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as _dt
import json
import math
import sys
import time
import traceback
from pathlib import Path
from typing import Any, Optional

import jax
import numpy as np
import yaml

from ._version import __version__
from .config import Config, ConfigError, config_to_dict, load_config, read_yaml_mapping
from .filter import (dead_reckoning, reported_map, reported_trajectory, run_batch, run_filter,
                     settings_from_config, stack_params)

def deterministic(method: str) -> bool:
    """Whether a run of ``method`` does not depend on the seed (Gaussian methods, dead reckoning)."""
    from .methods import get_method

    return get_method(method).kind != "particle"

RMSE_KEYS = ("rmse_fixed", "rmse_aligned", "rmse_fixed_clean", "rmse_aligned_clean", "final_error")


@dataclasses.dataclass(frozen=True)
class MethodSpec:
    """One row of the comparison.

    Attributes:
        label: name in the table and figures.
        set: ``key=value`` overrides of the base config (at least ``filter.method``).
        paper_rmse: the paper's RMSE for this method (m), if it reports one.
        paper_ms: the paper's time per step (ms), if it reports one.
    """

    label: str
    set: tuple[str, ...]
    paper_rmse: Optional[float] = None
    paper_ms: Optional[float] = None


@dataclasses.dataclass(frozen=True)
class CompareSpec:
    """A comparison (see the module docstring for the YAML layout).

    Attributes:
        name: used in titles.
        base: base config path (resolved), or None for the embedded default.
        methods: the rows.
        seeds: seeds per method.
        first_seed: seeds are ``first_seed, ..., first_seed + seeds - 1``.
        timing_chunk: segments per timed chunk of the single timing run.
        set: overrides applied to every method before its own.
        source: the file this came from.
    """

    name: str
    base: Optional[str]
    methods: tuple[MethodSpec, ...]
    seeds: int = 8
    first_seed: int = 0
    timing_chunk: int = 250
    set: tuple[str, ...] = ()
    source: str = ""


_TOP = {"name", "base", "seeds", "first_seed", "timing_chunk", "set", "methods"}
_ROW = {"label", "set", "paper_rmse", "paper_ms"}


def _str_list(value: Any, key: str, where: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, dict):  # {filter.method: nano} is accepted too
        return tuple(f"{k}={v}" for k, v in value.items())
    if not isinstance(value, list) or not all(isinstance(v, str) and "=" in v for v in value):
        raise ConfigError(f"{where}: key '{key}': expected a list of 'key=value' strings, got {value!r}")
    return tuple(value)


def _int(value: Any, key: str, where: str, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < lo:
        raise ConfigError(f"{where}: key '{key}': expected an integer >= {lo}, got {value!r}")
    return value


def _number(value: Any, key: str, where: str) -> Optional[float]:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where}: key '{key}': expected a number, got {value!r}")
    return float(value)


def read_comparison(path: Path, allowed: set) -> dict:
    """A comparison (or study) file's top-level mapping, its keys checked against ``allowed``."""
    raw = read_yaml_mapping(path, "comparison")
    unknown = set(raw) - allowed
    if unknown:
        raise ConfigError(f"{path}: unknown key(s) {sorted(unknown)}; expected some of {sorted(allowed)}")
    return raw


def resolve_base(base: Any, path: Path) -> Optional[str]:
    """A comparison file's ``base``: a config path relative to the file (or absolute), or None.

    Raises:
        ConfigError: naming the file, when it is not a string or the config does not exist.
    """
    if base is None:
        return None
    if not isinstance(base, str):
        raise ConfigError(f"{path}: key 'base': expected a config path or null, got {base!r}")
    base_path = Path(base) if Path(base).is_absolute() else path.parent / base
    if not base_path.is_file():
        raise ConfigError(f"{path}: key 'base': config file {base_path} not found")
    return str(base_path)


def method_rows(rows: Any, where: str, allowed: set) -> list[tuple[str, dict, str, tuple[str, ...]]]:
    """A comparison file's ``methods``: ``(key, row, label, set)`` per row, checked.

    Args:
        rows: the ``methods`` value.
        where: the file, for messages.
        allowed: the keys a row may have (at least ``label`` and ``set``).

    Raises:
        ConfigError: naming the file and the row's key, for a missing or repeated label, an
            unknown key or a ``set`` that is not a list of ``key=value`` strings.
    """
    if not isinstance(rows, list) or not rows:
        raise ConfigError(f"{where}: key 'methods': expected a non-empty list of {{{', '.join(sorted(allowed))}}}")
    out = []
    for i, row in enumerate(rows):
        key = f"methods[{i}]"
        if not isinstance(row, dict):
            raise ConfigError(f"{where}: key '{key}': expected a mapping, got {row!r}")
        unknown = set(row) - allowed
        if unknown:
            raise ConfigError(f"{where}: key '{key}': unknown key(s) {sorted(unknown)}; expected some of {sorted(allowed)}")
        label = row.get("label")
        if not isinstance(label, str) or not label:
            raise ConfigError(f"{where}: key '{key}.label': expected a non-empty string, got {label!r}")
        out.append((key, row, label, _str_list(row.get("set"), f"{key}.set", where)))
    labels = [r[2] for r in out]
    if len(set(labels)) != len(labels):
        raise ConfigError(f"{where}: key 'methods': labels must be unique, got {labels}")
    return out


def load_compare_spec(path: str | Path, overrides: tuple[str, ...] = (), seeds: Optional[int] = None) -> CompareSpec:
    """Read and validate a comparison file.

    Args:
        path: the YAML file.
        overrides: ``key=value`` config overrides applied to every method (after the file's ``set``).
        seeds: overrides the file's ``seeds``.

    Raises:
        ConfigError: naming the file and key, for unknown keys, wrong types or method overrides
            that the config rejects.
    """
    p = Path(path)
    where = str(p)
    raw = read_comparison(p, _TOP)
    base = resolve_base(raw.get("base"), p)
    methods = [MethodSpec(label, sets, _number(row.get("paper_rmse"), f"{key}.paper_rmse", where),
                          _number(row.get("paper_ms"), f"{key}.paper_ms", where))
               for key, row, label, sets in method_rows(raw.get("methods"), where, _ROW)]
    spec = CompareSpec(
        name=str(raw.get("name", p.stem)), base=base, methods=tuple(methods),
        seeds=_int(seeds if seeds is not None else raw.get("seeds", 8), "seeds", where, 1),
        first_seed=_int(raw.get("first_seed", 0), "first_seed", where, 0),
        timing_chunk=_int(raw.get("timing_chunk", 250), "timing_chunk", where, 1),
        set=_str_list(raw.get("set"), "set", where) + tuple(overrides), source=where,
    )
    for m in spec.methods:  # validate every method's config now, before anything runs
        method_config(spec, m)
    return spec


def method_config(spec: CompareSpec, m: MethodSpec) -> Config:
    """The resolved config of one method: base, then the comparison's ``set``, then the method's."""
    try:
        cfg = load_config(spec.base, list(spec.set) + list(m.set))
    except ConfigError as e:
        raise ConfigError(f"{spec.source}: method {m.label!r}: {e}") from None
    if cfg.smoother.enabled:
        raise ConfigError(f"{spec.source}: method {m.label!r}: smoother.enabled is not available in comparisons, "
                          "which score the filters' own estimates; set it to false (nanoslam run and "
                          "experiments/accuracy.py score the smoothed path)")
    return dataclasses.replace(cfg, name=f"{spec.name}-{m.label}")


def _quartiles(v: np.ndarray) -> tuple[float, float, float]:
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (math.nan,) * 3
    q1, med, q3 = np.percentile(v, [25, 50, 75])
    return float(med), float(q1), float(q3)


def _evaluate(cfg: Config, log, est: np.ndarray) -> dict:
    from .metrics import evaluate

    t = np.asarray(log.segments.time)
    if not np.all(np.isfinite(est)) or not len(log.raw.gps):
        return {k: math.nan for k in RMSE_KEYS}
    m = evaluate(t, est[:, :2], log.raw.gps, rotation_deg=cfg.metrics.gps_rotation_deg,
                 jump_speed=cfg.metrics.jump_speed, frame=log.frame)
    return {k: float(m[k]) for k in RMSE_KEYS}


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


def run_method(spec: CompareSpec, m: MethodSpec, log, progress=None) -> MethodResult:
    """Run one method over the seeds (vmapped) and once more, timed, for the time per scan."""
    cfg = method_config(spec, m)
    method = cfg.filter.method
    seg = log.segments
    n = int(seg.time.shape[0])
    t = np.asarray(seg.time)
    static, params = settings_from_config(cfg, seg.k_max)
    res = MethodResult(m, method, rows=[])
    seeds = [spec.first_seed] if deterministic(method) else list(range(spec.first_seed, spec.first_seed + spec.seeds))

    if method == "dead_reckoning":
        t0 = time.perf_counter()
        jax.block_until_ready(dead_reckoning(params, seg))
        t1 = time.perf_counter()
        est = np.asarray(dead_reckoning(params, seg))
        res.ms_per_scan = 1e3 * (time.perf_counter() - t1) / n
        res.compile_s = t1 - t0
        res.trajectory = est
        res.rows.append({"seed": spec.first_seed, **_evaluate(cfg, log, est), "n_landmarks": 0, "n_confirmed": 0, "finite": bool(np.all(np.isfinite(est)))})
        return res

    # Timing: one run of the first seed, chunk by chunk.
    single = run_filter(static, params, seg, spec.first_seed, chunk=min(spec.timing_chunk, n), timed=True)
    res.compile_s = single.compile_s
    res.ms_per_scan = 1e3 * single.run_s / n
    sizes = np.minimum(single.chunk_size, n - single.chunk_size * np.arange(len(single.chunk_s)))
    res.chunk_ms = 1e3 * np.asarray(single.chunk_s) / sizes
    mids = np.minimum(single.chunk_size * np.arange(len(sizes)) + sizes // 2, n - 1)
    res.chunk_t = t[mids]

    if len(seeds) == 1:
        maps = jax.tree.map(lambda a: np.asarray(a)[None], reported_map(single.state))
        overflow = np.asarray(single.state.overflow)[None]
        est_all = reported_trajectory(static.estimate, single.outputs, single.state)[None]
        res.batch_run_s = single.run_s
    else:
        batch = run_batch(static, stack_params([params] * len(seeds)), seg, np.asarray(seeds), chunk=cfg.output.chunk,
                          progress=progress)
        maps = jax.tree.map(np.asarray, jax.vmap(reported_map)(batch.state))
        overflow = np.asarray(batch.state.overflow)
        est_all = reported_trajectory(static.estimate, batch.outputs, batch.state)
        res.batch_run_s = batch.run_s
    for i, s in enumerate(seeds):
        est = est_all[i]
        finite = bool(np.all(np.isfinite(est)))
        res.rows.append({"seed": int(s), **_evaluate(cfg, log, est), "n_landmarks": int(maps.active[i].sum()),
                         "n_confirmed": int((maps.active[i] & maps.confirmed[i]).sum()),
                         "landmark_overflow": int(overflow[i]), "finite": finite})
    res.trajectory = est_all[0]
    res.landmarks = maps.mean[0][maps.active[0] & maps.confirmed[0]]
    bad = [r["seed"] for r in res.rows if not r["finite"]]
    if bad:
        res.status, res.reason = "failed", f"non-finite estimate for seed(s) {bad}"
    return res


def summarise(res: MethodResult) -> dict:
    """One table row: medians and quartiles over seeds."""
    out: dict[str, Any] = {"method": res.spec.label, "filter_method": res.method, "status": res.status,
                           "reason": res.reason, "seeds": len(res.rows)}
    for k in ("rmse_fixed", "rmse_aligned", "rmse_fixed_clean", "rmse_aligned_clean", "n_landmarks", "n_confirmed"):
        med, q1, q3 = _quartiles(np.array([r.get(k, math.nan) for r in res.rows], float))
        out.update({f"{k}_median": med, f"{k}_q1": q1, f"{k}_q3": q3})
    out.update(ms_per_scan=res.ms_per_scan, compile_s=res.compile_s, batch_run_s=res.batch_run_s,
               paper_rmse=res.spec.paper_rmse, paper_ms=res.spec.paper_ms)
    return out


def _fmt(v: Any, nd: int = 3) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "nan" if not math.isfinite(v) else f"{v:.{nd}f}"
    return str(v)


def markdown_table(rows: list[dict]) -> str:
    """The Table I layout: RMSE (median and IQR over seeds), ms per scan, landmarks, paper's figures."""
    lines = ["| method | seeds | RMSE fixed [m] median (IQR) | RMSE aligned [m] median (IQR) | ms per scan | confirmed landmarks | paper RMSE [m] | paper ms per step |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["status"] != "ok" and not math.isfinite(r.get("rmse_fixed_median", math.nan)):
            lines.append(f"| {r['method']} | {r['seeds']} | failed: {r['reason']} | | | | {_fmt(r['paper_rmse'])} | {_fmt(r['paper_ms'], 2)} |")
            continue
        iqr = lambda k: f"{_fmt(r[k + '_median'])} ({_fmt(r[k + '_q1'])}-{_fmt(r[k + '_q3'])})"  # noqa: E731
        lines.append(f"| {r['method']} | {r['seeds']} | {iqr('rmse_fixed')} | {iqr('rmse_aligned')} | "
                     f"{_fmt(r['ms_per_scan'], 2)} | {_fmt(r['n_confirmed_median'], 0)} | {_fmt(r['paper_rmse'])} | {_fmt(r['paper_ms'], 2)} |")
    return "\n".join(lines) + "\n"


def _write_csv(path: Path, rows: list[dict]) -> None:
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in keys]
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in keys})


def run_compare(spec: CompareSpec, out_dir: str | Path, data_dir: Optional[str] = None, plots: bool = True,
                stream=sys.stderr) -> list[dict]:
    """Run every method of ``spec`` and write the comparison directory.

    Args:
        spec: the comparison.
        out_dir: result directory (created).
        data_dir: log directory overriding ``data.path``.
        plots: draw Figures 3-5.
        stream: where progress lines go.

    Returns:
        The table rows (also in ``table1.csv``).
    """
    from .experiment import load_log, versions

    out = Path(out_dir)
    configs = {m.label: method_config(spec, m) for m in spec.methods}
    logs: dict[str, Any] = {}
    first = next(iter(configs.values()))
    key_of = lambda c: json.dumps([config_to_dict(c)[k] for k in ("data", "sim", "vehicle", "detector")],  # noqa: E731
                                  sort_keys=True)
    logs[key_of(first)] = load_log(first, data_dir)  # a bad log fails before anything is written
    if not len(logs[key_of(first)].raw.gps):
        raise ConfigError(f"{spec.source}: compare scores the trajectories against GPS, and the log "
                          f"{logs[key_of(first)].source} has none; score its map with `nanoslam sweep` "
                          f"(metric: survey_rmse) or `nanoslam run`")
    out.mkdir(parents=True, exist_ok=True)
    (out / "configs").mkdir(exist_ok=True)
    resolved = {"name": spec.name, "base": spec.base, "seeds": spec.seeds, "first_seed": spec.first_seed,
                "timing_chunk": spec.timing_chunk, "set": list(spec.set),
                "methods": [dataclasses.asdict(m) | {"set": list(m.set)} for m in spec.methods],
                "version": __version__, "versions": versions(), "source": spec.source,
                "written": _dt.datetime.now().isoformat(timespec="seconds")}
    (out / "compare.yaml").write_text(yaml.safe_dump(resolved, sort_keys=False))

    results: list[MethodResult] = []
    for i, m in enumerate(spec.methods):
        cfg = configs[m.label]
        safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in m.label)
        (out / "configs" / f"{safe}.yaml").write_text(
            f"# nanoslam-jax {__version__}, seeds {spec.first_seed}..{spec.first_seed + spec.seeds - 1}\n"
            + yaml.safe_dump(config_to_dict(cfg), sort_keys=False))
        stream.write(f"[{i + 1}/{len(spec.methods)}] {m.label} ({cfg.filter.method})\n")
        stream.flush()
        t0 = time.perf_counter()
        try:
            k = key_of(cfg)
            if k not in logs:
                logs[k] = load_log(cfg, data_dir)
            res = run_method(spec, m, logs[k])
        except Exception as e:  # recorded, the comparison goes on
            res = MethodResult(m, cfg.filter.method, rows=[], status="failed", reason=f"{type(e).__name__}: {e}")
            (out / f"error-{safe}.txt").write_text(traceback.format_exc())
        results.append(res)
        r = summarise(res)
        stream.write(f"    {res.status} in {time.perf_counter() - t0:.1f} s: rmse_fixed {_fmt(r['rmse_fixed_median'])}, "
                     f"rmse_aligned {_fmt(r['rmse_aligned_median'])}, {_fmt(res.ms_per_scan, 2)} ms/scan\n")
        stream.flush()
        # Written after every method: an interrupted comparison keeps what it finished.
        _write_outputs(out, spec, results)

    if plots:
        _figures(out, spec, results, logs, configs)
    return [summarise(r) for r in results]


def _write_outputs(out: Path, spec: CompareSpec, results: list[MethodResult]) -> None:
    table = [summarise(r) for r in results]
    _write_csv(out / "table1.csv", table)
    runs = [{"method": r.spec.label, "filter_method": r.method, **row} for r in results for row in r.rows]
    if runs:
        _write_csv(out / "runs.csv", runs)
    header = (f"# {spec.name}: {len(spec.methods)} methods, {spec.seeds} seeds "
              f"({spec.first_seed}..{spec.first_seed + spec.seeds - 1}; EKF-SLAM, NASRUKF and dead reckoning are deterministic: one run)\n\n")
    (out / "table1.md").write_text(header + markdown_table(table))
    safe = lambda v: None if isinstance(v, float) and not math.isfinite(v) else v  # noqa: E731
    (out / "summary.json").write_text(json.dumps([{k: safe(v) for k, v in row.items()} for row in table], indent=2) + "\n")


def _figures(out: Path, spec: CompareSpec, results: list[MethodResult], logs: dict, configs: dict) -> None:
    from .metrics import error_over_time, jump_mask, relative_gps
    from .plotting import plot_series, plot_trajectory_grid

    ok = [r for r in results if r.trajectory is not None and np.all(np.isfinite(r.trajectory))]
    if not ok:
        return
    cfg = configs[ok[0].spec.label]
    log = next(iter(logs.values()))
    gps = log.raw.gps
    t = np.asarray(log.segments.time)
    ref = relative_gps(gps[:, 1:3], cfg.metrics.gps_rotation_deg) if log.frame == "relative" else gps[:, 1:3]
    ref_label = "GPS (relative frame)" if log.frame == "relative" else "truth"
    plot_trajectory_grid(out / "fig3_trajectories.png", ref, [(r.spec.label, r.trajectory[:, :2], r.landmarks) for r in ok],
                         true_landmarks=log.raw.truth_landmarks, reference_label=ref_label,
                         title=f"{spec.name}: seed {spec.first_seed}")
    series = []
    keep = jump_mask(gps[:, 0], gps[:, 1:3], cfg.metrics.jump_speed)  # GPS jumps would dwarf the errors
    for r in ok:
        te, err = error_over_time(t, r.trajectory[:, :2], gps[keep], rotation_deg=cfg.metrics.gps_rotation_deg, frame=log.frame)
        series.append((r.spec.label, te, err))
    plot_series(out / "fig4_error.png", series, "position error [m]",
                f"{spec.name}: error against {ref_label}, GPS jumps removed (seed {spec.first_seed})")
    timed = [(r.spec.label, r.chunk_t, r.chunk_ms) for r in results if r.chunk_ms is not None]
    if timed:
        plot_series(out / "fig5_time.png", timed, "computation time per scan [ms]",
                    f"{spec.name}: time per scan (mean over chunks of {spec.timing_chunk} scans)", logy=True, marker=".")
