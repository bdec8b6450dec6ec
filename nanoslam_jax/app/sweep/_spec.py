"""The sweep description: YAML schema and validation.

A sweep file names a base configuration, the traced hyperparameters to vary (a ``grid`` and/or
``random`` samples), the static *shape* settings to vary (``shapes``: each value combination is
its own compiled program) and the seeds. :func:`load_sweep` validates it (every error names the
sweep file and the key); :func:`~._expand.expand` turns it into runs.
"""

from __future__ import annotations

import math
import os
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional

from nanoslam_jax.app.config import (
    Config,
    ConfigError,
    apply_overrides,
    config_from_dict,
    config_key_info,
    config_to_dict,
    load_config,
    read_yaml_mapping,
)

__all__ = [
    "RandomParam",
    "RandomSpec",
    "RunOptions",
    "SweepSpec",
    "ConfigPoint",
    "Run",
    "load_sweep",
    "sweep_from_dict",
    "config_key_info",
    "METRIC_KEYS",
    "SMOOTHER_METRIC_KEYS",
    "SURVEY_METRIC_KEYS",
]

#: Metrics every run records (lower is better for the errors; see :func:`nanoslam_jax.eval.metrics.evaluate`).
METRIC_KEYS = (
    "rmse_fixed",
    "rmse_aligned",
    "rmse_fixed_clean",
    "rmse_aligned_clean",
    "mean_error",
    "max_error",
    "final_error",
    "n_landmarks",
    "n_confirmed",
    "landmark_overflow",
    "window_overflow_max",
    "resample_count",
    "ess_mean",
    "ess_min",
    "nano_iterations_mean",
    "proposal_capped",
    "proposal_nonfinite",
    "weight_resets",
    "associations_per_scan",
)
#: Extra metrics of simulated logs (map against the true trees).
MAP_METRIC_KEYS = (
    "map_n_true",
    "map_n_found",
    "map_found_fraction",
    "map_n_spurious",
    "map_spurious_fraction",
    "map_rmse_matched",
    "map_median_est_to_true",
    "map_found_fraction_aligned",
    "map_spurious_fraction_aligned",
    "map_rmse_matched_aligned",
)
#: Extra metrics of real logs with surveyed landmarks (MRCLAM): the map after a rigid alignment
#: (:func:`nanoslam_jax.eval.metrics.survey_summary`; the ``_by_id`` ones with known association).
SURVEY_METRIC_KEYS = (
    "survey_rmse",
    "survey_found",
    "survey_spurious",
    "survey_landmarks",
    "survey_rmse_by_id",
    "survey_found_by_id",
    "survey_spurious_by_id",
)
#: Extra metrics of a sweep whose base config runs the smoother: the path it started from and the
#: filter's own estimate (``rmse_*_path``, ``rmse_*_best``), and the smoother's account.
SMOOTHER_METRIC_KEYS = (
    "rmse_fixed_path",
    "rmse_aligned_path",
    "rmse_fixed_best",
    "rmse_aligned_best",
    "smoother_iterations",
    "smoother_converged",
    "smoother_merged",
    "smoother_s",
)

_TOP_KEYS = (
    "name",
    "base",
    "set",
    "segments",
    "seeds",
    "grid",
    "random",
    "shapes",
    "metric",
    "goal",
    "run",
    "ray",
    "plots",
)
_RANDOM_KEYS = ("n", "seed", "combine", "params")
_RUN_KEYS = (
    "batch",
    "memory_gb",
    "vectorize",
    "backend",
    "parallel",
    "workers",
    "fail_on_overflow",
    "skip_invalid",
    "compile_cache",
)
_RAY_KEYS = ("address", "num_cpus")
#: Config keys no sweep may vary: identity, the seed (use ``seeds``), and output settings.
_UNSWEEPABLE = ("name", "seed")
#: Sections no sweep may vary: output settings, and the smoother's (it runs on the host after each run with the
#: base config's settings; experiments/smoother_tuning.py varies them over one batch of runs).
_UNSWEEPABLE_SECTIONS = ("output", "smoother")


@dataclass(frozen=True)
class RandomParam:
    """How one traced key is sampled.

    Attributes:
        key: dotted config key, e.g. ``noise.sigma_r``.
        low, high: bounds of a uniform (or log-uniform) float sample (``None`` with ``choice``).
        log: sample uniformly in ``log`` space (``low > 0``).
        choice: pick uniformly among these values instead.
    """

    key: str
    low: Optional[float] = None
    high: Optional[float] = None
    log: bool = False
    choice: Optional[tuple] = None


