"""Landmark EKF update, initialisation (eq. 16), data association and the local window.

Independent truths: the range-bearing model and its Jacobians written by hand here, the textbook
EKF update (standard and Joseph forms), Mahalanobis distances computed in numpy, and the
bookkeeping of a fixed-capacity map checked slot by slot.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nanoslam_jax.methods import (
    Gating,
    LandmarkMap,
    ScanDetections,
    associate,
    ekf_update,
    gather_window,
    init_landmark,
    scatter_window,
)
from nanoslam_jax.methods.maps._landmarks import add_landmarks, update_slots
from nanoslam_jax.methods.maps._association import innovation_information
from nanoslam_jax.methods.maps._landmarks import first_true, free_slots, prefix_count
from nanoslam_jax.methods._params import Static
from nanoslam_jax.methods._state import slots_in_use


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def g(x, m):
    dx, dy = m[0] - x[0], m[1] - x[1]
    return np.array([math.hypot(dx, dy), wrap(math.atan2(dy, dx) - x[2])])


def Gm_hand(x, m):
    """d g / d m by hand."""
    dx, dy = m[0] - x[0], m[1] - x[1]
    q = dx * dx + dy * dy
    r = math.sqrt(q)
    return np.array([[dx / r, dy / r], [-dy / q, dx / q]])


def Gx_hand(x, m):
    """d g / d x by hand."""
    dx, dy = m[0] - x[0], m[1] - x[1]
    q = dx * dx + dy * dy
    r = math.sqrt(q)
    return np.array([[-dx / r, -dy / r, 0.0], [dy / q, -dx / q, -1.0]])


def innov(z, z_hat):
    d = np.asarray(z) - np.asarray(z_hat)
    return np.array([d[0], wrap(d[1])])


R = np.diag([0.5**2, np.radians(2.0) ** 2])


# ----------------------------------------------------------------------------- EKF update


EKF_CASES = [
    # pose, landmark mean, landmark cov, detection
    (np.array([1.0, -2.0, 0.3]), np.array([8.0, 3.0]), np.array([[0.4, 0.1], [0.1, 0.2]]), np.array([8.4, 0.33])),
    (np.array([0.0, 0.0, 0.0]), np.array([12.0, 0.5]), np.diag([1.0, 2.0]), np.array([11.0, 0.1])),
    # Landmark behind: predicted bearing just below -pi + 0.5 ..., detection wraps across +-pi.
    (np.array([5.0, 5.0, 0.5]), np.array([-3.0, 4.0]), np.array([[0.3, -0.05], [-0.05, 0.5]]), np.array([8.0, -3.1])),
]


@pytest.mark.parametrize("case", range(len(EKF_CASES)))
@pytest.mark.slow
def test_ekf_update_matches_hand_update(case):
    x, m, S0, z = EKF_CASES[case]
    G = Gm_hand(x, m)
    S = G @ S0 @ G.T + R
    K = S0 @ G.T @ np.linalg.inv(S)
    nu = innov(z, g(x, m))
    assert abs(nu[1]) < 1.0  # the wrap case really wraps (raw difference near 2 pi)
    m_new = m + K @ nu
    I_KG = np.eye(2) - K @ G
    P_std = I_KG @ S0
    P_joseph = I_KG @ S0 @ I_KG.T + K @ R @ K.T
    np.testing.assert_allclose(P_std, P_joseph, atol=1e-14 * np.abs(S0).max() * 10)  # optimal gain: same
    mean, cov = ekf_update(jnp.asarray(x), jnp.asarray(z), jnp.asarray(m), jnp.asarray(S0), jnp.asarray(R))
    np.testing.assert_allclose(mean, m_new, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cov, 0.5 * (P_std + P_std.T), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(cov, cov.T, atol=0)
    assert np.all(np.linalg.eigvalsh(np.asarray(cov)) > 0)
    # Information form as a further cross-check: Sigma'^-1 = Sigma^-1 + G' R^-1 G.
    np.testing.assert_allclose(
        np.linalg.inv(np.asarray(cov)), np.linalg.inv(S0) + G.T @ np.linalg.inv(R) @ G, rtol=1e-10
    )


def test_ekf_update_consistent_detection_does_not_move():
    x, m, S0, _ = EKF_CASES[0]
    mean, cov = ekf_update(jnp.asarray(x), jnp.asarray(g(x, m)), jnp.asarray(m), jnp.asarray(S0), jnp.asarray(R))
    np.testing.assert_allclose(mean, m, atol=1e-12)
    assert np.linalg.det(np.asarray(cov)) < np.linalg.det(S0)


# ----------------------------------------------------------------------------- init (eq. 16)


@pytest.mark.parametrize(
    "x,z",
    [
        (np.array([1.0, 2.0, 0.4]), np.array([7.0, -0.6])),
        (np.array([-3.0, 0.5, -2.9]), np.array([15.0, 1.2])),
        (np.array([0.0, 0.0, 3.0]), np.array([3.0, 0.3])),
    ],
)
def test_init_landmark_is_inverse_model_with_eq16_cov(x, z):
    m, cov = init_landmark(jnp.asarray(x), jnp.asarray(z), jnp.asarray(R))
    m = np.asarray(m)
    np.testing.assert_allclose(m, x[:2] + z[0] * np.array([math.cos(x[2] + z[1]), math.sin(x[2] + z[1])]), atol=1e-12)
    np.testing.assert_allclose(g(x, m), z, atol=1e-12)  # the inverse model inverts g
    Gi = np.linalg.inv(Gm_hand(x, m))
    np.testing.assert_allclose(cov, Gi @ R @ Gi.T, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("phi", [0.0, 0.7, -2.5, math.pi])
@pytest.mark.parametrize("r", [2.0, 25.0])
def test_init_landmark_straight_ahead(phi, r):
    """Along the beam the variance is sigma_r^2, across it (r sigma_beta)^2, rotated by the heading."""
    x = np.array([3.0, -1.0, phi])
    m, cov = init_landmark(jnp.asarray(x), jnp.asarray([r, 0.0]), jnp.asarray(R))
    np.testing.assert_allclose(m, x[:2] + r * np.array([math.cos(phi), math.sin(phi)]), atol=1e-12)
    rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
    expected = rot @ np.diag([R[0, 0], r * r * R[1, 1]]) @ rot.T
    np.testing.assert_allclose(cov, expected, rtol=1e-10, atol=1e-14)


# ----------------------------------------------------------------------------- association

W, K = 4, 3  # window slots, detections per scan (provisional slots)
X = np.array([0.0, 0.0, 0.0])
P = np.diag([0.01, 0.01, np.radians(0.5) ** 2])
LANDMARKS = np.array([[10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [0.0, 0.0]])  # slot 3 inactive
LM_COV = np.broadcast_to(0.04 * np.eye(2), (4, 2, 2))
ACTIVE = np.array([True, True, True, False])
GATE, NEW = 5.991, 13.816


def local_map():
    lm = LandmarkMap.empty(W)
    return lm._replace(mean=jnp.asarray(LANDMARKS), cov=jnp.asarray(LM_COV), active=jnp.asarray(ACTIVE))


def hand_S(m, cov):
    return Gx_hand(X, m) @ P @ Gx_hand(X, m).T + Gm_hand(X, m) @ cov @ Gm_hand(X, m).T + R


def test_innovation_information_is_inverse_of_hand_S():
    # Per-component predicted detections and S^-1 over a window, against the closed form with
    # correlated pose and landmark covariances.
    rng = np.random.default_rng(7)
    x = np.array([3.0, -2.0, 0.7])
    A = rng.normal(size=(3, 3))
    Px = A @ A.T * 0.05 + 0.01 * np.eye(3)
    m = x[:2] + rng.uniform(-25, 25, size=(20, 2))
    B = rng.normal(size=(20, 2, 2))
    cov = B @ np.swapaxes(B, 1, 2) * 0.2 + 0.01 * np.eye(2)
    (zr, zb), (a00, a01, a11) = jax.jit(innovation_information)(x, Px, m, cov, jnp.asarray(R))
    for k in range(20):
        S = Gx_hand(x, m[k]) @ Px @ Gx_hand(x, m[k]).T + Gm_hand(x, m[k]) @ cov[k] @ Gm_hand(x, m[k]).T + R
        np.testing.assert_allclose([[a00[k], a01[k]], [a01[k], a11[k]]], np.linalg.inv(S), rtol=1e-10)
        np.testing.assert_allclose([zr[k], zb[k]], g(x, m[k]), rtol=1e-12, atol=1e-12)


def detection_at_d2(j, d2, direction):
    """A detection at squared Mahalanobis distance d2 from landmark slot j (hand S)."""
    S = hand_S(LANDMARKS[j], LM_COV[j])
    u = np.asarray(direction, float)
    u = u / math.sqrt(u @ np.linalg.inv(S) @ u)
    return g(X, LANDMARKS[j]) + math.sqrt(d2) * u


@pytest.fixture(scope="module")
def assoc_fn():
    def fn(z, z_mask, sequential):
        return associate(
            local_map(),
            jnp.asarray(X),
            jnp.asarray(P),
            ScanDetections(z, z_mask),
            jnp.asarray(R),
            Gating(jnp.asarray(GATE), jnp.asarray(NEW), sequential),
        )

    return {s: jax.jit(lambda z, m, s=s: fn(z, m, s)) for s in (True, False)}


@pytest.mark.parametrize("sequential", [True, False])
@pytest.mark.slow
def test_associate_match_new_drop(assoc_fn, sequential):
    z = np.stack(
        [
            detection_at_d2(0, 1.0, [1.0, 0.3]),  # existing landmark 0 (d2 = 1 < gate)
            np.array([20.0, -1.2]),  # far from everything: new landmark
            detection_at_d2(1, 9.0, [0.2, 1.0]),  # between gate and new-landmark threshold: dropped
        ]
    )
    a = assoc_fn[sequential](jnp.asarray(z), jnp.ones(K, bool))
    np.testing.assert_array_equal(a.slot, [0, -1, -1])
    np.testing.assert_array_equal(a.is_new, [False, True, False])
    np.testing.assert_allclose(a.d2[0], 1.0, rtol=1e-9)
    np.testing.assert_allclose(a.d2[2], 9.0, rtol=1e-9)
    assert a.d2[1] > NEW


def test_associate_masked_detections(assoc_fn):
    z = np.stack([g(X, LANDMARKS[0]), g(X, LANDMARKS[1]), np.array([20.0, -1.2])])
    for sequential in (True, False):
        a = assoc_fn[sequential](jnp.asarray(z), jnp.array([False, True, False]))
        np.testing.assert_array_equal(a.slot, [-1, 1, -1])
        np.testing.assert_array_equal(a.is_new, [False, False, False])
        assert np.isinf(a.d2[0]) and np.isinf(a.d2[2])


def test_associate_inactive_slot_never_matched(assoc_fn):
    """Slot 3 is inactive (its stale mean sits at the pose); a detection there must not match it."""
    z = np.stack([np.array([1e-3, 0.0]), g(X, LANDMARKS[2]), np.array([25.0, 1.4])])
    for sequential in (True, False):
        a = assoc_fn[sequential](jnp.asarray(z), jnp.ones(K, bool))
        assert a.slot[0] != 3
        assert a.slot[1] == 2


def test_sequential_two_detections_of_one_new_landmark(assoc_fn):
    """Sequential: the first detection creates a provisional landmark (slot W + 0), the second matches it."""
    z1 = np.array([18.0, -0.9])
    z = np.stack([z1, z1 + np.array([0.2, np.radians(0.5)]), np.array([25.0, 1.4])])
    a = assoc_fn[True](jnp.asarray(z), jnp.ones(K, bool))
    np.testing.assert_array_equal(a.is_new, [True, False, True])
    assert int(a.slot[0]) == -1
    assert int(a.slot[1]) == W + 0 and int(a.slot[1]) >= W
    assert int(a.slot[2]) == -1
    # Relaxed (non-sequential) association: both start a landmark.
    b = assoc_fn[False](jnp.asarray(z), jnp.ones(K, bool))
    np.testing.assert_array_equal(b.is_new, [True, True, True])
    np.testing.assert_array_equal(b.slot, [-1, -1, -1])


def test_each_landmark_claimed_at_most_once(assoc_fn):
    """Two detections near landmark 0: sequential gives it to the first, non-sequential to the closer."""
    z = np.stack([detection_at_d2(0, 2.0, [1.0, 0.0]), detection_at_d2(0, 0.5, [0.0, 1.0]), g(X, LANDMARKS[1])])
    a = assoc_fn[True](jnp.asarray(z), jnp.ones(K, bool))
    assert int(a.slot[0]) == 0 and int(a.slot[1]) != 0 and int(a.slot[2]) == 1
    b = assoc_fn[False](jnp.asarray(z), jnp.ones(K, bool))
    assert int(b.slot[0]) == -1 and int(b.slot[1]) == 0 and int(b.slot[2]) == 1
    for s in (a.slot, b.slot):
        s = np.asarray(s)
        matched = s[s >= 0]
        assert len(set(matched.tolist())) == len(matched)


def test_associate_many_random_scans_claim_once(assoc_fn):
    rng = np.random.default_rng(0)
    for _ in range(30):
        j = rng.integers(0, 3, K)
        z = np.stack([g(X, LANDMARKS[i]) + rng.normal(size=2) * [0.4, 0.02] for i in j])
        for sequential in (True, False):
            s = np.asarray(assoc_fn[sequential](jnp.asarray(z), jnp.ones(K, bool)).slot)
            matched = s[s >= 0]
            assert len(set(matched.tolist())) == len(matched)
            assert np.all(ACTIVE[matched[matched < W]])


@pytest.mark.parametrize("sequential", [True, False])
@pytest.mark.slow
def test_association_over_the_window_prefix_equals_the_whole_window(sequential):
    """``associate_window_prefix`` (the association over the 16, 32 or 64 leading window slots that
    hold the particle's landmarks, one branch for a vmapped batch) gives every detection what the
    association over the whole 64-slot window gives, provisional slots included (window + k):
    random scenes of 0-64 landmarks (in the leading slots, as ``gather_window`` leaves them) with
    detections of some of them, of nothing and twice of one new landmark, alone and in a batch
    (whose branch is its largest landmark count)."""
    from nanoslam_jax.methods.maps._association import associate_window_prefix

    Wp, k = 64, 6
    rng = np.random.default_rng(11)

    def scene(n):
        x = rng.normal(size=3) * [2.0, 2.0, 0.3]
        mean = x[:2] + rng.uniform(-25, 25, (Wp, 2))
        a = rng.normal(size=(Wp, 2, 2))
        cov = a @ np.swapaxes(a, 1, 2) * 0.05 + 0.01 * np.eye(2)
        active = np.arange(Wp) < n
        local = LandmarkMap.empty(Wp)._replace(mean=jnp.asarray(mean), cov=jnp.asarray(cov), active=jnp.asarray(active))
        z = np.stack([g(x, mean[rng.integers(0, max(n, 1))]) + rng.normal(size=2) * [0.3, 0.01] for _ in range(k)])
        z[3] = [22.0, -1.0]  # a new landmark ...
        z[4] = z[3] + [0.1, 0.003]  # ... detected twice (sequential: the second matches slot W + 3)
        z_mask = jnp.asarray(rng.uniform(size=k) < 0.9).at[3].set(True).at[4].set(True)
        return local, jnp.asarray(x), jnp.asarray(z), z_mask

    def args(x, z, z_mask):
        gating = Gating(jnp.asarray(GATE), jnp.asarray(NEW), sequential)
        return (x, jnp.asarray(P), ScanDetections(z, z_mask), jnp.asarray(R), gating)

    full = jax.jit(lambda loc, x, z, zm: associate(loc, *args(x, z, zm)))
    prefix = jax.jit(lambda loc, x, z, zm: associate_window_prefix(loc, *args(x, z, zm)))
    counts = (0, 1, 16, 17, 32, 33, 64)
    scenes = [scene(n) for n in counts]
    for n, sc in zip(counts, scenes):
        got, want = prefix(*sc), full(*sc)
        for f in ("slot", "is_new", "d2"):
            np.testing.assert_array_equal(getattr(got, f), getattr(want, f), err_msg=f"{f}, {n} landmarks")
    assert any(int(full(*sc).slot[4]) == Wp + 3 for sc in scenes) == sequential  # the provisional slot
    assert any(int(s) in range(16, 64) for sc in scenes for s in full(*sc).slot)  # matches past the first bucket
    batch = jax.tree.map(lambda *a: jnp.stack(a), *[scene(n) for n in (1, 5, 16, 17, 0, 30, 32, 2)])
    got, want = jax.jit(jax.vmap(prefix))(*batch), jax.jit(jax.vmap(full))(*batch)
    for f in ("slot", "is_new", "d2"):
        np.testing.assert_array_equal(getattr(got, f), getattr(want, f), err_msg=f"batch {f}")
    assert "cond[" in str(jax.make_jaxpr(jax.vmap(prefix))(*batch))  # a branch, not every prefix computed


# ----------------------------------------------------------------------------- window gather/scatter

CAP = 10


def full_map(n_active, seed=0):
    rng = np.random.default_rng(seed)
    lm = LandmarkMap.empty(CAP)
    mean = rng.uniform(-60, 60, (CAP, 2))
    a = rng.normal(size=(CAP, 2, 2))
    cov = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(2)
    active = np.zeros(CAP, bool)
    active[rng.permutation(CAP)[:n_active]] = True
    hits = rng.integers(1, 9, CAP) * active
    return lm._replace(
        mean=jnp.asarray(mean),
        cov=jnp.asarray(cov),
        active=jnp.asarray(active),
        hits=jnp.asarray(hits, jnp.int32),
        misses=jnp.asarray(rng.integers(0, 3, CAP), jnp.int32),
    )


def assert_maps_equal(a, b):
    for u, v in zip(a, b):
        np.testing.assert_array_equal(np.asarray(u), np.asarray(v))


gather = jax.jit(gather_window, static_argnums=2)
scatter = jax.jit(scatter_window)


@pytest.mark.parametrize("n_active,radius", [(0, 1000.0), (2, 1000.0), (7, 1000.0), (CAP, 45.0)])
@pytest.mark.slow
def test_gather_within_radius_and_round_trip(n_active, radius):
    lm = full_map(n_active)
    pos = jnp.asarray([5.0, -3.0])
    local, idx, over = gather(lm, pos, W, jnp.asarray(radius))
    assert local.mean.shape == (W, 2) and idx.shape == (W,)
    act = np.asarray(lm.active)
    d = np.linalg.norm(np.asarray(lm.mean) - np.asarray(pos), axis=1)
    near = np.flatnonzero(act & (d < radius))  # the independent truth: slots within the radius
    idx_np, loc_act = np.asarray(idx), np.asarray(local.active)
    got = idx_np[loc_act]
    assert len(set(got.tolist())) == len(got)  # no slot twice
    # All near landmarks when they fit, else the W lowest (oldest) slots among them.
    assert got.tolist() == near[:W].tolist()
    assert np.all(idx_np[~loc_act] == CAP)  # unused window slots point nowhere
    assert int(np.sum(loc_act)) == min(W, len(near))
    np.testing.assert_array_equal(np.asarray(local.mean)[loc_act], np.asarray(lm.mean)[got])
    np.testing.assert_array_equal(np.asarray(local.cov)[loc_act], np.asarray(lm.cov)[got])
    assert int(over) == max(len(near) - W, 0)
    # Nothing updated, nothing new: the map comes back unchanged.
    assert_maps_equal(scatter(lm, local, idx), lm)
    back, overflow = jax.jit(add_landmarks)(lm, LandmarkMap.empty(K), jnp.zeros(K, bool))
    assert int(overflow) == 0
    assert_maps_equal(back, lm)


@pytest.mark.parametrize("n_active,slots", [(0, 3), (4, 4), (6, 7), (6, CAP), (6, 2 * CAP)])
def test_gather_over_a_prefix_holding_every_landmark_equals_the_whole_map(n_active, slots):
    """Searching only the first ``slots`` slots changes nothing when no active landmark lies beyond
    them (unused window slots still point at ``capacity``, so write-backs drop them)."""
    lm = full_map(CAP, seed=n_active)
    lm = lm._replace(active=jnp.arange(CAP) < n_active)  # a prefix map, as without landmark management
    assert int(slots_in_use(lm)) == n_active  # one past the highest active slot
    pos, radius = jnp.asarray([5.0, -3.0]), jnp.asarray(55.0)
    whole = gather(lm, pos, W, radius)
    prefix = jax.jit(gather_window, static_argnums=(2, 4))(lm, pos, W, radius, slots)
    # The independent truth: the active slots within the radius, from numpy.
    d = np.linalg.norm(np.asarray(lm.mean) - np.asarray(pos), axis=1)
    near = np.flatnonzero(np.asarray(lm.active) & (d < float(radius)))
    idx = np.asarray(prefix[1])
    assert idx[np.asarray(prefix[0].active)].tolist() == near[:W].tolist()
    assert np.all(idx[~np.asarray(prefix[0].active)] == CAP)
    for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(prefix)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_slots_in_use_is_one_past_the_highest_active_slot_of_any_particle():
    active = np.zeros((3, CAP), bool)
    assert int(slots_in_use(LandmarkMap.empty(CAP)._replace(active=jnp.asarray(active)))) == 0
    active[0, [0, 2]] = True
    active[2, 6] = True  # a gap below it (a removed landmark): still counted up to slot 6
    lm = jax.vmap(lambda _: LandmarkMap.empty(CAP))(jnp.arange(3))._replace(active=jnp.asarray(active))
    assert int(slots_in_use(lm)) == 7


def test_slot_buckets_are_powers_of_two_from_64_then_the_capacity():
    assert Static(capacity=512).slot_buckets == (64, 128, 256, 512)
    assert Static(capacity=300).slot_buckets == (64, 128, 256, 300)
    assert Static(capacity=64).slot_buckets == (64,)
    assert Static(capacity=20).slot_buckets == (20,)


def test_window_overflow_counts_only_near_landmarks():
    lm = full_map(CAP)
    pos = jnp.asarray([0.0, 0.0])
    d = np.linalg.norm(np.asarray(lm.mean), axis=1)
    radius = float(np.sort(d)[6]) + 1e-6  # exactly 7 landmarks within the radius
    _, _, over = gather(lm, pos, W, jnp.asarray(radius))
    assert int(over) == 7 - W


def new_landmarks(means, is_new, covs=None):
    covs = np.broadcast_to(np.eye(2), (len(means), 2, 2)) if covs is None else covs
    return LandmarkMap.empty(len(means))._replace(
        mean=jnp.asarray(means, float),
        cov=jnp.asarray(covs, float),
        active=jnp.asarray(is_new),
        hits=jnp.asarray(is_new, jnp.int32),
        confirmed=jnp.asarray(is_new),
        log_odds=jnp.full(len(means), 2.5),
        diam=jnp.full(len(means), 0.3),
        diam_var=jnp.full(len(means), 0.01),
    )


@pytest.mark.parametrize("contiguous", [False, True])
def test_updates_and_new_landmarks_to_free_slots(contiguous):
    lm = full_map(5, seed=1)
    if contiguous:  # without landmark management the active slots are a prefix and no landmark has misses
        lm = lm._replace(active=jnp.asarray(np.arange(CAP) < 5), misses=jnp.zeros(CAP, jnp.int32))
    local, idx, _ = gather(lm, jnp.asarray([0.0, 0.0]), W, jnp.asarray(1000.0))
    # Update the first window slot's landmark (an active one; the other two rows change nothing)
    # and create two landmarks (candidates 0 and 2).
    j_upd = int(np.flatnonzero(np.asarray(local.active))[0])
    g_upd = int(idx[j_upd])
    rows = jnp.asarray([CAP, g_upd, CAP])
    upd_mean = jnp.asarray([[1e3, 1e3], [-7.0, 7.0], [1e3, 1e3]])
    upd_cov = jnp.asarray([np.eye(2) * 9.0, np.eye(2) * 0.25, np.eye(2) * 9.0])
    back = jax.jit(update_slots)(lm, rows, upd_mean, upd_cov)
    is_new = np.array([True, False, True])
    new = new_landmarks([[100.0, 1.0], [0.0, 0.0], [102.0, 3.0]], is_new)
    back, overflow = jax.jit(add_landmarks, static_argnums=3)(back, new, jnp.asarray(is_new), contiguous)
    assert int(overflow) == 0
    np.testing.assert_array_equal(back.mean[g_upd], [-7.0, 7.0])
    np.testing.assert_array_equal(back.cov[g_upd], np.eye(2) * 0.25)
    assert int(back.hits[g_upd]) == int(lm.hits[g_upd]) + 1
    free_before = np.flatnonzero(~np.asarray(lm.active))
    placed = np.flatnonzero(np.asarray(back.active) & ~np.asarray(lm.active))
    assert len(placed) == 2 and set(placed.tolist()) <= set(free_before.tolist())
    placed_means = {tuple(np.asarray(back.mean[p]).tolist()) for p in placed}
    assert placed_means == {(100.0, 1.0), (102.0, 3.0)}
    for p in placed:
        assert int(back.hits[p]) == 1 and int(back.misses[p]) == 0
    # Every other slot is untouched.
    untouched = np.ones(CAP, bool)
    untouched[placed] = False
    untouched[g_upd] = False
    for u, v in zip(back, lm):
        if v is not None:  # `ident` is None unless association is by known id
            np.testing.assert_array_equal(np.asarray(u)[untouched], np.asarray(v)[untouched])
    assert int(np.sum(back.active)) == int(np.sum(lm.active)) + 2


def test_scatter_window_writes_every_field_back():
    lm = full_map(7, seed=4)
    local, idx, _ = gather(lm, jnp.asarray([0.0, 0.0]), W, jnp.asarray(1000.0))
    # What landmark management does to a window: scores change and a landmark is removed.
    j = int(np.flatnonzero(np.asarray(local.active))[1])
    local = local._replace(misses=local.misses + 1, active=local.active.at[j].set(False))
    back = scatter(lm, local, idx)
    used = np.asarray(idx) < CAP
    np.testing.assert_array_equal(
        np.asarray(back.misses)[np.asarray(idx)[used]], np.asarray(lm.misses)[np.asarray(idx)[used]] + 1
    )
    assert not bool(back.active[int(idx[j])])
    assert int(np.sum(back.active)) == int(np.sum(lm.active)) - 1
    rest = np.ones(CAP, bool)
    rest[np.asarray(idx)[used]] = False
    for u, v in zip(back, lm):
        if v is not None:  # `ident` is None unless association is by known id
            np.testing.assert_array_equal(np.asarray(u)[rest], np.asarray(v)[rest])


@pytest.mark.parametrize("n_active,n_new,expect_overflow", [(CAP - 1, 2, 1), (CAP, 3, 3), (CAP - 3, 3, 0)])
def test_scatter_overflow_is_counted(n_active, n_new, expect_overflow):
    lm = full_map(n_active, seed=2)
    is_new = np.arange(K) < n_new
    new = new_landmarks([[500.0, 0.0], [501.0, 0.0], [502.0, 0.0]], is_new)
    back, overflow = jax.jit(add_landmarks)(lm, new, jnp.asarray(is_new))
    assert int(overflow) == expect_overflow
    # No silent loss: every new landmark is either in the map or counted.
    placed = int(np.sum(np.asarray(back.active))) - n_active
    assert placed + int(overflow) == n_new
    assert int(np.sum(back.active)) == min(CAP, n_active + n_new)
    # Existing landmarks were not overwritten.
    act = np.asarray(lm.active)
    np.testing.assert_array_equal(np.asarray(back.mean)[act], np.asarray(lm.mean)[act])


@pytest.mark.parametrize("n_active,n_new", [(0, 2), (4, 3), (CAP - 2, 3), (CAP, 1)])
@pytest.mark.slow
def test_contiguous_placement_equals_free_slot_search_on_prefix_maps(n_active, n_new):
    """Without landmark management the active slots are a prefix: placing new landmarks after them must give
    exactly what the general free-slot search gives (including the overflow count)."""
    lm = full_map(CAP, seed=3)
    # Without landmark management the active slots are a prefix and no landmark ever has misses.
    lm = lm._replace(active=jnp.asarray(np.arange(CAP) < n_active), misses=jnp.zeros(CAP, jnp.int32))
    is_new = jnp.asarray(np.arange(K) < n_new)
    new = new_landmarks([[50.0, 1.0], [51.0, 2.0], [52.0, 3.0]], is_new)
    a, ov_a = add_landmarks(lm, new, is_new, contiguous=False)
    b, ov_b = jax.jit(add_landmarks, static_argnums=3)(lm, new, is_new, True)
    assert int(ov_a) == int(ov_b) == max(n_active + n_new - CAP, 0)
    assert_maps_equal(a, b)


@pytest.mark.parametrize("n", [1, 31, 32, 77, 512])
@pytest.mark.slow
def test_first_true_and_prefix_count_equal_numpy(n):
    rng = np.random.default_rng(n)
    for p in (0.0, 0.05, 0.5, 1.0):
        mask = rng.uniform(size=n) < p
        np.testing.assert_array_equal(np.asarray(prefix_count(jnp.asarray(mask))), np.cumsum(mask))
        for size in (1, 8, 64):
            idx, count = first_true(jnp.asarray(mask), size)
            (ref,) = np.nonzero(mask)
            expect = np.full(size, n)
            expect[: min(size, ref.size)] = ref[:size]
            np.testing.assert_array_equal(np.asarray(idx), expect)
            assert int(count) == mask.sum()


@pytest.mark.slow
def test_free_slots_over_a_prefix_equal_numpy():
    """The first k free slots searched over a prefix holding every active landmark plus k are
    those of the whole map (numpy), with ``capacity`` where the map has fewer."""
    rng = np.random.default_rng(3)
    capacity, k = 512, 14
    for in_use in (0, 1, 60, 128, 300, 505, 512):
        active = np.zeros(capacity, bool)
        active[:in_use] = rng.uniform(size=in_use) < 0.9
        if in_use:
            active[in_use - 1] = True
        (free,) = np.nonzero(~active)
        expect = np.full(k, capacity)
        expect[: min(k, free.size)] = free[:k]
        for slots in (None, in_use + k, 512):
            np.testing.assert_array_equal(
                np.asarray(free_slots(jnp.asarray(active), k, slots)), expect, err_msg=f"{in_use} {slots}"
            )
