"""The ``nanoslam`` command line.

    nanoslam run [CONFIG] [--out DIR [--overwrite]] [--data DIR] [--set key=value ...]
    nanoslam config [CONFIG] [--set key=value ...]
    nanoslam simulate --out DIR [--seed S] [--config CONFIG] [--laser] [--set sim.key=value ...]
    nanoslam simulate --scenario city --out DIR [--seed S] [--set city.key=value ...] [--set sim.key=value ...]
    nanoslam simulate --scenario indoor --out DIR [--seed S] [--set indoor.key=value ...]
    nanoslam compare COMPARISON [--out DIR] [--data DIR] [--seeds S] [--set key=value ...]
                     [--quick] [--resume] [--methods LABEL ...] [--particles N ...]
                     [--parallel MODE]   (study files)
    nanoslam detect [CONFIG] --out DIR [--data DIR] [--plot SCANS] [--set detector.key=value ...]
    nanoslam sweep SWEEP [--out DIR] [--resume] [--data DIR] [--set key=value ...] [--backend local|ray]
    nanoslam --version

Every command that computes keeps its compiled programs in the persistent compilation cache
(:func:`nanoslam_jax.enable_compile_cache`: ``$NANOSLAM_CACHE_DIR``, else the user cache
directory), so a second run of the same shapes loads them instead of compiling; ``--no-cache``
turns it off for one command.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Optional, Sequence

from nanoslam_jax._version import __version__
from nanoslam_jax.app.config import ConfigError, load_config
from nanoslam_jax.lib._precision import in_float64


def _cache_flag() -> argparse.ArgumentParser:
    """The ``--no-cache`` option every computing subcommand takes."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument(
        "--no-cache",
        action="store_true",
        help="do not use the persistent compilation cache ($NANOSLAM_CACHE_DIR, else the user cache "
        "directory): compile every program afresh and keep nothing",
    )
    return p


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="nanoslam", description="Landmark SLAM with Rao-Blackwellised particle filters (JAX)."
    )
    p.add_argument("--version", action="version", version=f"nanoslam-jax {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    cache = _cache_flag()

    r = sub.add_parser("run", parents=[cache], help="run one method on a log and write a result directory")
    r.add_argument(
        "config",
        nargs="?",
        help="YAML config (default: NANO-SLAM on a simulated log; with --data, on that directory "
        "read as a Victoria Park-format log)",
    )
    r.add_argument(
        "--out",
        help="result directory (default: results/<config-name>-<timestamp>); checked before the run: "
        "it must not exist or be empty, unless --overwrite",
    )
    r.add_argument(
        "--overwrite",
        action="store_true",
        help="let --out be an earlier run's result directory (config.yaml and metrics.json): its files "
        "are deleted once the new run has finished, before the new ones are written",
    )
    r.add_argument("--data", help="log directory (overrides data.path and $NANOSLAM_DATA)")
    r.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key, e.g. --set filter.n_particles=20 (repeatable)",
    )
    r.add_argument("--quiet", action="store_true", help="no progress indicator and no compile messages")

    g = sub.add_parser(
        "config",
        help="print the resolved configuration with each key's meaning, type and range",
        description="Print the configuration a run would use (the file, its bases and the --set "
        "overrides resolved) as YAML, each key preceded by its meaning, type, range, "
        "whether it is static (recompiles) or traced (sweepable), and its default.",
    )
    g.add_argument("config", nargs="?", help="YAML config (default: the embedded default)")
    g.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key, e.g. --set filter.n_particles=20 (repeatable)",
    )

    s = sub.add_parser("simulate", parents=[cache], help="write a simulated Victoria Park-format log with ground truth")
    s.add_argument(
        "--out", required=True, help="directory to write inputs.dat, measurements.dat, gps.dat and truth files"
    )
    s.add_argument("--seed", type=int, help="simulation seed (sim.seed)")
    s.add_argument("--config", help="YAML config whose sim and vehicle sections are used")
    s.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key, e.g. --set sim.n_trees=200 (repeatable)",
    )
    s.add_argument(
        "--laser",
        action="store_true",
        help="also ray-cast raw scans (sim.laser_* keys: walls, fences, bushes, noise) and write LASER.txt, "
        "laser_truth.csv (which trees each scan hit, with how many beams) and laser_world.csv",
    )
    s.add_argument(
        "--scenario",
        choices=["park", "city", "indoor"],
        default="park",
        help="'park': the Victoria Park-like log (section sim); 'city': a drive of city.distance_m (20 km) "
        "through a street grid of about 10,000 trees and lamp posts, with the park's sensor and noise (sections "
        "city and sim, --seed sets city.seed; docs/simulate_city.md); 'indoor': rooms or corridors with walls, "
        "corners, doors and pillars, a low-speed differential-drive vehicle, raw scans and the truth "
        "of every line, arc, corner and break point (section indoor, --seed sets indoor.seed; "
        "docs/simulate_indoor.md)",
    )

    d = sub.add_parser(
        "detect",
        help="detect trees (and lines, circles, corners, break points) in a log's raw "
        "laser scans and write a complete log",
        description="Read the raw scans of --data (LASER.txt or aa3_lsr2.mat), extract their features "
        "with the config's detector section and write --out: measurements.dat (the trees, "
        "the dataset's format), inputs.dat and gps.dat (copied) and features.csv.",
    )
    d.add_argument("config", nargs="?", help="YAML config whose detector section is used (default: its defaults)")
    d.add_argument("--data", help="log directory with raw scans (overrides data.path and $NANOSLAM_DATA)")
    d.add_argument("--out", required=True, help="directory to write the detected log to")
    d.add_argument("--plot", metavar="SCANS", help="also draw these scans (0-based, e.g. 100,250-252) to OUT/scans/")
    d.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key, e.g. --set detector.split_distance=0.1 (repeatable)",
    )
    d.add_argument("--quiet", action="store_true", help="no progress bar")

    c = sub.add_parser(
        "compare",
        parents=[cache],
        help="run several methods over seeds: Table I (Markdown, CSV) and Figures 3-5; "
        "or, for a study file, over particle counts: accuracy against compute",
    )
    c.add_argument(
        "comparison",
        help="comparison YAML, e.g. configs/table1.yaml, or a study file (one with a "
        "'particles' section), e.g. configs/accuracy_vs_compute.yaml",
    )
    c.add_argument("--out", help="result directory (default: results/<name>-<timestamp>)")
    c.add_argument("--data", help="log directory (overrides data.path and $NANOSLAM_DATA)")
    c.add_argument("--seeds", type=int, help="seeds per method (overrides the file's seeds)")
    c.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config key for every method (repeatable)",
    )
    c.add_argument("--no-plots", action="store_true", help="skip Figures 3-5 (a study: its figure)")
    c.add_argument("--quiet", action="store_true", help="no compile messages on stderr")
    c.add_argument("--quick", action="store_true", help="study files: run the file's 'quick' variant")
    c.add_argument("--resume", action="store_true", help="study files: continue the study in --out")
    c.add_argument("--methods", nargs="+", metavar="LABEL", help="study files: run only these methods (labels)")
    c.add_argument(
        "--particles",
        nargs="+",
        type=int,
        metavar="N",
        help="study files: run only these particle counts (of the file's)",
    )
    c.add_argument(
        "--parallel",
        choices=["auto", "single", "devices", "processes"],
        help="study files: how the sweep runner uses several cores (default: the file's run.parallel)",
    )
    from nanoslam_jax.app.sweep._cli import add_sweep_parser

    add_sweep_parser(sub, parents=[cache])
    return p


