"""Landmark management (nanoslam_jax/methods/maps/_management.py): tentative and confirmed landmarks,
existence by negative evidence, occlusion, tree diameters, slot reuse, capacity.

Each test compares with an independent truth: log-odds computed by hand from the probabilities
of the config, hand-built geometry, the simulator's true trees and diameters, or a closed form.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.app.config import load_config
from nanoslam_jax.app.experiment import load_log
from nanoslam_jax.methods import Gating, LandmarkMap, Management, ScanDetections, associate, run_filter
from nanoslam_jax.app.filters import settings_from_config
from nanoslam_jax.methods.maps._management import manage_window, manage_window_prefix, occluded
from nanoslam_jax.methods._scan import make_proposal
from nanoslam_jax.methods.particle._step import ParticleIn, SegmentIn, particle_update

K = 3
CAP = 8


def logit(p):
    return math.log(p / (1 - p))


#: Management settings of the hand computations below.
MAP = dict(
    p_detect=0.8,
    p_false=0.2,
    birth_probability=0.5,
    confirm_probability=0.9,
    confirm_hits=3,
    max_probability=0.99,
    remove_probability=0.1,
    tentative_scans=5,
    view_margin=2.0,
    view_margin_deg=5.0,
    occlusion_width=0.3,
    use_tentative=False,
)


def settings(**extra):
    sets = [f"map.{k}={v}" for k, v in {**MAP, **extra}.items()]
    cfg = load_config(None, ["filter.method=fastslam1", f"filter.capacity={CAP}", "filter.window=4"] + sets)
    return cfg, *settings_from_config(cfg, K)


def stepper(static, params):
    """One particle standing at the origin (no motion), scan after scan: returns the map after
    each scan. FastSLAM 1.0 with the near-zero initial covariance: the sampled pose is the origin
    to within 1e-4 m."""
    proposal = make_proposal(static, params)
    pose = jnp.zeros(3)

    @jax.jit
    def step(lm, z, z_mask, diam, scan):
        out = particle_update(
            static,
            params,
            proposal,
            ParticleIn(pose, params.init_cov * jnp.eye(3), lm, jnp.zeros(3)),
            SegmentIn(jnp.zeros(1), jnp.zeros((1, 2)), jnp.zeros(1, bool), ScanDetections(z, z_mask, diam), True, scan),
        )
        return out.landmarks

    def run(scans):
        lm, maps = LandmarkMap.empty(CAP), []
        for s, (z, z_mask) in enumerate(scans):
            lm = step(lm, jnp.asarray(z, float), jnp.asarray(z_mask), jnp.full(K, 0.3), s)
            maps.append(jax.tree.map(np.asarray, lm))
        return maps

    return run


def detections(*rows):
    z, m = np.zeros((K, 2)), np.zeros(K, bool)
    for i, r in enumerate(rows):
        z[i], m[i] = r, True
    return z, m


@pytest.mark.slow
def test_existence_log_odds_follow_the_hand_computation():
    """A tree 10 m ahead, detected in scans 0-4 and then missed: its log-odds, confirmation and
    removal follow Bayes' rule computed by hand from p_detect, p_false and the thresholds."""
    cfg, static, params = settings()
    seen, missed = detections((10.0, 0.0)), detections()
    maps = stepper(static, params)([seen] * 5 + [missed] * 6)
    hit, miss = math.log(0.8 / 0.2), math.log(0.2 / 0.8)
    lo, expect = 0.0, []
    for s in range(11):
        if s > 0:
            lo = min(lo + (hit if s < 5 else miss), logit(0.99))
        expect.append(lo)
    removed_at = next(s for s, v in enumerate(expect) if v < logit(0.1))
    assert removed_at == 9  # 0, 1.39, 2.77, 4.16, 4.60 (capped), 3.21, 1.82, 0.43, -0.95, -2.34
    for s, lm in enumerate(maps):
        if s < removed_at:
            assert lm.active[0] and lm.active.sum() == 1, s
            np.testing.assert_allclose(lm.log_odds[0], expect[s], rtol=1e-12, atol=1e-12, err_msg=f"scan {s}")
            assert lm.hits[0] == min(s + 1, 5) and lm.misses[0] == max(s - 4, 0)
            # confirmed from the third detection on (log-odds 2.77 >= logit(0.9) = 2.20 with 3 hits)
            assert bool(lm.confirmed[0]) == (s >= 2), s
        else:
            assert not lm.active.any(), s
    np.testing.assert_allclose(maps[0].mean[0], [10.0, 0.0], atol=1e-3)


