"""The Gaussian methods' protocol: what the state and the step of a method without particles
(EKF-SLAM, NASRUKF) offer the driver.

A Gaussian method (a registered :class:`~nanoslam_jax.app.registry.Method` of kind ``"gaussian"``)
carries one hypothesis: a Gaussian over the pose (with its map), no particles, no weights, no
sampling. Its ``init(static, params)`` returns a state that satisfies :class:`GaussianState`, and
its ``step(static, params, state, segment, valid)`` returns the new state and a
:class:`GaussianStepOutput`. The driver owns the PRNG key (only a particle state carries one),
counts no resampling for a Gaussian state (:func:`~._scan.resample_count`), and turns the step's
record into the common per-scan :class:`~._step.StepOutput` in one place
(:func:`as_step_output`).
"""

from __future__ import annotations

from typing import NamedTuple, Optional, Protocol, runtime_checkable

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from nanoslam_jax.methods._state import LandmarkMap
from nanoslam_jax.methods.particle._step import StepOutput


@runtime_checkable
class GaussianState(Protocol):
    """What the state of every Gaussian method offers (a pytree: a NamedTuple of arrays).

    Attributes:
        pose: the pose mean ``(x, y, phi)``.
        pose_cov: the pose's marginal covariance.
        overflow: new landmarks (features) dropped so far because the state was full.
        scan: laser scans processed so far (the clock of the landmarks' ``born``).
    """

    @property
    def pose(self) -> Float[Array, "3"]: ...

    @property
    def pose_cov(self) -> Float[Array, "3 3"]: ...

    @property
    def overflow(self) -> Int[Array, ""]: ...

    @property
    def scan(self) -> Int[Array, ""]: ...

    def landmark_map(self) -> LandmarkMap:
        """The reported map: the landmarks' marginal means and covariances with their bookkeeping
        (``active``, ``confirmed``, ...)."""
        ...


class GaussianStepOutput(NamedTuple):
    """What a Gaussian method's step records for a segment: the estimate with its covariance and
    the map's counts (no particle fields).

    Attributes:
        pose: the pose mean after the segment.
        pose_cov: its covariance.
        n_landmarks: landmarks (tentative and confirmed) in the map.
        n_confirmed: confirmed landmarks in the map.
        n_associated: detections associated with a landmark.
        n_new: new landmarks started.
        overflow: new landmarks dropped for lack of capacity.
        n_nonfinite: 1 where the state is no longer finite, else 0.
        window_overflow: landmarks near the pose that did not fit the local window (None: the
            method has no window).
    """

    pose: Float[Array, "3"]
    pose_cov: Float[Array, "3 3"]
    n_landmarks: Int[Array, ""]
    n_confirmed: Int[Array, ""]
    n_associated: Int[Array, ""]
    n_new: Int[Array, ""]
    overflow: Int[Array, ""]
    n_nonfinite: Int[Array, ""]
    window_overflow: Optional[Int[Array, ""]] = None


def as_step_output(out: GaussianStepOutput) -> StepOutput:
    """The common per-scan record of a Gaussian step's: one hypothesis, so the best pose is the
    mean pose, the ESS is 1, it never resamples, and the proposal counters are 0."""
    x = out.pose
    zero = jnp.zeros((), jnp.int32)
    return StepOutput(
        best_pose=x,
        mean_pose=x,
        ess=jnp.ones((), x.dtype),
        resampled=jnp.zeros((), bool),
        n_landmarks=jnp.asarray(out.n_landmarks).astype(jnp.int32),
        n_confirmed=jnp.asarray(out.n_confirmed).astype(jnp.int32),
        iterations=jnp.zeros((), x.dtype),
        n_capped=zero,
        n_nonfinite=jnp.asarray(out.n_nonfinite).astype(jnp.int32),
        n_associated=jnp.asarray(out.n_associated).astype(x.dtype),
        n_new=jnp.asarray(out.n_new).astype(x.dtype),
        window_overflow=zero if out.window_overflow is None else jnp.asarray(out.window_overflow).astype(jnp.int32),
        overflow=jnp.asarray(out.overflow).astype(jnp.int32),
        weight_reset=jnp.zeros((), bool),
    )