def _compare(args) -> int:
    import datetime as _dt

    from nanoslam_jax.app.compare import load_compare_spec, run_compare
    from nanoslam_jax.app.study import is_study_file

    if is_study_file(args.comparison):
        return _study(args)
    for flag in ("quick", "resume", "parallel", "methods", "particles"):
        if getattr(args, flag):
            raise ConfigError(f"{args.comparison}: --{flag} applies to study files (with a 'particles' section) only")
    spec = load_compare_spec(args.comparison, tuple(args.overrides), seeds=args.seeds)
    out = Path(args.out) if args.out else Path("results") / f"{spec.name}-{_dt.datetime.now():%Y%m%d-%H%M%S}"
    rows = run_compare(spec, out, data_dir=args.data, plots=not args.no_plots)
    print((out / "table1.md").read_text())
    print(out)
    return 0 if all(r["status"] == "ok" for r in rows) else 1


def _study_flags(args) -> str:
    """The flags that chose the study's points, as the command line gave them."""
    flags = " --quick" if args.quick else ""
    if args.seeds is not None:
        flags += f" --seeds {args.seeds}"
    if args.methods:
        flags += " --methods " + " ".join(repr(m) if " " in m else m for m in args.methods)
    if args.particles:
        flags += " --particles " + " ".join(map(str, args.particles))
    return flags