@pytest.mark.slow
def test_a_tree_seen_once_is_dropped_after_the_tentative_period_and_its_slot_reused():
    """Seen once at 86 deg (outside the view shrunk by the 5 deg margin, so no miss is ever
    counted): it stays tentative for ``tentative_scans`` = 5 scans, is dropped at the sixth, and
    the next new landmark takes its slot."""
    cfg, static, params = settings()
    side = (10.0, math.radians(86.0))
    scans = [detections(side)] + [detections()] * 6 + [detections((12.0, 0.0))]
    maps = stepper(static, params)(scans)
    for s in range(6):
        assert maps[s].active[0] and not maps[s].confirmed[0] and maps[s].misses[0] == 0, s
        np.testing.assert_allclose(maps[s].log_odds[0], 0.0)
    assert not maps[6].active.any()
    assert maps[7].active.sum() == 1 and maps[7].active[0]  # slot 0 reused
    np.testing.assert_allclose(maps[7].mean[0], [12.0, 0.0], atol=1e-3)
    assert maps[7].born[0] == 7


@pytest.mark.slow
def test_a_confirmed_landmark_out_of_view_is_kept():
    """Confirmed (three detections), then out of view for longer than the tentative period: kept."""
    cfg, static, params = settings()
    side = (10.0, math.radians(86.0))
    maps = stepper(static, params)([detections(side)] * 3 + [detections()] * 10)
    assert maps[-1].active[0] and maps[-1].confirmed[0] and maps[-1].misses[0] == 0


@pytest.mark.slow
def test_clutter_only_log_confirms_no_landmark():
    """A simulated log whose every detection is clutter (p_detect 0, 2 false detections per scan):
    landmarks are started (tentative) but none is ever confirmed, with the default settings."""
    cfg = load_config(None, ["sim.duration=60", "sim.p_detect=0", "sim.clutter_rate=2", "filter.n_particles=4"])
    log = load_log(cfg)
    static, params = settings_from_config(cfg, log.segments.k_max)
    run = run_filter(static, params, log.segments, 0)
    assert np.asarray(run.outputs.n_new).sum() > 50
    assert int(np.max(run.outputs.n_landmarks)) > 0
    assert int(np.max(run.outputs.n_confirmed)) == 0
    lm = run.state.particles.landmarks
    assert not bool(jnp.any(lm.active & lm.confirmed))


@pytest.mark.slow
def test_occlusion_on_a_hand_built_scene():
    """Pose at the origin, heading +x, no detection of the local landmarks this scan:
    A (10 m, 0 deg, confirmed, 0.3 m diameter) hides B (20 m, 0.57 deg) behind it; C (20 m, 14 deg)
    is in the open; D (25 m, -20 deg) is hidden by a detection at 6 m, -20.5 deg. So A and C are
    missed, B and D are not; without the occlusion rule all four are missed."""
    cfg, static, params = settings()
    mp = params.map
    pts = {
        "A": (10.0, 0.0),
        "B": (20.0, 0.2),
        "C": (20 * math.cos(math.radians(14)), 20 * math.sin(math.radians(14))),
        "D": (25 * math.cos(math.radians(-20)), 25 * math.sin(math.radians(-20))),
    }
    local = LandmarkMap.empty(4)._replace(
        mean=jnp.asarray(list(pts.values())),
        active=jnp.ones(4, bool),
        confirmed=jnp.ones(4, bool),
        log_odds=jnp.full(4, 3.0),
        hits=jnp.full(4, 5, jnp.int32),
        diam=jnp.full(4, 0.3),
    )
    z, z_mask = detections((6.0, math.radians(-20.5)))
    # Geometry by hand: A's half-angle atan((0.15 + 0.3) / 10) = 2.6 deg covers B's 0.57 deg; the
    # detection's atan((0.15 + 0.3) / 6) = 4.3 deg covers D's 0.5 deg difference; nothing covers C.
    for occlusion, expect in ((True, [True, False, True, False]), (False, [True, True, True, True])):
        out = manage_window(
            local,
            jnp.zeros(3),
            jnp.zeros(4, bool),
            ScanDetections(jnp.asarray(z), jnp.asarray(z_mask), jnp.full(K, 0.3)),
            jnp.asarray(True),
            0,
            params.measurement,
            Management(mp, occlusion),
        )
        np.testing.assert_array_equal(np.asarray(out.misses), np.asarray(expect, int), err_msg=str(occlusion))
        np.testing.assert_allclose(out.log_odds, np.where(expect, 3.0 + math.log(0.2 / 0.8), 3.0), rtol=1e-12)
    # The rule itself: a nearer occluder at the same bearing hides; a farther one does not.
    zp = jnp.array([[20.0, 0.0], [5.0, 0.0]])
    hidden = occluded(zp, jnp.array([[10.0, 0.01]]), jnp.array([0.2]), jnp.array([True]), 0.0)
    np.testing.assert_array_equal(hidden, [True, False])
    # Across the +-pi seam (behind the vehicle): 0.02 rad apart, half-angle atan(0.2 / 10) = 0.02
    # rad, so the pair 0.015 rad apart is hidden and the one 0.03 rad apart is not.
    zp = jnp.array([[20.0, -math.pi + 0.005], [20.0, -math.pi + 0.02], [20.0, math.pi - 0.02]])
    hidden = occluded(zp, jnp.array([[10.0, math.pi - 0.01]]), jnp.array([0.2]), jnp.array([True]), 0.0)
    np.testing.assert_array_equal(hidden, [True, False, True])


