"""The study file: methods x particle counts x seeds, validated, and its exact expansion into points.

A study file is a comparison file (``nanoslam compare``) with a ``particles`` section::

    name: accuracy_vs_compute
    base: victoria_park_nano.yaml      # relative to this file; null: the embedded default
    set: [output.progress=false]       # overrides applied to every method
    first_seed: 0                      # the seeds of a point are first_seed, first_seed + 1, ...
    particles: {10: 16, 100: 16, 1000: 8}   # particle count -> seeds (the default of every method)
    segments: null                     # only the first N segments of the log (null: all)
    timing: {repeats: 3, budget_s: 60} # timed single runs per point (see StudyTiming)
    run: {memory_gb: 2.0}              # options of the sweep runner (see configs/sweep_example.yaml)
    paired: {reference: NANO-SLAM, against: [UFastSLAM, FastSLAM 2.0]}
    methods:
      - label: NANO-SLAM
        set: [filter.method=nano]
      - label: FastSLAM 1.0
        set: [filter.method=fastslam1]
        particles: {10: 16, 1000: 8, 3000: 8}   # this method's own counts (replaces the default)
      - label: EKF-SLAM
        set: [filter.method=ekf_slam]    # deterministic: one run (first_seed), no particle count
    quick:                               # `--quick`: these keys replace the ones above
      particles: {10: 4, 100: 4}
      segments: 2000
      methods: [NANO-SLAM, EKF-SLAM]     # labels kept (default: all)
      timing: {repeats: 1}

:func:`load_study` validates it (every error names the file and the key) and :func:`expand_study`
turns it into :class:`StudyPoint` objects: one per (method, particle count), ordered by particle
count and then by the file's method order (so a partial study holds the cheap points of every
method first), each with its seeds.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any, NamedTuple, Optional, Sequence

from nanoslam_jax.app.compare import deterministic, int_at_least, method_rows, read_comparison, resolve_base, str_list
from nanoslam_jax.app.config import Config, ConfigError, config_to_dict, load_config, read_yaml_mapping

__all__ = [
    "StudyMethod",
    "StudyTiming",
    "PairedSpec",
    "StudySpec",
    "StudyPoint",
    "load_study",
    "is_study_file",
    "expand_study",
    "point_config",
    "point_sweep_dict",
    "STUDY_METRICS",
]

_TOP = {"name", "base", "set", "first_seed", "particles", "segments", "timing", "run", "paired", "methods", "quick"}
_QUICK = {"particles", "segments", "methods", "timing", "first_seed"}
_METHOD = {"label", "set", "particles"}
_TIMING = {"repeats", "budget_s"}
_PAIRED = {"reference", "against", "metrics", "bootstrap", "confidence", "bootstrap_seed"}
#: The errors the study summarises, pairs and plots.
STUDY_METRICS = ("rmse_fixed", "rmse_aligned", "rmse_fixed_clean", "rmse_aligned_clean")


@dataclasses.dataclass(frozen=True)
class StudyMethod:
    """One method of the study.

    Attributes:
        label: its name in tables and figures.
        set: ``key=value`` overrides of the base config (at least ``filter.method``).
        particles: particle count -> number of seeds, or ``None`` for the study's default.
    """

    label: str
    set: tuple[str, ...]
    particles: Optional[tuple[tuple[int, int], ...]] = None


@dataclasses.dataclass(frozen=True)
class StudyTiming:
    """How the seconds per log of a point are measured.

    Each point's first seed runs alone, in a fresh process set up as ``nanoslam run`` sets
    itself up (the particles split over the cores from 64 particles), over the study's log, after
    compilation; the run is repeated up to ``repeats`` times, but no new repeat starts once
    ``budget_s`` seconds of timed runs have been spent. The point's ``seconds_per_log`` is the
    median of these runs.

    Attributes:
        repeats: most timed runs per point (at least 1).
        budget_s: no further repeat once the timed runs add up to this many seconds.
    """

    repeats: int = 3
    budget_s: float = 60.0


@dataclasses.dataclass(frozen=True)
class PairedSpec:
    """The paired comparison (see :func:`nanoslam_jax.app.study.paired_comparison`).

    Attributes:
        reference: label of the method compared (NANO-SLAM).
        against: labels of the methods it is compared with.
        metrics: the errors compared.
        bootstrap: resamples of the bootstrap interval of the median paired difference.
        confidence: level of that interval.
        bootstrap_seed: seed of the resampling (the interval is reproducible).
    """

    reference: str
    against: tuple[str, ...]
    metrics: tuple[str, ...] = ("rmse_fixed", "rmse_aligned")
    bootstrap: int = 10000
    confidence: float = 0.95
    bootstrap_seed: int = 0


@dataclasses.dataclass(frozen=True)
class StudySpec:
    """A validated study (see the module docstring for the YAML layout).

    Attributes:
        name: used in titles.
        source: the file it came from.
        base: base config path (resolved), or None for the embedded default.
        set: overrides applied to every method (the file's, then the command line's).
        methods: the methods, in file order.
        particles: the default particle count -> seeds of the particle methods.
        first_seed: first seed of every point.
        segments: use only the first this many segments (None: all).
        timing: how seconds per log are measured.
        run: options of the sweep runner (its ``run`` section), passed on unchanged.
        paired: the paired comparison (None: none).
        quick: whether this is the file's ``quick`` variant.
    """

    name: str
    source: str
    base: Optional[str]
    set: tuple[str, ...]
    methods: tuple[StudyMethod, ...]
    particles: tuple[tuple[int, int], ...]
    first_seed: int = 0
    segments: Optional[int] = None
    timing: StudyTiming = StudyTiming()
    run: tuple[tuple[str, Any], ...] = ()
    paired: Optional[PairedSpec] = None
    quick: bool = False


@dataclasses.dataclass(frozen=True)
class StudyPoint:
    """One point of the study: a method at one particle count, with its seeds.

    Attributes:
        point_id: a stable file-name-safe id, e.g. ``NANO-SLAM_N0100`` (``EKF-SLAM`` for a
            deterministic method).
        label: the method's label.
        method: its ``filter.method``.
        particles: the particle count (``None`` for a deterministic method).
        seeds: the seeds (one for a deterministic method).
        config: the resolved configuration.
    """

    point_id: str
    label: str
    method: str
    particles: Optional[int]
    seeds: tuple[int, ...]
    config: Config


def is_study_file(path: str | Path) -> bool:
    """Whether a comparison file is a study (it has a ``particles`` section)."""
    return "particles" in read_yaml_mapping(Path(path), "comparison")


def _particle_map(value: Any, key: str, where: str) -> tuple[tuple[int, int], ...]:
    if not isinstance(value, dict) or not value:
        raise ConfigError(
            f"{where}: key '{key}': expected a mapping of particle counts to seeds, e.g. {{10: 16, 1000: 8}}, "
            f"got {value!r}"
        )
    out = []
    for n, s in value.items():
        int_at_least(n, f"{key}.{n}", where, 1)
        int_at_least(s, f"{key}.{n}", where, 1)
        out.append((n, s))
    return tuple(sorted(out))


def _timing(value: Any, where: str, base: StudyTiming) -> StudyTiming:
    if value is None:
        return base
    if not isinstance(value, dict) or set(value) - _TIMING:
        raise ConfigError(f"{where}: key 'timing': expected a mapping with keys {sorted(_TIMING)}, got {value!r}")
    repeats = int_at_least(value.get("repeats", base.repeats), "timing.repeats", where, 1)
    budget = value.get("budget_s", base.budget_s)
    if isinstance(budget, bool) or not isinstance(budget, (int, float)) or not budget > 0:
        raise ConfigError(f"{where}: key 'timing.budget_s': expected a number > 0, got {budget!r}")
    return StudyTiming(repeats, float(budget))


def _paired(value: Any, labels: list[str], where: str) -> Optional[PairedSpec]:
    if value is None:
        return None
    if not isinstance(value, dict) or set(value) - _PAIRED:
        raise ConfigError(f"{where}: key 'paired': expected a mapping with keys {sorted(_PAIRED)}, got {value!r}")
    ref = value.get("reference")
    against = value.get("against")
    if isinstance(against, str):
        against = [against]
    if not isinstance(against, list) or not against:
        raise ConfigError(f"{where}: key 'paired.against': expected a non-empty list of method labels, got {against!r}")
    for key, lab in [("paired.reference", ref)] + [("paired.against", a) for a in against]:
        if lab not in labels:
            raise ConfigError(f"{where}: key '{key}': {lab!r} is not a method label; labels: {labels}")
    metrics = value.get("metrics", list(PairedSpec.metrics))
    if not isinstance(metrics, list) or not metrics or any(m not in STUDY_METRICS for m in metrics):
        raise ConfigError(
            f"{where}: key 'paired.metrics': expected a list of some of {list(STUDY_METRICS)}, got {metrics!r}"
        )
    conf = value.get("confidence", PairedSpec.confidence)
    if isinstance(conf, bool) or not isinstance(conf, (int, float)) or not 0 < conf < 1:
        raise ConfigError(f"{where}: key 'paired.confidence': expected a number in (0, 1), got {conf!r}")
    return PairedSpec(
        str(ref),
        tuple(against),
        tuple(metrics),
        int_at_least(value.get("bootstrap", PairedSpec.bootstrap), "paired.bootstrap", where, 100),
        float(conf),
        int_at_least(value.get("bootstrap_seed", 0), "paired.bootstrap_seed", where, 0),
    )


def _segments(value: Any, key: str, where: str) -> Optional[int]:
    return None if value is None else int_at_least(value, key, where, 1)


class _Variant(NamedTuple):
    """The settings of the study a call runs: the file's (or its ``quick`` variant's), narrowed by
    the command line.

    Attributes:
        methods: the methods run, in file order.
        particles: the default particle count -> seeds of the particle methods.
        first_seed: first seed of every point.
        segments: use only the first this many segments (None: all).
        timing: how seconds per log are measured.
    """

    methods: list[StudyMethod]
    particles: tuple[tuple[int, int], ...]
    first_seed: int
    segments: Optional[int]
    timing: StudyTiming


def _check_quick(raw: dict, where: str) -> None:
    """The file has a ``quick`` section of known keys (for ``--quick``)."""
    q = raw.get("quick")
    if not isinstance(q, dict):
        raise ConfigError(f"{where}: --quick needs a 'quick' section (a mapping of {sorted(_QUICK)}), got {q!r}")
    bad = set(q) - _QUICK
    if bad:
        raise ConfigError(f"{where}: key 'quick': unknown key(s) {sorted(bad)}; expected some of {sorted(_QUICK)}")


def _study_methods(raw: dict, where: str) -> list[StudyMethod]:
    """The file's methods, each with its own particle counts (or ``None``)."""
    return [
        StudyMethod(
            label,
            sets,
            None if row.get("particles") is None else _particle_map(row["particles"], f"{key}.particles", where),
        )
        for key, row, label, sets in method_rows(raw.get("methods"), where, _METHOD)
    ]


