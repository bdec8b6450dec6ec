"""The exact expansion of a sweep into configurations and runs, and the sweep's identity.

:func:`expand` turns a :class:`~._spec.SweepSpec` into its :class:`~._spec.ConfigPoint` objects
(shape combinations outermost, then the grid, then the random samples) and one :class:`~._spec.Run`
per configuration and seed, in a fixed order with stable ids; :func:`spec_identity` is what a
resumed sweep must match.
"""

from __future__ import annotations

import copy
import itertools
import math
from typing import Any

import numpy as np

from nanoslam_jax.app.config import Config, ConfigError, config_from_dict
from nanoslam_jax.app.sweep._spec import ConfigPoint, RandomSpec, Run, SweepSpec

__all__ = ["expand", "sample_random", "spec_to_dict", "spec_identity", "stored_identity"]


def _get(cfg: Config, key: str) -> Any:
    node: Any = cfg
    for part in key.split("."):
        node = node.get(part) if isinstance(node, dict) else getattr(node, part)
    return node


def _set(raw: dict, key: str, value: Any) -> None:
    parts = key.split(".")
    node = raw
    for part in parts[:-1]:
        if not isinstance(node.get(part), dict):
            node[part] = {}
        node = node[part]
    node[parts[-1]] = value


def sample_random(random: RandomSpec) -> list[dict]:
    """The random samples: ``random.n`` mappings key -> value, reproducible from ``random.seed``.

    Keys are drawn in file order for each sample in turn: uniform ``low + (high - low) u``,
    log-uniform ``exp(log low + (log high - log low) u)``, or ``choice[rng.integers(len)]``.
    """
    rng = np.random.default_rng(random.seed)
    out = []
    for _ in range(random.n):
        s = {}
        for p in random.params:
            if p.choice is not None:
                s[p.key] = p.choice[int(rng.integers(len(p.choice)))]
            elif p.low is None or p.high is None:
                raise ValueError(f"random key {p.key!r}: expected low and high, or a choice")
            elif p.log:
                s[p.key] = float(math.exp(rng.uniform(math.log(p.low), math.log(p.high))))
            else:
                s[p.key] = float(rng.uniform(p.low, p.high))
        out.append(s)
    return out


def _points(spec: SweepSpec) -> list[dict]:
    """Value mappings of every configuration (shape combination outermost, then grid, then random)."""
    shape_keys = [k for k, _ in spec.shapes]
    grid_keys = [k for k, _ in spec.grid]
    shape_combos = [dict(zip(shape_keys, c)) for c in itertools.product(*(v for _, v in spec.shapes))]
    grid_combos = [dict(zip(grid_keys, c)) for c in itertools.product(*(v for _, v in spec.grid))]
    if spec.random is None:
        inner = grid_combos
    else:
        samples = sample_random(spec.random)
        if spec.random.combine == "product":
            inner = [{**g, **s} for g in grid_combos for s in samples]
        else:
            inner = (grid_combos if spec.grid else []) + samples
    return [{**sc, **pt} for sc in shape_combos for pt in inner]


def expand(spec: SweepSpec) -> tuple[list[ConfigPoint], list[Run], list[tuple[dict, str]]]:
    """Every configuration and run of a sweep.

    Returns:
        ``(points, runs, skipped)``: the configurations in order (ids ``c0000``...), one
        :class:`Run` per configuration and seed (configuration-major), and the value mappings
        rejected by validation with the reason (only with ``run.skip_invalid``).

    Raises:
        ConfigError: a configuration is invalid (naming the sweep file, the configuration and
            the key), unless ``run.skip_invalid``.
    """
    keys = spec.swept_keys
    raws = _points(spec)
    width = max(4, len(str(len(raws) - 1)))
    points: list[ConfigPoint] = []
    skipped: list[tuple[dict, str]] = []
    for i, values in enumerate(raws):
        raw = copy.deepcopy(spec.base)
        for k, v in values.items():
            _set(raw, k, v)
        label = ", ".join(f"{k}={v!r}" for k, v in values.items()) or "the base config"
        try:
            cfg = config_from_dict(raw, source=f"{spec.source}: configuration {label}")
        except ConfigError as e:
            if spec.run.skip_invalid:
                skipped.append((values, str(e)))
                continue
            raise
        cid = f"c{len(points):0{width}d}"
        points.append(ConfigPoint(cid, {k: _get(cfg, k) for k in keys}, cfg))
    if not points:
        raise ConfigError(f"{spec.source}: every configuration was rejected; first reason: {skipped[0][1]}")
    runs = [Run(f"{p.config_id}-s{s}", p, s) for p in points for s in spec.seeds]
    return points, runs, skipped


def spec_to_dict(spec: SweepSpec) -> dict:
    """The resolved sweep as a plain mapping (``sweep.yaml`` of a sweep directory).

    Runtime options that cannot change any result (backend, parallelism, workers) are left out
    of ``identity`` so a resumed sweep may use other ones.
    """
    d = {
        "name": spec.name,
        "source": spec.source,
        "segments": spec.segments,
        "seeds": list(spec.seeds),
        "grid": {k: list(v) for k, v in spec.grid},
        "random": None
        if spec.random is None
        else {
            "n": spec.random.n,
            "seed": spec.random.seed,
            "combine": spec.random.combine,
            "params": {
                p.key: (
                    {"choice": list(p.choice)} if p.choice is not None else {"low": p.low, "high": p.high, "log": p.log}
                )
                for p in spec.random.params
            },
        },
        "shapes": {k: list(v) for k, v in spec.shapes},
        "metric": spec.metric,
        "goal": spec.goal,
        "fail_on_overflow": spec.run.fail_on_overflow,
        "skip_invalid": spec.run.skip_invalid,
        "base": spec.base,
    }
    return d


def spec_identity(spec: SweepSpec) -> dict:
    """What decides a sweep's runs and their results (compared when a sweep is resumed). The base
    config's ``name`` is a label and decides nothing a run computes, so a renamed sweep (or a
    study's point under another study name) resumes its runs."""
    d = spec_to_dict(spec)
    return stored_identity(
        {k: d[k] for k in ("segments", "seeds", "grid", "random", "shapes", "fail_on_overflow", "skip_invalid", "base")}
    )


def stored_identity(identity: dict | None) -> dict:
    """An identity as read from a sweep directory's ``sweep.yaml``, comparable with
    :func:`spec_identity` (directories written before the name was left out hold it)."""
    out = dict(identity or {})
    if isinstance(out.get("base"), dict):
        out["base"] = {k: v for k, v in out["base"].items() if k != "name"}
    return out