@pytest.mark.slow
def test_management_over_the_window_prefix_equals_the_whole_window():
    """``manage_window_prefix`` (management over the 16, 32 or 64 leading window slots that hold
    the particle's landmarks, one branch for a vmapped batch) gives every landmark what
    management over the whole window gives: the hand-built occlusion scene in a 64-slot window
    has the hand-computed misses, and random scenes (1-64 landmarks, alone and in a vmapped
    batch; random detections and associations) match the whole-window computation bit for bit."""
    cfg, static, params = settings()
    mp, W = params.map, 64
    rng = np.random.default_rng(5)

    def scene(n):
        r, b = rng.uniform(2, 40, W), rng.uniform(-np.pi, np.pi, W)
        active = np.arange(W) < n
        local = LandmarkMap.empty(W)._replace(
            mean=jnp.asarray(np.where(active[:, None], np.stack([r * np.cos(b), r * np.sin(b)], -1), 0.0)),
            active=jnp.asarray(active),
            confirmed=jnp.asarray(active & (rng.random(W) < 0.7)),
            log_odds=jnp.asarray(np.where(active, rng.uniform(-1, 4, W), 0.0)),
            hits=jnp.asarray(np.where(active, rng.integers(1, 6, W), 0).astype(np.int32)),
            born=jnp.asarray(np.where(active, rng.integers(-10, 1, W), 0).astype(np.int32)),
            diam=jnp.asarray(np.where(active, rng.uniform(0.1, 0.8, W), 0.0)),
        )
        seen = jnp.asarray(active & (rng.random(W) < 0.2))
        z = jnp.asarray(np.stack([rng.uniform(2, 40, K), rng.uniform(-np.pi, np.pi, K)], -1))
        return local, seen, z, jnp.asarray(rng.random(K) < 0.8)

    def full(local, seen, z, z_mask):
        dets = ScanDetections(z, z_mask, jnp.full(K, 0.3))
        return manage_window(
            local, jnp.zeros(3), seen, dets, jnp.asarray(True), 0, params.measurement, Management(mp, True)
        )

    def prefix(local, seen, z, z_mask):
        manage = lambda loc, sn: full(loc, sn, z, z_mask)  # noqa: E731
        return manage_window_prefix(local, seen, jnp.sum(local.active), manage)

    # Alone: buckets 16, 16, 32, 32, 64, 64; the batch (at most 32) takes the 32 branch.
    alone = [scene(n) for n in (1, 16, 17, 32, 33, 64)]
    batch = jax.tree.map(lambda *a: jnp.stack(a), *[scene(n) for n in (1, 5, 16, 17, 0, 30, 32, 2)])
    for got, want in (
        (jax.jit(jax.vmap(prefix))(*batch), jax.vmap(full)(*batch)),
        *((jax.jit(prefix)(*sc), full(*sc)) for sc in alone),
    ):
        for f in ("log_odds", "misses", "confirmed", "active"):
            np.testing.assert_array_equal(np.asarray(getattr(got, f)), np.asarray(getattr(want, f)), err_msg=f)
    # The hand-built scene of test_occlusion_on_a_hand_built_scene in the first 4 of 64 slots.
    pts = [
        (10.0, 0.0),
        (20.0, 0.2),
        (20 * math.cos(math.radians(14)), 20 * math.sin(math.radians(14))),
        (25 * math.cos(math.radians(-20)), 25 * math.sin(math.radians(-20))),
    ]
    first = np.arange(W) < 4
    local = LandmarkMap.empty(W)._replace(
        mean=jnp.asarray(np.concatenate([pts, np.zeros((W - 4, 2))])),
        active=jnp.asarray(first),
        confirmed=jnp.asarray(first),
        log_odds=jnp.asarray(np.where(first, 3.0, 0.0)),
        hits=jnp.asarray(np.where(first, 5, 0).astype(np.int32)),
        diam=jnp.full(W, 0.3),
    )
    z, z_mask = detections((6.0, math.radians(-20.5)))
    out = prefix(local, jnp.zeros(W, bool), jnp.asarray(z), jnp.asarray(z_mask))
    np.testing.assert_array_equal(np.asarray(out.misses)[:4], [1, 0, 1, 0])
    np.testing.assert_array_equal(np.asarray(out.misses)[4:], 0)


