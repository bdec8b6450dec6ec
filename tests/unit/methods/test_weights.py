"""The particle weight of one scan against hand-computed closed forms (docs/method/filter.md).

One particle, one scan, two detections of mapped landmarks and one of a new landmark. The
expected log-weight increment is computed here with numpy and hand-written Jacobians:

    sum_k log N(z_k; g(x, mu_k), Gx P Gx' + Gm Sigma_k Gm' + R) + log p0

at the proposal (``filter.weight: product``, eq. 17) or at the prior (``marginal``), with the
proposal of FastSLAM 2.0 computed by a hand-written EKF update (the test_nano reference).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import load_config
from nanoslam_jax.methods import LandmarkMap
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods._scan import make_proposal
from nanoslam_jax.methods.maps._association import ScanDetections
from nanoslam_jax.methods.particle._step import ParticleIn, SegmentIn, particle_update
from tests.unit.methods.test_nano import ekf_pose_update, rb_jacobian_landmark, rb_jacobian_pose, rb_residual_np, wrap

K = 3
POSE = np.array([2.0, -1.0, 0.3])
POSE_COV = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, -0.003], [0.002, -0.003, 0.0025]])
LM_MEAN = np.array([[14.0, 4.0], [6.0, 9.0]])
LM_COV = np.array([[[0.3, 0.05], [0.05, 0.2]], [[0.1, -0.02], [-0.02, 0.15]]])


def g(x, m):
    d = m - x[:2]
    return np.array([np.hypot(*d), wrap(np.arctan2(d[1], d[0]) - x[2])])


def logpdf(nu, S):
    return float(-0.5 * nu @ np.linalg.solve(S, nu) - 0.5 * np.log(np.linalg.det(2 * np.pi * S)))


def hand_loglik(x, P, z, R):
    """Sum over the two mapped landmarks of log N(z_k; g(x, mu_k), Gx P Gx' + Gm Sigma_k Gm' + R)."""
    Gx = rb_jacobian_pose(x, LM_MEAN)
    total = 0.0
    for k in range(2):
        Gm = rb_jacobian_landmark(x, LM_MEAN[k])
        S = Gx[k] @ P @ Gx[k].T + Gm @ LM_COV[k] @ Gm.T + R
        nu = z[k] - g(x, LM_MEAN[k])
        nu[1] = wrap(nu[1])
        total += logpdf(nu, S)
    return total


def scene(sets, confirmed=(True, True)):
    cfg = load_config(
        None,
        [
            "filter.capacity=8",
            "filter.window=4",
            "filter.prior_cov=carry",
            "noise.sigma_r=0.5",
            "noise.sigma_beta_deg=2",
        ]
        + sets,
    )
    static, params = settings_from_config(cfg, K)
    lm = LandmarkMap.empty(8)._replace(
        mean=jnp.zeros((8, 2)).at[:2].set(LM_MEAN),
        cov=jnp.broadcast_to(jnp.eye(2), (8, 2, 2)).at[:2].set(LM_COV),
        active=jnp.arange(8) < 2,
        confirmed=jnp.zeros(8, bool).at[:2].set(jnp.asarray(confirmed)),
        hits=jnp.full(8, 5, jnp.int32),
        log_odds=jnp.full(8, 3.0),
    )
    # The two mapped trees seen 0.2 m / 1 deg off their prediction, and a tree nowhere near the map.
    z = np.stack(
        [g(POSE, LM_MEAN[0]) + [0.2, math.radians(1.0)], g(POSE, LM_MEAN[1]) - [0.15, math.radians(0.8)], [20.0, -1.2]]
    )
    out = jax.jit(
        lambda: particle_update(
            static,
            params,
            make_proposal(static, params),
            ParticleIn(jnp.asarray(POSE), jnp.asarray(POSE_COV), lm, jnp.zeros(3)),
            SegmentIn(
                jnp.zeros(2), jnp.zeros((2, 2)), jnp.zeros(2, bool), ScanDetections(jnp.asarray(z), jnp.ones(K, bool))
            ),
        )
    )()
    assert int(out.n_associated) == 2 and int(out.n_new) == 1
    return cfg, params, z, out


@pytest.mark.parametrize("manage", [True, False])
@pytest.mark.slow
def test_product_weight_equals_the_hand_formula(manage):
    """FastSLAM 1.0 (the proposal is the prior, here the carried pose covariance unchanged by an
    empty segment): eq. 17 at (pose, pose_cov) plus log p0 for the new landmark."""
    cfg, params, z, out = scene(["filter.method=fastslam1", f"map.manage={str(manage).lower()}"])
    R = np.asarray(params.R)
    expect = hand_loglik(POSE, POSE_COV, z, R) + math.log(cfg.filter.p0)
    np.testing.assert_allclose(float(out.dlogw), expect, rtol=1e-10)


@pytest.mark.parametrize("weight", ["product", "marginal"])
@pytest.mark.slow
def test_fastslam2_weight_at_the_proposal_or_at_the_prior(weight):
    """FastSLAM 2.0 moves the pose: the product weight is eq. 17 at its (hand-computed EKF)
    proposal, the marginal weight the same formula at the prior; the two differ."""
    cfg, params, z, out = scene(["filter.method=fastslam2", f"filter.weight={weight}"])
    R = np.asarray(params.R)
    Rk = np.stack(
        [R + rb_jacobian_landmark(POSE, m) @ c @ rb_jacobian_landmark(POSE, m).T for m, c in zip(LM_MEAN, LM_COV)]
    )
    x_p, P_p = ekf_pose_update(POSE, POSE_COV, LM_MEAN, z[:2], Rk)
    np.testing.assert_allclose(np.asarray(out.pose_cov), P_p, rtol=1e-9, atol=1e-14)  # the proposal itself
    at = {"product": (x_p, P_p), "marginal": (POSE, POSE_COV)}
    expect = hand_loglik(*at[weight], z, R) + math.log(cfg.filter.p0)
    np.testing.assert_allclose(float(out.dlogw), expect, rtol=1e-9)
    other = hand_loglik(*at["marginal" if weight == "product" else "product"], z, R) + math.log(cfg.filter.p0)
    assert abs(float(out.dlogw) - other) > 0.1


@pytest.mark.parametrize("use_tentative", [False, True])
def test_a_tentative_landmark_weighs_as_new_unless_tentative_landmarks_are_used(use_tentative):
    """The second landmark tentative: its detection weighs log p0 (as a new landmark), or with
    map.use_tentative its Gaussian likelihood like a confirmed one."""
    cfg, params, z, out = scene(
        ["filter.method=fastslam1", f"map.use_tentative={str(use_tentative).lower()}"], confirmed=(True, False)
    )
    R = np.asarray(params.R)
    lp0 = math.log(cfg.filter.p0)
    if use_tentative:
        expect = hand_loglik(POSE, POSE_COV, z, R) + lp0
    else:
        Gx = rb_jacobian_pose(POSE, LM_MEAN[:1])[0]
        Gm = rb_jacobian_landmark(POSE, LM_MEAN[0])
        nu = rb_residual_np(POSE, LM_MEAN[:1], z[:1])[0]
        expect = logpdf(nu, Gx @ POSE_COV @ Gx.T + Gm @ LM_COV[0] @ Gm.T + R) + 2 * lp0
    np.testing.assert_allclose(float(out.dlogw), expect, rtol=1e-10)
