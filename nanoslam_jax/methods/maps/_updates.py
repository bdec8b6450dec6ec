"""How a particle's landmarks start and update from its detections: the EKF (FastSLAM, NANO-SLAM)
or the unscented transform (UFastSLAM). Each is an object with the same two methods, chosen once
when a method is built and passed to the particle step."""

from __future__ import annotations

import abc

import equinox as eqx
import jax
from jaxtyping import Array, Float, Int

from nanoslam_jax.lib.quadrature import Unscented
from nanoslam_jax.models import AbstractMeasurementModel, row_models, row_noise
from nanoslam_jax.methods.maps._landmarks import ekf_update_loglik, init_landmark, ukf_init_landmark, ukf_update_loglik


class AbstractLandmarkUpdate(eqx.Module):
    """Starts and updates the landmarks of a scan's detection rows at one (sampled) pose.

    A particle method names its own (:attr:`~nanoslam_jax.methods.Method.landmark_update`); the
    step takes it with the run's traced hyperparameters (:meth:`bind`).
    """

    def bind(self, params) -> "AbstractLandmarkUpdate":
        """This update with what it takes from the run's hyperparameters ``params`` (a
        :class:`~nanoslam_jax.methods.Params`) filled in; by default itself."""
        return self

    @abc.abstractmethod
    def start(
        self,
        x: Float[Array, "3"],
        z: Float[Array, "k d"],
        R: Float[Array, "d d"],
        model: AbstractMeasurementModel,
        kind: Int[Array, " k"] | None,
    ) -> tuple[Float[Array, "k l"], Float[Array, "k l l"]]:
        """The landmark each detection row would start at pose ``x``.

        Args:
            x: the pose.
            z: the detections, one per row.
            R: measurement noise covariance.
            model: the measurement model.
            kind: each row's type for a :class:`~nanoslam_jax.models.Composite` model (its
                model and noise), or None.
        """

    @abc.abstractmethod
    def update(
        self,
        x: Float[Array, "3"],
        z: Float[Array, "k d"],
        mean: Float[Array, "k l"],
        cov: Float[Array, "k l l"],
        R: Float[Array, "d d"],
        model: AbstractMeasurementModel,
        kind: Int[Array, " k"] | None,
    ) -> tuple[Float[Array, "k l"], Float[Array, "k l l"], Float[Array, " k"]]:
        """Each row's landmark ``(mean, cov)`` updated with its detection at pose ``x``, and the
        detection's log-likelihood ``log N(nu; 0, S)`` (arguments as for :meth:`start`)."""


class EkfLandmarkUpdate(AbstractLandmarkUpdate):
    """Landmarks started by the inverse model's linearisation (eq. 16) and updated by the EKF in
    Joseph form (:func:`~nanoslam_jax.methods.init_landmark`,
    :func:`~nanoslam_jax.methods.ekf_update_loglik`); a composite model's rows each take their
    type's model and noise."""

    def start(self, x, z, R, model, kind):
        rows, ax = row_models(model, kind)
        R_rows, r_ax = row_noise(rows, ax, R)
        return jax.vmap(init_landmark, (None, 0, r_ax, ax))(x, z, R_rows, rows)

    def update(self, x, z, mean, cov, R, model, kind):
        rows, ax = row_models(model, kind)
        R_rows, r_ax = row_noise(rows, ax, R)
        return jax.vmap(ekf_update_loglik, (None, 0, 0, 0, r_ax, ax))(x, z, mean, cov, R_rows, rows)


class UnscentedLandmarkUpdate(AbstractLandmarkUpdate):
    """Landmarks started and updated by the unscented transform (UFastSLAM): sigma points of the
    detection noise through the inverse model, and of the landmark through the model
    (:func:`~nanoslam_jax.methods.maps._landmarks.ukf_init_landmark`, ``ukf_update_loglik``).
    One model for all rows.

    Attributes:
        rule: the unscented transform's parameters; None (the default): the run's traced
            ``filter.ut_alpha``, ``ut_beta``, ``ut_kappa`` (:meth:`bind`), so a sweep over them
            compiles once.
    """

    rule: Unscented | None = None

    def bind(self, params) -> "UnscentedLandmarkUpdate":
        if self.rule is not None:
            return self
        return UnscentedLandmarkUpdate(Unscented(alpha=params.ut_alpha, beta=params.ut_beta, kappa=params.ut_kappa))

    def _bound_rule(self) -> Unscented:
        if self.rule is None:
            raise ValueError("UnscentedLandmarkUpdate: no rule; bind(params) gives the run's traced ut_* one")
        return self.rule

    def start(self, x, z, R, model, kind):
        rule = self._bound_rule()
        return jax.vmap(lambda zk: ukf_init_landmark(x, zk, R, rule, model))(z)

    def update(self, x, z, mean, cov, R, model, kind):
        rule = self._bound_rule()
        return jax.vmap(lambda zk, m, c: ukf_update_loglik(x, zk, m, c, R, rule, model))(z, mean, cov)