@pytest.mark.slow
def test_diameter_term_separates_two_trees_at_the_same_range_and_bearing():
    """Two landmarks at the same place, diameters 0.2 and 0.5 m: a detection of diameter 0.5 m
    matches the second only with the diameter term (without it, the tie goes to the first slot)."""
    cfg, static, params = settings()
    local = LandmarkMap.empty(2)._replace(
        mean=jnp.array([[10.0, 0.0], [10.0, 0.0]]),
        cov=jnp.broadcast_to(0.01 * jnp.eye(2), (2, 2, 2)),
        active=jnp.ones(2, bool),
        diam=jnp.array([0.2, 0.5]),
        diam_var=jnp.full(2, 1e-4),
    )
    z, z_mask = detections((10.0, 0.0))
    for use, slot in ((False, 0), (True, 1)):
        a = associate(
            local,
            jnp.zeros(3),
            1e-6 * jnp.eye(3),
            ScanDetections(jnp.asarray(z), jnp.asarray(z_mask), jnp.array([0.5, 0.0, 0.0])),
            params.R,
            Gating(params.gate, params.new_landmark, use_diameter=use, sigma_diameter=0.05),
        )
        assert int(a.slot[0]) == slot, use
    # The distance to the 0.2 m tree carries (0.3)^2 / (1e-4 + 0.05^2) = 34.6 more.
    np.testing.assert_allclose(float(a.d2[0]), 0.0, atol=1e-9)


@pytest.mark.slow
def test_diameter_estimates_converge_to_the_true_diameters():
    """On a simulated log (per-detection diameter noise 0.02 m), the confirmed landmarks matched to
    a true tree carry its diameter to well below the noise of one detection. The controls are exact
    here, so that the map lies on the true trees and every landmark can be matched to its tree."""
    cfg = load_config(
        None,
        [
            "sim.duration=60",
            "filter.n_particles=4",
            "sim.sigma_v=0",
            "sim.sigma_alpha_deg=0",
            "sim.steering_bias_deg=0",
            "noise.sigma_v=0.05",
            "noise.sigma_alpha_deg=0.5",
            "noise.sigma_r=0.3",
            "noise.sigma_beta_deg=1",
        ],
    )
    log = load_log(cfg)
    static, params = settings_from_config(cfg, log.segments.k_max)
    run = run_filter(static, params, log.segments, 0)
    lm = jax.tree.map(lambda a: np.asarray(a)[int(run.state.best)], run.state.particles.landmarks)
    sel = lm.active & lm.confirmed
    tree = log.raw.truth_landmarks
    d = np.linalg.norm(lm.mean[sel][:, None] - tree[None], axis=-1)
    near, j = d.min(axis=1) < 1.0, d.argmin(axis=1)
    assert near.sum() >= 20
    err = np.abs(lm.diam[sel][near] - log.raw.truth_diameters[j[near]])
    hits = lm.hits[sel][near]
    assert np.median(hits) >= 10
    assert np.median(err) < 0.01 and np.max(err) < 0.06  # one detection: 0.02 sd
    # the scalar filter's variance is sigma_diameter^2 / hits (the running mean)
    np.testing.assert_allclose(lm.diam_var[sel][near], cfg.map.sigma_diameter**2 / hits, rtol=1e-9)


