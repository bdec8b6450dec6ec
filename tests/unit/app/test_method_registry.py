"""The method registry: a proposal registered from this test module (outside the package) runs
through ``run`` and ``sweep``, with its traced parameter from ``filter.method_params``."""

import dataclasses
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import pytest

import nanoslam_jax as ns
from nanoslam_jax.app.config import Config, ConfigError, load_config
from nanoslam_jax.methods import (
    IteratedStatic,
    NanoParams,
    NanoStatic,
    NasrukfParams,
    NasrukfStatic,
    Static,
    make_proposal,
)
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.app.registry import Method, get_method, method_names, register
from nanoslam_jax.methods.proposals import AbstractProposal, ProposalResult
from nanoslam_jax.app.sweep import read_results, run_sweep, sweep_from_dict


class InflatedPrior(AbstractProposal):
    """Sample from the prior with its covariance scaled by ``scale`` (a toy proposal)."""

    scale: jnp.ndarray

    def __call__(self, x0, P0, det, R) -> ProposalResult:
        zero = jnp.zeros((), jnp.int32)
        return ProposalResult(x0, self.scale * P0, zero, zero)


TOY = register(
    Method(
        "toy_inflated_prior",
        proposal=lambda static, params, mp: InflatedPrior(mp["scale"]),
        defaults={"scale": 1.0},
        description="the prior, its covariance scaled",
    ),
    replace=True,
)

BASE = ["sim.duration=20", "filter.n_particles=6", "output.plots=false"]


@dataclasses.dataclass(frozen=True)
class ToyStatic:
    """A toy method's static settings.

    Attributes:
        square: the covariance is scaled by ``scale`` squared.
    """

    square: bool


class ToyParams(NamedTuple):
    """A toy method's traced settings.

    Attributes:
        scale: the covariance's scale.
    """

    scale: jnp.ndarray


NESTED = register(
    Method(
        "toy_nested_settings",
        proposal=lambda static, params, mp: InflatedPrior(mp.scale**2 if static.method_settings.square else mp.scale),
        section="nano",
        static_settings=lambda cfg: ToyStatic(square=cfg.nano.max_iter > 1),
        static_default=ToyStatic(square=True),
        traced_settings=lambda cfg: ToyParams(scale=jnp.asarray(cfg.nano.step, dtype=float)),
        description="the prior, its covariance scaled by nano.step (squared for nano.max_iter > 1)",
    ),
    replace=True,
)


def test_settings_are_nested_per_method():
    """Each method's own settings sit in one field of Static and of Params; the shared ones stay flat."""
    cfg = load_config(None, ["filter.method=nano", "nano.gamma=0.01"])
    static, params = settings_from_config(cfg, 14)
    assert static.method_settings == cfg.nano.static() and isinstance(params.method, NanoParams)
    assert float(params.method.gamma) == 0.01 and hash(static) == hash(dataclasses.replace(static))
    assert Static(method=get_method("nano")).method_settings == Config().nano.static() == NanoStatic()
    static, params = settings_from_config(load_config(None, ["filter.method=iterated"]), 14)
    assert isinstance(static.method_settings, IteratedStatic) and params.method == {}
    static, params = settings_from_config(load_config(None, ["filter.method=nasrukf"]), 14)
    assert isinstance(static.method_settings, NasrukfStatic) and isinstance(params.method, NasrukfParams)
    assert params.method.beams is None
    # Another method's section does not reach a program: FastSLAM 2.0 carries no NANO settings.
    a, pa = settings_from_config(load_config(None, ["filter.method=fastslam2"]), 14)
    b, _ = settings_from_config(load_config(None, ["filter.method=fastslam2", "nano.max_iter=3"]), 14)
    assert a == b and a.method_settings is None and pa.method == {}
    # A method registered with defaults: no static settings, its traced ones the dict.
    static, params = settings_from_config(load_config(None, ["filter.method=toy_inflated_prior"]), 14)
    assert static.method_settings is None and set(params.method) == {"scale"}


