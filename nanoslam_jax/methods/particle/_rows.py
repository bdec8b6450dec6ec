"""The per-row work of a particle's scan: the proposal over the detection rows, the sampled pose,
each row's weight likelihoods and its landmark's start and update, and the row buckets that run
it over only as many rows as the scan has (``filter.row_buckets``)."""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar, NamedTuple, TYPE_CHECKING

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from nanoslam_jax.lib._linalg import chol3, gaussian_logpdf, mv
from nanoslam_jax.lib._trig import computed_once
from nanoslam_jax.models import row_models, wrap_angle
from nanoslam_jax.methods.proposals import AbstractProposal, Detections, ProposalResult
from nanoslam_jax.methods.maps._association import predicted_measurements

if TYPE_CHECKING:
    from nanoslam_jax.methods._params import Params, Static


@dataclasses.dataclass(frozen=True)
class AbstractWeight:
    """Where a particle's importance weight evaluates its detections of mapped landmarks
    (``filter.weight`` names one): a filter's component, a frozen dataclass (hashable).

    Attributes:
        name: its name (``filter.weight``).
    """

    name: ClassVar[str] = ""

    @abc.abstractmethod
    def at(
        self, proposal: ProposalResult, x0: Float[Array, "3"], P0: Float[Array, "3 3"]
    ) -> tuple[Float[Array, "3"], Float[Array, "3 3"]]:
        """The pose Gaussian the detections' likelihoods are taken over, from the particle's
        proposal and its prior ``(x0, P0)``."""


@dataclasses.dataclass(frozen=True)
class ProductWeight(AbstractWeight):
    """Eq. 17: the likelihoods over the proposal (the product of the prior and the detections)."""

    name: ClassVar[str] = "product"

    def at(self, proposal, x0, P0):
        return proposal.mean, proposal.cov


@dataclasses.dataclass(frozen=True)
class MarginalWeight(AbstractWeight):
    """The marginal likelihoods over the prior (FastSLAM 1.0's weight)."""

    name: ClassVar[str] = "marginal"

    def at(self, proposal, x0, P0):
        return x0, P0


class RowResults(NamedTuple):
    """What each detection row of a scan gives a particle (:func:`row_work`).

    Attributes:
        proposal: the proposal over the rows.
        pose: the pose sampled from it.
        ll: each row's log-likelihood for the weight (eq. 17, or the marginal at the prior).
        llp: each row's log-likelihood at the sampled pose (for a row matching a landmark an
            earlier row of the scan started).
        new_mean, new_cov: the landmark each row would start at the sampled pose (eq. 16).
        upd_mean, upd_cov: the row's landmark (matched, else the one it would start) after the
            row's EKF (UFastSLAM: unscented) update at the sampled pose.
    """

    proposal: ProposalResult
    pose: Float[Array, "3"]
    ll: Float[Array, " k"]
    llp: Float[Array, " k"]
    new_mean: Float[Array, "k l"]
    new_cov: Float[Array, "k l l"]
    upd_mean: Float[Array, "k l"]
    upd_cov: Float[Array, "k l l"]


class RowInputs(NamedTuple):
    """A scan's detection rows as one particle's proposal and landmark updates take them.

    Attributes:
        det: the rows (detections, their matched landmarks, which rows are used).
        existing: which rows matched a landmark of the map (else ``det``'s landmark is unused).
        ps: for a row that matched a landmark an earlier row of the scan started, that row.
        mask: which rows are real detections (the same for every particle).
    """

    det: Detections
    existing: Bool[Array, " k"]
    ps: Int[Array, " k"]
    mask: Bool[Array, " k"]