def _study(args) -> int:
    import datetime as _dt

    from nanoslam_jax.app.study import load_study, run_study

    spec = load_study(
        args.comparison,
        tuple(args.overrides),
        quick=args.quick,
        seeds=args.seeds,
        only=args.methods,
        counts=args.particles,
    )
    if args.resume and not args.out:
        raise ConfigError("--resume needs --out DIR (the study directory to continue)")
    out = Path(args.out) if args.out else Path("results") / f"{spec.name}-{_dt.datetime.now():%Y%m%d-%H%M%S}"
    try:
        res = run_study(
            spec, out, resume=args.resume, data_dir=args.data, plots=not args.no_plots, parallel=args.parallel
        )
    except KeyboardInterrupt:
        print(
            f"\nnanoslam: study interrupted; finished batches are saved in {out}; continue with:\n"
            f"  nanoslam compare {args.comparison}{_study_flags(args)} --out {out} --resume",
            file=sys.stderr,
        )
        return 130
    print((out / "summary.md").read_text())
    print((out / "paired.md").read_text())
    if (out / "gps_floor.md").is_file():
        print((out / "gps_floor.md").read_text())
    print(out)
    return 0 if res.n_failed == 0 else 1


def _sweep(args) -> int:
    from nanoslam_jax.app.sweep._cli import sweep_command

    return sweep_command(args)


def _log_kind_overrides(data: str) -> list[str]:
    """The ``data`` keys that read ``--data DIR`` as a log when ``run`` is given no config.

    A directory holding ``inputs.dat`` or ``aa3_dr.mat`` (a Victoria Park-format log) is read with
    ``data.kind: victoria_park`` and ``data.format: auto``; any other directory (an MRCLAM dataset,
    an indoor log, no known log) is refused with the config keys it needs.
    """
    d = Path(data).expanduser()
    if not d.is_dir():
        return ["data.kind=victoria_park"]  # resolve_data_dir names the missing directory
    if (d / "Barcodes.dat").is_file():
        raise ConfigError(
            f"--data {data}: an MRCLAM dataset (Barcodes.dat) and no config; give one with data.format: mrclam "
            "and model.motion: unicycle, e.g. nanoslam run configs/mrclam.yaml --data DIR"
        )
    if (d / "truth_walls.csv").is_file():
        raise ConfigError(
            f"--data {data}: an indoor log (truth_walls.csv) and no config; give one with data.kind: indoor, "
            "e.g. nanoslam run configs/indoor_lines.yaml --data DIR"
        )
    if (d / "inputs.dat").is_file() or (d / "aa3_dr.mat").is_file():
        print(
            f"nanoslam: note: no config given; reading --data {data} as a Victoria Park-format log "
            "(data.kind victoria_park, data.format auto) with the embedded default's filter settings",
            file=sys.stderr,
        )
        return ["data.kind=victoria_park", "data.format=auto"]
    raise ConfigError(
        f"--data {data}: no config given and the directory holds no known log (inputs.dat or aa3_dr.mat: "
        "Victoria Park format; Barcodes.dat: MRCLAM); give a config with data.kind and data.format, "
        "e.g. configs/victoria_park_nano.yaml"
    )


def _check_run_out(out: Path, overwrite: bool) -> bool:
    """Check ``run --out`` before any work; True when it holds an earlier run to delete.

    Raises:
        ConfigError: a file is in its place, or a non-empty directory without ``--overwrite``, or
            with ``--overwrite`` a directory that is not a result directory.
    """
    if not out.exists():
        return False
    if not out.is_dir():
        raise ConfigError(f"--out {out}: a file of that name exists; expected a result directory (new or empty)")
    if not any(out.iterdir()):
        return False
    is_result = (out / "config.yaml").is_file() and (out / "metrics.json").is_file()
    if not overwrite:
        raise ConfigError(
            f"--out {out}: the directory is not empty; give a new directory, or --overwrite to replace "
            "the earlier run's result directory"
        )
    if not is_result:
        raise ConfigError(
            f"--out {out}: --overwrite replaces an earlier run's result directory (config.yaml and "
            "metrics.json), and this directory is not one; give a new directory"
        )
    return True