@dataclass(frozen=True)
class RandomSpec:
    """Random samples of traced keys.

    Attributes:
        n: number of samples.
        seed: seed of the sampler (``numpy.random.default_rng``), so the samples are reproducible.
        combine: ``'product'``: every sample with every grid point; ``'union'``: the samples are
            configurations of their own (the grid keys at their base values), next to the grid.
        params: one :class:`RandomParam` per key, in file order.
    """

    n: int
    seed: int = 0
    combine: Literal["product", "union"] = "product"
    params: tuple[RandomParam, ...] = ()


@dataclass(frozen=True)
class RunOptions:
    """How the sweep is executed (these do not change any result).

    Attributes:
        batch: runs per compiled call (``None``: automatic, from ``memory_gb``); a group's last
            batch is padded with copies so every batch of a group has the same shape.
        memory_gb: memory budget of one batch, used by the automatic batch size.
        vectorize: how a batch is computed in its program: ``'vmap'`` (vectorised over the
            batch), ``'map'`` (``lax.map``: one member after another, each bit-identical to the
            same run alone) or ``'auto'`` (see ``AUTO_VECTORIZE``; ``vmap`` on accelerators).
        backend: ``'local'`` (this machine) or ``'ray'`` (a Ray cluster; ``pip install nanoslam-jax[ray]``).
        parallel: how the local backend uses several cores: ``'single'`` (one process, one device),
            ``'devices'`` (one process, the batch sharded over JAX CPU devices, ``SWEEP_DEVICES_PER_CORE`` per core),
            ``'processes'`` (one process pinned to each core) or ``'auto'``.
        workers: cores to use (``None``: all cores this process may run on).
        fail_on_overflow: a run whose landmark capacity overflowed is recorded as failed.
        skip_invalid: drop configurations the config validation rejects (e.g. ``new_landmark``
            below ``gate`` in a grid) instead of stopping with an error.
        compile_cache: keep compiled programs in the persistent compilation cache every command
            uses (``$NANOSLAM_CACHE_DIR``, else the user cache directory; see
            :func:`nanoslam_jax.enable_compile_cache`), so a resumed or repeated sweep and worker
            processes do not compile again; ``--no-cache`` turns it off.
    """

    batch: Optional[int] = None
    memory_gb: float = 2.0
    vectorize: Literal["auto", "vmap", "map"] = "auto"
    backend: Literal["local", "ray"] = "local"
    parallel: Literal["auto", "single", "devices", "processes"] = "auto"
    workers: Optional[int] = None
    fail_on_overflow: bool = True
    skip_invalid: bool = False
    compile_cache: bool = True


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep.

    Attributes:
        name: sweep name (default: the file's stem).
        source: the sweep file (for messages).
        base: the resolved base configuration as a nested mapping (what ``config_to_dict`` gives).
        segments: use only the first this many segments of the log (``None``: all).
        seeds: the seeds every configuration runs with.
        grid: ``(key, values)`` pairs of traced keys; their Cartesian product is swept.
        random: random samples of traced keys (or ``None``).
        shapes: ``(key, values)`` pairs of static keys (one compiled program per combination).
        metric: the metric the best configuration is chosen by (its median over seeds).
        goal: ``'min'`` (default: lower is better, as for the errors) or ``'max'``.
        run: execution options.
        ray_address: Ray cluster address (``None``: start a local instance).
        ray_num_cpus: CPUs of a local Ray instance (``None``: Ray's default).
        plots: write the figures.
    """

    name: str
    source: str
    base: dict
    segments: Optional[int] = None
    seeds: tuple[int, ...] = (0,)
    grid: tuple[tuple[str, tuple], ...] = ()
    random: Optional[RandomSpec] = None
    shapes: tuple[tuple[str, tuple], ...] = ()
    metric: str = "rmse_aligned"
    goal: Literal["min", "max"] = "min"
    run: RunOptions = field(default_factory=RunOptions)
    ray_address: Optional[str] = None
    ray_num_cpus: Optional[int] = None
    plots: bool = True

    @property
    def base_config(self) -> Config:
        """The base configuration."""
        return config_from_dict(self.base, source=f"{self.source}: base")

    @property
    def swept_keys(self) -> tuple[str, ...]:
        """Every varied key: shapes, then grid, then random, in file order."""
        keys = [k for k, _ in self.shapes] + [k for k, _ in self.grid]
        if self.random is not None:
            keys += [p.key for p in self.random.params]
        return tuple(keys)


@dataclass(frozen=True)
class ConfigPoint:
    """One configuration of the sweep.

    Attributes:
        config_id: stable id (``c0000``...), in expansion order.
        values: swept key -> value (coerced to the config's types), in ``swept_keys`` order.
        config: the full configuration.
    """

    config_id: str
    values: dict
    config: Config


@dataclass(frozen=True)
class Run:
    """One run: a configuration and a seed.

    Attributes:
        run_id: ``<config_id>-s<seed>``.
        point: the configuration.
        seed: the PRNG seed of the filter.
    """

    run_id: str
    point: ConfigPoint
    seed: int

    @property
    def config_id(self) -> str:
        return self.point.config_id


# --------------------------------------------------------------------------- parsing


def _check_mapping(value: Any, allowed: tuple[str, ...], where: str, what: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: '{what}' must be a mapping, got {value!r}")
    unknown = [k for k in value if k not in allowed]
    if unknown:
        prefix = f"{what}." if what else ""
        raise ConfigError(f"{where}: unknown key '{prefix}{unknown[0]}'; known keys here: {', '.join(allowed)}")
    return value


def _check_sweep_key(key: Any, section: str, where: str, *, want_static: bool) -> None:
    if not isinstance(key, str):
        raise ConfigError(f"{where}: key '{section}.{key}': expected a dotted config key such as filter.gate")
    _, static = config_key_info(key, f"{where}: key '{section}.{key}'")
    if key in _UNSWEEPABLE or key.split(".")[0] in _UNSWEEPABLE_SECTIONS:
        hint = "; list seeds under 'seeds'" if key == "seed" else ""
        if key.startswith("smoother."):
            hint = (
                "; the smoother runs after each run with the base config's settings "
                "(experiments/smoother_tuning.py varies them over one batch of runs)"
            )
        raise ConfigError(f"{where}: key '{section}.{key}': '{key}' cannot be swept{hint}")
    if want_static and not static:
        raise ConfigError(
            f"{where}: key '{section}.{key}': '{key}' is a traced hyperparameter (no recompilation); "
            f"list it under 'grid' or 'random', not 'shapes'"
        )
    if not want_static and static:
        raise ConfigError(
            f"{where}: key '{section}.{key}': '{key}' changes shapes or the compiled program; list it under 'shapes'"
        )


def _value_list(values: Any, key: str, section: str, where: str) -> tuple:
    if not isinstance(values, list) or not values:
        raise ConfigError(f"{where}: key '{section}.{key}': expected a non-empty list of values, got {values!r}")
    if len(set(map(repr, values))) != len(values):
        raise ConfigError(f"{where}: key '{section}.{key}': the values repeat: {values!r}")
    return tuple(values)


def _number(value: Any, what: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}: key '{what}': expected a finite number, got {value!r}")
    return float(value)


def _parse_random(raw: Any, where: str) -> Optional[RandomSpec]:
    if raw is None:
        return None
    r = _check_mapping(raw, _RANDOM_KEYS, where, "random")
    n = r.get("n")
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ConfigError(f"{where}: key 'random.n': expected a positive integer, got {n!r}")
    seed = r.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{where}: key 'random.seed': expected a non-negative integer, got {seed!r}")
    combine = r.get("combine", "product")
    if combine not in ("product", "union"):
        raise ConfigError(f"{where}: key 'random.combine': expected 'product' or 'union', got {combine!r}")
    params_raw = r.get("params")
    if not isinstance(params_raw, dict) or not params_raw:
        raise ConfigError(
            f"{where}: key 'random.params': expected a mapping of config keys to "
            f"{{low, high[, log]}} or {{choice: [...]}}, got {params_raw!r}"
        )
    params = tuple(_parse_random_param(key, d, where) for key, d in params_raw.items())
    return RandomSpec(n, seed, combine, params)


def _parse_random_param(key: str, d: Any, where: str) -> RandomParam:
    """One entry of ``random.params``: ``{choice: [...]}`` or ``{low, high[, log]}`` of a float key."""
    _check_sweep_key(key, "random.params", where, want_static=False)
    what = f"random.params.{key}"
    if not isinstance(d, dict):
        raise ConfigError(f"{where}: key '{what}': expected {{low, high[, log]}} or {{choice: [...]}}, got {d!r}")
    unknown = [k for k in d if k not in ("low", "high", "log", "choice")]
    if unknown:
        raise ConfigError(f"{where}: unknown key '{what}.{unknown[0]}'; known keys here: low, high, log, choice")
    if "choice" in d:
        if set(d) != {"choice"}:
            raise ConfigError(f"{where}: key '{what}': 'choice' cannot be combined with low/high/log")
        return RandomParam(key, choice=_value_list(d["choice"], key + ".choice", "random.params", where))
    if "low" not in d or "high" not in d:
        raise ConfigError(f"{where}: key '{what}': expected both 'low' and 'high' (or 'choice')")
    lo, hi = _number(d["low"], what + ".low", where), _number(d["high"], what + ".high", where)
    log = d.get("log", False)
    if not isinstance(log, bool):
        raise ConfigError(f"{where}: key '{what}.log': expected true or false, got {log!r}")
    if not lo < hi:
        raise ConfigError(f"{where}: key '{what}': expected low < high, got low {lo}, high {hi}")
    if log and lo <= 0:
        raise ConfigError(f"{where}: key '{what}': log sampling needs low > 0, got {lo}")
    tp, _ = config_key_info(key, where)
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        tp = [a for a in typing.get_args(tp) if a is not type(None)][0]
    if tp is not float:
        raise ConfigError(f"{where}: key '{what}': '{key}' is not a float key; sample it with 'choice'")
    return RandomParam(key, lo, hi, log)


def _parse_seeds(raw: Any, base_seed: int, where: str) -> tuple[int, ...]:
    if raw is None:
        return (base_seed,)
    if isinstance(raw, bool):
        raise ConfigError(f"{where}: key 'seeds': expected a positive integer or a list of seeds, got {raw!r}")
    if isinstance(raw, int):
        if raw < 1:
            raise ConfigError(f"{where}: key 'seeds': expected a positive integer, got {raw!r}")
        return tuple(range(base_seed, base_seed + raw))
    if isinstance(raw, list) and raw and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in raw):
        if len(set(raw)) != len(raw):
            raise ConfigError(f"{where}: key 'seeds': the seeds repeat: {raw!r}")
        return tuple(raw)
    raise ConfigError(
        f"{where}: key 'seeds': expected a positive integer or a list of non-negative integers, got {raw!r}"
    )


def _parse_run(raw: Any, where: str) -> RunOptions:
    r = _check_mapping(raw, _RUN_KEYS, where, "run")
    kw: dict = {}
    hints = typing.get_type_hints(RunOptions)
    for key, value in r.items():
        what = f"run.{key}"
        if key == "batch":
            if value in (None, "auto"):
                value = None
            elif isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{where}: key '{what}': expected a positive integer or 'auto', got {value!r}")
        elif key == "workers":
            if value in (None, "auto"):
                value = None
            elif isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"{where}: key '{what}': expected a positive integer or 'auto', got {value!r}")
        elif key == "memory_gb":
            value = _number(value, what, where)
            if value <= 0:
                raise ConfigError(f"{where}: key '{what}': expected a value > 0, got {value}")
        elif typing.get_origin(hints[key]) is Literal:
            allowed = typing.get_args(hints[key])
            if value not in allowed:
                raise ConfigError(
                    f"{where}: key '{what}': expected one of {', '.join(map(repr, allowed))}, got {value!r}"
                )
        elif hints[key] is bool and not isinstance(value, bool):
            raise ConfigError(f"{where}: key '{what}': expected true or false, got {value!r}")
        kw[key] = value
    return RunOptions(**kw)


def _load_base(raw: Any, overrides: tuple[str, ...], path: Optional[Path], where: str) -> dict:
    """The base configuration as a resolved mapping."""
    if raw is None:
        cfg = load_config(None, list(overrides))
    elif isinstance(raw, str):
        p = Path(raw).expanduser()
        if not p.is_absolute() and path is not None:
            p = path.parent / p
        if not p.is_file():
            raise ConfigError(f"{where}: key 'base': config file {p} not found (paths are relative to the sweep file)")
        cfg = load_config(p, list(overrides))
    elif isinstance(raw, dict):
        mapping = apply_overrides(raw, list(overrides))
        mapping.setdefault("name", "base")
        cfg = config_from_dict(mapping, source=f"{where}: base")
    else:
        raise ConfigError(f"{where}: key 'base': expected a config file name or a mapping of config keys, got {raw!r}")
    return config_to_dict(cfg)


def sweep_from_dict(
    raw: Any, *, source: str = "<sweep>", path: Optional[Path] = None, overrides: tuple[str, ...] = ()
) -> SweepSpec:
    """Validate a sweep mapping (as read from YAML).

    Args:
        raw: the mapping.
        source: name of the sweep in error messages (usually its file).
        path: the sweep file (a relative ``base`` is resolved against its directory).
        overrides: ``key=value`` strings applied to the base configuration.
    """
    where = source
    top = _check_mapping(raw, _TOP_KEYS, where, "")
    set_list = top.get("set") or []
    if not isinstance(set_list, list) or not all(isinstance(s, str) for s in set_list):
        raise ConfigError(f"{where}: key 'set': expected a list of 'key=value' strings, got {set_list!r}")
    base = _load_base(top.get("base"), tuple(set_list) + tuple(overrides), path, where)
    name = top.get("name", path.stem if path is not None else "sweep")
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{where}: key 'name': expected a non-empty string, got {name!r}")
    segments = top.get("segments")
    if segments is not None and (isinstance(segments, bool) or not isinstance(segments, int) or segments < 1):
        raise ConfigError(f"{where}: key 'segments': expected a positive integer or null, got {segments!r}")

    grid = _key_lists(top, "grid", where, want_static=False)
    shapes = _key_lists(top, "shapes", where, want_static=True)
    random = _parse_random(top.get("random"), where)

    seen: dict[str, str] = {}
    for section, keys in (
        ("shapes", [k for k, _ in shapes]),
        ("grid", [k for k, _ in grid]),
        ("random.params", [p.key for p in random.params] if random else []),
    ):
        for k in keys:
            if k in seen:
                raise ConfigError(f"{where}: key '{section}.{k}': '{k}' is already swept under '{seen[k]}'")
            seen[k] = section

    metric = top.get("metric", "rmse_aligned")
    if metric not in METRIC_KEYS + MAP_METRIC_KEYS + SURVEY_METRIC_KEYS:
        raise ConfigError(
            f"{where}: key 'metric': expected one of "
            f"{', '.join(METRIC_KEYS + MAP_METRIC_KEYS + SURVEY_METRIC_KEYS)}, got {metric!r}"
        )
    goal = top.get("goal", "min")
    if goal not in ("min", "max"):
        raise ConfigError(f"{where}: key 'goal': expected 'min' (lower is better) or 'max', got {goal!r}")
    ray = _check_mapping(top.get("ray"), _RAY_KEYS, where, "ray")
    address = ray.get("address")
    if address is not None and not isinstance(address, str):
        raise ConfigError(f"{where}: key 'ray.address': expected a string or null, got {address!r}")
    num_cpus = ray.get("num_cpus")
    if num_cpus is not None and (isinstance(num_cpus, bool) or not isinstance(num_cpus, int) or num_cpus < 1):
        raise ConfigError(f"{where}: key 'ray.num_cpus': expected a positive integer or null, got {num_cpus!r}")
    plots = top.get("plots", True)
    if not isinstance(plots, bool):
        raise ConfigError(f"{where}: key 'plots': expected true or false, got {plots!r}")

    spec = SweepSpec(
        name=name,
        source=source,
        base=base,
        segments=segments,
        seeds=_parse_seeds(top.get("seeds"), int(base["seed"]), where),
        grid=tuple(grid),
        random=random,
        shapes=tuple(shapes),
        metric=metric,
        goal=goal,
        run=_parse_run(top.get("run"), where),
        ray_address=address,
        ray_num_cpus=num_cpus,
        plots=plots,
    )
    if spec.base_config.filter.method == "dead_reckoning" and "filter.method" not in dict(spec.shapes):
        raise ConfigError(f"{where}: key 'base': filter.method 'dead_reckoning' has no filter to sweep")
    for key, values in spec.shapes:
        if key == "filter.method" and "dead_reckoning" in values:
            raise ConfigError(f"{where}: key 'shapes.filter.method': 'dead_reckoning' has no filter to sweep")
    return spec


def _key_lists(top: dict, section: str, where: str, want_static: bool) -> list:
    """``[(key, values), ...]`` of the ``grid`` (traced keys) or ``shapes`` (static keys) section."""
    raw = top.get(section) or {}
    if not isinstance(raw, dict):
        raise ConfigError(
            f"{where}: key '{section}': expected a mapping of config keys to lists of values, got {raw!r}"
        )
    out = []
    for key, values in raw.items():
        _check_sweep_key(key, section, where, want_static=want_static)
        out.append((key, _value_list(values, key, section, where)))
    return out


def load_sweep(path: str | os.PathLike, overrides: tuple[str, ...] | list[str] = ()) -> SweepSpec:
    """Read and validate a sweep YAML file.

    Args:
        path: the sweep file.
        overrides: ``key=value`` strings applied to the base configuration.
    """
    p = Path(path)
    raw = read_yaml_mapping(p, "sweep")
    return sweep_from_dict(raw, source=str(p), path=p, overrides=tuple(overrides))
