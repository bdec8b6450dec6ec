"""``map.csv``: the columns and rows of a run's reported map."""

from __future__ import annotations


import numpy as np
from scipy.special import expit

from nanoslam_jax.app.config import Config
from nanoslam_jax.app._models import measurement_model_from_config
from nanoslam_jax.models import Composite


#: Columns of ``map.csv`` (and, with ``filter.association: known``, :data:`MAP_ID_COLUMN` last).
MAP_COLUMNS = [
    "x",
    "y",
    "cov_xx",
    "cov_xy",
    "cov_yy",
    "hits",
    "misses",
    "existence",
    "confirmed",
    "diameter",
    "diameter_sd",
]
#: The last column of ``map.csv`` when landmarks carry the id of the detection that started them.
MAP_ID_COLUMN = "id"


def map_columns(dim: int = 2, kinds: bool = False) -> list[str]:
    """The columns of ``map.csv`` for landmarks of ``dim`` values (the measurement model's
    ``landmark_dim``): :data:`MAP_COLUMNS` with the values past the first two after ``y``, as
    ``m2``, ``m3``, ... (a circle's radius: ``m2``), then with ``kinds`` (a composite model's map)
    each landmark's type ``kind`` (the index of its model); the covariance columns are those of the
    first two values."""
    return MAP_COLUMNS[:2] + [f"m{i}" for i in range(2, dim)] + ["kind"] * kinds + MAP_COLUMNS[2:]


def _map_layout(cfg: Config) -> tuple[int, tuple[str, ...] | None]:
    """The landmark dimension of ``cfg``'s measurement model and, for a composite, its types' names."""
    model = measurement_model_from_config(cfg)
    return model.landmark_dim, (model.names if isinstance(model, Composite) else None)


def map_table(lm) -> np.ndarray:
    """The rows of ``map.csv`` (:func:`map_columns`) of a reported map's active landmarks (host arrays):
    ``existence`` is the existence probability, ``confirmed`` 1 or 0 (0: tentative); a map whose
    landmarks carry ids (known association) has their id as a last column."""
    act = np.asarray(lm.active)
    cov = np.asarray(lm.cov)[act]
    existence = expit(np.asarray(lm.log_odds, float)[act])
    kind = getattr(lm, "kind", None)
    table = np.c_[
        np.asarray(lm.mean)[act],
        np.asarray(kind)[act] if kind is not None else np.zeros((int(act.sum()), 0)),
        cov[:, 0, 0],
        cov[:, 0, 1],
        cov[:, 1, 1],
        np.asarray(lm.hits)[act],
        np.asarray(lm.misses)[act],
        existence,
        np.asarray(lm.confirmed)[act],
        np.asarray(lm.diam)[act],
        np.sqrt(np.asarray(lm.diam_var)[act]),
    ]
    if getattr(lm, "ident", None) is not None:
        table = np.c_[table, np.asarray(lm.ident)[act]]
    return table