def _run(args) -> int:
    from nanoslam_jax.app._devices import setup_run_devices
    from nanoslam_jax.app.experiment import default_out_dir, run_experiment

    clear = _check_run_out(Path(args.out), args.overwrite) if args.out else False
    overrides = list(args.overrides)
    sets_kind = any(o.split("=", 1)[0].strip() in ("data.kind", "data.format") for o in overrides)
    if args.data is not None and args.config is None and not sets_kind:
        overrides = _log_kind_overrides(args.data) + overrides
    cfg = load_config(args.config, overrides)
    if args.data is not None and cfg.data.kind in ("simulated", "city"):
        raise ConfigError(
            f"--data {args.data}: {args.config or 'the config'} has data.kind {cfg.data.kind}, which reads no "
            "directory; give a config with data.kind victoria_park (or indoor), or --set data.kind=victoria_park"
        )
    setup_run_devices(cfg)
    out = Path(args.out) if args.out else default_out_dir(cfg)
    metrics = run_experiment(cfg, out, data_dir=args.data, progress=False if args.quiet else None, clear=clear)
    keys = [
        "rmse_fixed",
        "rmse_aligned",
        "rmse_fixed_clean",
        "final_error",
        "dr_rmse_fixed",
        "rmse_heading_deg",
        "ref_rmse",
        "dr_ref_rmse",
        "n_landmarks",
        "n_confirmed",
        "map_found_fraction",
        "map_spurious_fraction",
        "map_found_fraction_aligned",
        "map_spurious_fraction_aligned",
        "ms_per_scan",
        "compile_s",
    ]
    summary = {k: round(metrics[k], 3) if isinstance(metrics[k], float) else metrics[k] for k in keys if k in metrics}
    if "dr_rmse_fixed" in metrics and "rmse_fixed" in metrics:
        print(
            f"{cfg.filter.method}: RMSE {metrics['rmse_fixed']:.2f} m against the {'truth' if metrics['frame'] == 'slam' else 'GPS'}; "
            f"dead reckoning on the same log: {metrics['dr_rmse_fixed']:.2f} m ({metrics['dr_over_slam']:.1f}x the error)"
        )
    print(json.dumps(summary))
    for w in metrics.get("warnings", []):
        print(f"nanoslam: warning: {w}", file=sys.stderr)
    print(out)
    return 0


def _config(args) -> int:
    from nanoslam_jax.app.config_reference import annotated_yaml

    cfg = load_config(args.config, args.overrides)
    source = args.config or "the embedded default"
    sets = "".join(f" --set {o}" for o in args.overrides)
    header = (
        f"nanoslam-jax {__version__}: {source}{sets}, resolved.\n"
        "Each key: its meaning, then [type; range; static (a shape or branch: recompiles) or traced\n"
        "(a hyperparameter: one compiled program serves every value); default]."
    )
    print(annotated_yaml(cfg, header), end="")
    return 0


def _simulate(args) -> int:
    from nanoslam_jax.sim.park import simulate_to_dir

    if args.scenario == "indoor":
        return _simulate_indoor(args)
    if args.scenario == "city":
        return _simulate_city(args)
    overrides = list(args.overrides) + ([f"sim.seed={args.seed}"] if args.seed is not None else [])
    cfg = load_config(args.config, overrides)
    unicycle = cfg.unicycle if cfg.model.motion == "unicycle" else None
    if args.laser:
        from nanoslam_jax.sim.laser import simulate_laser_to_dir

        log = simulate_laser_to_dir(args.out, cfg.sim, cfg.vehicle, unicycle)
        raw = log.raw
    else:
        raw = simulate_to_dir(args.out, cfg.sim, cfg.vehicle, unicycle)
    n_scans = len(set(raw.detections[:, 0].tolist()))
    assert raw.truth_landmarks is not None  # a simulated log has its truth
    print(
        f"wrote {args.out}: {raw.dr.shape[0]} DR samples, {raw.detections.shape[0]} detections in {n_scans} scans, "
        f"{raw.truth_landmarks.shape[0]} landmarks (seed {cfg.sim.seed})"
    )
    if args.laser:
        print(
            f"LASER.txt: {log.scans.n_scans} scans of {log.scans.n_beams} beams; laser_truth.csv: "
            f"{int((log.truth[:, 2] >= 3).sum())} trees hit by 3 or more beams over all scans"
        )
    return 0


def _simulate_city(args) -> int:
    from nanoslam_jax.sim.city import simulate_city_to_dir

    if args.laser:
        raise ConfigError("--laser applies to --scenario park; the city log has no raw scans")
    overrides = list(args.overrides) + ([f"city.seed={args.seed}"] if args.seed is not None else [])
    cfg = load_config(args.config, overrides)
    unicycle = cfg.unicycle if cfg.model.motion == "unicycle" else None
    log = simulate_city_to_dir(args.out, cfg.city, cfg.sim, cfg.vehicle, unicycle)
    raw, c = log.raw, cfg.city
    n_scans = len(set(raw.detections[:, 0].tolist()))
    print(
        f"wrote {args.out}: a city of {c.blocks}x{c.blocks} blocks (seed {c.seed}), {c.distance_m:g} m in "
        f"{raw.dr[-1, 0]:.0f} s, {raw.dr.shape[0]} DR samples, {raw.detections.shape[0]} detections in "
        f"{n_scans} scans, {log.world.landmarks.shape[0]} landmarks"
    )
    return 0