def _file_variant(raw: dict, methods: list[StudyMethod], where: str) -> _Variant:
    """The top-level settings of the file."""
    particles = _particle_map(raw.get("particles"), "particles", where)
    first_seed = int_at_least(raw.get("first_seed", 0), "first_seed", where, 0)
    segments = _segments(raw.get("segments"), "segments", where)
    timing = _timing(raw.get("timing"), where, StudyTiming())
    return _Variant(methods, particles, first_seed, segments, timing)


def _quick_variant(q: dict, v: _Variant, where: str) -> _Variant:
    """``v`` with the keys of the ``quick`` section ``q`` in place of the top-level ones."""
    methods, particles, first_seed, segments, timing = v
    if "particles" in q:  # replaces every method's counts
        particles = _particle_map(q["particles"], "quick.particles", where)
        methods = [dataclasses.replace(m, particles=None) for m in methods]
    if "segments" in q:
        segments = _segments(q["segments"], "quick.segments", where)
    if "first_seed" in q:
        first_seed = int_at_least(q["first_seed"], "quick.first_seed", where, 0)
    timing = _timing(q.get("timing"), where, timing)
    keep = q.get("methods")
    if keep is not None:
        labels = [m.label for m in v.methods]
        if not isinstance(keep, list) or not keep or any(k not in labels for k in keep):
            raise ConfigError(
                f"{where}: key 'quick.methods': expected a list of method labels from {labels}, got {keep!r}"
            )
        methods = [m for m in methods if m.label in keep]
    return _Variant(methods, particles, first_seed, segments, timing)


