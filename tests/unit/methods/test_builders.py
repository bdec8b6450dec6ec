"""A filter built from core objects alone (models, components, settings; no ``Config`` in the
call) runs the same program as the one a configuration builds, and a component of the user's
own (a resampler defined here) takes the built-in one's place.

Independent truths: the configuration's run of the same settings (every value the objects use is
also set in the configuration), and the genealogy the run records (a resampler that copies the
heaviest particle leaves every particle descended from the best one of its step).
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax import float64
from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods import (
    EKF_SLAM,
    FASTSLAM1,
    FASTSLAM2,
    ITERATED,
    NANO,
    NASRUKF,
    UFASTSLAM,
    AbstractResampler,
    AncestralPath,
    BestParticle,
    FilterConfig,
    MapConfig,
    MapParams,
    NanoConfig,
    NanoParams,
    NanoStatic,
    NasrukfParams,
    NasrukfConfig,
    NearestAssociation,
    NoiseConfig,
    Params,
    ProductWeight,
    Static,
    Systematic,
    UnscentedPrior,
    hyperparameters,
    run_filter,
)
from nanoslam_jax.models import Ackermann, RangeBearing

FILTER = dict(
    init_cov=1e-8, ut_alpha=0.9, ut_beta=2.0, ut_kappa=0.0, gate=5.991, new_landmark=9.21, resample_threshold=0.5
)
MAP = dict(p_detect=0.9, p_false=0.1, birth_probability=0.5, confirm_probability=0.9, confirm_hits=3)
SETTINGS = ["data.t_end=40", "filter.n_particles=6", "filter.capacity=128", "filter.window=32"]
SETTINGS += [f"filter.{k}={v}" for k, v in FILTER.items()] + [f"map.{k}={v}" for k, v in MAP.items()]
SETTINGS += [
    "noise.sigma_v=0.5",
    "noise.sigma_alpha_deg=6.0",
    "noise.sigma_r=0.3",
    "noise.sigma_beta_deg=1.0",
    "filter.window_margin=5.0",
]


def _logit(p):
    return math.log(p / (1 - p))


def params_from_objects(method_params) -> Params:
    """The run's hyperparameters, every one written here."""
    a = lambda x: jnp.asarray(x, dtype=float)  # noqa: E731
    map_params = MapParams(
        log_odds_hit=a(math.log(0.9 / 0.1)),
        log_odds_miss=a(math.log(0.1 / 0.9)),
        log_odds_birth=a(_logit(0.5)),
        log_odds_confirm=a(_logit(0.9)),
        confirm_hits=a(3),
        tentative_scans=a(40),
        log_odds_remove=a(_logit(0.02)),
        log_odds_max=a(_logit(0.999)),
        occlusion_width=a(1.0),
        use_tentative=jnp.asarray(False),
        use_diameter=jnp.asarray(False),
        sigma_diameter=a(0.05),
    )
    return Params(
        motion=Ackermann(sigma_v=0.5, sigma_alpha=math.radians(6.0)),
        measurement=RangeBearing(sigma_r=0.3, sigma_beta=math.radians(1.0)),
        **{k: a(v) for k, v in FILTER.items()},
        log_p0=a(math.log(0.05)),
        max_range=a(30.0),
        window_margin=a(5.0),
        map=map_params,
        forgetting=a(0.99),
        noise_floor=a(0.01),
        method=method_params,
    )


def _nano():
    return NanoParams(*(jnp.asarray(v, dtype=float) for v in (1e-4, 1.0, 1.0, 2.0, 0.0)))


def _nasrukf():
    return NasrukfParams(*(jnp.asarray(v, dtype=float) for v in (1.0, 0.99, 0.01)))


# Each method by its config name, with its traced settings (its config section's defaults) and
# its static settings (None: the method's default ones).
METHODS = {
    "nano": (NANO, _nano, NanoStatic(landmark_noise=True)),
    "fastslam1": (FASTSLAM1, dict, None),
    "fastslam2": (FASTSLAM2, dict, None),
    "ufastslam": (UFASTSLAM, dict, None),
    "iterated": (ITERATED, dict, None),
    "ekf_slam": (EKF_SLAM, dict, None),
    "nasrukf": (NASRUKF, _nasrukf, None),
}
SLOW = {"fastslam2", "ufastslam", "iterated", "ekf_slam", "nasrukf"}


