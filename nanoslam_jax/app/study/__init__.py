"""Accuracy against compute: every method over particle counts and seeds, on one log.

    nanoslam compare configs/accuracy_vs_compute.yaml --out results/study         # the study
    nanoslam compare configs/accuracy_vs_compute.yaml --quick --out results/quick # minutes
    nanoslam compare configs/accuracy_vs_compute.yaml --out results/study --resume

    from nanoslam_jax.app.study import load_study, run_study
    result = run_study(load_study("configs/accuracy_vs_compute.yaml", quick=True), "results/quick")

A study file is a comparison file with a ``particles`` section (see :mod:`nanoslam_jax.app.study._spec`);
each (method, particle count) point runs its seeds through the sweep runner and is timed alone
(:mod:`nanoslam_jax.app.study._runner`); the statistics are in :mod:`nanoslam_jax.app.study._stats`.
"""

from nanoslam_jax.app.study._plots import plot_accuracy_vs_compute
from nanoslam_jax.app.study._runner import TIMING_FIELDS, StudyResult, run_study, write_tables
from nanoslam_jax.app.study._spec import (
    STUDY_METRICS,
    PairedSpec,
    StudyMethod,
    StudyPoint,
    StudySpec,
    StudyTiming,
    expand_study,
    is_study_file,
    load_study,
    point_config,
    point_sweep_dict,
)
from nanoslam_jax.app.study._stats import equal_time, error_values, paired_comparison, summarize_points, summary_stats

__all__ = [
    "STUDY_METRICS",
    "TIMING_FIELDS",
    "PairedSpec",
    "StudyMethod",
    "StudyPoint",
    "StudyResult",
    "StudySpec",
    "StudyTiming",
    "equal_time",
    "error_values",
    "expand_study",
    "is_study_file",
    "load_study",
    "paired_comparison",
    "plot_accuracy_vs_compute",
    "point_config",
    "point_sweep_dict",
    "run_study",
    "summarize_points",
    "summary_stats",
    "write_tables",
]