@pytest.mark.slow
def test_capacity_is_never_exceeded_silently():
    """A map too small for the log: new landmarks that find no slot are counted, never lost
    silently, and no map holds more than its capacity."""
    cfg = load_config(None, ["sim.duration=40", "filter.n_particles=3", "filter.capacity=6", "filter.window=6"])
    log = load_log(cfg)
    static, params = settings_from_config(cfg, log.segments.k_max)
    run = run_filter(static, params, log.segments, 0)
    assert int(run.state.overflow) > 0 and int(np.sum(run.outputs.overflow)) == int(run.state.overflow)
    assert int(np.max(np.sum(run.state.particles.landmarks.active, axis=1))) == 6


@pytest.mark.slow
def test_management_settings_are_traced():
    """Every management value is a traced hyperparameter: configurations differing only in them
    share the static settings (one compiled program) and give different runs."""
    a = load_config(None, ["sim.duration=30", "filter.n_particles=3"])
    b = load_config(
        None,
        [
            "sim.duration=30",
            "filter.n_particles=3",
            "map.p_detect=0.6",
            "map.p_false=0.3",
            "map.confirm_hits=2",
            "map.tentative_scans=9",
            "map.use_tentative=true",
            "map.use_diameter=true",
            "map.sigma_diameter=0.1",
            "map.view_margin=1",
            "map.occlusion_width=0.5",
            "map.remove_probability=0.2",
        ],
    )
    log = load_log(a)
    (sa, pa), (sb, pb) = (settings_from_config(c, log.segments.k_max) for c in (a, b))
    assert sa == sb
    ra, rb = (run_filter(sa, p, log.segments, 0) for p in (pa, pb))
    assert not np.array_equal(np.asarray(ra.outputs.n_landmarks), np.asarray(rb.outputs.n_landmarks))


def test_observable_trees_are_those_in_view_long_enough():
    """The map is judged against the trees the true path saw: compare the observable mask with a
    brute-force count of scans in view."""
    from nanoslam_jax.eval.metrics import observable_landmarks

    tp = np.array([[0.0, 0, 0, 0], [10.0, 10, 0, 0]])  # moving along +x at 1 m/s, heading +x
    trees = np.array([[4.7, 3.0], [30.0, 0.0], [-4.0, 0.0], [5.0, 40.0]])
    t = np.arange(0.0, 10.0, 0.5)  # 20 scans at x = 0 .. 9.5
    got = observable_landmarks(trees, tp, t, max_range=20.0, fov_deg=180.0, min_scans=10)
    # tree 0: in view while x <= 4.5 (10 scans), then behind the laser; tree 1: within
    # 20 m from x > 10 only (never); tree 2: behind (never); tree 3: 40 m off (never)
    np.testing.assert_array_equal(got, [True, False, False, False])
    assert observable_landmarks(trees, tp, t, 20.0, 180.0, min_scans=11).sum() == 0


@pytest.mark.parametrize("method", ["ekf_slam"])
@pytest.mark.slow
def test_ekf_slam_clutter_only_confirms_nothing_and_removal_marginalises(method):
    """EKF-SLAM with management: a clutter-only log confirms no landmark, and every removed slot
    is an exact inactive slot of the joint Gaussian (mean 0, identity block, zero cross-covariance:
    the marginal of the others)."""
    cfg = load_config(
        None,
        ["sim.duration=40", "sim.p_detect=0", "sim.clutter_rate=2", f"filter.method={method}", "filter.capacity=64"],
    )
    log = load_log(cfg)
    static, params = settings_from_config(cfg, log.segments.k_max)
    run = run_filter(static, params, log.segments, 0)
    assert int(np.max(run.outputs.n_confirmed)) == 0 and np.asarray(run.outputs.n_new).sum() > 50
    st = run.state
    inactive = ~np.asarray(st.landmarks.active)
    rows = 3 + 2 * np.flatnonzero(inactive)
    idx = np.sort(np.concatenate([rows, rows + 1]))
    cov = np.asarray(st.cov)
    np.testing.assert_array_equal(np.asarray(st.mean)[idx], 0.0)
    block = cov[np.ix_(idx, idx)]
    np.testing.assert_array_equal(block, np.eye(len(idx)))
    rest = np.setdiff1d(np.arange(cov.shape[0]), idx)
    np.testing.assert_array_equal(cov[np.ix_(idx, rest)], 0.0)
