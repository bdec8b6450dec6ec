"""The state of NASRUKF with per-beam measurements (:mod:`._nasrukf_beams`), the features' forms,
and the fits that start a feature from a front-end segment's or arc's beams.

Lines and arcs are kept in two sets of fixed-capacity slots, each feature as the existing NASRUKF
stores it (:mod:`._nasrukf`): its conditional given the shared pose, ``m | x ~ N(mean + gain (x -
x_mean), sqrt sqrt')``. A line is ``(rho, alpha)`` in the normal form (``nasrukf.line_form:
normal``) or, in the paper's form, ``(a, b)`` of ``y = a x + b`` or ``(c, 0)`` of ``x = c``
(``vertical``; the second value is unused and has no variance). An arc is ``(xc, yc, R)``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._linalg import mmt
from nanoslam_jax.models import wrap_angle
from nanoslam_jax.models._lines import (
    line_from_slope_intercept,
    line_from_vertical,
    normalize_line,
    slope_intercept_from_line,
)
from nanoslam_jax.methods._method_settings import nasrukf_params, nasrukf_static
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods._state import LandmarkMap

#: Lines steeper than this take the paper's vertical form ``x = c`` (``nasrukf.line_form: slope_intercept``).
VERTICAL_SLOPE = 1e3
#: Codes of a stored unmatched datum's kind (:attr:`Candidates.kind`).
EMPTY, LINE, ARC = -1, 0, 1
#: A stored unmatched datum not seen again within this many times ``N_new`` scans is dropped.
CANDIDATE_AGE = 4
#: The variance of a new feature's fit is this many times its value for white range noise on the
#: model (a segment's ends take in corner returns; a pillar's arc is short).
FIT_INFLATION = 4.0


class BeamFeatures(NamedTuple):
    """Fixed-capacity features of one kind (lines or arcs), each given the shared pose.

    Attributes:
        mean: the feature's parameters at the pose mean.
        gain: their regression on the pose, ``Cov(m, x) Cov(x)^-1``.
        sqrt: lower square root of their covariance given the pose.
        vertical: lines in the paper's form only: the line is ``x = c`` (else ``y = a x + b``).
        active: the slot holds a feature.
        hits: scans in which the feature's beams updated it (its first included).
        born: the scan it was created in.
    """

    mean: Float[Array, "c f"]
    gain: Float[Array, "c f 3"]
    sqrt: Float[Array, "c f f"]
    vertical: Bool[Array, " c"]
    active: Bool[Array, " c"]
    hits: Int[Array, " c"]
    born: Int[Array, " c"]

    @staticmethod
    def empty(capacity: int, dim: int) -> "BeamFeatures":
        """No features in ``capacity`` slots of ``dim`` parameters."""
        return BeamFeatures(
            mean=jnp.zeros((capacity, dim)),
            gain=jnp.zeros((capacity, dim, 3)),
            sqrt=jnp.broadcast_to(jnp.eye(dim), (capacity, dim, dim)),
            vertical=jnp.zeros(capacity, bool),
            active=jnp.zeros(capacity, bool),
            hits=jnp.zeros(capacity, jnp.int32),
            born=jnp.zeros(capacity, jnp.int32),
        )


class Candidates(NamedTuple):
    """The paper's stored new-feature data: front-end segments and arcs no feature explained.

    Attributes:
        kind: :data:`EMPTY`, :data:`LINE` or :data:`ARC`.
        param: the world line ``(rho, alpha, 0)`` or arc ``(xc, yc, R)`` of the latest datum.
        count: data stored for it.
        last: the scan it was last seen in.
    """

    kind: Int[Array, " g"]
    param: Float[Array, "g 3"]
    count: Int[Array, " g"]  # type: ignore[assignment]  # the field shadows tuple.count
    last: Int[Array, " g"]


class NasrukfBeamState(NamedTuple):
    """NASRUKF's state with per-beam measurements (a :class:`~._gaussian.GaussianState`).

    Attributes:
        pose, pose_sqrt: the global (fused) pose and its lower square root.
        lines, arcs: the features.
        candidates: the stored unmatched data (``nasrukf.n_new``).
        noise: the range noise variance of one beam in use, ``(1,)`` (configured or adaptive).
        noise_count: residual sets the adaptive estimate has seen.
        process_scale, process_count, process_basis: the adaptive process noise, as
            :class:`~._nasrukf_state.NasrukfState` holds it.
        moving: static initialisation is over.
        count: active features (lines and arcs).
        overflow: new features dropped because the slots were full.
        scan: scans processed so far.
        slope_form: the lines are in the paper's form (``nasrukf.line_form: slope_intercept``).
    """

    pose: Float[Array, "3"]
    pose_sqrt: Float[Array, "3 3"]
    lines: BeamFeatures
    arcs: BeamFeatures
    candidates: Candidates
    noise: Float[Array, "1"]
    noise_count: Int[Array, ""]
    process_scale: Float[Array, "w w"]
    process_count: Int[Array, ""]
    process_basis: Float[Array, "w w 3 3"]
    moving: Bool[Array, ""]
    count: Int[Array, ""]  # type: ignore[assignment]  # the field shadows tuple.count
    overflow: Int[Array, ""]
    scan: Int[Array, ""]
    slope_form: Bool[Array, ""]

    def normal_lines(self) -> Float[Array, "c 2"]:
        """Every line slot in the normal form ``(rho, alpha)`` (whatever the state's form)."""
        m, v = self.lines.mean, self.lines.vertical
        paper = jnp.where(v[:, None], line_from_vertical(m[:, 0]), line_from_slope_intercept(m[:, 0], m[:, 1]))
        return jnp.where(self.slope_form, paper, normalize_line(m))

    @property
    def pose_cov(self) -> Float[Array, "3 3"]:
        """The pose covariance ``pose_sqrt pose_sqrt'``."""
        return mmt(self.pose_sqrt, self.pose_sqrt)

    def landmark_map(self) -> LandmarkMap:
        """The lines as a map (``mean`` the normal form ``(rho, alpha)``), every active line confirmed."""
        lm = LandmarkMap.empty(self.lines.mean.shape[0])
        act = self.lines.active
        return lm._replace(mean=self.normal_lines(), active=act, confirmed=act, hits=self.lines.hits)

    def arc_table(self) -> tuple[Float[Array, "a 3"], Bool[Array, " a"]]:
        """The arcs ``(xc, yc, R)`` and which slots hold one."""
        return self.arcs.mean, self.arcs.active


def init_beam_state(static: Static, params: Params) -> NasrukfBeamState:
    """The pose at the origin with covariance ``init_cov * I``, no features, the configured noise.

    Args:
        static: static settings (``capacity``, NASRUKF's ``arc_capacity`` and ``groups``).
        params: hyperparameters (``init_cov``, NASRUKF's ``beams.sigma_beam``).
    """
    ns, bp = nasrukf_static(static), nasrukf_params(params).beams
    assert bp is not None
    g, w = ns.groups, params.motion.noise_dim
    zero = jnp.zeros((), jnp.int32)
    return NasrukfBeamState(
        pose=jnp.zeros(3),
        pose_sqrt=jnp.sqrt(jnp.asarray(params.init_cov, float)) * jnp.eye(3),
        lines=BeamFeatures.empty(static.capacity, 2),
        arcs=BeamFeatures.empty(ns.arc_capacity, 3),
        candidates=Candidates(
            jnp.full(g, EMPTY, jnp.int32), jnp.zeros((g, 3)), jnp.zeros(g, jnp.int32), jnp.zeros(g, jnp.int32)
        ),
        noise=jnp.square(jnp.asarray(bp.sigma_beam, float))[None],
        noise_count=zero,
        process_scale=jnp.eye(w),
        process_count=zero,
        process_basis=jnp.zeros((w, w, 3, 3)),
        moving=jnp.zeros((), bool),
        count=zero,
        overflow=zero,
        scan=zero,
        slope_form=jnp.asarray(ns.line_form == "slope_intercept"),
    )


# --------------------------------------------------------------------------- forms


def line_param(line: Float[Array, "2"], form: str) -> tuple[Float[Array, "2"], Bool[Array, ""]]:
    """A world line in normal form as the state's parameters: itself (``normal``), or the paper's
    ``(a, b)`` / ``(c, 0)`` with its ``vertical`` flag (``slope_intercept``)."""
    if form == "normal":
        return line, jnp.zeros((), bool)
    si = slope_intercept_from_line(line, VERTICAL_SLOPE)
    return jnp.where(si.vertical, jnp.stack([si.c, 0.0 * si.c]), jnp.stack([si.a, si.b])), si.vertical


def to_normal(m: Float[Array, "2"], vertical: Bool[Array, ""], form: str) -> Float[Array, "2"]:
    """A line's parameters in the normal form (normalised)."""
    if form == "normal":
        return normalize_line(m)
    return jnp.where(vertical, line_from_vertical(m[0]), line_from_slope_intercept(m[0], m[1]))


def line_distance(a: Float[Array, "2"], b: Float[Array, "2"]) -> Float[Array, ""]:
    """``|d rho| + 1 m |d alpha|`` between two normal-form lines, each in the orientation nearer
    the other's."""
    d_alpha = wrap_angle(a[1] - b[1])
    flip = jnp.abs(d_alpha) > jnp.pi / 2
    d_rho = jnp.where(flip, -a[0], a[0]) - b[0]
    return jnp.abs(d_rho) + jnp.abs(jnp.where(flip, wrap_angle(d_alpha + jnp.pi), d_alpha))


# --------------------------------------------------------------------------- fits of a group's beams


class GroupFit(NamedTuple):
    """The fits of one front-end feature's beams, in the sensor frame.

    Attributes:
        n: beams.
        line: total least squares line ``(rho, alpha)`` ...
        line_cov: ... and its covariance for the beams' noise (inflated).
        arc: algebraic circle fit ``(xc, yc, R)`` ...
        arc_cov: ... and its covariance (inflated).
    """

    n: Float[Array, ""]
    line: Float[Array, "2"]
    line_cov: Float[Array, "2 2"]
    arc: Float[Array, "3"]
    arc_cov: Float[Array, "3 3"]


def fit_group(r: Float[Array, " k"], phi: Float[Array, " k"], w: Bool[Array, " k"], var: Float[Array, ""]) -> GroupFit:
    """The line and circle through the beams ``w`` of a scan (returns at ranges ``r`` along ``phi``).

    Line: total least squares (the normal is the scatter's least eigenvector), ``Var(alpha) =
    s^2 / sum (t - t_mean)^2`` and ``Var(rho) = s^2 / n + t0^2 Var(alpha)`` with ``t`` the points'
    positions along the line and ``t0`` the centroid's from the foot point. Circle: the algebraic
    (Kasa) fit ``x^2 + y^2 = 2 xc x + 2 yc y + (R^2 - xc^2 - yc^2)``, whose residual is ``2 R`` times
    the range noise; its covariance propagated to ``(xc, yc, R)``. Both times :data:`FIT_INFLATION`.

    Args:
        r, phi: the scan's beams.
        w: the beams of the group.
        var: the range noise variance of a beam.
    """
    wf = w.astype(r.dtype)
    r = jnp.where(w, r, 0.0)
    n = jnp.sum(wf)
    ns = jnp.maximum(n, 1.0)
    px, py = r * jnp.cos(phi), r * jnp.sin(phi)
    cx, cy = jnp.sum(wf * px) / ns, jnp.sum(wf * py) / ns
    dx, dy = px - cx, py - cy
    C = jnp.array([[jnp.sum(wf * dx * dx), jnp.sum(wf * dx * dy)], [jnp.sum(wf * dx * dy), jnp.sum(wf * dy * dy)]])
    # the scatter's eigenvectors in closed form: the direction of the points at angle t, the normal beside it
    t = 0.5 * jnp.arctan2(2.0 * C[0, 1], C[0, 0] - C[1, 1])
    half = 0.5 * (C[0, 0] + C[1, 1])
    spread = half + jnp.sqrt(jnp.square(0.5 * (C[0, 0] - C[1, 1])) + jnp.square(C[0, 1]))
    normal = jnp.stack([-jnp.sin(t), jnp.cos(t)])
    rho = normal[0] * cx + normal[1] * cy
    line = normalize_line(jnp.stack([rho, jnp.arctan2(normal[1], normal[0])]))
    along = jnp.stack([-normal[1], normal[0]])
    t0 = along[0] * cx + along[1] * cy
    var_alpha = var / jnp.maximum(spread, 1e-12)
    line_cov = FIT_INFLATION * jnp.diag(jnp.stack([var / ns + t0 * t0 * var_alpha, var_alpha]))
    A = jnp.stack([px, py, jnp.ones_like(px)], axis=1) * wf[:, None]
    b = (px * px + py * py) * wf
    AtA = A.T @ A + 1e-9 * jnp.eye(3)
    sol = jnp.linalg.solve(AtA, A.T @ b)
    xc, yc = 0.5 * sol[0], 0.5 * sol[1]
    R = jnp.sqrt(jnp.maximum(sol[2] + xc * xc + yc * yc, 1e-12))
    J = jnp.array([[0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [xc / (2 * R), yc / (2 * R), 1.0 / (2 * R)]])
    arc_cov = FIT_INFLATION * 4.0 * R * R * var * (J @ jnp.linalg.inv(AtA) @ J.T)
    return GroupFit(n, line, line_cov, jnp.stack([xc, yc, R]), 0.5 * (arc_cov + arc_cov.T))


def candidate_update(
    cand: Candidates,
    new: Bool[Array, " g"],
    kind: Int[Array, " g"],
    param: Float[Array, "g 3"],
    scan: Int[Array, ""],
    n_new: Float[Array, ""],
    gate: Float[Array, ""],
) -> tuple[Candidates, Bool[Array, " g"]]:
    """Store a scan's unmatched front-end features and say which of them start a feature (the
    paper's N_new rule).

    A datum of the same kind within ``gate`` of a stored one (lines: :func:`line_distance`, arcs:
    centre distance) adds to its count; else it is stored in a free slot (an empty one, or one not
    seen for :data:`CANDIDATE_AGE` ``n_new`` scans). A datum whose count reaches ``n_new`` starts
    a feature and its slot is freed. Within a scan, a datum near an earlier one of the scan counts
    once (the two pieces of a wall split by a door).

    Args:
        cand: the stored data.
        new: the scan's unmatched front-end features.
        kind: their kinds (:data:`LINE`, :data:`ARC`).
        param: their world lines ``(rho, alpha, 0)`` or arcs.
        scan: the scan index.
        n_new: ``N_new``.
        gate: ``nasrukf.merge_gate``.

    Returns:
        The stored data after the scan and which of the scan's data start a feature.
    """
    g = new.shape[0]

    def dist(a_kind, a, b_kind, b):
        d = jnp.where(a_kind == LINE, line_distance(a[:2], b[:2]), jnp.hypot(a[0] - b[0], a[1] - b[1]))
        return jnp.where(a_kind == b_kind, d, jnp.inf)

    pair = jax.vmap(jax.vmap(dist, (None, None, 0, 0)), (0, 0, None, None))
    within = pair(kind, param, kind, param) < gate
    earlier = jnp.tril(jnp.ones((g, g), bool), -1)
    new = new & ~jnp.any(within & earlier & new[None, :], axis=1)
    stale = scan - cand.last > CANDIDATE_AGE * n_new
    live = (cand.kind != EMPTY) & ~stale
    d = jnp.where(live[None, :], pair(kind, param, cand.kind, cand.param), jnp.inf)
    best = jnp.argmin(d, axis=1)
    hit = new & (jnp.min(d, axis=1) < gate)
    slot_free = ~live
    free_idx, _ = _first_true(slot_free, g)
    rank = jnp.cumsum(new & ~hit) - 1
    fresh = jnp.where(new & ~hit, free_idx[jnp.clip(rank, 0, g - 1)], g)
    fresh = jnp.where(fresh < g, fresh, g)
    slot = jnp.where(hit, best, fresh)
    stored = new & (slot < g)
    base = jnp.where(live, cand.count, 0)
    count = base.at[jnp.where(stored, slot, g)].add(1, mode="drop")
    starts = stored & (count[jnp.clip(slot, 0, g - 1)] >= n_new)
    first_of_slot = ~jnp.any((slot[None, :] == slot[:, None]) & earlier & stored[None, :], axis=1)
    starts = starts & first_of_slot
    tgt = jnp.where(stored, slot, g)
    kind_new = jnp.where(live, cand.kind, EMPTY).at[tgt].set(kind, mode="drop")
    param_new = cand.param.at[tgt].set(param, mode="drop")
    last = cand.last.at[tgt].set(scan, mode="drop")
    done = jnp.zeros(g, bool).at[jnp.where(starts, slot, g)].set(True, mode="drop")
    kind_new = jnp.where(done, EMPTY, kind_new)
    count = jnp.where(done | (kind_new == EMPTY), 0, count)
    return Candidates(kind_new, param_new, count.astype(jnp.int32), last), starts


def _first_true(mask: Bool[Array, " n"], size: int) -> tuple[Int[Array, " size"], Int[Array, ""]]:
    idx = jnp.nonzero(mask, size=size, fill_value=mask.shape[0])[0]
    return idx.astype(jnp.int32), jnp.sum(mask)
