"""The scan driver: the whole log as one ``lax.scan`` of :func:`filter_step`.

:func:`filter_scan` is pure (jit- and vmap-friendly: sweeps vmap it over :class:`Params` and
keys). :func:`run_filter` is the host driver: it compiles one chunk program and calls it over
fixed-size chunks of the log (padding the last, whose padding the program skips), reporting
progress between chunks.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
import time
from typing import Any, Callable, NamedTuple, Optional

import jax
import jax.extend
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, Key

from nanoslam_jax.lib._cache import compile_program
from nanoslam_jax.data import Segments
from nanoslam_jax.methods._method import Method
from nanoslam_jax.methods.proposals import AbstractProposal
from nanoslam_jax.methods._params import Params, Static
from nanoslam_jax.methods.particle._prior import AbstractPrior, UnscentedPrior, predict_mean, relative_prior
from nanoslam_jax.methods.gaussian._gaussian import as_step_output
from nanoslam_jax.methods._state import FilterState, LandmarkMap, init_state
from nanoslam_jax.methods.particle._step import StepOutput, filter_step


def is_gaussian(method: Method) -> bool:
    """Whether a method is Gaussian (no particles; a run does not depend on the seed)."""
    return method.kind == "gaussian"


def make_proposal(static: Static, params: Params) -> AbstractProposal:
    """The proposal of ``static.method`` (a registered particle method) with its traced
    hyperparameters from ``params``."""
    method = static.method
    if method.kind != "particle" or method.proposal is None:
        raise ValueError(
            f"filter.method: {method.name!r} is a {method.kind.replace('_', ' ')} method and has no particle-filter "
            "proposal; expected a particle method"
        )
    return method.proposal(static, params, params.method)


def _check_filter_method(static: Static) -> None:
    """Refuse dead reckoning, which ``run_filter`` / ``run_batch`` cannot scan, before tracing (any
    other unknown method is refused by :func:`make_proposal`)."""
    if static.method.kind == "dead_reckoning":
        raise ValueError(
            "filter.method: 'dead_reckoning' is deterministic and has no filter to run: use "
            "nanoslam_jax.methods.dead_reckoning(params, segments) (what `nanoslam run` and "
            "`nanoslam compare` do for it)"
        )


def check_controls(params: Params, segments: Segments) -> None:
    """Raise a ValueError naming ``model.motion`` when the segments' DR pieces hold fewer controls
    than the motion model reads (its ``control_dim``), e.g. a log of ``(v, omega)`` rows with the
    odometry model's ``(vx, vy, omega)``."""
    have, need = int(np.shape(segments.u)[-1]), int(params.motion.control_dim)
    if have < need:
        raise ValueError(
            f"model.motion: {type(params.motion).__name__} reads {need} controls per DR piece, the log's "
            f"segments hold {have}; the log's DR rows must be (time, {need} controls)"
        )


def _masked_step(static: Static, params: Params, state, inp: tuple):
    seg, valid, rel_prior = inp
    method = static.method
    if method.kind == "gaussian":
        assert method.step is not None  # Method requires it of a Gaussian method
        state, out = method.step(static, params, state, seg, valid)
        return state, as_step_output(out)
    return filter_step(static, params, make_proposal(static, params), state, seg, valid, rel_prior)


def segment_priors(
    static: Static, params: Params, segments: Segments
) -> Optional[tuple[Float[Array, "segments 3"], Float[Array, "segments 3 3"]]]:
    """Every segment's :func:`relative_prior` (the prior in the frame of the segment's start pose,
    shared by all particles), or None where the particles' priors are their own (EKF-SLAM, NASRUKF,
    ``filter.prior_cov: carry``, a motion model that is not ``rigid``). It depends on the controls
    and the hyperparameters only, so :func:`filter_scan` computes it for all segments at once,
    before the scan."""
    if is_gaussian(static.method) or not static.prior.reset or not params.motion.rigid:
        return None
    return relative_priors(segments, params, static.prior)


def relative_priors(
    segments: Segments, params: Params, prior: AbstractPrior = UnscentedPrior()
) -> tuple[Float[Array, "segments 3"], Float[Array, "segments 3 3"]]:
    """:func:`relative_prior` of every segment (``prior``: ``filter.prior``). Traced inside the
    filter's program by :func:`segment_priors`; the offline smoother calls its compiled form."""
    rel = lambda dt, u, m: relative_prior(dt, u, m, params, prior)  # noqa: E731
    return jax.vmap(rel)(segments.dt, segments.u, segments.dr_mask)


