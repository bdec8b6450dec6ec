"""Prediction of a particle's pose through the log pieces of one segment (the prior).

The motion model comes with the hyperparameters (``params.motion``, an
:class:`~nanoslam_jax.models.AbstractMotionModel`). A model with ``rigid = True`` moves a pose by a
body-frame increment that depends on the controls only (``x' = x (+) delta(u)``), so a rigid motion
of the plane commutes with it. Both priors keep that symmetry: the linearised one exactly, the
unscented one because its square root is the Cholesky factor in the order (heading, x, y), whose
columns either perturb the heading (one column, the same in every frame) or only the position,
which such a model moves linearly. A segment's prior from an isotropic start covariance is then
the same for every particle in the particle's own frame: :func:`relative_prior` computes it once
per segment and :func:`compose_prior` places it at each particle's pose.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar, TYPE_CHECKING

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from nanoslam_jax.lib._linalg import chol3, mm, mt, mv, sandwich, sym
from nanoslam_jax.lib._trig import sincos
from nanoslam_jax.models import AbstractRateModel, wrap_angle
from nanoslam_jax.lib.quadrature import Unscented

if TYPE_CHECKING:
    from nanoslam_jax.methods._params import Params


def _sqrt_heading_first(P: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """A square root ``L L' = P`` whose first column holds all the heading spread: the Cholesky
    factor of ``P`` in the order (heading, x, y), rows returned in the order (x, y, heading)."""
    order, back = jnp.array([2, 0, 1]), jnp.array([1, 2, 0])
    return chol3(P[order][:, order])[back]


def _moments(y, centre, wm, wc):
    """Mean and covariance of moved sigma points ``y`` (heading deviations wrapped about ``centre``)."""
    dev = (y - centre).at[:, 2].set(wrap_angle(y[:, 2] - centre[2]))
    delta = mv(mt(dev), wm)
    d = dev - delta
    cov = mm(mt(d) * wc, d)
    mean = (centre + delta).at[2].set(wrap_angle(centre[2] + delta[2]))
    return mean, sym(cov)


def _ut_piece(x, P, u, dt, params: Params):
    """Unscented transform over the augmented state (pose, process noise) for one log piece.

    The pose's square root is :func:`_sqrt_heading_first` (which makes the transform commute with
    rigid motions; see the module docstring). The augmented covariance is block-diagonal, so each
    sigma point of the rule (the centre and ``+-s`` along each column of the square root) perturbs
    either the pose or the noise. For a model with control noise that splits into rates and a move
    (:class:`~nanoslam_jax.models.AbstractRateModel`), the rates are computed once per distinct
    control and the move once per point; otherwise every point goes through
    :meth:`~nanoslam_jax.models.AbstractMotionModel.noisy_step`. The moments are those of the full
    rule either way.
    """
    motion = params.motion
    nw = motion.noise_dim
    xi, wm, wc = Unscented(params.ut_alpha, params.ut_beta, params.ut_kappa).unit_points(3 + nw)
    s = xi[1, 0]  # the rule's points: centre, then +s e_i, then -s e_i (i = 0 .. 2 + nw)
    dxs = s * mt(_sqrt_heading_first(P))  # row i: s L[:, i]
    poses = jnp.concatenate([x[None], x + dxs, x - dxs])  # centre, +pose axes, -pose axes
    if isinstance(motion, AbstractRateModel) and motion.noise == "control":
        y = _rate_points(motion, x, poses, u, dt, s)
    else:
        dws = s * mt(motion.noise_sqrt(dt))  # row j: s Lw[:, j]
        zero_w = jnp.zeros((3, nw), dtype=x.dtype)
        ws = jnp.concatenate([jnp.zeros((1, nw), x.dtype), zero_w, dws, zero_w, -dws])
        pts = jnp.concatenate([poses[:4], jnp.broadcast_to(x, (nw, 3)), poses[4:], jnp.broadcast_to(x, (nw, 3))])
        y = jax.vmap(motion.noisy_step, (0, None, 0, None))(pts, u, ws, dt)
    return _moments(y, y[0], wm, wc)


def _rate_points(motion: AbstractRateModel, x, poses, u, dt, s):
    """The rule's points moved by a rate model, in the rule's order (centre, +pose(3), +control(c),
    -pose(3), -control(c)): ``rates`` once per distinct control, ``move`` once per point."""
    c = motion.control_dim
    du = s * mt(motion.noise_sqrt(dt))  # row j: s Lw[:, j]
    rates = jax.vmap(motion.rates)(jnp.concatenate([u[None], u + du, u - du]))
    pts = jnp.concatenate([poses[:4], jnp.broadcast_to(x, (c, 3)), poses[4:], jnp.broadcast_to(x, (c, 3))])
    rts = jnp.concatenate(
        [jnp.broadcast_to(rates[0], (4, 2)), rates[1 : 1 + c], jnp.broadcast_to(rates[0], (3, 2)), rates[1 + c :]]
    )
    return jax.vmap(motion.move, (0, 0, None))(pts, rts, dt)


def _linear_piece(x, P, u, dt, params: Params):
    """First-order propagation with autodiff Jacobians for one log piece."""
    motion = params.motion
    F, G = motion.jacobians(x, u, dt)
    return motion.step(x, u, dt), sym(sandwich(F, P) + sandwich(G, motion.noise_cov(dt)))


@dataclasses.dataclass(frozen=True)
class AbstractPrior(abc.ABC):
    """How a particle's pose Gaussian is carried through a segment's pieces (``filter.prior``), and
    the covariance each segment starts from (``filter.prior_cov``).

    A subclass is a frozen dataclass (hashable: part of a filter's static settings) with
    :meth:`piece`, one log piece's propagation.

    Attributes:
        name: the prior's name (``filter.prior``).
        reset: each segment starts from ``init_cov * I`` at the particle's pose (``prior_cov:
            reset``), instead of the particle's last proposal covariance (``carry``).
    """

    name: ClassVar[str] = ""
    reset: bool = True

    @abc.abstractmethod
    def piece(
        self, x: Float[Array, "3"], P: Float[Array, "3 3"], u: Float[Array, " c"], dt: Float[Array, ""], params: Params
    ) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
        """The pose Gaussian ``(x, P)`` moved by one piece of controls ``u`` over ``dt``."""


@dataclasses.dataclass(frozen=True)
class UnscentedPrior(AbstractPrior):
    """The augmented unscented transform over (pose, process noise), with the traced ``ut_*``
    parameters."""

    name: ClassVar[str] = "unscented"

    def piece(self, x, P, u, dt, params):
        return _ut_piece(x, P, u, dt, params)


@dataclasses.dataclass(frozen=True)
class LinearisedPrior(AbstractPrior):
    """First-order propagation with the motion model's autodiff Jacobians."""

    name: ClassVar[str] = "linearized"

    def piece(self, x, P, u, dt, params):
        return _linear_piece(x, P, u, dt, params)


