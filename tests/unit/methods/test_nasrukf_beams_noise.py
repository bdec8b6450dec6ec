"""NASRUKF per beam: the beam-noise estimate with the state's uncertainty projected out
(``nasrukf.noise_residual: projected``) against a simulated noise, whatever the state's covariance;
and, on a simulated indoor log, the beam noise and the adaptive process noise against the
simulator's alongside each other."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import load_config
from nanoslam_jax.methods.gaussian._nasrukf_beams_update import projected_rows
from nanoslam_jax.methods.gaussian._srukf import predict_measurement
from nanoslam_jax.lib.quadrature import Unscented

RULE = Unscented(0.9, 2.0, 0.0)
_projected_rows = jax.jit(projected_rows)


@jax.jit
def _linear_prediction(y, L, H, use):
    return predict_measurement(y, L, lambda s: jnp.where(use, H @ s, 0.0), RULE)


def _draws(p_scale, seed=0, n=5, b=16, used=12, draws=800, r=1e-4):
    """Innovations of a linear measurement ``H y`` of ``b`` beams (``used`` of them real) with noise
    variance ``r``: the filter's state covariance ``P``, the truth's ``p_scale P``."""
    rng = np.random.default_rng(seed)
    H = rng.normal(size=(b, n))
    H[:, 3] = H[:, 0]  # a direction the beams cannot see (as a line's parameters and the pose's)
    A = rng.normal(size=(n, n))
    P = 1e-3 * (A @ A.T + n * np.eye(n))
    L = np.linalg.cholesky(P)
    use = np.arange(b) < used
    y = rng.normal(size=n)
    dev = rng.normal(size=(draws, n)) @ (np.sqrt(p_scale) * L).T
    z = (y + dev) @ H.T + np.sqrt(r) * rng.normal(size=(draws, b))
    pred = _linear_prediction(jnp.asarray(y), jnp.asarray(L), jnp.asarray(H), jnp.asarray(use))
    preds = jax.tree.map(lambda a: jnp.broadcast_to(a, (draws, *a.shape)), pred)
    use_w = jnp.broadcast_to(jnp.asarray(use), (draws, b))
    return (None, None, jnp.asarray(z), None, use_w, preds), r


@pytest.mark.parametrize("p_scale", [0.1, 1.0, 10.0])
def test_projected_noise_rows_recover_the_beam_noise_whatever_the_state_covariance(p_scale):
    """The truth is the simulated noise variance; the state's covariance is right (1), 10 times
    too large (0.1: the truth's is a tenth) or 10 times too small. 800 draws of 12 beams less
    the 4 directions the state moves them in: 6,400 degrees of freedom, 1.8 % standard error."""
    dat, r = _draws(p_scale)
    nu, pv, ok = _projected_rows(dat, jnp.asarray(r))
    assert bool(jnp.all(ok))
    assert np.all(np.asarray(pv) == 0.0)
    est = float(jnp.mean(jnp.square(nu)))
    assert abs(est / r - 1.0) < 0.07, est / r
    if p_scale == 0.1:  # eq. 11's innovation form: the mean square less the predicted variance falls below 0
        _, _, z, _, use, preds = dat
        nu2 = jnp.sum(jnp.where(use, jnp.square(z - preds.z_hat), 0.0), axis=1) / 12
        pvar = jnp.sum(jnp.where(use, jax.vmap(lambda p: p.variance())(preds), 0.0), axis=1) / 12
        assert float(jnp.mean(nu2 - pvar)) < 0.0


def test_projected_noise_rows_need_a_degree_of_freedom():
    """With as many real beams as the directions the state moves them in, no row is used."""
    dat, r = _draws(1.0, used=4)
    _, _, ok = _projected_rows(dat, jnp.asarray(r))
    assert not bool(jnp.any(ok))


@pytest.mark.slow
def test_adaptive_noises_stay_apart_with_the_projected_beam_noise():
    """An indoor log without wheel slip whose odometry noise is 3 times the configured one: the beam
    noise estimate ends within 15 % of the simulator's 1 cm, and the adaptive process-noise ratios
    rise from 1 towards the truth, 3, without passing it by more than 15 % (the innovation form's
    beam noise falls to its floor and the process noise runs past the truth; the rise is slow, as
    each scan's beams correct a small part of the pose's prior variance)."""
    import nanoslam_jax as ns

    cfg = load_config(
        "configs/nasrukf_indoor.yaml",
        [
            "indoor.duration=30",
            "indoor.seed=7",
            "seed=7",
            "indoor.slip_fraction=0",
            "unicycle.sigma_v=0.0033333333333333335",
            "unicycle.sigma_omega_deg=0.3333333333333333",
            "noise.adaptive=true",
            "nasrukf.adaptive_process=true",
            "nasrukf.noise_residual=projected",
            "output.progress=false",
        ],
    )
    m = ns.run(cfg).metrics
    assert m["finite"]
    assert abs(m["noise_sigma_r_final"] / 0.01 - 1.0) < 0.15, m["noise_sigma_r_final"]
    for j in (0, 1):
        assert 1.05 < m[f"process_noise_ratio_{j}"] < 3.0 * 1.15, m[f"process_noise_ratio_{j}"]
    assert m["rmse_fixed"] < 0.01