def _only_methods(v: _Variant, only: Sequence[str], where: str) -> _Variant:
    """``v`` with only the methods labelled ``only`` (``--methods``)."""
    have = [m.label for m in v.methods]
    if not only or any(k not in have for k in only):
        raise ConfigError(f"{where}: --methods: expected labels of the study's methods {have}, got {list(only)}")
    return v._replace(methods=[m for m in v.methods if m.label in only])


def _only_counts(v: _Variant, counts: Sequence[int], where: str) -> _Variant:
    """``v`` with only the particle counts ``counts`` (``--particles``), each one of the study's."""
    have_n = sorted({n for n, _ in v.particles} | {n for m in v.methods if m.particles for n, _ in m.particles})
    if not counts or any(not isinstance(n, int) or n not in have_n for n in counts):
        raise ConfigError(f"{where}: --particles: expected particle counts of the study {have_n}, got {list(counts)}")
    particles = tuple((n, s) for n, s in v.particles if n in counts)
    methods = [
        m
        if m.particles is None
        else dataclasses.replace(m, particles=tuple((n, s) for n, s in m.particles if n in counts))
        for m in v.methods
    ]
    return v._replace(methods=methods, particles=particles)


def _with_seeds(v: _Variant, seeds: int, where: str) -> _Variant:
    """``v`` with ``seeds`` seeds at every particle count (``--seeds``)."""
    int_at_least(seeds, "--seeds", where, 1)
    particles = tuple((n, seeds) for n, _ in v.particles)
    methods = [
        m if m.particles is None else dataclasses.replace(m, particles=tuple((n, seeds) for n, _ in m.particles))
        for m in v.methods
    ]
    return v._replace(methods=methods, particles=particles)