def initial_state(static: Static, params: Params, key: Key[Array, ""]):
    """The state a run starts from: a :class:`FilterState` (its particles drawn with ``key``, which
    it carries on), or a Gaussian method's :class:`~._gaussian.GaussianState` (an
    ``EkfSlamState`` for EKF-SLAM, a ``NasrukfState`` for NASRUKF; ``key`` is not used: a
    Gaussian method does not sample)."""
    method = static.method
    if method.kind == "gaussian":
        assert method.init is not None  # Method requires it of a Gaussian method
        return method.init(static, params)
    return init_state(static, params, key)


def resample_count(state) -> Int[Array, "*batch"]:
    """Resampling steps so far: a particle state's count, 0 for a Gaussian state (no particles).

    Works on a single or a batched state (zeros of the batch's shape for a Gaussian one).
    """
    if isinstance(state, FilterState):
        return state.resample_count
    return jnp.zeros(jnp.shape(state.scan), jnp.int32)


def reported_map(state) -> LandmarkMap:
    """The map of the reported estimate: the best particle's, or the marginals of EKF-SLAM's or
    NASRUKF's features.

    Works on a single state; ``jax.vmap`` it over a batched state.
    """
    if isinstance(state, FilterState):
        return jax.tree.map(lambda a: a[state.best], state.particles.landmarks)
    return state.landmark_map()


def filter_scan(
    static: Static,
    params: Params,
    segments: Segments,
    key: Optional[Key[Array, ""]],
    state: Optional[Any] = None,
    valid: Optional[Bool[Array, " segments"]] = None,
    skip_padding: bool = False,
) -> tuple[Any, StepOutput]:
    """Run the filter over all segments in one ``lax.scan``.

    Args:
        static: static settings (a static argument when jitted).
        params: traced hyperparameters.
        segments: the log's segments.
        key: PRNG key of a fresh state (used only when ``state`` is None; a particle state
            carries its key on, a Gaussian method does not sample).
        state: state to continue from (default: a fresh state from ``key``).
        valid: which segments are real (padding segments leave the state unchanged).
        skip_padding: stop after the last real segment (a loop with a traced trip count): the
            padding after it is not computed (a padding step leaves the state unchanged but costs
            a whole step), and its records are zeros. The chunk driver's setting.

    Returns:
        The final state and a :class:`StepOutput` per segment.
    """
    if state is None:
        if key is None:
            raise ValueError("filter_scan: a key is needed to start a fresh state (state None)")
        state = initial_state(static, params, key)
    if valid is None:
        valid = jnp.ones(segments.time.shape[0], bool)
    inputs = (segments, valid, segment_priors(static, params, segments))
    step = functools.partial(_masked_step, static, params)
    if skip_padding:
        return _scan_prefix(step, state, inputs, jnp.max(jnp.where(valid, jnp.arange(valid.shape[0]) + 1, 0)))
    return jax.lax.scan(step, state, inputs)


def _scan_prefix(f, init, xs, length: Int[Array, ""]):
    """``jax.lax.scan(f, init, xs)`` over the first ``length`` entries of ``xs`` only (a loop with
    a traced trip count): the carry after them, and the outputs stacked to the full length of
    ``xs``, zeros past ``length``.

    ``f`` is traced once, as ``lax.scan`` traces it: its jaxpr gives the outputs' shapes and is
    what the loop evaluates (tracing a many-particle filter step takes seconds).
    """
    total = jax.tree.leaves(xs)[0].shape[0]
    closed, out_shapes = jax.make_jaxpr(f, return_shape=True)(init, jax.tree.map(lambda a: a[0], xs))
    step, out_tree = jax.extend.core.jaxpr_as_fun(closed), jax.tree.structure(out_shapes)
    ys = jax.tree.map(lambda s: jnp.zeros((total,) + s.shape, s.dtype), out_shapes[1])

    def body(i, c):
        carry, ys = c
        x = jax.tree.map(lambda a: jax.lax.dynamic_index_in_dim(a, i, keepdims=False), xs)
        carry, y = jax.tree.unflatten(out_tree, step(*jax.tree.leaves((carry, x))))
        return carry, jax.tree.map(lambda buf, v: jax.lax.dynamic_update_index_in_dim(buf, v, i, 0), ys, y)

    return jax.lax.fori_loop(0, length, body, (init, ys))


@functools.partial(jax.jit, static_argnames=("static",))
def _chunk(static: Static, params: Params, state: Any, segments: Segments, valid) -> tuple[Any, StepOutput]:
    return filter_scan(static, params, segments, None, state, valid, skip_padding=True)


