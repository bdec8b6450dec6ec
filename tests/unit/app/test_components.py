"""The configuration's names for the filter's components (``filter.prior``, ``association``,
``weight``, ``resampler``, ``estimate``) are exactly the built-in classes' names, each builds its
class, and a run's recorded settings name them back."""

import typing

import pytest

from nanoslam_jax.app.config import ConfigError
from nanoslam_jax.app._build import COMPONENTS, static_summary
from nanoslam_jax.methods import FilterConfig
from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods import (
    AbstractAssociation,
    AbstractEstimate,
    AbstractPrior,
    AbstractResampler,
    AbstractWeight,
)

BASES = {
    "prior": AbstractPrior,
    "association": AbstractAssociation,
    "weight": AbstractWeight,
    "resampler": AbstractResampler,
    "estimate": AbstractEstimate,
}


@pytest.mark.parametrize("key", list(BASES))
def test_each_config_choice_names_one_builtin_component(key):
    hints = typing.get_type_hints(FilterConfig)
    assert set(typing.get_args(hints[key])) == set(COMPONENTS[key])
    for name, cls in COMPONENTS[key].items():
        assert issubclass(cls, BASES[key]) and cls.name == name


@pytest.mark.parametrize(
    "overrides",
    [
        ["filter.prior=linearized", "filter.prior_cov=carry", "filter.weight=marginal", "filter.estimate=mean"],
        ["filter.resampler=residual", "filter.association=known", "filter.estimate=path"],
    ],
)
def test_a_configured_static_names_its_components_back(overrides):
    cfg = load_config(None, ["data.t_end=5", *overrides])
    static, _ = settings_from_config(cfg, 8)
    summary = static_summary(static)
    for key in BASES:
        assert summary[key] == getattr(cfg.filter, key)
        assert isinstance(getattr(static, key), COMPONENTS[key][getattr(cfg.filter, key)])
    assert summary["prior_cov"] == cfg.filter.prior_cov
    assert static.prior.reset == (cfg.filter.prior_cov == "reset")


@pytest.mark.parametrize("key", list(BASES))
def test_an_unknown_component_name_is_refused_naming_the_key(key):
    with pytest.raises(ConfigError, match=f"filter.{key}") as err:
        load_config(None, [f"filter.{key}=bogus"])
    assert all(name in str(err.value) for name in COMPONENTS[key])
