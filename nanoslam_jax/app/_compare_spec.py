"""A comparison file (``nanoslam compare``): its rows, seeds and overrides, read and checked
(the layout is in :mod:`nanoslam_jax.app.compare`'s docstring)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Optional

from nanoslam_jax.app.config import Config, ConfigError, load_config, read_yaml_mapping

__all__ = [
    "CompareSpec",
    "MethodSpec",
    "deterministic",
    "int_at_least",
    "load_compare_spec",
    "method_config",
    "method_rows",
    "read_comparison",
    "resolve_base",
    "seed_config",
    "str_list",
]


def deterministic(method: str) -> bool:
    """Whether a run of ``method`` does not depend on the seed (Gaussian methods, dead reckoning)."""
    from nanoslam_jax.app.registry import get_method

    return get_method(method).kind != "particle"


@dataclasses.dataclass(frozen=True)
class MethodSpec:
    """One row of the comparison.

    Attributes:
        label: name in the table and figures.
        set: ``key=value`` overrides of the base config (at least ``filter.method``).
        paper_rmse: the paper's RMSE for this method (m), if it reports one.
        paper_ms: the paper's time per step (ms), if it reports one.
        base: this row's base config path (resolved), replacing the comparison's; None: the comparison's.
    """

    label: str
    set: tuple[str, ...]
    paper_rmse: Optional[float] = None
    paper_ms: Optional[float] = None
    base: Optional[str] = None


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
        seed_keys: config keys set to the seed with ``seed`` itself, one run per seed and row
            (a key of the log, ``indoor.seed``: each seed its own world, every row on the same
            worlds); empty: the seeds vary the filter's random numbers on one log.
    """

    name: str
    base: Optional[str]
    methods: tuple[MethodSpec, ...]
    seeds: int = 8
    first_seed: int = 0
    timing_chunk: int = 250
    set: tuple[str, ...] = ()
    source: str = ""
    seed_keys: tuple[str, ...] = ()

    @property
    def seed_list(self) -> list[int]:
        """``first_seed, ..., first_seed + seeds - 1``."""
        return list(range(self.first_seed, self.first_seed + self.seeds))


_TOP = {"name", "base", "seeds", "first_seed", "timing_chunk", "set", "methods", "seed_keys"}
_ROW = {"label", "set", "paper_rmse", "paper_ms", "base"}


def str_list(value: Any, key: str, where: str) -> tuple[str, ...]:
    """A comparison (or study) file's list of ``key=value`` overrides (a mapping is taken too), checked."""
    if value is None:
        return ()
    if isinstance(value, dict):  # {filter.method: nano} is accepted too
        return tuple(f"{k}={v}" for k, v in value.items())
    if not isinstance(value, list) or not all(isinstance(v, str) and "=" in v for v in value):
        raise ConfigError(f"{where}: key '{key}': expected a list of 'key=value' strings, got {value!r}")
    return tuple(value)


def int_at_least(value: Any, key: str, where: str, lo: int) -> int:
    """A comparison (or study) file's integer ``value`` of ``key``, at least ``lo``, checked."""
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


def resolve_base(base: Any, path: Path, key: str = "base") -> Optional[str]:
    """A comparison file's ``base`` (or a row's, named by ``key``): a config path relative to the
    file (or absolute), or None.

    Raises:
        ConfigError: naming the file, when it is not a string or the config does not exist.
    """
    if base is None:
        return None
    if not isinstance(base, str):
        raise ConfigError(f"{path}: key '{key}': expected a config path or null, got {base!r}")
    base_path = Path(base) if Path(base).is_absolute() else path.parent / base
    if not base_path.is_file():
        raise ConfigError(f"{path}: key '{key}': config file {base_path} not found")
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
            raise ConfigError(
                f"{where}: key '{key}': unknown key(s) {sorted(unknown)}; expected some of {sorted(allowed)}"
            )
        label = row.get("label")
        if not isinstance(label, str) or not label:
            raise ConfigError(f"{where}: key '{key}.label': expected a non-empty string, got {label!r}")
        out.append((key, row, label, str_list(row.get("set"), f"{key}.set", where)))
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
    methods = [
        MethodSpec(
            label,
            sets,
            _number(row.get("paper_rmse"), f"{key}.paper_rmse", where),
            _number(row.get("paper_ms"), f"{key}.paper_ms", where),
            resolve_base(row["base"], p, f"{key}.base") if "base" in row else None,
        )
        for key, row, label, sets in method_rows(raw.get("methods"), where, _ROW)
    ]
    spec = CompareSpec(
        name=str(raw.get("name", p.stem)),
        base=base,
        methods=tuple(methods),
        seeds=int_at_least(seeds if seeds is not None else raw.get("seeds", 8), "seeds", where, 1),
        first_seed=int_at_least(raw.get("first_seed", 0), "first_seed", where, 0),
        timing_chunk=int_at_least(raw.get("timing_chunk", 250), "timing_chunk", where, 1),
        set=str_list(raw.get("set"), "set", where) + tuple(overrides),
        source=where,
        seed_keys=_seed_keys(raw.get("seed_keys"), where),
    )
    for m in spec.methods:  # validate every method's config now, before anything runs
        seed_config(spec, m, spec.first_seed) if spec.seed_keys else method_config(spec, m)
    return spec


def _seed_keys(value: Any, where: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, str) and v and "=" not in v for v in value):
        raise ConfigError(
            f"{where}: key 'seed_keys': expected a list of config keys (e.g. [indoor.seed]), got {value!r}"
        )
    return tuple(value)


def method_config(spec: CompareSpec, m: MethodSpec) -> Config:
    """The resolved config of one method: its base (the row's, else the comparison's), then the
    comparison's ``set``, then the method's."""
    try:
        cfg = load_config(m.base if m.base is not None else spec.base, list(spec.set) + list(m.set))
    except ConfigError as e:
        raise ConfigError(f"{spec.source}: method {m.label!r}: {e}") from None
    return dataclasses.replace(cfg, name=f"{spec.name}-{m.label}")


def seed_config(spec: CompareSpec, m: MethodSpec, seed: int) -> Config:
    """The resolved config of one method's run of ``seed`` in a comparison with ``seed_keys``:
    :func:`method_config` with ``seed`` and every key of ``spec.seed_keys`` set to ``seed``."""
    sets = [f"{k}={seed}" for k in ("seed", *spec.seed_keys)]
    try:
        cfg = load_config(m.base if m.base is not None else spec.base, [*spec.set, *m.set, *sets])
    except ConfigError as e:
        raise ConfigError(f"{spec.source}: method {m.label!r}, seed {seed} (seed_keys): {e}") from None
    return dataclasses.replace(cfg, name=f"{spec.name}-{m.label}")
