"""Particle and map pytrees: a leading particle axis over fixed-capacity landmark arrays."""

from __future__ import annotations

from typing import NamedTuple, TYPE_CHECKING

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, Key

from nanoslam_jax.models import AbstractMeasurementModel, is_composite

if TYPE_CHECKING:
    from nanoslam_jax.methods._params import Params, Static


#: Slots per block of a long map's window search and of its :class:`BlockIndex`, and the fewest
#: slots of a map searched by blocks (below, a search of the whole map is as cheap).
SEARCH_BLOCK, SEARCH_FROM = 64, 1024


class LandmarkMap(NamedTuple):
    """Fixed-capacity landmark arrays of one particle (or stacked: leading particle axis).

    Attributes:
        mean: landmark states (``l``: the measurement model's ``landmark_dim``; a point's position,
            a line's ``(rho, alpha)``, a circle's ``(xc, yc, R)``).
        cov: their covariances.
        active: which slots hold a landmark (tentative or confirmed).
        hits: detections associated with each landmark (the one that started it included).
        misses: scans in which the landmark was in view, not hidden and not detected.
        log_odds: existence log-odds (landmark management; see ``map`` in the config).
        confirmed: the landmark has been confirmed (else it is tentative).
        born: the scan (count of laser scans before it) in which the landmark was started.
        diam: estimated tree diameter (m).
        diam_var: variance of the diameter estimate (m^2).
        ident: the landmark id of the detection that started each landmark (``filter.association:
            known``), or None (no field: the ids are not kept).
        kind: each landmark's type, the index of its model in a
            :class:`~nanoslam_jax.models.Composite` measurement model, or None (one type).
    """

    mean: Float[Array, "*particles slots l"]
    cov: Float[Array, "*particles slots l l"]
    active: Bool[Array, "*particles slots"]
    hits: Int[Array, "*particles slots"]
    misses: Int[Array, "*particles slots"]
    log_odds: Float[Array, "*particles slots"]
    confirmed: Bool[Array, "*particles slots"]
    born: Int[Array, "*particles slots"]
    diam: Float[Array, "*particles slots"]
    diam_var: Float[Array, "*particles slots"]
    ident: Int[Array, "*particles slots"] | None = None
    kind: Int[Array, "*particles slots"] | None = None

    @staticmethod
    def empty(
        slots: int, batch: tuple[int, ...] = (), ident: bool = False, dim: int = 2, kinds: bool = False
    ) -> "LandmarkMap":
        """An empty map with ``slots`` slots (and optional leading batch axes) of landmarks of
        ``dim`` values (a measurement model's ``landmark_dim``); ``ident``: with the ``ident``
        field (all -1); ``kinds``: with the ``kind`` field (all 0)."""
        shape = batch + (slots,)
        return LandmarkMap(
            mean=jnp.zeros(shape + (dim,)),
            cov=jnp.broadcast_to(jnp.eye(dim), shape + (dim, dim)),
            active=jnp.zeros(shape, bool),
            hits=jnp.zeros(shape, jnp.int32),
            misses=jnp.zeros(shape, jnp.int32),
            log_odds=jnp.zeros(shape),
            confirmed=jnp.zeros(shape, bool),
            born=jnp.zeros(shape, jnp.int32),
            diam=jnp.zeros(shape),
            diam_var=jnp.ones(shape),
            ident=jnp.full(shape, -1, jnp.int32) if ident else None,
            kind=jnp.zeros(shape, jnp.int32) if kinds else None,
        )