def _run_options(raw: dict, where: str) -> dict:
    """The file's ``run`` section (options of the sweep runner), ``{}`` when absent."""
    run = raw.get("run") or {}
    if not isinstance(run, dict):
        raise ConfigError(f"{where}: key 'run': expected a mapping of sweep run options, got {run!r}")
    return run


def _paired_in_variant(raw: dict, labels: list[str], in_variant: list[str], where: str) -> Optional[PairedSpec]:
    """The paired comparison, against the compared methods the variant keeps (``None`` when it keeps
    the reference or none of them)."""
    paired = _paired(raw.get("paired"), labels, where)
    if paired is None:
        return None
    against = tuple(a for a in paired.against if a in in_variant)
    return dataclasses.replace(paired, against=against) if paired.reference in in_variant and against else None


def _check_points(spec: StudySpec, labels: list[str]) -> None:
    """Validate every method's config, its filter method, the ``run`` options and the point ids."""
    where = spec.source
    points = expand_study(spec)  # every method's config is validated here, before anything runs
    from nanoslam_jax.app.registry import method_names
    from nanoslam_jax.app.sweep import sweep_from_dict

    for pt in points:
        if pt.method not in method_names():
            raise ConfigError(
                f"{where}: method {pt.label!r}: filter.method {pt.method!r} is not registered; "
                f"registered: {', '.join(method_names())}"
            )

    sweep_from_dict(point_sweep_dict(spec, points[0]), source=where)  # the 'run' options, named by this file
    if len({pt.point_id for pt in points}) != len(points):
        raise ConfigError(f"{where}: key 'methods': labels must stay distinct once made file-name safe, got {labels}")