@pytest.fixture(scope="module")
def log():
    return load_log(load_config(None, SETTINGS))


@pytest.mark.parametrize("name", [pytest.param(n, marks=[pytest.mark.slow] if n in SLOW else []) for n in METHODS])
def test_a_filter_built_from_objects_equals_the_configured_one(log, name):
    method, traced, settings = METHODS[name]
    with float64():
        static = Static(
            method=method,
            n_particles=6,
            capacity=128,
            window=32,
            k_max=log.segments.k_max,
            prior=UnscentedPrior(reset=True),
            association=NearestAssociation(),
            weight=ProductWeight(),
            resampler=Systematic(),
            estimate=BestParticle(),
            **({} if settings is None else {"method_settings": settings}),
        )
        mine = run_filter(static, params_from_objects(traced()), log.segments, 3)
        cfg = load_config(None, [*SETTINGS, f"filter.method={name}"])
        static_cfg, params_cfg = settings_from_config(cfg, log.segments.k_max)
        assert static_cfg == static
        ref = run_filter(static_cfg, params_cfg, log.segments, 3)
    np.testing.assert_allclose(
        np.asarray(mine.outputs.best_pose), np.asarray(ref.outputs.best_pose), rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(
        np.asarray(mine.outputs.mean_pose), np.asarray(ref.outputs.mean_pose), rtol=0, atol=1e-12
    )


def _equal_trees(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(la, lb):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-15, atol=0)


def test_the_core_settings_build_the_hand_written_hyperparameters():
    """The core's settings objects (probabilities, degrees, p0) turn into the traced form (log-odds,
    log p0) exactly as written out by hand above."""
    with float64():
        built = hyperparameters(
            Ackermann(sigma_v=0.5, sigma_alpha=math.radians(6.0)),
            RangeBearing(sigma_r=0.3, sigma_beta=math.radians(1.0)),
            max_range=30.0,
            filter=FilterConfig(**FILTER, p0=0.05, window_margin=5.0),
            map=MapConfig(**MAP, max_probability=0.999, use_tentative=False),
            noise=NoiseConfig(forgetting=0.99, adaptive_floor=0.01),
            method=NanoConfig().params(),
        )
        _equal_trees(built, params_from_objects(_nano()))
        _equal_trees(NasrukfConfig().params(), _nasrukf())
    assert NanoConfig().static() == NanoStatic()


@dataclasses.dataclass(frozen=True)
class KeepBest(AbstractResampler):
    """Every particle a copy of the heaviest one."""

    name = "keep_best"

    def __call__(self, key, log_w):
        return jnp.full(log_w.shape, jnp.argmax(log_w), jnp.int32)


def test_a_users_resampler_takes_the_builtin_ones_place(log):
    cfg = load_config(None, [*SETTINGS, "filter.method=fastslam1", "filter.resample_threshold=1.0"])
    with float64():
        static, params = settings_from_config(cfg, log.segments.k_max)
        static = dataclasses.replace(static, resampler=KeepBest(), estimate=AncestralPath())
        out = run_filter(static, params, log.segments, 0).outputs
    resampled = np.asarray(out.resampled)
    anc, poses, best = np.asarray(out.ancestors), np.asarray(out.poses), np.asarray(out.best_pose)
    assert resampled.sum() > 5
    for t in np.flatnonzero(resampled):
        assert np.all(anc[t] == anc[t, 0])  # one ancestor for all ...
        np.testing.assert_array_equal(poses[t, anc[t, 0]], best[t])  # ... the step's best particle
    assert np.all(anc[~resampled] == np.arange(anc.shape[1]))


def test_a_static_setting_must_be_a_component():
    with pytest.raises(TypeError, match="Static.resampler: expected a AbstractResampler"):
        Static(resampler="systematic")
