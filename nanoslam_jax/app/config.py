"""Typed, frozen run configuration loaded from YAML and overridable from the command line.

Every section is a frozen dataclass (defined in :mod:`nanoslam_jax.app._config_schema`, re-exported
here); :func:`load_config` turns a YAML file (or nothing: the embedded default) plus
``key=value`` overrides into a validated :class:`Config`. Every error names the offending key
(and the file) and what was expected.

Which fields are *static* (they change array shapes or the compiled program) and which are
*traced* (sweepable without recompiling) is recorded in the field metadata (``static=True``).
"""

from __future__ import annotations

import copy
import dataclasses
import os
import re
import types
import typing
from pathlib import Path
from typing import Any, Literal

import yaml

from nanoslam_jax.app._config_checks import CHECKS
from nanoslam_jax.app._config_schema import (
    ADAPTIVE_NOISE_METHODS,
    Config,
    DataConfig,
    DetectorConfig,
    FilterConfig,
    CityConfig,
    IndoorConfig,
    IteratedConfig,
    MapConfig,
    MetricsConfig,
    ModelConfig,
    NanoConfig,
    NasrukfConfig,
    NoiseConfig,
    OdometryConfig,
    OutputConfig,
    RandomWalkConfig,
    SmootherConfig,
    SimConfig,
    UnicycleConfig,
    VehicleConfig,
)
from nanoslam_jax.methods._params import ROW_BUCKETS_FROM, SPLIT_DEVICES_FROM

__all__ = [
    "Config",
    "ConfigError",
    "DataConfig",
    "DetectorConfig",
    "ModelConfig",
    "UnicycleConfig",
    "OdometryConfig",
    "RandomWalkConfig",
    "VehicleConfig",
    "NoiseConfig",
    "FilterConfig",
    "MapConfig",
    "NanoConfig",
    "IteratedConfig",
    "NasrukfConfig",
    "MetricsConfig",
    "SimConfig",
    "CityConfig",
    "IndoorConfig",
    "OutputConfig",
    "SmootherConfig",
    "load_config",
    "config_from_dict",
    "config_to_dict",
    "apply_overrides",
    "resolve_data_dir",
    "DEFAULT_DATA_DIR",
    "DEFAULT_MRCLAM_DIR",
    "DATASET_HELP",
    "MRCLAM_HELP",
    "type_name",
    "ROW_BUCKETS_FROM",
    "SPLIT_DEVICES_FROM",
    "ADAPTIVE_NOISE_METHODS",
]


class _Loader(yaml.SafeLoader):
    """Safe YAML loader that also reads ``1e-5`` (no dot) as a float, as YAML 1.2 does."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _yaml_load(text: str) -> Any:
    return yaml.load(text, Loader=_Loader)


class ConfigError(ValueError):
    """A configuration problem; the message names the key (and file) and what was expected."""


# --------------------------------------------------------------------------- validation


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return " or ".join(_type_name(a) for a in args) + " or null"
    if origin is tuple:
        return f"a list of {len(typing.get_args(tp))} numbers"
    return getattr(tp, "__name__", str(tp))


def type_name(tp: Any) -> str:
    """What values a config field of annotation ``tp`` takes, in the words error messages use."""
    return _type_name(tp)


def _coerce_bool(value: Any, key: str, where: str) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"{where}key '{key}': expected true or false, got {value!r}")
    return value


def _coerce_int(value: Any, key: str, where: str) -> int:
    """An integer; a float with an integral value becomes one."""
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ConfigError(f"{where}key '{key}': expected an integer, got {value!r}")
    return value


def _coerce_float(value: Any, key: str, where: str) -> float:
    """A finite number, as a float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{where}key '{key}': expected a number, got {value!r}")
    value = float(value)
    if value != value or value in (float("inf"), float("-inf")):
        raise ConfigError(f"{where}key '{key}': expected a finite number, got {value!r}")
    return value


def _coerce_dict(value: Any, key: str, where: str) -> dict:
    """A mapping of names to numbers; a value may itself be such a mapping (a composite measurement
    model's per-type parameters)."""
    if not isinstance(value, dict):
        raise ConfigError(f"{where}key '{key}': expected a mapping of names to numbers, got {value!r}")
    return {str(k): _coerce(v, dict if isinstance(v, dict) else float, f"{key}.{k}", where) for k, v in value.items()}


def _coerce_str(value: Any, key: str, where: str) -> str:
    if not isinstance(value, str):
        raise ConfigError(f"{where}key '{key}': expected a string, got {value!r}")
    return value


