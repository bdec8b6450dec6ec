"""The reported trajectory: the best particle's pose per segment, the weighted mean, or the final
best particle's ancestral path.

A particle of a Rao-Blackwellised filter is a whole path hypothesis, and its map is conditioned
on that path. The filter's per-segment estimates (``best``, ``mean``) report at each segment the
particles alive then; ``path`` reports the history of the particle that is best at the end of the
log, followed back through the resampling steps: the trajectory its final map was built along
(FastSLAM's own estimate of the path). It uses every scan up to the end of the log, so it is an
offline (smoothed) estimate, not a filtering one.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int


def ancestral_path(
    poses: Float[Array, "segments particles 3"],
    ancestors: Int[Array, "segments particles"],
    final: Int[Array, ""],
) -> Float[Array, "segments 3"]:
    """The path of particle ``final`` of the last step, followed back through its ancestors.

    Args:
        poses: every particle's pose at each segment, after the proposal and before resampling
            (``StepOutput.poses``).
        ancestors: at each segment, the particle (of that segment's ``poses``) each particle after
            the segment descends from (``StepOutput.ancestors``; ``arange`` without resampling).
        final: the particle after the last segment whose path is wanted (``FilterState.best``).

    Returns:
        Its pose at each segment.
    """

    def back(j, step):
        pose, parent = step
        i = parent[j]
        return i, pose[i]

    ancestors = jnp.asarray(ancestors, jnp.int32)
    _, path = jax.lax.scan(back, jnp.asarray(final, jnp.int32), (jnp.asarray(poses), ancestors), reverse=True)
    return path


@functools.partial(jax.jit, static_argnames=("batched",))
def _ancestral_path(poses, ancestors, final, batched: bool):
    return (jax.vmap(ancestral_path) if batched else ancestral_path)(poses, ancestors, final)


@dataclasses.dataclass(frozen=True)
class AbstractEstimate(abc.ABC):
    """The trajectory a run reports (``filter.estimate`` names one): a filter's component, a frozen
    dataclass (hashable: part of its static settings).

    Attributes:
        name: its name (``filter.estimate``).
        records_path: the run records every particle's pose and ancestor per segment
            (``StepOutput.poses``, ``ancestors``), which the estimate follows back.
    """

    name: ClassVar[str] = ""
    records_path: ClassVar[bool] = False

    @abc.abstractmethod
    def trajectory(self, outputs, state=None) -> np.ndarray:
        """The reported trajectory as a host array ``(segments, 3)`` (``(batch, segments, 3)`` for
        a batch's outputs and state).

        Args:
            outputs: the run's per-segment :class:`StepOutput` (host or device arrays).
            state: the run's final state (needed where the estimate follows its best particle).
        """


@dataclasses.dataclass(frozen=True)
class BestParticle(AbstractEstimate):
    """At each segment the pose of the particle with the largest weight then."""

    name: ClassVar[str] = "best"

    def trajectory(self, outputs, state=None):
        return np.asarray(outputs.best_pose)


@dataclasses.dataclass(frozen=True)
class WeightedMean(AbstractEstimate):
    """At each segment the particles' weighted mean pose (headings averaged on the circle)."""

    name: ClassVar[str] = "mean"

    def trajectory(self, outputs, state=None):
        return np.asarray(outputs.mean_pose)


@dataclasses.dataclass(frozen=True)
class AncestralPath(AbstractEstimate):
    """The history of the particle that is best at the end of the log (:func:`ancestral_path`):
    an offline (smoothed) estimate."""

    name: ClassVar[str] = "path"
    records_path: ClassVar[bool] = True

    def trajectory(self, outputs, state=None):
        if outputs.poses is None or state is None:
            raise ValueError(
                "filter.estimate 'path' needs the particles' poses and ancestors, which a run records "
                "only when its config has filter.estimate: path, and the run's final state"
            )
        batched = np.ndim(outputs.poses) == 4
        poses, ancestors, best = jnp.asarray(outputs.poses), jnp.asarray(outputs.ancestors), jnp.asarray(state.best)
        return np.asarray(_ancestral_path(poses, ancestors, best, batched=batched))
