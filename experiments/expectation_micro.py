"""Would NANO's quadrature expectations run faster in a sweep batch written one array per component?

NANO's iteration (``expected_grad_hess``) takes ~80 % of its loop, the loop a third of a sweep
batch's step. The library evaluates the range-bearing residuals at every quadrature point and
their Jacobian by ``jax.jacfwd``, and sums ``J' W r`` and ``J' W J`` with the tiny-matrix helpers of
``_linalg``, so every intermediate carries 2- and 3-wide matrix axes innermost. This script
times it against the same expectations written over one array per residual and Jacobian entry
(``J[a][i]`` of shape ``(points, rows)``, autodiff by one ``jax.jvp`` per pose component, no
stacked 2- or 3-vectors until the 3 + 9 sums), in three variants of the final sums:

* ``components, jnp.sum``: each sum a reduction over (points, rows);
* ``components, unrolled``: each sum unrolled into additions of slices (as ``_linalg.tsum``);
* ``components, unrolled, once``: as above, with the residuals and Jacobian entries written to
  memory once (``computed_once``) instead of recomputed inside every sum;

and ``hybrid``: the Jacobian entries by one ``jvp`` per pose component (so the other components'
tangents are symbolic zeros rather than multiplications by the zeros of an identity basis), then
stacked per point and summed as the library does.

All on a sweep batch's shape (64 runs x 10 particles, vmapped; cubature, 6 points) and ``--rows``
detection rows, float64, compiled once each and called alternately ``--repeat`` times (best and
median shown), with the largest difference from the library's result.

    python experiments/expectation_micro.py
    python experiments/expectation_micro.py --rows 4 --repeat 30
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import nanoslam_jax  # noqa: F401  (float64)
from nanoslam_jax._linalg import chol3, inv3, mm, mt, mv, sym, tsum
from nanoslam_jax._trig import computed_once
from nanoslam_jax.models import range_bearing_components, wrap_angle
from nanoslam_jax.proposals import Detections
from nanoslam_jax.proposals._base import noise_information, range_bearing_residuals
from nanoslam_jax.proposals._natural_gradient import Gaussian, expected_grad_hess
from nanoslam_jax.quadrature import Cubature

RULE = Cubature()


def library(x, P, m, z, cov, mask, R):
    det = Detections(z, m, cov, mask)
    W = noise_information(x, det, R, False)
    return expected_grad_hess(RULE, Gaussian(x, inv3(P), P), range_bearing_residuals(det), W, mask)


def residual_components(m, z):
    """``(px, py, phi) -> (range, bearing)`` residuals of every row, one array per component
    (the pose components broadcast against the rows)."""
    def residual(px, py, phi):
        r, b = range_bearing_components(px, py, phi, m[:, 0], m[:, 1])
        return z[:, 0] - r, wrap_angle(z[:, 1] - b)

    return residual


def components(total: str, once: bool):
    def f(x, P, m, z, cov, mask, R):
        det = Detections(z, m, cov, mask)
        Wm = noise_information(x, det, R, False) * mask[:, None, None]
        xi, wm, _ = RULE.unit_points(3)
        L = chol3(P)
        X = [(x[i] + sum(xi[:, j] * L[i, j] for j in range(3)))[:, None] for i in range(3)]  # (points, 1)
        residual = residual_components(m, z)

        cols = []
        for i in range(3):
            along = lambda a, i=i: residual(*[a if j == i else X[j] for j in range(3)])  # noqa: E731
            r, dr = jax.jvp(along, (X[i],), (jnp.ones_like(X[i]),))
            cols.append(dr)
        J = [[cols[i][a] for i in range(3)] for a in range(2)]  # J[a][i]: (points, rows)
        if once:
            r, J = computed_once((r, J))
        Wr = [sum(Wm[:, a, b] * r[b] for b in range(2)) for a in range(2)]
        WJ = [[sum(Wm[:, a, b] * J[b][i] for b in range(2)) for i in range(3)] for a in range(2)]
        w = wm[:, None]
        S = (lambda a: tsum(tsum(a, -1), -1)) if total == "unrolled" else jnp.sum
        g = [S(w * sum(J[a][i] * Wr[a] for a in range(2))) for i in range(3)]
        H = [[S(w * sum(J[a][i] * WJ[a][j] for a in range(2))) for j in range(3)] for i in range(3)]
        return jnp.stack(g), sym(jnp.stack([jnp.stack(h) for h in H]))

    return f


def hybrid(x, P, m, z, cov, mask, R):
    """Jacobian entries by one jvp per pose component (symbolic zeros elsewhere), then stacked and
    summed as the library does."""
    det = Detections(z, m, cov, mask)
    Wm = noise_information(x, det, R, False) * mask[:, None, None]
    xi, wm, _ = RULE.unit_points(3)
    X = x + mm(xi, mt(chol3(P)))

    residual = residual_components(m, z)

    def at_point(xp):
        comps = (xp[0], xp[1], xp[2])
        cols = []
        for i in range(3):
            along = lambda a, i=i: residual(*[a if j == i else comps[j] for j in range(3)])  # noqa: E731
            r, dr = jax.jvp(along, (comps[i],), (jnp.ones_like(comps[i]),))
            cols.append(jnp.broadcast_to(jnp.stack(dr, -1), (m.shape[0], 2)))
        J = jnp.stack(cols, -1)  # (k, 2, 3)
        r = jnp.stack(r, -1)
        JtW = mm(mt(J), Wm)
        return tsum(mv(JtW, r)), tsum(mm(JtW, J))

    g, H = jax.vmap(at_point)(X)
    return tsum(wm[:, None] * g), sym(tsum(wm[:, None, None] * H))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--batch", type=int, default=640, help="particles in the batch (runs x particles)")
    p.add_argument("--rows", type=int, default=8, help="detection rows")
    p.add_argument("--repeat", type=int, default=20)
    p.add_argument("--calls", type=int, default=100, help="calls per timing")
    args = p.parse_args()

    rng = np.random.default_rng(0)
    B, k = args.batch, args.rows
    A = rng.normal(size=(B, 3, 3)) * 0.1
    inputs = (
        jnp.asarray(rng.normal(size=(B, 3))),
        jnp.asarray(A @ A.transpose(0, 2, 1) + 0.01 * np.eye(3)),
        jnp.asarray(rng.normal(size=(B, k, 2)) * 20.0),
        jnp.asarray(np.abs(rng.normal(size=(B, k, 2))) * 10.0),
        jnp.broadcast_to(0.1 * jnp.eye(2), (B, k, 2, 2)),
        jnp.asarray(rng.random((B, k)) < 0.7),
    )
    R = jnp.diag(jnp.array([1.0, 0.01]))
    cases = {
        "library (jacfwd, _linalg helpers)": library,
        "components, jnp.sum": components("sum", False),
        "components, unrolled": components("unrolled", False),
        "components, unrolled, once": components("unrolled", True),
        "hybrid": hybrid,
    }
    fns = {name: jax.jit(jax.vmap(f, (0, 0, 0, 0, 0, 0, None))) for name, f in cases.items()}
    ref = jax.block_until_ready(fns["library (jacfwd, _linalg helpers)"](*inputs, R))
    diffs = {}
    for name, f in fns.items():
        out = jax.block_until_ready(f(*inputs, R))
        diffs[name] = max(float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b))) for a, b in zip(out, ref))
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(args.repeat):  # alternated, so a slow period of the machine hits every case
        for name, f in fns.items():
            t = time.perf_counter()
            for _ in range(args.calls):
                out = f(*inputs, R)
            jax.block_until_ready(out)
            times[name].append(1e6 * (time.perf_counter() - t) / args.calls)
    print(f"\nE[grad], E[Hess] of the range-bearing residuals: {B} particles x 6 cubature points x {k} rows, "
          f"float64, {args.repeat} alternated timings of {args.calls} calls\n")
    print("| formulation | best [us] | median [us] | largest relative difference |")
    print("|---|---|---|---|")
    for name, t in times.items():
        print(f"| {name} | {min(t):.0f} | {np.median(t):.0f} | {diffs[name]:.1e} |")


if __name__ == "__main__":
    main()
