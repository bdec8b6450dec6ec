"""Comparison files (:mod:`nanoslam_jax.app.compare`): a row with its own base config, the recommended
configuration's comparison (configs/recommended.yaml, the published table of docs/results.md) and
the row of the filter's own estimate beside a smoothed method."""

from __future__ import annotations

import math

import pytest
import yaml

from nanoslam_jax.app.compare import MethodResult, load_compare_spec, markdown_table, method_config, summarise
from nanoslam_jax.app.config import ConfigError, load_config
from tests.helpers.paths import REPO_ROOT

ROOT = REPO_ROOT
CONFIGS = ROOT / "configs"


def test_a_row_with_its_own_base_takes_its_config_from_it(tmp_path):
    """Each row resolves from its own base (else the comparison's), then the comparison's ``set``,
    then its own: the values of the two config files, not one file's with overrides."""
    f = tmp_path / "cmp.yaml"
    f.write_text(
        yaml.safe_dump(
            {
                "name": "two",
                "base": str(CONFIGS / "victoria_park_best.yaml"),
                "set": ["filter.capacity=300"],
                "methods": [
                    {"label": "best", "set": []},
                    {"label": "paper", "base": str(CONFIGS / "victoria_park_nano.yaml"), "set": ["filter.window=40"]},
                ],
            }
        )
    )
    spec = load_compare_spec(f)
    best, paper = (method_config(spec, m) for m in spec.methods)
    ref_best = load_config(CONFIGS / "victoria_park_best.yaml")
    ref_paper = load_config(CONFIGS / "victoria_park_nano.yaml")
    assert best.noise == ref_best.noise and best.smoother == ref_best.smoother
    assert paper.noise == ref_paper.noise and paper.smoother == ref_paper.smoother
    assert best.noise != paper.noise and best.filter.n_particles != paper.filter.n_particles
    assert best.filter.capacity == paper.filter.capacity == 300  # the comparison's set applies to both
    assert paper.filter.window == 40 and best.filter.window == ref_best.filter.window


def test_a_row_base_that_is_missing_or_not_a_path_is_named(tmp_path):
    f = tmp_path / "cmp.yaml"
    for base, message in (("nope.yaml", r"methods\[1\]\.base.*not found"), (3, r"methods\[1\]\.base.*config path")):
        f.write_text(
            yaml.safe_dump(
                {"name": "x", "base": None, "methods": [{"label": "a", "set": []}, {"label": "b", "base": base}]}
            )
        )
        with pytest.raises(ConfigError, match=message):
            load_compare_spec(f)


def test_the_recommended_comparison_holds_the_published_rows():
    """configs/recommended.yaml: the shipped recommended config on the held-out seeds 100-131, its
    two smoother ablations, the tuned filter at 10 particles unsmoothed and the paper setting."""
    spec = load_compare_spec(CONFIGS / "recommended.yaml")
    assert (spec.first_seed, spec.seeds) == (100, 32)
    cfgs = [method_config(spec, m) for m in spec.methods]
    best = load_config(CONFIGS / "victoria_park_best.yaml")
    nano = load_config(CONFIGS / "victoria_park_nano.yaml")
    shipped, no_history, no_closure, ten, paper = cfgs
    assert shipped.smoother == best.smoother and shipped.filter == best.filter and shipped.noise == best.noise
    assert not no_history.smoother.map_history and no_history.smoother.loop_closure
    assert not no_closure.smoother.map_history and not no_closure.smoother.loop_closure
    assert not ten.smoother.enabled and ten.filter.n_particles == 10 and ten.filter.estimate == "best"
    assert ten.noise == best.noise
    assert paper.noise == nano.noise and paper.filter == nano.filter and paper.smoother == nano.smoother


def _row(seed: int, fixed: float, best: float) -> dict:
    return {
        "seed": seed,
        "status": "ok",
        "reason": "",
        "rmse_fixed": fixed,
        "rmse_aligned": fixed - 0.5,
        "rmse_fixed_path": best + 0.1,
        "rmse_aligned_path": best - 0.4,
        "rmse_fixed_best": best,
        "rmse_aligned_best": best - 0.5,
        "n_landmarks": 180,
        "n_confirmed": 178,
        "smoother_s": 4.0,
    }


