"""The sweeps the sweep tests share: one static configuration (FastSLAM 1.0, 4 particles, capacity
96, window 24, two DR pieces per segment, on a 20 s simulated log) and its grid, so that the tests
compile the vmapped batch program once (tests/unit/app/test_sweep.py, test_sweep_spec.py)."""

from __future__ import annotations

from nanoslam_jax.app.sweep import sweep_from_dict

BASE = {
    "name": "sweep-test",
    # Two DR pieces per segment: the prior's unrolled loop is short, which halves the compile time.
    "data": {"kind": "simulated", "max_dr_per_segment": 2},
    "sim": {"duration": 20},
    "noise": {"sigma_v": 0.3, "sigma_alpha_deg": 1.5, "sigma_r": 0.5, "sigma_beta_deg": 2.0},
    "filter": {"method": "fastslam1", "n_particles": 4, "capacity": 96, "window": 24},
    # Every detection beyond the new-landmark threshold a permanent landmark, so that the failing
    # configuration below overflows the capacity for certain.
    "map": {"manage": False},
}

GRID = {"filter.gate": [4.0, 5.991], "filter.new_landmark": [13.816, 20.0]}

#: 4 grid configurations + 2 random ones, 2 seeds: 12 runs in 3 batches of 4.
MAIN = {
    "base": BASE,
    "seeds": 2,
    "grid": GRID,
    "random": {"n": 2, "seed": 3, "combine": "union", "params": {"noise.sigma_r": {"low": 0.3, "high": 0.9}}},
    "run": {"batch": 4, "parallel": "single", "vectorize": "vmap"},
    "plots": False,
}
#: The grid part only: 8 runs in 2 batches of 4 (the same program; the same ids c0000-c0003).
SMALL = {**{k: v for k, v in MAIN.items() if k != "random"}}


def spec_of(raw: dict, **changes):
    d = {**raw, **changes}
    return sweep_from_dict(d, source="test-sweep.yaml")
