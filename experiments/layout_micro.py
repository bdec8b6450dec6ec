"""Does the layout vmap gives a sweep batch hold its arithmetic back? A micro-benchmark.

One kernel of the association, the distances from each particle's position to its window's
landmarks, ``rsqrt(max(dx^2 + dy^2, 1e-24))`` over 64 runs x 10 particles x 78 window slots, timed
in three layouts inside a ``lax.scan`` (each step reads an input that depends on the carry, so
nothing is hoisted; the outputs are summed so nothing is dropped):

* ``vmap``: as a vmapped batch holds it, ``(64, 10, 78, 2)`` with the x/y pair innermost;
* ``components first``: ``(2, 64, 10, 78)``;
* ``particles innermost``: ``(78, 2, 640)``, the layout a hand-written "structure of arrays"
  step would use.

    python experiments/layout_micro.py
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)


def vmap_layout(m, x):
    dx, dy = m[..., 0] - x[..., 0:1], m[..., 1] - x[..., 1:2]
    return jax.lax.rsqrt(jnp.maximum(dx * dx + dy * dy, 1e-24))


def components_first(m, x):
    dx, dy = m[0] - x[0][..., None], m[1] - x[1][..., None]
    return jax.lax.rsqrt(jnp.maximum(dx * dx + dy * dy, 1e-24))


def particles_innermost(m, x):
    dx, dy = m[:, 0] - x[0], m[:, 1] - x[1]
    return jax.lax.rsqrt(jnp.maximum(dx * dx + dy * dy, 1e-24))


def per_step_us(f, m, x, steps: int = 200, repeat: int = 7) -> float:
    def body(c, _):
        return c + jnp.sum(f(m + c, x)), None

    run = jax.jit(lambda: jax.lax.scan(body, jnp.zeros(()), None, length=steps)[0])
    jax.block_until_ready(run())
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(run())
        best = min(best, time.perf_counter() - t)
    return 1e6 * best / steps


def main() -> None:
    rng = np.random.default_rng(0)
    m = rng.normal(size=(64, 10, 78, 2))
    x = rng.normal(size=(64, 10, 2))
    cases = [
        ("vmap: (64, 10, 78, 2)", vmap_layout, m, x),
        ("components first: (2, 64, 10, 78)", components_first, np.moveaxis(m, -1, 0).copy(), np.moveaxis(x, -1, 0).copy()),
        ("particles innermost: (78, 2, 640)", particles_innermost, m.reshape(640, 78, 2).transpose(1, 2, 0).copy(),
         x.reshape(640, 2).T.copy()),
    ]
    print("| layout | us per step (best of 7, 200 steps) |\n|---|---|")
    for name, f, a, b in cases:
        print(f"| {name} | {per_step_us(f, jnp.asarray(a), jnp.asarray(b)):.1f} |")


if __name__ == "__main__":
    main()