def load_study(
    path: str | Path,
    overrides: tuple[str, ...] = (),
    *,
    quick: bool = False,
    seeds: Optional[int] = None,
    only: Optional[Sequence[str]] = None,
    counts: Optional[Sequence[int]] = None,
) -> StudySpec:
    """Read and validate a study file.

    Args:
        path: the YAML file.
        overrides: ``key=value`` config overrides applied to every method (after the file's ``set``).
        quick: use the file's ``quick`` variant (its keys replace the top-level ones).
        seeds: seeds of every particle point (overrides the file's counts; a deterministic
            method still runs once).
        only: run only the methods with these labels (``None``: all of the file's, or of its
            ``quick.methods``).
        counts: run only these particle counts (``None``: all of the file's, or of its
            ``quick.particles``); each must be one of the study's counts.

    Raises:
        ConfigError: naming the file and the key, for unknown keys, wrong types, unknown labels,
            or method overrides that the config rejects.
    """
    p = Path(path)
    where = str(p)
    raw = read_comparison(p, _TOP)
    if quick:
        _check_quick(raw, where)
    base = resolve_base(raw.get("base"), p)
    methods = _study_methods(raw, where)
    labels = [m.label for m in methods]
    v = _file_variant(raw, methods, where)
    if quick:
        v = _quick_variant(raw["quick"], v, where)
    in_variant = [m.label for m in v.methods]  # --methods and --particles narrow a run, not the study
    if only is not None:
        v = _only_methods(v, only, where)
    if counts is not None:
        v = _only_counts(v, counts, where)
    if seeds is not None:
        v = _with_seeds(v, seeds, where)
    run = _run_options(raw, where)
    paired = _paired_in_variant(raw, labels, in_variant, where)
    spec = StudySpec(
        name=str(raw.get("name", p.stem)) + ("-quick" if quick else ""),
        source=where,
        base=base,
        set=str_list(raw.get("set"), "set", where) + tuple(overrides),
        methods=tuple(v.methods),
        particles=v.particles,
        first_seed=v.first_seed,
        segments=v.segments,
        timing=v.timing,
        run=tuple(run.items()),
        paired=paired,
        quick=quick,
    )
    _check_points(spec, labels)
    return spec


def _safe(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", label).strip("_") or "method"


def point_config(spec: StudySpec, m: StudyMethod, particles: Optional[int] = None) -> Config:
    """The resolved configuration of a method, at a particle count (``None``: the configured one)."""
    over = [] if particles is None else [f"filter.n_particles={particles}"]
    try:
        cfg = load_config(spec.base, list(spec.set) + list(m.set) + over)
    except ConfigError as e:
        raise ConfigError(f"{spec.source}: method {m.label!r}: {e}") from None
    if cfg.filter.method == "dead_reckoning":
        raise ConfigError(f"{spec.source}: method {m.label!r}: filter.method 'dead_reckoning' has no filter to study")
    return dataclasses.replace(cfg, name=f"{spec.name}-{_safe(m.label)}" + (f"-N{particles}" if particles else ""))


def expand_study(spec: StudySpec) -> list[StudyPoint]:
    """Every point of the study, each with its seeds.

    A particle method gets one point per particle count of its own ``particles`` (or the
    study's), with seeds ``first_seed .. first_seed + n - 1``; a deterministic method
    (EKF-SLAM) gets one point with the one seed ``first_seed``. Points are ordered by particle
    count (deterministic methods first), then by the file's method order.
    """
    rows = []
    for order, m in enumerate(spec.methods):
        cfg = point_config(spec, m)
        if deterministic(cfg.filter.method):
            rows.append(
                ((0, order), StudyPoint(_safe(m.label), m.label, cfg.filter.method, None, (spec.first_seed,), cfg))
            )
            continue
        counts = m.particles if m.particles is not None else spec.particles  # () once --particles drops them all
        if not counts:
            continue
        width = max(4, len(str(max(n for n, _ in counts))))
        for n, s in counts:
            rows.append(
                (
                    (n, order),
                    StudyPoint(
                        f"{_safe(m.label)}_N{n:0{width}d}",
                        m.label,
                        cfg.filter.method,
                        n,
                        tuple(range(spec.first_seed, spec.first_seed + s)),
                        point_config(spec, m, n),
                    ),
                )
            )
    return [pt for _, pt in sorted(rows, key=lambda r: r[0])]


def point_sweep_dict(spec: StudySpec, pt: StudyPoint) -> dict:
    """The sweep (``nanoslam sweep`` file layout) that runs one point's seeds: no grid, no shapes."""
    return {
        "name": pt.point_id,
        "base": config_to_dict(pt.config),
        "seeds": list(pt.seeds),
        "segments": spec.segments,
        "run": dict(spec.run),
        "plots": False,
    }
