"""Batch hyperparameter sweeps: one compiled program per shape, vmapped over configs and seeds.

    from nanoslam_jax.app.sweep import load_sweep, run_sweep
    spec = load_sweep("configs/sweep_example.yaml")
    result = run_sweep(spec, "results/sweep1")          # results.csv, summary.md, best.yaml, plots/

The names are loaded on first use, so ``nanoslam`` starts quickly whatever the command.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS = {
    "_spec": (
        "SweepSpec",
        "RunOptions",
        "RandomSpec",
        "RandomParam",
        "ConfigPoint",
        "Run",
        "load_sweep",
        "sweep_from_dict",
        "METRIC_KEYS",
        "MAP_METRIC_KEYS",
        "SMOOTHER_METRIC_KEYS",
        "SURVEY_METRIC_KEYS",
    ),
    "_expand": ("expand", "sample_random", "spec_identity", "stored_identity"),
    "_plan": ("Group", "plan_groups", "make_tasks"),
    "_batch": (
        "LogData",
        "BatchTask",
        "BatchOutput",
        "batch_program",
        "single_program",
        "execute_batch",
        "batch_outputs",
        "load_log_data",
        "compile_events",
    ),
    "_runner": ("run_sweep", "SweepOverrides", "SweepResult", "resolve_parallel", "AUTO_PARALLEL"),
    "_results": (
        "ResultsFile",
        "read_results",
        "summarize",
        "select_best",
        "write_summary",
        "write_best_yaml",
        "TIMING_COLUMNS",
    ),
    "_plots": ("plot_sweep", "plot_metric_vs_param", "plot_heatmap", "RunMetric"),
    "_ray": ("ray_iter", "import_ray"),
    "_cli": ("add_sweep_parser", "sweep_command"),
}
_WHERE = {name: mod for mod, names in _EXPORTS.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    mod = _WHERE.get(name)
    if mod is None:
        raise AttributeError(f"module 'nanoslam_jax.app.sweep' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{mod}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__


if TYPE_CHECKING:  # pragma: no cover
    from nanoslam_jax.app.sweep._cli import add_sweep_parser, sweep_command  # noqa: F401
    from nanoslam_jax.app.sweep._plots import RunMetric, plot_heatmap, plot_metric_vs_param, plot_sweep  # noqa: F401
    from nanoslam_jax.app.sweep._ray import import_ray, ray_iter  # noqa: F401
    from nanoslam_jax.app.sweep._results import (  # noqa: F401
        TIMING_COLUMNS,
        ResultsFile,
        read_results,
        select_best,
        summarize,
        write_best_yaml,
        write_summary,
    )
    from nanoslam_jax.app.sweep._batch import (  # noqa: F401
        BatchOutput,
        BatchTask,
        LogData,
        batch_outputs,
        batch_program,
        compile_events,
        execute_batch,
        load_log_data,
        single_program,
    )
    from nanoslam_jax.app.sweep._expand import expand, sample_random, spec_identity, stored_identity  # noqa: F401
    from nanoslam_jax.app.sweep._plan import Group, make_tasks, plan_groups  # noqa: F401
    from nanoslam_jax.app.sweep._runner import (  # noqa: F401
        AUTO_PARALLEL,
        SweepOverrides,
        SweepResult,
        resolve_parallel,
        run_sweep,
    )
    from nanoslam_jax.app.sweep._spec import (  # noqa: F401
        MAP_METRIC_KEYS,
        METRIC_KEYS,
        SMOOTHER_METRIC_KEYS,
        SURVEY_METRIC_KEYS,
        ConfigPoint,
        RandomParam,
        RandomSpec,
        Run,
        RunOptions,
        SweepSpec,
        load_sweep,
        sweep_from_dict,
    )