def _simulate_indoor(args) -> int:
    from nanoslam_jax.sim.indoor import simulate_indoor_to_dir

    if args.laser:
        raise ConfigError("--laser applies to --scenario park; an indoor log always has its raw scans")
    overrides = list(args.overrides) + ([f"indoor.seed={args.seed}"] if args.seed is not None else [])
    cfg = load_config(args.config, overrides)
    log = simulate_indoor_to_dir(args.out, cfg.indoor)
    w = log.world
    print(
        f"wrote {args.out}: {w.template} (seed {cfg.indoor.seed}), {log.time.size} odometry samples, "
        f"{log.scans.n_scans} scans of {log.scans.n_beams} beams; {w.walls.shape[0]} wall segments on "
        f"{len(set(w.wall_line.tolist()))} lines, {w.pillars.shape[0]} pillars, {w.corners.shape[0]} corners, "
        f"{w.breakpoints.shape[0]} break points; slip {100 * log.slip.mean():.0f} % of the time"
    )
    if log.scans.n_beams != 361:
        print(
            "nanoslam: note: nanoslam detect reads 361-beam LASER.txt files; read this one with "
            f"load_laser(path, n_beams={log.scans.n_beams}, fov_deg={cfg.indoor.fov_deg})",
            file=sys.stderr,
        )
    return 0


def _detect(args) -> int:
    import numpy as np

    from nanoslam_jax.app.config import resolve_data_dir
    from nanoslam_jax.frontend import detect_log

    cfg = load_config(args.config, args.overrides)
    data = resolve_data_dir(cfg, args.data)

    def bar(done: int, total: int) -> None:
        filled = int(30 * done / max(total, 1))
        print(
            f"\rdetect: [{'#' * filled}{' ' * (30 - filled)}] {done}/{total} scans",
            end="" if done < total else "\n",
            file=sys.stderr,
            flush=True,
        )

    raw, feats = detect_log(data, args.out, cfg.detector, progress=None if args.quiet else bar, fmt=cfg.data.format)
    if args.plot:
        from nanoslam_jax.data import load_laser
        from nanoslam_jax.frontend._plot import parse_scan_list, plot_scan

        scans = load_laser(data)
        chosen = parse_scan_list(args.plot, scans.n_scans)
        (Path(args.out) / "scans").mkdir(exist_ok=True)
        for k in chosen:
            plot_scan(scans, feats, k, Path(args.out) / "scans" / f"scan_{k:05d}.png")
    n_scans = feats.time.size
    print(
        f"wrote {args.out}: {raw.detections.shape[0]} trees in {n_scans} scans "
        f"({len(np.unique(raw.detections[:, 0]))} with a tree); features.csv: {feats.lines.scan.size} line segments, "
        f"{feats.circles.scan.size} circles, {feats.corners.scan.size} corners, "
        f"{feats.breakpoints.scan.size} break points"
    )
    return 0


#: The commands that say on stderr what they compile (:mod:`nanoslam_jax.app._compile_report`).
_COMPILING = ("run", "compare", "sweep", "detect")


@in_float64
def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the ``nanoslam`` console script."""
    import warnings

    from nanoslam_jax.data import LogFormatError, LogWarning

    args = _parser().parse_args(argv)
    show = warnings.showwarning

    def show_log_warning(message, category, *rest, **kw):
        if issubclass(category, LogWarning):
            print(f"nanoslam: warning: {message}", file=sys.stderr)
        else:
            show(message, category, *rest, **kw)

    warnings.showwarning = show_log_warning
    try:
        if not getattr(args, "no_cache", True):
            from nanoslam_jax.lib._cache import compile_stats, enable_compile_cache

            compile_stats()  # count this command's compile time from the start
            enable_compile_cache()
        command = {
            "run": _run,
            "config": _config,
            "simulate": _simulate,
            "compare": _compare,
            "sweep": _sweep,
            "detect": _detect,
        }[args.command]
        if args.command not in _COMPILING:
            return command(args)
        from nanoslam_jax.app._compile_report import compile_messages

        with compile_messages(enabled=not getattr(args, "quiet", False)):
            return command(args)
    except (ConfigError, LogFormatError, FileNotFoundError, ValueError, FloatingPointError) as e:
        print(f"nanoslam: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("nanoslam: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = show


if __name__ == "__main__":
    sys.exit(main())