#: The coercion of each plain (not generic) field type.
_PLAIN_COERCIONS: dict[Any, Any] = {
    bool: _coerce_bool,
    int: _coerce_int,
    float: _coerce_float,
    dict: _coerce_dict,
    str: _coerce_str,
}


def _coerce(value: Any, tp: Any, key: str, where: str) -> Any:
    """``value`` as a field of annotation ``tp`` takes it.

    Raises:
        ConfigError: naming ``key`` (after ``where``) and what it expects, when ``value`` does not fit.
    """
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _coerce(value, inner, key, where)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(f"{where}key '{key}': expected {_type_name(tp)}, got {value!r}")
        return value
    if origin is tuple:  # a fixed number of numbers, e.g. a pose [x, y, theta]
        n = len(typing.get_args(tp))
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise ConfigError(f"{where}key '{key}': expected {_type_name(tp)}, got {value!r}")
        return tuple(_coerce(v, float, f"{key}[{i}]", where) for i, v in enumerate(value))
    coerce = _PLAIN_COERCIONS.get(tp)
    if coerce is None:
        raise TypeError(f"unsupported config type {tp!r} for {key}")
    return coerce(value, key, where)


def _check_range(value: Any, meta: Any, key: str, where: str) -> None:
    if value is None or isinstance(value, (bool, str)):
        return
    lo, hi, lo_open = meta.get("lo"), meta.get("hi"), meta.get("lo_open")
    if lo is not None and (value < lo or (lo_open and value == lo)):
        rel = ">" if lo_open else ">="
        raise ConfigError(f"{where}key '{key}': expected a value {rel} {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise ConfigError(f"{where}key '{key}': expected a value <= {hi}, got {value!r}")


def _build(cls: type, raw: Any, prefix: str, where: str) -> Any:
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        name = prefix.rstrip(".") or "the top level"
        raise ConfigError(f"{where}key '{name}': expected a mapping, got {raw!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(raw) - set(fields))
    if unknown:
        key = prefix + str(unknown[0])
        raise ConfigError(f"{where}unknown key '{key}'; known keys here: {', '.join(sorted(fields))}")
    kwargs = {}
    for name, value in raw.items():
        f, tp, key = fields[name], hints[name], prefix + name
        if dataclasses.is_dataclass(tp):
            kwargs[name] = _build(tp, value, key + ".", where)
        else:
            value = _coerce(value, tp, key, where)
            _check_range(value, f.metadata, key, where)
            kwargs[name] = value
    return cls(**kwargs)


def _check_consistency(cfg: Config, where: str) -> None:
    """Apply the consistency checks (:data:`nanoslam_jax.app._config_checks.CHECKS`) in order.

    Raises:
        ConfigError: with the message of the first rule ``cfg`` breaks, after ``where``.
    """
    for check in CHECKS:
        message = check(cfg)
        if message is not None:
            raise ConfigError(f"{where}{message}")


def config_from_dict(raw: Any, *, source: str | None = None) -> Config:
    """Validate a nested mapping (as read from YAML) into a :class:`Config`.

    Args:
        raw: the mapping; missing keys take their defaults.
        source: file name used in error messages.
    """
    where = f"{source}: " if source else ""
    cfg = _build(Config, raw, "", where)
    _check_consistency(cfg, where)
    return cfg


def config_to_dict(cfg: Config) -> dict:
    """The resolved configuration as a plain nested dict (what ``config.yaml`` holds)."""
    return dataclasses.asdict(cfg)


def config_key_info(dotted: str, where: str) -> tuple[Any, bool]:
    """The type of a dotted config key and whether it is static (a shape setting).

    Args:
        dotted: dotted key, e.g. ``filter.gate``.
        where: prefix of error messages (the file, and the key's place in it).

    Raises:
        ConfigError: naming the key when it is not a config key, or is a section.
    """
    parts = dotted.split(".")
    cls: Any = Config
    for i, part in enumerate(parts):
        fields = {f.name: f for f in dataclasses.fields(cls)}
        if part not in fields:
            prefix = ".".join(parts[:i])
            here = f" under '{prefix}'" if prefix else ""
            raise ConfigError(f"{where}: unknown key '{dotted}'{here}; known keys: {', '.join(sorted(fields))}")
        tp = typing.get_type_hints(cls)[part]
        if i == len(parts) - 1:
            if dataclasses.is_dataclass(tp):
                raise ConfigError(f"{where}: key '{dotted}' is a section; set one of its keys, e.g. {dotted}.<key>")
            return tp, bool(fields[part].metadata.get("static", False))
        if typing.get_origin(tp) in (typing.Union, types.UnionType) and dict in typing.get_args(tp):
            if i == len(parts) - 2:  # a parameter inside a mapping-valued key
                return float, bool(fields[part].metadata.get("static", False))
        if not dataclasses.is_dataclass(tp):
            raise ConfigError(f"{where}: key '{'.'.join(parts[: i + 1])}' is not a section (in '{dotted}')")
        cls = tp
    raise AssertionError("unreachable")


def _set_path(raw: dict, dotted: str, value: Any, source: str) -> None:
    config_key_info(dotted, source)  # the whole key against the schema first
    parts = dotted.split(".")
    node = raw
    for i, part in enumerate(parts[:-1]):
        if node.get(part) is None:
            node[part] = {}
        if not isinstance(node[part], dict):
            raise ConfigError(f"{source}: key '{'.'.join(parts[: i + 1])}' must be a mapping to set '{dotted}'")
        node = node[part]
    node[parts[-1]] = value


def apply_overrides(raw: dict, overrides: list[str] | tuple[str, ...]) -> dict:
    """Apply ``key=value`` strings (values parsed as YAML) to a raw config mapping (copied)."""
    import copy

    out = copy.deepcopy(raw) if raw else {}
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected key=value, e.g. filter.n_particles=20")
        key, text = item.split("=", 1)
        key = key.strip()
        try:
            value = _yaml_load(text) if text.strip() else None
        except yaml.YAMLError as e:
            raise ConfigError(f"--set {item!r}: the value is not valid YAML ({e})") from None
        _set_path(out, key, value, f"--set {key}")
    return out


def _merge(base: dict, top: dict) -> dict:
    """``top`` over ``base``, section by section."""
    out = dict(base)
    for k, v in top.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def read_yaml_mapping(p: Path, what: str = "config", note: str = "") -> dict:
    """A YAML file whose top level is a mapping (an empty file is ``{}``).

    Args:
        p: the file.
        what: what the file is, for messages (``'config'``, ``'sweep'``, ``'comparison'``).
        note: appended to the not-found message (e.g. which file named it).

    Raises:
        ConfigError: naming the file (and line) when it is missing, not YAML, or not a mapping.
    """
    if not p.is_file():
        raise ConfigError(f"{p}: {what} file not found{note}")
    try:
        raw = _yaml_load(p.read_text())
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(f"{p}:{line} is not valid YAML: {getattr(e, 'problem', e)}") from None
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ConfigError(f"{p}: expected a mapping of {what} keys at the top level, got {type(raw).__name__}")
    return raw


def _read_with_base(p: Path, chain: tuple[Path, ...]) -> dict:
    """The raw mapping of a config file, merged over the file named by its ``base`` key (if any)."""
    raw = read_yaml_mapping(p, "config", f" (base of {chain[-1]})" if chain else "")
    base = raw.pop("base", None)
    if base is None:
        return raw
    if not isinstance(base, str):
        raise ConfigError(f"{p}: key 'base': expected the path of another config file, got {base!r}")
    bp = Path(base) if Path(base).is_absolute() else p.parent / base
    if bp.resolve() in [c.resolve() for c in chain + (p,)]:
        raise ConfigError(f"{p}: key 'base': {bp} is already in the chain of bases (a cycle)")
    merged = _read_with_base(bp, chain + (p,))
    merged.pop("name", None)  # a derived config is named after its own file unless it says otherwise
    return _merge(merged, raw)


#: The embedded default (``nanoslam run`` without a config): NANO-SLAM with 30 particles on the
#: default simulated log (240 s, two laps, 250 trees, clutter 0.2 per scan, a tree in view missed
#: in 25 % of scans (``sim.p_detect`` 0.75, the rate the real-log tuning chose for ``map.p_detect``); odometry
#: with a 0.3 deg steering bias and white noise, 0.3 m/s and 2 deg per sample, so dead reckoning
#: ends about 40 m RMSE off). The filter's noise matches the simulator's: the sensor's exactly
#: (0.3 m, 1 deg); the controls' white noise widened to 0.5 m/s and 6 deg to cover the steering
#: bias, which white noise cannot model (with 2 deg the filter drifts with the bias); the
#: landmark noise enters the proposal (nano.landmark_noise). Landmark management assumes a
#: detector that sees a tree in 90 % of scans and a non-tree in 10 % (fewer scans to confirm a tree
#: than the real-log defaults; measured on the simulator's 75 % detector: README's figures).
EMBEDDED_DEFAULT = {
    "name": "default",
    "data": {"kind": "simulated"},
    "noise": {"sigma_v": 0.5, "sigma_alpha_deg": 6.0, "sigma_r": 0.3, "sigma_beta_deg": 1.0},
    "filter": {"n_particles": 30, "new_landmark": 13.816},
    "nano": {"landmark_noise": True},
    "map": {"p_detect": 0.9, "p_false": 0.1, "confirm_hits": 3, "max_probability": 0.999, "use_tentative": False},
}


def load_config(path: str | os.PathLike | None = None, overrides: list[str] | tuple[str, ...] = ()) -> Config:
    """Load and validate a configuration.

    Args:
        path: a YAML file; ``None`` gives the embedded default (NANO-SLAM on a simulated log).
        overrides: ``key=value`` strings applied after the file, e.g. ``filter.n_particles=20``.

    A file may start from another with ``base: other.yaml`` (relative to the file): its keys are
    merged over the base's, section by section; the resolved config holds every key.
    """
    if path is None:
        raw: Any = copy.deepcopy(EMBEDDED_DEFAULT)
        source = "embedded default config"
    else:
        p = Path(path)
        source = str(p)
        raw = _read_with_base(p, ())
        raw.setdefault("name", p.stem)
    raw = apply_overrides(raw, list(overrides))
    if overrides:
        source += " with --set " + " ".join(overrides)
    return config_from_dict(raw, source=source)


# --------------------------------------------------------------------------- data directory

DEFAULT_DATA_DIR = Path("..") / "shared" / "data" / "victoria_park"
#: The default directory of ``data.format: mrclam`` (UTIAS MRCLAM dataset 1).
DEFAULT_MRCLAM_DIR = Path("..") / "shared" / "data" / "utias_mrclam" / "MRCLAM_Dataset1"

DATASET_HELP = (
    "The Victoria Park log (Guivant & Nebot, ACFR, University of Sydney) is not shipped with "
    "nanoslam-jax. Obtain the dataset (aa3_dr.mat and aa3_gpsx.mat from the original "
    "distribution, plus the tree detections as measurements.dat, or the three ASCII files "
    "inputs.dat, measurements.dat, gps.dat; see README.md, 'The Victoria Park log'), put the "
    "files in one directory and pass it with --data DIR, data.path in the config, or the "
    "NANOSLAM_DATA environment variable."
)


MRCLAM_HELP = (
    "The UTIAS MRCLAM dataset (Leung, Halpern, Barfoot and Liu, IJRR 2011) is not shipped with "
    "nanoslam-jax. Obtain dataset 1 (Barcodes.dat, Landmark_Groundtruth.dat, RobotN_Odometry.dat and "
    "RobotN_Measurement.dat for N = 1..5), put the files in one directory and pass it with --data DIR, "
    "data.path in the config, or the NANOSLAM_DATA environment variable."
)


def resolve_data_dir(cfg: Config, cli_data: str | None = None) -> Path:
    """The log directory: ``--data``, then ``data.path``, then ``$NANOSLAM_DATA``, then the default
    (:data:`DEFAULT_DATA_DIR`; :data:`DEFAULT_MRCLAM_DIR` for ``data.format: mrclam``), relative to
    the working directory or to the project. With ``data.format: rosbag``: the bag (a ROS 1 ``.bag``
    file or a ROS 2 bag directory), which has no default.

    Raises:
        FileNotFoundError: with instructions for obtaining the dataset when no directory exists.
    """
    mrclam, bag = cfg.data.format == "mrclam", cfg.data.format == "rosbag"
    help_text, default = (MRCLAM_HELP, DEFAULT_MRCLAM_DIR) if mrclam else (DATASET_HELP, DEFAULT_DATA_DIR)
    what = "MRCLAM dataset" if mrclam else "Victoria Park log"
    candidates = [
        ("--data", cli_data),
        ("data.path", cfg.data.path),
        ("NANOSLAM_DATA", os.environ.get("NANOSLAM_DATA")),
    ]
    for origin, value in candidates:
        if value:
            p = Path(value).expanduser()
            if bag and not p.exists():
                raise FileNotFoundError(
                    f"{p} (from {origin}): ROS bag not found (a .bag file or a ROS 2 bag directory)"
                )
            if not (p.is_dir() or bag):
                raise FileNotFoundError(f"{p} (from {origin}): log directory not found. {help_text}")
            return p
    if bag:
        raise FileNotFoundError("data.format rosbag: give the bag with --data BAG (or data.path)")
    for base in (Path.cwd(), Path(__file__).resolve().parents[1]):
        p = (base / default).resolve()
        if p.is_dir():
            return p
    raise FileNotFoundError(f"no {what} directory given and {default} does not exist. {help_text}")