@functools.partial(jax.jit, static_argnames=("static",))
def _init(static: Static, params: Params, key) -> Any:
    return initial_state(static, params, key)


@functools.partial(jax.jit, static_argnames=("static",))
def _chunk_batch(static: Static, params: Params, state: Any, segments: Segments, valid) -> tuple[Any, StepOutput]:
    run = lambda p, s: filter_scan(static, p, segments, None, s, valid, skip_padding=True)  # noqa: E731
    return jax.vmap(run)(params, state)


@functools.partial(jax.jit, static_argnames=("static",))
def _init_batch(static: Static, params: Params, keys) -> Any:
    return jax.vmap(lambda p, k: initial_state(static, p, k))(params, keys)


class MapHistory(NamedTuple):
    """The best particle's map at the end of each chunk of a run (host arrays).

    A particle whose pose drifts where it comes back to trees it mapped earlier misses them where
    it expects them, and landmark management removes them; its final map then holds only the
    drifted copies it made instead. The offline smoother takes the removed landmarks back from
    here (:func:`nanoslam_jax.smoother._smoother.held_landmarks`).

    Attributes:
        mean: the landmark slots' states (a leading batch axis after the chunk axis for
            :func:`run_batch`).
        held: which slots held a confirmed landmark.
    """

    mean: Float[np.ndarray, "chunks *batch slots l"]
    held: Bool[np.ndarray, "chunks *batch slots"]


class FilterRun(NamedTuple):
    """Outputs of :func:`run_filter` (host arrays).

    Attributes:
        state: the final filter state.
        outputs: per-segment records (numpy).
        compile_s: compilation time of the chunk program.
        run_s: run time after compilation (all chunks).
        chunk_s: wall time of each chunk call (only when timed or with progress; else empty).
        chunk_size: segments per chunk.
        history: the best particle's confirmed landmarks after each chunk (``None`` for the
            methods without particles).
    """

    state: Any
    outputs: StepOutput
    compile_s: float
    run_s: float
    chunk_s: tuple = ()
    chunk_size: int = 0
    history: MapHistory | None = None


def _best_map(state: Any) -> tuple[Float[Array, "slots l"], Bool[Array, " slots"]]:
    lm = reported_map(state)  # the fields not returned are not computed under jit
    return lm.mean, lm.active & lm.confirmed


_best_map_single = jax.jit(_best_map)
_best_map_batch = jax.jit(jax.vmap(_best_map))


def _pad(segments: Segments, length: int) -> tuple[Segments, np.ndarray]:
    n = segments.time.shape[0]
    valid = np.arange(length) < n
    pad = lambda a: np.concatenate([a, np.zeros((length - n,) + a.shape[1:], a.dtype)]) if length > n else a  # noqa: E731
    padded = (None if a is None else pad(np.asarray(a)) for a in segments)
    return Segments(*padded), valid  # type: ignore[arg-type]  # numpy on the host


class _Chunks(NamedTuple):
    """How the driver runs a log: ``size`` segments per call of the compiled program,
    ``progress(done, total, seconds)`` after each (or None), and ``timed``: each call's time kept."""

    size: int
    progress: Any = None
    timed: bool = False