def predict(
    x: Float[Array, "3"],
    P: Float[Array, "3 3"],
    dt: Float[Array, " dr"],
    u: Float[Array, "dr c"],
    dr_mask: Bool[Array, " dr"],
    params: Params,
    prior: AbstractPrior = UnscentedPrior(),
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """Propagate a pose Gaussian through a segment's DR pieces.

    Args:
        x: pose at the start of the segment.
        P: its covariance.
        dt: piece durations (padding: 0).
        u: piece controls (the motion model's ``control_dim`` values).
        dr_mask: which pieces are real (padding leaves the Gaussian unchanged).
        params: hyperparameters (vehicle constants, control noise, unscented parameters).
        prior: the propagation (:class:`UnscentedPrior` or :class:`LinearisedPrior`).

    Returns:
        The prior mean and covariance at the segment's scan time.
    """

    def body(i, carry):
        xc, Pc = carry
        xn, Pn = prior.piece(xc, Pc, u[i], dt[i], params)
        return jnp.where(dr_mask[i], xn, xc), jnp.where(dr_mask[i], Pn, Pc)

    # Only up to the last real piece (most segments have 9-10 of 12): under vmap over particles,
    # whose segment is shared, the count stays one loop bound for all of them.
    n_pieces = jnp.max(jnp.where(dr_mask, jnp.arange(1, dr_mask.shape[0] + 1), 0))
    return jax.lax.fori_loop(0, n_pieces, body, (x, P))


def predict_mean(
    x: Float[Array, "3"], dt: Float[Array, " dr"], u: Float[Array, "dr c"], params: Params
) -> Float[Array, "3"]:
    """Noise-free propagation (dead reckoning) through a segment's pieces (padding has dt = 0)."""

    def body(xc, inp):
        return params.motion.step(xc, inp[1], inp[0]), None

    x, _ = jax.lax.scan(body, x, (dt, u), unroll=True)
    return x


def relative_prior(
    dt: Float[Array, " dr"],
    u: Float[Array, "dr c"],
    dr_mask: Bool[Array, " dr"],
    params: Params,
    prior: AbstractPrior = UnscentedPrior(),
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """The prior of a segment in the frame of its start pose, from covariance ``init_cov * I``.

    It does not depend on the start pose, so it is computed once per segment for all particles
    (whose start covariance is ``init_cov * I`` with ``filter.prior_cov: reset``);
    ``compose_prior(x, *relative_prior(...))`` equals ``predict(x, init_cov * I, ...)`` up to
    rounding. Arguments as for :func:`predict`.
    """
    zero = jnp.zeros(3, dtype=jnp.result_type(dt, float))
    return predict(zero, params.init_cov * jnp.eye(3, dtype=zero.dtype), dt, u, dr_mask, params, prior)


def compose_prior(
    x: Float[Array, "3"], rel_mean: Float[Array, "3"], rel_cov: Float[Array, "3 3"]
) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
    """Place a :func:`relative_prior` at the pose ``x``: mean ``x (+) rel_mean`` and covariance
    ``A rel_cov A'`` with ``A`` the rotation of the plane by the heading of ``x``."""
    s, c = sincos(x[2])
    one, zero = jnp.ones_like(s), jnp.zeros_like(s)
    A = jnp.stack([jnp.stack([c, -s, zero]), jnp.stack([s, c, zero]), jnp.stack([zero, zero, one])])
    mean = jnp.stack(
        [
            x[0] + c * rel_mean[0] - s * rel_mean[1],
            x[1] + s * rel_mean[0] + c * rel_mean[1],
            wrap_angle(x[2] + rel_mean[2]),
        ]
    )
    return mean, sym(sandwich(A, rel_cov))