def test_a_smoothed_method_is_followed_by_the_filters_own_estimate():
    """table1.md: below a smoothed method, the same runs' per-scan best particle (rmse_*_best)
    summarised over the seeds (median, quartiles, worst); an unsmoothed method has no such row."""
    from nanoslam_jax.app.compare import MethodSpec

    rows = [_row(100 + i, 2.9 + 0.01 * i, 3.0 + i) for i in range(5)]  # best: 3, 4, 5, 6, 7
    smoothed = summarise(MethodResult(MethodSpec("best", ()), "nano", rows=rows))
    plain_rows = [{k: v for k, v in r.items() if "_path" not in k and "_best" not in k} for r in rows]
    plain = summarise(MethodResult(MethodSpec("plain", ()), "nano", rows=plain_rows))
    assert smoothed["rmse_fixed_best_median"] == 5.0 and smoothed["rmse_fixed_best_worst"] == 7.0
    assert smoothed["smoother_s_median"] == 4.0
    lines = markdown_table([smoothed, plain]).splitlines()
    own = [ln for ln in lines if "the filter's own estimate" in ln]
    assert len(own) == 1 and own[0].startswith("| best: the filter's own estimate, same runs | 5 |")
    cells = [c.strip() for c in own[0].split("|")]
    assert cells[3] == "5.000 (4.000-6.000)" and cells[4] == "7.00"
    assert cells[5] == "4.500 (3.500-5.500)" and cells[6] == "6.50"
    assert math.isclose(float(lines[2].split("|")[3].split()[0]), 2.92)  # the smoothed path's median


@pytest.mark.slow
def test_rows_differing_only_in_the_smoother_share_their_filter_runs(tmp_path, monkeypatch):
    """Two smoothed rows (map history on, off) of the same filter run it once (one batch, one timing
    run); the second row's figures equal those of a comparison that runs it alone."""
    import io

    import nanoslam_jax.app.compare as compare

    calls = {"batch": 0, "single": 0}
    run_batch, run_filter = compare.run_batch, compare.run_filter

    def counting_batch(*a, **k):
        calls["batch"] += 1
        return run_batch(*a, **k)

    def counting_filter(*a, **k):
        calls["single"] += 1
        return run_filter(*a, **k)

    monkeypatch.setattr(compare, "run_batch", counting_batch)
    monkeypatch.setattr(compare, "run_filter", counting_filter)
    sim = [
        "data.kind=simulated",
        "sim.duration=30",
        "data.max_dr_per_segment=2",
        "filter.capacity=96",
        "filter.window=24",
        "filter.n_particles=4",
        "filter.method=fastslam1",
        "output.progress=false",
        "filter.row_buckets=never",
        "output.chunk=40",
    ]
    rows = [{"label": "history", "set": []}, {"label": "no history", "set": ["smoother.map_history=false"]}]

    def compare_rows(name, methods):
        f = tmp_path / f"{name}.yaml"
        f.write_text(
            yaml.safe_dump(
                {
                    "name": name,
                    "base": str(CONFIGS / "victoria_park_best.yaml"),
                    "seeds": 2,
                    "set": sim,
                    "timing_chunk": 40,
                    "methods": methods,
                }
            )
        )
        return {
            r["method"]: r
            for r in compare.run_compare(load_compare_spec(f), tmp_path / name, plots=False, stream=io.StringIO())
        }

    both = compare_rows("both", rows)
    assert calls == {"batch": 1, "single": 1}
    alone = compare_rows("alone", rows[1:])
    assert calls == {"batch": 2, "single": 2}
    for k in ("rmse_fixed_median", "rmse_aligned_worst", "rmse_fixed_best_median", "rmse_fixed_path_median"):
        assert both["no history"][k] == alone["no history"][k], k
    assert both["history"]["rmse_fixed_best_median"] == both["no history"]["rmse_fixed_best_median"]
    assert both["history"]["n_failed"] == both["no history"]["n_failed"] == 0