def _drive(
    chunk_fn, static: Static, params: Params, state: Any, segments: Segments, chunks: _Chunks, time_axis: int
) -> FilterRun:
    """Compile ``chunk_fn`` once for ``chunks.size`` segments and call it over the padded log."""
    progress, timed = chunks.progress, chunks.timed
    n = segments.time.shape[0]
    chunk = max(1, min(chunks.size, n))
    n_chunks = -(-n // chunk)
    padded, valid = _pad(segments, n_chunks * chunk)

    def piece(c):
        return (
            jax.tree.map(lambda a: jnp.asarray(a[c * chunk : (c + 1) * chunk]), padded),
            jnp.asarray(valid[c * chunk : (c + 1) * chunk]),
        )

    t0 = time.perf_counter()
    batch = int(np.shape(jax.tree.leaves(state)[0])[0]) if time_axis == 1 else 1
    compiled = compile_program(  # traced and compiled, or cached
        chunk_fn, static, params, state, *piece(0), label="filter program", segments=chunk, batch=batch
    )
    compile_s = time.perf_counter() - t0
    outs, chunk_s, held = [], [], []
    best_map = _best_map_single if time_axis == 0 else _best_map_batch
    particles = isinstance(state, FilterState)  # EKF-SLAM and NASRUKF have one map, no particles
    t1 = tc = time.perf_counter()
    for c in range(n_chunks):
        state, out = compiled(params, state, *piece(c))
        outs.append(out)
        if particles:
            held.append(best_map(state))
        if progress is not None or timed:
            jax.block_until_ready(state)
            now = time.perf_counter()
            chunk_s.append(now - tc)
            tc = now
            if progress is not None:
                progress(min((c + 1) * chunk, n), n, now - t1)
    jax.block_until_ready(state)
    run_s = time.perf_counter() - t1
    cat = lambda *a: np.take(np.concatenate([np.asarray(x) for x in a], axis=time_axis), np.arange(n), axis=time_axis)  # noqa: E731
    history = MapHistory(*(np.stack([np.asarray(h[i]) for h in held]) for i in (0, 1))) if held else None
    return FilterRun(state, jax.tree.map(cat, *outs), compile_s, run_s, tuple(chunk_s), chunk, history)


def run_filter(
    static: Static,
    params: Params,
    segments: Segments,
    seed: int,
    *,
    chunk: int = 500,
    progress: Optional[Callable[[int, int, float], None]] = None,
    timed: bool = False,
) -> FilterRun:
    """Run the filter over a log in compiled chunks of ``chunk`` segments.

    One program is compiled for a chunk and called over the log; the last chunk is padded with
    no-op segments, so the whole log needs one compilation whatever its length. The program stops
    after a chunk's last real segment, so the padding costs no filter steps.

    Args:
        static, params: filter settings.
        segments: the log's segments (host or device arrays).
        seed: PRNG seed.
        chunk: segments per compiled call.
        progress: called as ``progress(done, total, elapsed_s)`` after each chunk.
        timed: record each chunk's wall time (``FilterRun.chunk_s``; the computation time per
            scan over the log, e.g. EKF-SLAM's growth with the map).
    """
    _check_filter_method(static)
    check_controls(params, segments)
    state = _init(static, params, jax.random.key(seed))
    return _drive(_chunk, static, params, state, segments, _Chunks(chunk, progress, timed), time_axis=0)


def run_batch(
    static: Static,
    params: Params,
    segments: Segments,
    seeds: "np.ndarray | list[int]",
    *,
    chunk: int = 500,
    progress: Optional[Callable[[int, int, float], None]] = None,
) -> FilterRun:
    """Run a batch of filters in one compiled program, vmapped over hyperparameters and seeds.

    Args:
        static: static settings shared by the batch.
        params: hyperparameters with a leading batch axis on every leaf (see :func:`stack_params`).
        segments: the log's segments (shared).
        seeds: one PRNG seed per batch member.
        chunk, progress: as in :func:`run_filter`.

    Returns:
        A :class:`FilterRun` whose state and outputs carry a leading batch axis.

    Each member's particles stay on one device (``static.devices`` is ignored).
    """
    _check_filter_method(static)
    check_controls(params, segments)
    static = dataclasses.replace(static, devices=1)  # a batch member's particles stay on one device
    keys = jax.vmap(jax.random.key)(jnp.asarray(np.asarray(seeds)))
    state = _init_batch(static, params, keys)
    return _drive(_chunk_batch, static, params, state, segments, _Chunks(chunk, progress), time_axis=1)


def stack_params(params: "list[Params]") -> Params:
    """Stack a list of :class:`Params` into one with a leading batch axis."""
    return jax.tree.map(lambda *a: jnp.stack([jnp.asarray(x) for x in a]), *params)


def text_progress(label: str = "filter", stream=sys.stderr) -> Callable[[int, int, float], None]:
    """A progress callback printing ``label: done/total segments (pct) elapsed, eta``."""

    def report(done: int, total: int, elapsed: float) -> None:
        eta = elapsed / max(done, 1) * (total - done)
        end = "\n" if done >= total else "\r"
        stream.write(
            f"{label}: {done}/{total} scans ({100 * done / total:5.1f}%) {elapsed:6.1f} s elapsed, ~{eta:5.1f} s left{end}"
        )
        stream.flush()

    return report


@jax.jit
def dead_reckoning(params: Params, segments: Segments) -> Float[Array, "segments 3"]:
    """Noise-free propagation of the pose from the origin through every segment (the DR baseline)."""
    check_controls(params, segments)

    def body(x, seg):
        x = predict_mean(x, seg.dt, seg.u, params)
        return x, x

    _, poses = jax.lax.scan(body, jnp.zeros(3), segments)
    return poses
