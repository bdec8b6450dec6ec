"""The NASRUKF FastSLAM state (:mod:`._nasrukf`): the features' joint-state parts, the fused pose
and the measurement-noise estimate, and the initial state.

A feature is stored as ``(mean, gain, sqrt)``, its centre's (and for arcs its radius's) conditional
given the pose, ``m | x ~ N(mean + gain (x - x_mean), sqrt sqrt')``, beside the same bookkeeping
fields as the particle filters' landmarks (a :class:`~._state.LandmarkMap`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from nanoslam_jax.lib._linalg import mmt, sandwich, sym
from nanoslam_jax.methods._method_settings import NasrukfParams, NasrukfStatic, nasrukf_static
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods._state import LandmarkMap


class NasrukfFeatures(NamedTuple):
    """Fixed-capacity features: each joint state's feature part, given the shared pose.

    Attributes:
        mean: the feature's mean (centre, and radius for arcs) at the pose mean.
        gain: its regression on the pose, ``Cov(m, x) Cov(x)^-1``.
        sqrt: lower square root of its covariance given the pose.
        landmarks: the per-feature bookkeeping (``active``, ``hits``, ``misses``, ``log_odds``,
            ``confirmed``, ``born``, ``diam``, ``diam_var``) as a :class:`~._state.LandmarkMap`
            whose ``mean`` and ``cov`` are not used (the features' own are above), as EKF-SLAM's
            state keeps its landmarks' bookkeeping.
    """

    mean: Float[Array, "capacity f"]
    gain: Float[Array, "capacity f 3"]
    sqrt: Float[Array, "capacity f f"]
    landmarks: LandmarkMap

    def book(self, cov: Float[Array, "capacity 2 2"] | None = None) -> LandmarkMap:
        """The features as a :class:`~._state.LandmarkMap` (centres; ``cov``: their covariances,
        default identity placeholders) for the shared landmark-management functions."""
        n = self.mean.shape[0]
        cov = jnp.broadcast_to(jnp.eye(2, dtype=self.mean.dtype), (n, 2, 2)) if cov is None else cov
        return self.landmarks._replace(mean=self.mean[:, :2], cov=cov)


class NasrukfState(NamedTuple):
    """The NASRUKF state carried from one segment to the next (a
    :class:`~._gaussian.GaussianState`).

    Attributes:
        pose: the global (fused) pose mean.
        pose_sqrt: its lower square root.
        features: the per-feature joint states' feature parts.
        noise: the measurement-noise variances in use (range, bearing, and diameter for arcs): the
            configured ones, or the adaptive estimate.
        noise_count: residuals the adaptive estimate has seen.
        process_scale: the process-noise scale ``Lambda`` in use: the time update's noise is
            ``S(dt) Lambda^(1/2) e`` with ``S`` the motion model's configured square root (identity,
            or the adaptive estimate with ``nasrukf.adaptive_process``).
        process_count: updates the adaptive process-noise estimate has seen.
        process_basis: the linearised map from ``Lambda`` to the pose covariance added since the last
            update (:func:`~._srukf.process_noise_basis`; zeros unless the estimate is on).
        count: active features.
        overflow: new features dropped so far because the slots were full.
        scan: laser scans processed so far (the clock of ``born``).
    """

    pose: Float[Array, "3"]
    pose_sqrt: Float[Array, "3 3"]
    features: NasrukfFeatures
    noise: Float[Array, " mz"]
    noise_count: Int[Array, ""]
    process_scale: Float[Array, "w w"]
    process_count: Int[Array, ""]
    process_basis: Float[Array, "w w 3 3"]
    count: Int[Array, ""]  # type: ignore[assignment]  # the field shadows tuple.count
    overflow: Int[Array, ""]
    scan: Int[Array, ""]

    @property
    def pose_cov(self) -> Float[Array, "3 3"]:
        """The pose covariance ``pose_sqrt pose_sqrt'``."""
        return mmt(self.pose_sqrt, self.pose_sqrt)

    def landmark_map(self) -> LandmarkMap:
        """The tree centres with their marginal covariances ``sqrt sqrt' + gain P gain'``."""
        f = self.features
        P = mmt(self.pose_sqrt, self.pose_sqrt)
        g, s = f.gain[:, :2], f.sqrt[:, :2, :2]
        cov = sym(mmt(s, s) + sandwich(g, P))
        return f.book(jnp.where(f.landmarks.active[:, None, None], cov, jnp.eye(2)))


def feature_dim(static: Static) -> int:
    """Feature dimension: 2 (centre) or 3 (centre and radius)."""
    return 3 if nasrukf_static(static).feature == "arc" else 2


def configured_noise(static: Static, params: Params) -> Float[Array, " mz"]:
    """The configured measurement-noise variances (range, bearing, and diameter for arcs; the range of
    one beam with ``nasrukf.measurement: beams``). Only NASRUKF's settings add the diameter or
    the beam."""
    ns = static.method_settings
    beams = params.method.beams if isinstance(params.method, NasrukfParams) else None
    if isinstance(ns, NasrukfStatic) and ns.measurement == "beams" and beams is not None:
        return jnp.square(jnp.asarray(beams.sigma_beam, float))[None]
    arc = isinstance(ns, NasrukfStatic) and ns.feature == "arc"
    sig = [params.sigma_r, params.sigma_beta] + ([params.map.sigma_diameter] if arc else [])
    return jnp.square(jnp.stack([jnp.asarray(s, float) for s in sig]))


def init_nasrukf_state(static: Static, params: Params) -> NasrukfState:
    """The pose at the origin with covariance ``init_cov * I``, no features, the configured noise
    (measurement and process).

    Args:
        static: static settings (``capacity``, NASRUKF's ``feature``).
        params: hyperparameters (``init_cov``, noise).
    """
    c, f, w = static.capacity, feature_dim(static), params.motion.noise_dim
    zero = jnp.zeros((), jnp.int32)
    features = NasrukfFeatures(
        mean=jnp.zeros((c, f)),
        gain=jnp.zeros((c, f, 3)),
        sqrt=jnp.broadcast_to(jnp.eye(f), (c, f, f)),
        landmarks=LandmarkMap.empty(c, ident=static.association.known),
    )
    return NasrukfState(
        pose=jnp.zeros(3),
        pose_sqrt=jnp.sqrt(jnp.asarray(params.init_cov, float)) * jnp.eye(3),
        features=features,
        noise=configured_noise(static, params),
        noise_count=zero,
        process_scale=jnp.eye(w),
        process_count=zero,
        process_basis=jnp.zeros((w, w, 3, 3)),
        count=zero,
        overflow=zero,
        scan=zero,
    )
