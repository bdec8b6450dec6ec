"""Natural-gradient Gaussian approximation (docs/method/proposals.md, "NANO"), model-agnostic.

Minimises ``J(q) = KL(q || N(x0, P0)) + E_q[l]`` over Gaussians ``q = N(x, P)`` with
``l(x) = 1/2 sum_k r_k(x)' W_k r_k(x)``, by the iteration

    Lambda' = (1 - beta) Lambda + beta (L0 + E_q[Hess l])
    x'      = x - beta Lambda'^-1 (E_q[grad l] + L0 (x - x0))

started at ``(x0, L0 = P0^-1)`` and stopped when ``KL(q || q') < gamma``. Expectations use a
quadrature rule; gradients and Hessians come from autodiff of the residuals.

The loop is an ``optimistix.fixed_point`` solve with :class:`NaturalGradientKL`, a fixed-point
solver whose stopping rule is the KL criterion (``throw=False``; the result code says whether
the cap was reached), or an equivalent plain ``lax.while_loop`` (``solver='while_loop'``).
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from nanoslam_jax.lib._linalg import chol3, inv3, logdet_spd, mm, mt, mv, quad_form, sym, tsum
from nanoslam_jax.lib.quadrature import QuadratureRule


class Gaussian(NamedTuple):
    """``N(mean, inv(precision))`` with its covariance kept alongside."""

    mean: Float[Array, " n"]
    precision: Float[Array, "n n"]
    cov: Float[Array, "n n"]


def _inv(a):
    return inv3(a) if a.shape[-1] == 3 else jnp.linalg.inv(a)


def _chol(a):
    return chol3(a) if a.shape[-1] == 3 else jnp.linalg.cholesky(a)


def _logdet(a):
    return logdet_spd(a) if a.shape[-1] in (2, 3) else jnp.linalg.slogdet(a)[1]


def kl_gaussian(q: Gaussian, p: Gaussian, diff: Callable = jnp.subtract) -> Float[Array, ""]:
    """``KL(q || p)`` for Gaussians given with precisions."""
    n = q.mean.shape[-1]
    d = diff(p.mean, q.mean)
    # Clamped at 0: near convergence round-off can make the value slightly negative.
    return jnp.maximum(
        0.0,
        0.5
        * (
            tsum(tsum(p.precision * mt(q.cov), -1), -1)
            - n
            + quad_form(d, p.precision)
            + _logdet(q.precision)
            - _logdet(p.precision)
        ),
    )


def expected_grad_hess(
    rule: QuadratureRule,
    q: Gaussian,
    residual: Callable[[Array], Array],
    weights: Float[Array, "k d d"],
    mask: Bool[Array, " k"],
    hessian: str = "gauss_newton",
) -> tuple[Float[Array, " n"], Float[Array, "n n"]]:
    """``E_q[grad l]`` and ``E_q[Hess l]`` by quadrature.

    Args:
        rule: the quadrature rule.
        q: the Gaussian the expectation is over.
        residual: ``x -> r (k, d)``; ``l(x) = 1/2 sum_k mask_k r_k' W_k r_k``.
        weights: ``W_k``, the inverse noise of each residual.
        mask: which residuals count.
        hessian: ``'gauss_newton'`` (``sum J' W J``, positive semi-definite) or ``'exact'``.
    """
    n = q.mean.shape[-1]
    xi, wm, _ = rule.unit_points(n)
    X = q.mean + mm(xi, mt(_chol(q.cov)))
    Wm = weights * mask[:, None, None]

    def at_point(x):
        r = residual(x)
        J = jax.jacfwd(residual)(x)  # (k, d, n)
        JtW = mm(mt(J), Wm)  # (k, n, d)
        g = tsum(mv(JtW, r))
        if hessian == "exact":
            nll = lambda y: 0.5 * jnp.sum(residual(y) * mv(Wm, residual(y)))  # noqa: E731
            H = jax.hessian(nll)(x)
        else:
            H = tsum(mm(JtW, J))
        return g, H

    g, H = jax.vmap(at_point)(X)
    return tsum(wm[:, None] * g), sym(tsum(wm[:, None, None] * H))


def _guard_pd(precision: Float[Array, "n n"], floor: Float[Array, "n n"]) -> Float[Array, "n n"]:
    """Make a precision positive definite by clipping eigenvalues at those of a floor's scale."""
    w, V = jnp.linalg.eigh(precision)
    lo = 1e-6 * jnp.min(jnp.linalg.eigvalsh(floor))
    return sym((V * jnp.maximum(w, lo)) @ V.T)


class NaturalGradientProblem(eqx.Module):
    """One natural-gradient step as a fixed-point map ``(x, Lambda) -> (x', Lambda')``."""

    rule: QuadratureRule
    prior: Gaussian
    residual: Callable
    weights: Array
    mask: Array
    step: Array
    hessian: str = eqx.field(static=True)
    diff: Callable = eqx.field(static=True)
    project: Callable = eqx.field(static=True)

    def __call__(self, y: tuple[Array, Array], args: Any = None) -> tuple[Array, Array]:
        x, lam = y
        q = Gaussian(x, lam, _inv(lam))
        Eg, EH = expected_grad_hess(self.rule, q, self.residual, self.weights, self.mask, self.hessian)
        L0 = self.prior.precision
        lam_new = sym((1.0 - self.step) * lam + self.step * (L0 + EH))
        if self.hessian == "exact":
            lam_new = _guard_pd(lam_new, L0)
        P_new = _inv(lam_new)
        x_new = self.project(x - self.step * mv(P_new, Eg + mv(L0, self.diff(x, self.prior.mean))))
        return x_new, lam_new


class _KLState(eqx.Module):
    kl: Array


class NaturalGradientKL(optx.AbstractFixedPointSolver):
    """Fixed-point iteration that stops when ``KL(q_r || q_{r+1}) < gamma``.

    The iterate is ``(mean, precision)``; the map is a natural-gradient step. ``rtol``,
    ``atol`` and ``norm`` are required by optimistix's solver interface but unused: the KL
    criterion is scale-free.
    """

    # To mypy the solver interface's abstract rtol, atol, norm come first; equinox keeps this order.
    gamma: Array  # type: ignore[misc]
    diff: Callable = eqx.field(static=True, default=jnp.subtract)
    rtol: float = eqx.field(static=True, default=0.0)
    atol: float = eqx.field(static=True, default=0.0)
    norm: Callable = eqx.field(static=True, default=optx.max_norm)

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        return _KLState(jnp.array(jnp.inf, dtype=y[0].dtype))

    def step(self, fn, y, args, options, state, tags):
        y_new, aux = fn(y, args)
        q = Gaussian(y[0], y[1], _inv(y[1]))
        q_new = Gaussian(y_new[0], y_new[1], _inv(y_new[1]))
        kl = kl_gaussian(q, q_new, self.diff)
        return y_new, _KLState(jnp.where(jnp.isfinite(kl), kl, jnp.inf)), aux

    def terminate(self, fn, y, args, options, state, tags):
        return state.kl < self.gamma, optx.RESULTS.successful

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}


