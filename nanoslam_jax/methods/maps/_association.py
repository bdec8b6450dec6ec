"""Data association of a scan's detections with a particle's local map (docs/method/filter.md)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from nanoslam_jax.lib._linalg import inv_small, quad_form, sandwich, sym
from nanoslam_jax.lib._trig import computed_once
from nanoslam_jax.models import (
    AbstractMeasurementModel,
    RangeBearing,
    is_composite,
    is_range_bearing,
    range_bearing_jacobian_components,
    row_models,
    row_noise,
    wrap_angle,
)
from nanoslam_jax.methods.maps._landmarks import init_landmark, window_prefixes
from nanoslam_jax.methods._state import LandmarkMap


class Association(NamedTuple):
    """Result of associating ``k_max`` detections with a local map of ``window`` slots.

    Attributes:
        slot: local slot matched by each detection, -1 if none. Slots ``>= window`` are
            provisional landmarks created earlier in the same scan.
        is_new: detection starts a new landmark (in provisional slot ``window + k``).
        d2: best squared Mahalanobis distance of each detection (inf if no candidate).
    """

    slot: Int[Array, " k_max"]
    is_new: Bool[Array, " k_max"]
    d2: Float[Array, " k_max"]


def predicted_measurements(
    x: Float[Array, "3"],
    P: Float[Array, "3 3"],
    mean: Float[Array, "slots l"],
    cov: Float[Array, "slots l l"],
    R: Float[Array, "d d"],
    model: AbstractMeasurementModel | None = None,
    kind: Int[Array, " slots"] | None = None,
) -> tuple[Float[Array, "slots d"], Float[Array, "slots d d"]]:
    """Predicted detection and innovation covariance ``Gx P Gx' + Gm Sigma Gm' + R`` of each slot
    (``model``: the measurement model, default range-bearing; for a composite, ``kind``: each
    slot's type, whose model and noise it takes)."""
    model = RangeBearing() if model is None else model
    rows, ax = row_models(model, kind)
    z_hat = jax.vmap(lambda md, m: md.h(x, m), (ax, 0))(rows, mean)
    Gx, Gm = jax.vmap(lambda md, m: md.jacobians(x, m), (ax, 0))(rows, mean)
    S = sandwich(Gx, P) + sandwich(Gm, cov) + row_noise(rows, ax, R)[0]
    return z_hat, S


def innovation_information(
    x: Float[Array, "3"],
    P: Float[Array, "3 3"],
    mean: Float[Array, "slots l"],
    cov: Float[Array, "slots l l"],
    R: Float[Array, "d d"],
    model: AbstractMeasurementModel | None = None,
    kind: Int[Array, " slots"] | None = None,
):
    """:func:`predicted_measurements` and the inverse of ``S`` (``kind``: each slot's type, for a
    composite model).

    Returns:
        For a range-bearing ``model`` (the default), one array per component: ``(r, beta)``
        predicted for each slot and ``(a00, a01, a11)``, the entries of ``S^-1`` (symmetric).
        Kept apart because on XLA:CPU the stacked per-slot 2x2 algebra costs ~10 % of a whole
        1000-particle filter step more (this is evaluated for every slot of the window). For any
        other model: ``z_hat`` ``(slots, d)`` and ``S^-1`` ``(slots, d, d)`` (autodiff Jacobians).
    """
    if model is not None and not is_range_bearing(model):
        z_hat, S = predicted_measurements(x, P, mean, cov, R, model, kind)
        return z_hat, inv_small(sym(S))
    (zr, zb), J = range_bearing_jacobian_components(x[0], x[1], x[2], mean[:, 0], mean[:, 1])

    def s(a, b):  # (Gx P Gx' + Gm cov Gm' + R)[a, b]
        return (
            sum(J[a][i] * J[b][j] * P[i, j] for i in range(3) for j in range(3))
            + sum(J[a][3 + i] * J[b][3 + j] * cov[:, i, j] for i in range(2) for j in range(2))
            + R[a, b]
        )

    s00, s01, s11 = computed_once((s(0, 0), s(0, 1), s(1, 1)))  # else each entry of S^-1 recomputes all three
    det = s00 * s11 - s01 * s01
    return (zr, zb), (s11 / det, -s01 / det, s00 / det)


class ScanDetections(NamedTuple):
    """A scan's detections, as association and landmark management take them.

    Attributes:
        z: the detections ``(k_max, d)``.
        mask: which rows are real detections.
        diam: the diameter reported with each detection (None: none).
        ident: each detection's landmark id, for known association (``filter.association: known``;
            -1: none), or None (association by distance).
        kind: each detection's type, for a :class:`~nanoslam_jax.models.Composite` measurement
            model, or None (one type).
    """

    z: Float[Array, "k_max d"]
    mask: Bool[Array, " k_max"]
    diam: Float[Array, " k_max"] | None = None
    ident: Int[Array, " k_max"] | None = None
    kind: Int[Array, " k_max"] | None = None


@dataclasses.dataclass(frozen=True)
class AbstractAssociation:
    """Which landmark each detection is (``filter.association`` names one): a filter's component,
    a frozen dataclass (hashable: part of its static settings).

    Attributes:
        name: its name (``filter.association``).
        known: detections carry the id of their landmark and are matched by it (the map keeps
            each landmark's id); otherwise by distance through the gates (:class:`Gating`).
    """

    name: ClassVar[str] = ""
    known: ClassVar[bool] = False

    def detection_ids(self, z_id: Int[Array, " k_max"] | None) -> Int[Array, " k_max"] | None:
        """The landmark ids association matches by (``z_id``: the log's, -1 for none), or None."""
        return z_id if self.known else None


@dataclasses.dataclass(frozen=True)
class NearestAssociation(AbstractAssociation):
    """Nearest neighbour by squared Mahalanobis distance, within the chi-square gates."""

    name: ClassVar[str] = "nearest"


@dataclasses.dataclass(frozen=True)
class KnownAssociation(AbstractAssociation):
    """By the landmark id each detection carries (a simulator's or a surveyed log's); a detection
    without an id (-1) is not associated."""

    name: ClassVar[str] = "known"
    known: ClassVar[bool] = True


class Gating(eqx.Module):
    """The nearest-neighbour association rule: its chi-square gates and how detections take turns.

    Attributes:
        gate: a detection whose best squared Mahalanobis distance is below this is associated.
        new_landmark: a detection whose best distance is above this starts a landmark.
        sequential: (static) process detections in order, so a landmark is claimed at most once
            and a landmark created by detection k can be matched by a later one. If False,
            detections are associated independently with existing landmarks and, when two pick
            the same landmark, only the closer keeps it.
        use_diameter: add ``(d_k - d_j)^2 / (var_j + sigma_diameter^2)`` to the distance of
            detection ``k`` to landmark ``j`` (its diameter estimate ``d_j``, variance ``var_j``;
            a provisional landmark has the diameter of the detection that created it and variance
            ``sigma_diameter^2``). The distance is then a 3-dof chi-square; the gates apply to it.
            Only where the detections carry diameters.
        sigma_diameter: diameter measurement noise (m).
    """

    gate: Float[ArrayLike, ""]
    new_landmark: Float[ArrayLike, ""]
    sequential: bool = eqx.field(static=True, default=True)
    use_diameter: Bool[ArrayLike, ""] | bool = False
    sigma_diameter: Float[ArrayLike, ""] | float = 1.0


class SlotTerms(NamedTuple):
    """What :func:`nearest_neighbours` adds to the innovation distances (each None: not used).

    Attributes:
        diam: ``(diam, slot_diam, slot_info, use)``: each detection's diameter, each slot's
            diameter estimate and ``1 / (var_j + sigma_diameter^2)``, and whether the term
            ``(d_k - d_j)^2 slot_info_j`` is added to the distances (see :class:`Gating`).
        ident: ``(z_id, slot_id)``: known association by landmark id: detection ``k`` is at
            distance 0 from the slots whose id is ``z_id[k] >= 0`` and at infinity from every other.
        kind: ``(z_kind, slot_kind)``: each detection's and each slot's type (a composite model):
            a detection is at infinity from every slot of another type.
    """

    diam: tuple | None = None
    ident: tuple | None = None
    kind: tuple | None = None


def associate(
    local: LandmarkMap,
    x: Float[Array, "3"],
    P: Float[Array, "3 3"],
    dets: ScanDetections,
    R: Float[Array, "d d"],
    gating: Gating,
    model: AbstractMeasurementModel | None = None,
) -> Association:
    """Nearest-neighbour association with a chi-square gate and a new-landmark threshold, or by
    known landmark ids.

    Args:
        local: the particle's local map (``window`` slots). Each detection ``k`` also has a
            provisional landmark (slot ``window + k``, initialised at the prior mean), which a
            later detection may match if detection ``k`` starts a landmark.
        x, P: the particle's prior mean and covariance.
        dets: the scan's detections. With ``dets.ident`` (known association) a detection matches
            the landmark whose ``ident`` is its id and starts one when none has it (its
            provisional landmark carries the id); a detection without an id is not associated;
            the distances are not used (``d2`` is 0 for a match). With ``dets.kind`` (a composite
            ``model``; the local map then has the ``kind`` field) a detection is associated only
            with the landmarks of its type.
        R: measurement noise covariance.
        gating: the association rule (gates, order, diameter term).
        model: the measurement model (default range-bearing).
    """
    z_kind = dets.kind
    # Provisional landmarks, one per detection, initialised at the prior mean.
    rows, ax = row_models(RangeBearing() if model is None else model, z_kind)
    R_rows, r_ax = row_noise(rows, ax, R)
    prov_mean, prov_cov = jax.vmap(init_landmark, (None, 0, r_ax, ax))(x, dets.z, R_rows, rows)
    mean, cov = jnp.concatenate([local.mean, prov_mean]), jnp.concatenate([local.cov, prov_cov])
    kind_term = None
    if z_kind is not None and is_composite(model):
        if local.kind is None:
            raise ValueError(
                "a composite model's association needs a map with the kind field (LandmarkMap.empty(..., kinds=True))"
            )
        kind_term = (z_kind, jnp.concatenate([local.kind, z_kind]))
    z_hat, s_inv = innovation_information(x, P, mean, cov, R, model, None if kind_term is None else kind_term[1])
    diam_term = None
    if dets.diam is not None:
        var_d = jnp.square(gating.sigma_diameter)
        slot_diam = jnp.concatenate([local.diam, dets.diam])
        slot_var = jnp.concatenate([local.diam_var, jnp.broadcast_to(var_d, dets.diam.shape)]) + var_d
        diam_term = (dets.diam, slot_diam, 1.0 / slot_var, gating.use_diameter)
    id_term = None
    if dets.ident is not None:
        if local.ident is None:
            raise ValueError(
                "association by landmark id needs a map with the ident field (LandmarkMap.empty(..., ident=True))"
            )
        id_term = (dets.ident, jnp.concatenate([local.ident, dets.ident]))
    terms = SlotTerms(diam_term, id_term, kind_term)
    return nearest_neighbours(z_hat, s_inv, local.active, dets.z, dets.mask, gating, terms, model)


def associate_window_prefix(local: LandmarkMap, *args, **kwargs) -> Association:
    """:func:`associate` (same arguments) over the smallest prefix of the local window that holds
    its landmarks: 16, 32 or all slots (``lax.switch``).

    The local window holds its landmarks in its leading slots (:func:`._landmarks.gather_window`)
    and inactive slots never match, so every detection gets the association it gets over the whole
    window, while the predicted detections and innovation covariances are computed for
    ``prefix + k_max`` slots instead of ``window + k_max``. A provisional landmark keeps its slot
    number (``window + k``). One branch for all particles (:func:`._landmarks.window_prefixes`).
    """
    w = local.active.shape[0]
    sizes, index = window_prefixes(w, jnp.sum(local.active))
    if len(sizes) == 1:
        return associate(local, *args, **kwargs)

    def prefix(b):
        def branch(loc):
            a = associate(jax.tree.map(lambda f: f[:b], loc), *args, **kwargs)
            return a._replace(slot=jnp.where(a.slot >= b, a.slot - b + w, a.slot))

        return branch

    return jax.lax.switch(index, [prefix(b) for b in sizes], local)


def nearest_neighbours(
    z_hat: tuple[Float[Array, " slots"], Float[Array, " slots"]] | Float[Array, "slots d"],
    s_inv: tuple[Float[Array, " slots"], Float[Array, " slots"], Float[Array, " slots"]] | Float[Array, "slots d d"],
    active: Bool[Array, " window"],
    z: Float[Array, "k_max d"],
    z_mask: Bool[Array, " k_max"],
    gating: Gating,
    terms: SlotTerms = SlotTerms(),
    model: AbstractMeasurementModel | None = None,
) -> Association:
    """The association rule of :func:`associate`, given every slot's predicted detection and
    innovation information (for filters whose innovation covariances are their own, e.g. NASRUKF's
    joint pose-feature states).

    Args:
        z_hat: predicted range and bearing of each slot: the ``window`` slots of the local map,
            then one provisional landmark per detection (``slots = window + k_max``); for a
            generic ``model``, its predicted detections ``(slots, d)``.
        s_inv: the entries ``(a00, a01, a11)`` of each slot's inverse innovation covariance; for
            a generic ``model``, the inverses ``(slots, d, d)``.
        active: which of the ``window`` local slots hold a landmark.
        z, z_mask: the scan's detections and which are real.
        gating: the association rule (:class:`Gating`).
        terms: the diameter, id and type terms of the distances (:class:`SlotTerms`).
        model: the measurement model of a generic ``(z_hat, s_inv)`` (arrays from
            :func:`innovation_information`: its ``innovation`` gives the residuals); unused
            for the range-bearing components.
    """
    k_max = z.shape[0]
    window = active.shape[0]
    # Components kept apart: stacking each detection's innovations (range, bearing) into one array
    # per loop step is slower on CPU.
    components = isinstance(z_hat, tuple)
    if components:
        (zr, zb), (a00, a01, a11) = z_hat, s_inv
    active = jnp.concatenate([active, jnp.zeros(k_max, bool)])
    gate, new_landmark = gating.gate, gating.new_landmark
    diam_term, id_term, kind_term = terms
    if diam_term is None:
        diam, slot_diam, slot_info, use_diameter = jnp.zeros(k_max, z.dtype), 0.0, 0.0, False
    else:
        diam, slot_diam, slot_info, use_diameter = diam_term

    z_kind, slot_kind = (None, None) if kind_term is None else kind_term
    if id_term is not None:
        z_id, slot_id = id_term
        z_mask = z_mask & (z_id >= 0)
        diam = z_id  # each detection's id reaches ``distances`` in place of its diameter

        def distances(zk, ik, kk):
            return jnp.where(slot_id == ik, 0.0, jnp.inf).astype(z.dtype)
    elif not components:
        assert model is not None and not isinstance(z_hat, tuple) and not isinstance(s_inv, tuple)

        def distances(zk, dk, kk):
            md = model if slot_kind is None else model.of_kind(kk)  # type: ignore[attr-defined]  # a Composite
            nu = jax.vmap(md.innovation, (None, 0))(zk, z_hat)
            d2 = quad_form(nu, s_inv) + jnp.where(use_diameter, jnp.square(dk - slot_diam) * slot_info, 0.0)
            return d2 if slot_kind is None else jnp.where(slot_kind == kk, d2, jnp.inf)
    else:

        def distances(zk, dk, kk):
            nr, nb = zk[0] - zr, wrap_angle(zk[1] - zb)
            d2 = nr * (a00 * nr + a01 * nb) + nb * (a01 * nr + a11 * nb)
            return d2 + jnp.where(use_diameter, jnp.square(dk - slot_diam) * slot_info, 0.0)

    if not gating.sequential:
        return _independent(jax.vmap(distances)(z, diam, z_kind), active, z_mask, gating)

    slots = jnp.arange(window + k_max)

    def body(k, carry):
        avail, slot, is_new, d2_best = carry
        zk, mk = z[k], z_mask[k]
        d2 = jnp.where(avail, distances(zk, diam[k], None if z_kind is None else z_kind[k]), jnp.inf)
        best = jnp.min(d2)
        # The first slot attaining the minimum, by two min-reductions (cheaper than argmin on CPU).
        j = jnp.min(jnp.where(d2 == best, slots, slots.shape[0] - 1))
        matched = mk & (best < gate)
        new = mk & (best > new_landmark)
        # One-hot updates (element-wise, fused) rather than scatters.
        avail = (avail & ~((slots == j) & matched)) | ((slots == window + k) & new)
        return (
            avail,
            slot.at[k].set(jnp.where(matched, j, -1)),
            is_new.at[k].set(new),
            d2_best.at[k].set(jnp.where(mk, best, jnp.inf)),
        )

    # Only up to the last real detection: the count does not depend on the particle, so under
    # vmap this stays one loop of that many steps (a scan's mean is ~5 detections, k_max 14).
    n_steps = jnp.max(jnp.where(z_mask, jnp.arange(k_max) + 1, 0))
    init = (active, jnp.full(k_max, -1), jnp.zeros(k_max, bool), jnp.full(k_max, jnp.inf, z.dtype))
    _, slot, is_new, d2 = jax.lax.fori_loop(0, n_steps, body, init)
    return Association(slot, is_new, d2)


def _independent(
    d2: Float[Array, "k_max slots"], active: Bool[Array, " slots"], z_mask: Bool[Array, " k_max"], gating: Gating
) -> Association:
    """Each detection's nearest slot, found independently (``gating.sequential`` False): when two
    detections claim one landmark, only the closer keeps it."""
    k_max = z_mask.shape[0]
    d2 = jnp.where(active[None, :], d2, jnp.inf)
    j = jnp.argmin(d2, axis=1)
    best = jnp.take_along_axis(d2, j[:, None], 1)[:, 0]
    matched = z_mask & (best < gating.gate)
    # Keep only the closest claimant of each landmark.
    claim = jnp.where(matched[:, None] & (j[:, None] == jnp.arange(d2.shape[1])), best[:, None], jnp.inf)
    winner = jnp.argmin(claim, axis=0)
    matched = matched & (winner[j] == jnp.arange(k_max))
    is_new = z_mask & (best > gating.new_landmark)
    return Association(jnp.where(matched, j, -1), is_new, jnp.where(z_mask, best, jnp.inf))