def row_work(
    static: Static,
    params: Params,
    proposal: AbstractProposal,
    x0: Float[Array, "3"],
    P0: Float[Array, "3 3"],
    R: Float[Array, "d d"],
    rows: RowInputs,
    eps: Float[Array, "3"],
) -> RowResults:
    """The proposal, the sampled pose and each row's likelihoods, landmark start and landmark update.

    Args:
        x0, P0: the particle's prior.
        R: measurement noise covariance.
        rows: the detection rows.
        eps: the standard normal draw of the sampled pose.
    """
    det, existing, ps = rows.det, rows.existing, rows.ps
    prop = proposal(x0, P0, det, R)
    x_s = prop.mean + mv(chol3(prop.cov), eps)
    x_s = computed_once(x_s.at[2].set(wrap_angle(x_s[2])))
    # Weight of the associations with existing landmarks (eq. 17, or the marginal at the prior).
    xw, Pw = static.weight.at(prop, x0, P0)
    model = params.measurement
    # A composite's rows each take their type's model and noise (one shared model otherwise).
    row_model, ax = row_models(model, det.kind)
    z_hat, S = predicted_measurements(xw, Pw, det.mean, det.cov, R, model, det.kind)
    ll = gaussian_logpdf(jax.vmap(lambda md, z, zh: md.innovation(z, zh), (ax, 0, 0))(row_model, det.z, z_hat), S)
    # New landmarks at the sampled pose (eq. 16, or its unscented counterpart for UFastSLAM).
    updates = static.method.landmark_update.bind(params)
    new_mean, new_cov = updates.start(x_s, det.z, R, model, det.kind)
    # EKF (UFastSLAM: unscented) updates at the sampled pose; each landmark is matched at most once
    # per scan. A match to a landmark created earlier in this scan weighs with its likelihood at x_s.
    cur_mean = jnp.where(existing[:, None], det.mean, new_mean[ps])
    cur_cov = jnp.where(existing[:, None, None], det.cov, new_cov[ps])
    upd_mean, upd_cov, llp = updates.update(x_s, det.z, cur_mean, cur_cov, R, model, det.kind)
    # Both computed before the masked sums (a reduction fusion does not vectorise its operand).
    ll, llp = computed_once((ll, llp))
    return RowResults(prop, x_s, ll, llp, new_mean, new_cov, upd_mean, upd_cov)


def rows_over_buckets(
    static: Static,
    params: Params,
    proposal: AbstractProposal,
    x0: Float[Array, "3"],
    P0: Float[Array, "3 3"],
    R: Float[Array, "d d"],
    rows: RowInputs,
    eps: Float[Array, "3"],
) -> RowResults:
    """:func:`row_work` over the first ``b`` detection rows only, ``b`` the smallest of
    ``static.row_buckets`` (then ``k_max``) that holds the scan's last real detection
    (``rows.mask``); the rows after them are padded (zero means and likelihoods, unit covariances).

    Rows past the last real detection are never associated and start no landmark, so the
    result is the same as over all ``k_max`` rows where it is used; the work is proportional to
    the rows (an iterative proposal's most of all), and most scans have far fewer detections
    than the log's busiest one. The bucket depends only on the scan (``rows.mask`` is shared by all
    particles), so under ``vmap`` this stays a branch (``lax.switch`` with an unbatched index)
    and does not turn into computing every bucket. Only these per-row results cross the switch:
    with the whole particle update (the map's write-back) inside it, the switch's outputs would
    copy every particle's map at every step.
    """
    k_max = rows.mask.shape[0]
    sizes = sorted({b for b in static.row_buckets if 0 < b < k_max} | {k_max})
    if len(sizes) == 1:
        return row_work(static, params, proposal, x0, P0, R, rows, eps)

    def branch(b: int):
        def head(det, existing, ps):
            det, existing = jax.tree.map(lambda a: a[:b], (det, existing))
            # A row matching a landmark an earlier row started lies after that row; the other
            # rows' ``ps`` is unused.
            sliced = RowInputs(det, existing, jnp.minimum(ps[:b], b - 1), rows.mask[:b])
            out = row_work(static, params, proposal, x0, P0, R, sliced, eps)

            def pad(a, fill):
                return jnp.concatenate([a, jnp.broadcast_to(jnp.asarray(fill, a.dtype), (k_max - b,) + a.shape[1:])])

            return out._replace(
                ll=pad(out.ll, 0.0),
                llp=pad(out.llp, 0.0),
                new_mean=pad(out.new_mean, 0.0),
                new_cov=pad(out.new_cov, jnp.eye(out.new_cov.shape[-1])),
                upd_mean=pad(out.upd_mean, 0.0),
                upd_cov=pad(out.upd_cov, jnp.eye(out.upd_cov.shape[-1])),
            )

        return head

    n_rows = jnp.max(jnp.where(rows.mask, jnp.arange(1, k_max + 1), 0))
    index = jnp.sum(n_rows > jnp.asarray(sizes[:-1]))
    return jax.lax.switch(index, [branch(b) for b in sizes], rows.det, rows.existing, rows.ps)