class NaturalGradientResult(NamedTuple):
    """Outcome of :func:`natural_gradient_gaussian`."""

    q: Gaussian
    iterations: Int[Array, ""]
    result: Int[Array, ""]  # 0 converged, 1 cap reached, 2 non-finite (prior returned)


class StateSpace(NamedTuple):
    """How iterates of a state are compared and kept valid.

    Attributes:
        diff: ``(a, b) -> a - b`` on the state space (wraps angles for poses).
        project: maps an iterate back onto the state space (wraps angles for poses).
    """

    diff: Callable = jnp.subtract
    project: Callable = lambda x: x


class NaturalGradientSettings(eqx.Module):
    """The natural-gradient iteration's settings.

    Attributes:
        gamma: KL stopping threshold (may be traced).
        step: natural-gradient step, 1 the undamped iteration of the paper (may be traced).
        max_iter: (static) iteration cap.
        hessian: (static) ``'gauss_newton'`` or ``'exact'`` (then guarded positive definite).
        solver: (static) ``'optimistix'`` (fixed-point solve with :class:`NaturalGradientKL`) or
            ``'while_loop'``.
    """

    gamma: Float[ArrayLike, ""] = 1e-4
    step: Float[ArrayLike, ""] = 1.0
    max_iter: int = eqx.field(static=True, default=10)
    hessian: str = eqx.field(static=True, default="gauss_newton")
    solver: str = eqx.field(static=True, default="optimistix")


def natural_gradient_gaussian(
    prior: Gaussian,
    residual: Callable[[Array], Array],
    weights: Float[Array, "k d d"],
    mask: Bool[Array, " k"],
    rule: QuadratureRule,
    *,
    settings: NaturalGradientSettings = NaturalGradientSettings(),
    start: Gaussian | None = None,
    space: StateSpace = StateSpace(),
) -> NaturalGradientResult:
    """The Gaussian minimising ``KL(q || prior) + E_q[l]`` by natural-gradient iteration.

    Args:
        prior: the prior Gaussian ``N(x0, P0)``.
        residual: ``x -> r (k, d)``, the residuals of the likelihood.
        weights: inverse noise covariance of each residual.
        mask: which residuals count (none: the prior is returned after one step).
        rule: quadrature rule for the expectations.
        settings: the iteration's stopping threshold, step, cap, Hessian and solver.
        start: initial iterate (default: the prior).
        space: the state space's difference and projection (default: Euclidean).
    """
    diff, project = space
    max_iter, hessian, step = settings.max_iter, settings.hessian, settings.step
    problem = NaturalGradientProblem(
        rule, prior, residual, weights, mask, jnp.asarray(step, prior.mean.dtype), hessian, diff, project
    )
    gamma = jnp.asarray(settings.gamma, prior.mean.dtype)
    y0 = (prior.mean, prior.precision) if start is None else (start.mean, start.precision)
    if settings.solver == "optimistix":
        sol: optx.Solution = optx.fixed_point(
            problem,
            NaturalGradientKL(gamma=gamma, diff=diff),
            y0,
            max_steps=max_iter,
            throw=False,
            adjoint=optx.RecursiveCheckpointAdjoint(),
        )
        (x, lam), steps = sol.value, sol.stats["num_steps"]
        capped = jnp.asarray(sol.result != optx.RESULTS.successful)
    else:

        def cond(c):
            i, _, kl = c
            return (i < max_iter) & ~(kl < gamma)

        def body(c):
            i, y, _ = c
            y_new = problem(y)
            q = Gaussian(y[0], y[1], _inv(y[1]))
            kl = kl_gaussian(q, Gaussian(y_new[0], y_new[1], _inv(y_new[1])), diff)
            return i + 1, y_new, jnp.where(jnp.isfinite(kl), kl, jnp.inf)

        steps, (x, lam), kl = jax.lax.while_loop(cond, body, (jnp.array(0), y0, jnp.array(jnp.inf, prior.mean.dtype)))
        capped = ~(kl < gamma)
    P = _inv(lam)
    finite = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(P))
    q = jax.tree.map(lambda a, b: jnp.where(finite, a, b), Gaussian(x, lam, sym(P)), prior)
    code = jnp.where(finite, jnp.where(capped, 1, 0), 2)
    return NaturalGradientResult(q, jnp.asarray(steps, jnp.int32), code.astype(jnp.int32))
