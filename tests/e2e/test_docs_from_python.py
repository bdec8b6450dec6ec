"""The example of docs/getting-started.md that builds a run from the core's objects alone runs as
a user copies it, and is the run of the embedded default configuration with the same settings
(independent truth: the configuration's own run)."""

from __future__ import annotations

import re

import numpy as np

from nanoslam_jax import float64
from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods import run_filter
from tests.helpers.paths import REPO_ROOT

PAGE = REPO_ROOT / "docs" / "getting-started.md"


def test_the_run_built_from_objects_is_the_embedded_default():
    blocks = [b for b in re.findall(r"```python\n(.*?)```", PAGE.read_text(), flags=re.S) if "hyperparameters(" in b]
    assert len(blocks) == 1, "one Python block of docs/getting-started.md builds a run from objects"
    namespace: dict = {}
    exec(compile(blocks[0], str(PAGE), "exec"), namespace)
    mine = np.asarray(namespace["run"].outputs.best_pose)

    cfg = load_config(None, ["sim.duration=60", "filter.n_particles=20", "seed=0"])
    log = load_log(cfg)
    with float64():
        static, params = settings_from_config(cfg, log.segments.k_max)
        assert static == namespace["static"]
        ref = np.asarray(run_filter(static, params, log.segments, cfg.seed).outputs.best_pose)
    np.testing.assert_allclose(mine, ref, rtol=0, atol=1e-12)
    assert np.all(np.isfinite(mine)) and np.ptp(mine[:, 0]) > 10.0  # it drove somewhere