def test_registered_method_declares_its_own_settings():
    """A registered method's static_settings and traced_settings build its nested settings, and its
    proposal receives the traced ones."""
    cfg = load_config(None, ["filter.method=toy_nested_settings", "nano.step=0.5", "nano.max_iter=1"])
    static, params = settings_from_config(cfg, 14)
    assert static.method_settings == ToyStatic(square=False) and float(params.method.scale) == 0.5
    assert float(make_proposal(static, params).scale) == 0.5
    static, params = settings_from_config(load_config(None, ["filter.method=toy_nested_settings", "nano.step=0.5"]), 14)
    assert static.method_settings == ToyStatic(square=True) and float(make_proposal(static, params).scale) == 0.25
    assert Static(method=get_method("toy_nested_settings")).method_settings == ToyStatic(square=True)


def test_registered_method_is_known_and_validated():
    assert "toy_inflated_prior" in method_names() and get_method("toy_inflated_prior") is TOY
    cfg = load_config(None, ["filter.method=toy_inflated_prior", "filter.method_params.scale=2"])
    assert cfg.filter.method_params == {"scale": 2.0}
    with pytest.raises(ConfigError, match="filter.method_params.size"):
        load_config(None, ["filter.method=toy_inflated_prior", "filter.method_params.size=2"])
    with pytest.raises(ConfigError, match="filter.method"):
        load_config(None, ["filter.method=no_such_method"])
    with pytest.raises(ValueError, match="needs a proposal"):
        Method("broken")


@pytest.mark.slow
def test_toy_with_scale_one_is_fastslam1_and_the_scale_matters():
    """With scale 1 the toy proposal is the prior: the run equals FastSLAM 1.0's to rounding (the two
    programs are built differently, so XLA may order the arithmetic differently: 1e-9 m is far below
    any effect of a proposal, 1e-2 m and more here); another scale changes the run."""
    fs1 = ns.run(overrides=BASE + ["filter.method=fastslam1"], seed=2)
    toy = ns.run(overrides=BASE + ["filter.method=toy_inflated_prior"], seed=2)
    np.testing.assert_allclose(toy.trajectory, fs1.trajectory, rtol=0, atol=1e-9)
    wide = ns.run(overrides=BASE + ["filter.method=toy_inflated_prior", "filter.method_params.scale=4"], seed=2)
    assert not np.allclose(wide.trajectory, fs1.trajectory)


@pytest.mark.slow
def test_registered_method_runs_through_a_sweep(tmp_path):
    """A sweep over the toy's traced parameter: one program, the scale-1 row equals a single run."""
    spec = sweep_from_dict(
        {
            "base": {
                "name": "toy",
                "data": {"kind": "simulated", "max_dr_per_segment": 2},
                "sim": {"duration": 20},
                "filter": {"method": "toy_inflated_prior", "n_particles": 4, "capacity": 96, "window": 24},
            },
            "grid": {"filter.method_params.scale": [1.0, 3.0]},
            "run": {"batch": 2, "parallel": "single", "vectorize": "vmap"},
            "plots": False,
        },
        source="toy-sweep.yaml",
    )
    run_sweep(spec, tmp_path / "sweep", progress=False)
    rows = read_results(tmp_path / "sweep" / "results.csv")
    assert len(rows) == 2 and all(r["status"] == "ok" for r in rows), rows
    single = ns.run(
        {
            "name": "toy",
            "data": {"kind": "simulated", "max_dr_per_segment": 2},
            "sim": {"duration": 20},
            "filter": {"method": "toy_inflated_prior", "n_particles": 4, "capacity": 96, "window": 24},
            "output": {"plots": False},
        }
    )
    one = [r for r in rows if float(r["filter.method_params.scale"]) == 1.0][0]
    assert float(one["rmse_fixed"]) == pytest.approx(single.metrics["rmse_fixed"], rel=1e-6, abs=1e-9)
