"""Median, quartiles, worst and best of one setting's errors over its seeds: the summary the
comparison study (:mod:`nanoslam_jax.study`) and sweeps (:mod:`nanoslam_jax.sweep`) both report."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["summary_stats"]

#: Stand-in for an infinite error inside ``np.quantile`` (interpolating towards ``inf`` can give NaN).
_BIG = 1e300


def summary_stats(values: np.ndarray) -> dict:
    """``median``, ``q1``, ``q3`` (linear interpolation, as ``numpy.percentile``), ``worst`` (max)
    and ``best`` (min) of errors that may hold ``inf``; a quantile that reaches an ``inf`` is ``inf``.
    All NaN for no values."""
    v = np.asarray(values, float)
    if v.size == 0:
        return dict(median=math.nan, q1=math.nan, q3=math.nan, worst=math.nan, best=math.nan)
    q = np.quantile(np.minimum(v, _BIG), [0.5, 0.25, 0.75])
    top = np.max(v[np.isfinite(v)], initial=-math.inf)
    q = [math.inf if x > top else float(x) for x in q]
    return dict(median=q[0], q1=q[1], q3=q[2], worst=float(np.max(v)), best=float(np.min(v)))
