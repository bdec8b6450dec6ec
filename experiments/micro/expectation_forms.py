"""NANO's quadrature expectations (``expected_grad_hess``) in the library's form against other
formulations, on one device's share of a 1000-particle split step (a decision script: kept in the
history, not in the tree).

Each formulation computes ``E_q[J' W r]`` and ``E_q[J' W J]`` over the 6 cubature points and the
detection rows of every particle (``vmap`` over particles), with autodiff Jacobians; the script
prints each one's largest relative difference from the library's result and its time (best and
median of alternated timings, so a slow period of the machine hits every form).

    python experiments/micro/expectation_forms.py --particles 500 --rows 8
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from nanoslam_jax._linalg import chol2, inv3, mm, mt, mv, sym, tsum
from nanoslam_jax.models import range_bearing_components, wrap_angle
from nanoslam_jax.proposals._base import Detections, noise_information, range_bearing_residuals
from nanoslam_jax.proposals._natural_gradient import Gaussian, _chol, expected_grad_hess
from nanoslam_jax.quadrature import Cubature

RULE = Cubature()


def _setup(x, P, m, z, cov, mask, R):
    det = Detections(z, m, cov, mask)
    W = noise_information(x, det, R, False)
    xi, wm, _ = RULE.unit_points(3)
    X = x + mm(xi, mt(_chol(P)))
    return det, W, W * mask[:, None, None], wm, X


def library(x, P, m, z, cov, mask, R):
    det, W, _, _, _ = _setup(x, P, m, z, cov, mask, R)
    return expected_grad_hess(RULE, Gaussian(x, inv3(P), P), range_bearing_residuals(det), W, mask)


def has_aux(x, P, m, z, cov, mask, R):
    """The residual evaluated once per point (``jacfwd(..., has_aux=True)`` returns it)."""
    det, _, Wm, wm, X = _setup(x, P, m, z, cov, mask, R)
    residual = range_bearing_residuals(det)

    def at_point(xp):
        J, r = jax.jacfwd(lambda y: (residual(y), residual(y)), has_aux=True)(xp)
        JtW = mm(mt(J), Wm)
        return tsum(mv(JtW, r)), tsum(mm(JtW, J))

    g, H = jax.vmap(at_point)(X)
    return tsum(wm[:, None] * g), sym(tsum(wm[:, None, None] * H))


def gram(x, P, m, z, cov, mask, R):
    """Whitened ``[J | r]`` of all points and rows, then one product ``A' diag(w) A``."""
    det, W, _, wm, X = _setup(x, P, m, z, cov, mask, R)
    residual = range_bearing_residuals(det)
    L = chol2(W) * mask[:, None, None]  # W = L L'

    def at_point(xp):
        A = jnp.concatenate([jax.jacfwd(residual)(xp), residual(xp)[..., None]], -1)  # (k, 2, 4)
        return jnp.stack([L[:, 0, 0, None] * A[:, 0] + L[:, 1, 0, None] * A[:, 1], L[:, 1, 1, None] * A[:, 1]], 1)

    A = jax.vmap(at_point)(X).reshape(-1, 4)
    M = (A * jnp.repeat(wm, A.shape[0] // wm.shape[0])[:, None]).T @ A
    return M[:3, 3], sym(M[:3, :3])


def entries_dot(x, P, m, z, cov, mask, R):
    """The 6 + 3 distinct entries per point and row, summed by one weighted contraction."""
    det, _, Wm, wm, X = _setup(x, P, m, z, cov, mask, R)
    residual = range_bearing_residuals(det)

    def at_point(xp):
        r, J = residual(xp), jax.jacfwd(residual)(xp)
        WJ = [[Wm[:, a, 0] * J[:, 0, i] + Wm[:, a, 1] * J[:, 1, i] for i in range(3)] for a in range(2)]
        Wr = [Wm[:, a, 0] * r[:, 0] + Wm[:, a, 1] * r[:, 1] for a in range(2)]
        e = [J[:, 0, i] * WJ[0][j] + J[:, 1, i] * WJ[1][j] for i in range(3) for j in range(i, 3)]
        return jnp.stack(e + [J[:, 0, i] * Wr[0] + J[:, 1, i] * Wr[1] for i in range(3)])

    C = jax.vmap(at_point)(X)  # (points, 9, k)
    s = jnp.einsum("pek,p->e", C, wm)
    H = jnp.stack([jnp.stack([s[0], s[1], s[2]]), jnp.stack([s[1], s[3], s[4]]), jnp.stack([s[2], s[4], s[5]])])
    return s[6:9], H


def rows_first(x, P, m, z, cov, mask, R):
    """Each entry summed over the rows before the 3x3 is stacked (no per-row 3x3 array)."""
    det, _, Wm, wm, X = _setup(x, P, m, z, cov, mask, R)
    residual = range_bearing_residuals(det)

    def at_point(xp):
        r, J = residual(xp), jax.jacfwd(residual)(xp)
        JtW = mm(mt(J), Wm)
        g = jnp.stack([tsum(JtW[:, i, 0] * r[:, 0] + JtW[:, i, 1] * r[:, 1]) for i in range(3)])
        H = jnp.stack([jnp.stack([tsum(JtW[:, i, 0] * J[:, 0, j] + JtW[:, i, 1] * J[:, 1, j]) for j in range(3)])
                       for i in range(3)])
        return g, H

    g, H = jax.vmap(at_point)(X)
    return tsum(wm[:, None] * g), sym(tsum(wm[:, None, None] * H))


def per_input_jvp(x, P, m, z, cov, mask, R):
    """Residuals on (points, rows) component arrays, one ``jvp`` per pose input, then the
    library's products."""
    det, _, Wm, wm, _ = _setup(x, P, m, z, cov, mask, R)
    xi = RULE.unit_points(3)[0]
    L = _chol(P)
    X = [(x[i] + sum(xi[:, j] * L[i, j] for j in range(3)))[:, None] for i in range(3)]

    def residual(px, py, phi):
        r, b = range_bearing_components(px, py, phi, m[:, 0], m[:, 1])
        return z[:, 0] - r, wrap_angle(z[:, 1] - b)

    cols = []
    for i in range(3):
        r, dr = jax.jvp(lambda a, i=i: residual(*[a if j == i else X[j] for j in range(3)]), (X[i],),
                        (jnp.ones_like(X[i]),))
        cols.append(dr)
    J = jnp.stack([jnp.stack([cols[i][a] for i in range(3)], -1) for a in range(2)], -2)  # (points, k, 2, 3)
    JtW = mm(mt(J), Wm)
    g, H = tsum(mv(JtW, jnp.stack(r, -1)), 1), tsum(mm(JtW, J), 1)
    return tsum(wm[:, None] * g), sym(tsum(wm[:, None, None] * H))


def residuals_and_jacobians(x, P, m, z, cov, mask, R):
    """Only the residuals and their ``jacfwd`` Jacobians at the points (no products, no sums)."""
    det, _, _, _, X = _setup(x, P, m, z, cov, mask, R)
    residual = range_bearing_residuals(det)
    return jax.vmap(lambda xp: (residual(xp), jax.jacfwd(residual)(xp)))(X)


def residuals_only(x, P, m, z, cov, mask, R):
    det, _, _, _, X = _setup(x, P, m, z, cov, mask, R)
    return jax.vmap(range_bearing_residuals(det))(X)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--particles", type=int, default=500)
    p.add_argument("--rows", type=int, default=8)
    p.add_argument("--repeat", type=int, default=15)
    p.add_argument("--calls", type=int, default=50)
    args = p.parse_args()
    jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(0)
    B, k = args.particles, args.rows
    A = rng.normal(size=(B, 3, 3)) * 0.1
    inputs = (jnp.asarray(rng.normal(size=(B, 3))), jnp.asarray(A @ A.transpose(0, 2, 1) + 0.01 * np.eye(3)),
              jnp.asarray(rng.normal(size=(B, k, 2)) * 20.0), jnp.asarray(np.abs(rng.normal(size=(B, k, 2))) * 10.0),
              jnp.broadcast_to(0.1 * jnp.eye(2), (B, k, 2, 2)), jnp.asarray(rng.random((B, k)) < 0.7))
    R = jnp.diag(jnp.array([1.0, 0.01]))
    cases = {"library (jacfwd, stacked 3x3 per point and row)": library, "jacfwd with has_aux": has_aux,
             "whitened [J | r], one product": gram, "9 entries, one weighted contraction": entries_dot,
             "entries summed over rows before stacking": rows_first, "one jvp per pose input": per_input_jvp,
             "(part) residuals and Jacobians only": residuals_and_jacobians, "(part) residuals only": residuals_only}
    fns = {name: jax.jit(jax.vmap(f, (0,) * 6 + (None,))) for name, f in cases.items()}
    ref = jax.block_until_ready(fns["library (jacfwd, stacked 3x3 per point and row)"](*inputs, R))
    diffs = {}
    for name, f in fns.items():
        out = jax.block_until_ready(f(*inputs, R))
        if not name.startswith("(part)"):
            diffs[name] = max(float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b))) for a, b in zip(out, ref))
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(args.repeat):
        for name, f in fns.items():
            t = time.perf_counter()
            for _ in range(args.calls):
                out = f(*inputs, R)
            jax.block_until_ready(out)
            times[name].append(1e6 * (time.perf_counter() - t) / args.calls)
    print(f"\nE[grad], E[Hess]: {B} particles x 6 cubature points x {k} rows, float64, "
          f"{args.repeat} alternated timings of {args.calls} calls\n")
    print("| formulation | best [us] | median [us] | largest relative difference |")
    print("|---|---|---|---|")
    for name, t in times.items():
        d = f"{diffs[name]:.1e}" if name in diffs else ""
        print(f"| {name} | {min(t):.0f} | {np.median(t):.0f} | {d} |")


if __name__ == "__main__":
    main()