class BlockIndex(NamedTuple):
    """A map's spatial index: a box per block of :data:`SEARCH_BLOCK` slots that holds the
    positions (first two components) of the block's active landmarks, so that a window search
    (:func:`~nanoslam_jax.methods.maps._landmarks.gather_window` with ``index``) visits only the blocks whose
    box comes near the particle. The boxes only widen (:meth:`widen` at every write of a
    position); an empty block's box is empty (``lo = +inf``, ``hi = -inf``).

    Attributes:
        lo: the smallest ``(x, y)`` of each block's landmarks.
        hi: the largest.
    """

    lo: Float[Array, "*particles blocks 2"]
    hi: Float[Array, "*particles blocks 2"]

    @staticmethod
    def empty(capacity: int, batch: tuple[int, ...] = ()) -> "BlockIndex":
        """The index of an empty map of ``capacity`` slots (a multiple of the block), with optional
        leading batch axes."""
        shape = batch + (capacity // SEARCH_BLOCK, 2)
        return BlockIndex(jnp.full(shape, jnp.inf), jnp.full(shape, -jnp.inf))

    def widen(self, slots: Int[Array, " k"], points: Float[Array, "k l"]) -> "BlockIndex":
        """The index after landmarks at ``points`` (their first two components) were written to
        ``slots`` (those at or past the capacity are ignored)."""
        block = slots // SEARCH_BLOCK
        xy = points[:, :2]
        return BlockIndex(self.lo.at[block].min(xy, mode="drop"), self.hi.at[block].max(xy, mode="drop"))

    def near(self, position: Float[Array, "2"], radius2: Float[Array, ""], blocks: int) -> Bool[Array, " blocks"]:
        """Which of the first ``blocks`` blocks have a box within ``sqrt(radius2)`` of ``position``.

        The box's distance is a lower bound of each of its landmarks' (rounding is monotone), and
        the comparison is widened by a relative 1e-9, so a block holding a landmark within the
        radius is always near."""
        lo, hi = self.lo[:blocks], self.hi[:blocks]
        dx = jnp.maximum(jnp.maximum(lo[:, 0] - position[0], position[0] - hi[:, 0]), 0.0)
        dy = jnp.maximum(jnp.maximum(lo[:, 1] - position[1], position[1] - hi[:, 1]), 0.0)
        return jnp.square(dx) + jnp.square(dy) <= radius2 * (1.0 + 1e-9)


def keeps_index(capacity: int, model: AbstractMeasurementModel) -> bool:
    """Whether a map of ``capacity`` slots of ``model``'s landmarks keeps a :class:`BlockIndex`:
    from :data:`SEARCH_FROM` slots (a multiple of the block), for point landmarks."""
    point = type(model).window_distance2 is AbstractMeasurementModel.window_distance2
    return capacity >= SEARCH_FROM and capacity % SEARCH_BLOCK == 0 and point


def keeps_versions(capacity: int, devices: int) -> bool:
    """Whether the particles' maps of ``capacity`` slots keep block versions
    (``Particles.map_version``): from :data:`SEARCH_FROM` slots (a multiple of the block), on one
    device (split over devices, resampling gathers the maps across them)."""
    return capacity >= SEARCH_FROM and capacity % SEARCH_BLOCK == 0 and devices == 1


class Particles(NamedTuple):
    """The particle set.

    Attributes:
        pose: sampled laser poses ``(px, py, phi)``.
        pose_cov: each particle's last proposal covariance (used when ``prior_cov='carry'``).
        log_w: normalised log-weights (logsumexp = 0).
        landmarks: per-particle maps.
        noise: each particle's measurement-noise variances (the diagonal of ``R``; range and bearing
            for range-bearing detections): the configured ones, or
            its adaptive estimate (``noise.adaptive``).
        noise_count: residuals each particle's adaptive estimate has seen.
        map_index: each particle's :class:`BlockIndex` of its map, kept where :func:`keeps_index`
            (None: the window is searched over the map).
        map_version: each particle's version of each block of :data:`SEARCH_BLOCK` slots of its
            map, kept where :func:`keeps_versions`: two particles' blocks with the same version
            hold the same slots, so that resampling copies only the blocks that differ from the
            ancestor's (None: it copies the slots in use).
    """

    pose: Float[Array, "particles 3"]
    pose_cov: Float[Array, "particles 3 3"]
    log_w: Float[Array, " particles"]
    landmarks: LandmarkMap
    noise: Float[Array, "particles d"]
    noise_count: Int[Array, " particles"]
    map_index: BlockIndex | None = None
    map_version: Int[Array, "particles blocks"] | None = None


class FilterState(NamedTuple):
    """Everything carried from one segment to the next.

    Attributes:
        particles: the particle set.
        key: PRNG key.
        best: index of the highest-weight particle (tracked through resampling).
        resample_count: resampling steps so far.
        overflow: new landmarks dropped so far because a particle's map was full (all particles).
        scan: laser scans processed so far (the clock of the landmarks' ``born``).
        slots: one past the highest active landmark slot of any particle (every active landmark
            lies below; :func:`slots_in_use` of the particles' maps). A step's map work stays
            below it.
    """

    particles: Particles
    key: Key[Array, ""]
    best: Int[Array, ""]
    resample_count: Int[Array, ""]
    overflow: Int[Array, ""]
    scan: Int[Array, ""]
    slots: Int[Array, ""]


def init_state(static: Static, params: Params, key: Key[Array, ""]) -> FilterState:
    """All particles at the origin with covariance ``init_cov * I``, empty maps, equal weights."""
    n = static.n_particles
    particles = Particles(
        pose=jnp.zeros((n, 3)),
        pose_cov=jnp.broadcast_to(params.init_cov * jnp.eye(3), (n, 3, 3)),
        log_w=jnp.full((n,), -jnp.log(n)),
        landmarks=LandmarkMap.empty(
            static.capacity,
            (n,),
            ident=static.association.known,
            dim=params.measurement.landmark_dim,
            kinds=is_composite(params.measurement),
        ),
        noise=jnp.broadcast_to(jnp.diagonal(params.R), (n, params.measurement.measurement_dim)),
        noise_count=jnp.zeros(n, jnp.int32),
        map_index=BlockIndex.empty(static.capacity, (n,)) if keeps_index(static.capacity, params.measurement) else None,
        map_version=(
            jnp.zeros((n, static.capacity // SEARCH_BLOCK), jnp.int32)
            if keeps_versions(static.capacity, static.devices)
            else None
        ),
    )
    zero = jnp.zeros((), jnp.int32)
    return FilterState(particles, key, zero, zero, zero, zero, zero)


def count_landmarks(landmarks: LandmarkMap) -> Int[Array, "*particles"]:
    """Active landmarks (tentative and confirmed) per particle."""
    return jnp.sum(landmarks.active, axis=-1)


def count_confirmed(landmarks: LandmarkMap) -> Int[Array, "*particles"]:
    """Confirmed landmarks per particle."""
    return jnp.sum(landmarks.active & landmarks.confirmed, axis=-1)


def slots_in_use(landmarks: LandmarkMap) -> Int[Array, ""]:
    """One past the highest active slot over all particles (0 when no landmark is active): every
    active landmark lies in the slots below."""
    active = landmarks.active.reshape(-1, landmarks.active.shape[-1])
    return jnp.max(jnp.where(active, jnp.arange(1, active.shape[-1] + 1, dtype=jnp.int32), 0), initial=0)
