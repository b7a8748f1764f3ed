"""A fused Pallas (Triton) kernel for the SERN softmax fast path: state on chip across rounds.

``make_pallas_run(config)`` returns ``fn(keys [S], params) -> simulate.RunOutput`` (leading
axis S) with the semantics, random draws and outputs of ``vmap(fast_softmax.make_fast_run)``
for the configurations :func:`supports` accepts (those of :mod:`sern_jax.engine.fast_softmax`, in
float32, with K a power of two, 2 ≤ K ≤ 256: Triton tensors have power-of-two sizes, and
:func:`_tiled_prefix_sums` follows XLA's cumsum order only up to 16 tiles of 16).

Why a kernel. On a GPU the XLA engine keeps each seed's ``[K]`` weights, prefix sums,
statistics and compensator in HBM and streams them through every round. Here one program
instance owns ``seeds_per_program`` seeds, holds their ``[B, K]`` state in registers for all T
rounds, and writes only the checkpoint outputs.

What one seed-round does (the same as :mod:`sern_jax.engine.fast_softmax`, op for op):

* the two uniforms come from the same counter-based threefry hashes
  (``uniform(fold_in(key_agent, t), ())`` for the arm, ``uniform(fold_in(key_env, t), (2,))[1]``
  for the reward; :func:`sern_jax.core.prng.threefry2x32`). They are computed for a whole block of
  ``block`` rounds at once as a ``[B, block]`` tile (every element once, no replication across
  the threads that share a seed) and round ``j`` takes column ``j`` by a masked sum (exact:
  the other terms are +0);
* the arm is ``min(#{a: cdf_a <= u·W}, K − 1)``; its count, reward sum and mean are masked sums
  over the one-hot row (exact); regret, ``min π``, the compensator ``A += w/W`` and the
  prefix-sum update ``cdf += δ·1{a ≥ arm}`` are the engine's expressions; ``W`` (= ``cdf[K−1]``)
  is kept as its own ``[B]`` value, updated by the same ``+ δ``;
* every ``block`` rounds (and at every checkpoint) the prefix sums are recomputed from ``w``
  (``rebase``) and the block sums go into Kahan totals (``flush``), on the engine's schedule.

Same arithmetic as the engine (all float32), checked op by op against XLA on the H100
(``experiments/results/bench/pallas_ops_probe_h100.json``): ``exp`` is libdevice's
``__nv_expf`` in both (100 % equal), division is plain ``/`` (Triton's equals XLA's on 100 %;
IEEE ``div.rn`` would not), ``a + b·c`` gives the same float32 in both (100 %; whether
either contracts it to an FMA was not established: XLA's equals the once-rounded value on
75.7 % only, so likely neither does), and the
prefix sums at each rebase follow XLA's own order for the engine's ``jnp.cumsum``
(:func:`_tiled_prefix_sums`). One difference is left: ``Σ_a w_a r_a`` at each rebase is
``sum(w·r)`` here and ``dot(w, r)`` in the engine, so the Rao–Blackwellised regret may differ
by rounding (at most about ``t·K·2^-23`` after t rounds); the arms do not depend on it.
In Pallas' interpreter (CPU) every output equals the engine's bit for bit (tests); on the
GPU ``sern bench bandit --pallas`` reports the fraction of seeds whose outputs equal the
engine's.

One device only: the kernel is not sharded. ``drive.run_seeds`` takes it by default on one
GPU wherever :func:`supports` holds (``plan.pallas_by_default``; ``runner="fast"`` keeps the
XLA fast runner), and ``sern bench bandit --pallas`` times it beside the engine. Use
``interpret=True`` off-GPU (tests); on a GPU the kernel compiles through Triton
(``jax.experimental.pallas.triton.CompilerParams``). The Pallas Triton backend is deprecated
in recent jax releases: where :func:`available` says it is gone, ``run_seeds`` keeps the fast
runner, which draws the same arms.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.engine import fast_softmax
from sern_jax.core import schedules
from sern_jax.engine import simulate as sim
from sern_jax.core.prng import threefry2x32
from sern_jax.core.types import Array, Key

__all__ = [
    "DEFAULT_NUM_WARPS",
    "DEFAULT_SEEDS_PER_PROGRAM",
    "MAX_ARMS",
    "REBASE_MODES",
    "make_pallas_run",
    "pad_seeds",
    "supports",
]

DEFAULT_SEEDS_PER_PROGRAM = 16  # B: seeds one program instance owns (rows of its tiles)
DEFAULT_NUM_WARPS = 4
REBASE_MODES = ("tiled16", "scan", "sequential")
MAX_ARMS = 256  # 16 tiles of 16: the K up to which _tiled_prefix_sums is XLA's cumsum order


SUPPORTS_TEXT = ("SERN softmax with one context, a local estimator, no diagnostics, float32 "
                 f"and K a power of two in [2, {MAX_ARMS}]")


def available() -> bool:
    """Whether this jax lowers Pallas kernels to Triton (``jax.experimental.pallas.triton``).
    Where it does not, ``run_seeds`` keeps the fast runner on a GPU, whose arms are the same."""
    try:
        from jax.experimental.pallas import triton  # noqa: F401
    except ImportError:
        return False
    return True


def supports(config: sim.RunConfig, params: sim.RunParams | None = None) -> bool:
    """Whether :func:`make_pallas_run` reproduces the fast engine for ``config``.

    True when ``fast_softmax.supports(config, params)`` holds, the dtype is float32 and
    K is a power of two with 2 ≤ K ≤ ``MAX_ARMS`` (256). Above 256 (more than 16 tiles of 16)
    XLA's cumsum also sums the tile totals in tiles, which :func:`_tiled_prefix_sums` does not
    (on CPU its prefix sums equal ``jnp.cumsum``'s on ~0.79 of elements at K = 512, ~0.53 at
    1024), so the kernel would not reproduce the engine there.
    """
    k = config.num_arms
    return (fast_softmax.supports(config, params) and config.dtype == "float32"
            and 2 <= k <= MAX_ARMS and k & (k - 1) == 0)


def pad_seeds(num_seeds: int, seeds_per_program: int) -> int:
    """Seeds rounded up to a whole number of programs."""
    return -(-num_seeds // seeds_per_program) * seeds_per_program


def _tiled_prefix_sums(w: Array, tile: int) -> Array:
    """``[B, K]`` prefix sums of ``w`` along K in XLA's order for ``jnp.cumsum`` (its
    ``ReduceWindowRewriter``, base length 16, on CPU and GPU alike; ``tile ≥ K``: plain left
    to right): left to right within tiles of ``tile`` arms, then each tile plus the left-to-right
    sum of the earlier tiles' totals. That is XLA's order for at most 16 tiles (K ≤ 256 with
    tile 16); with more, XLA sums the tile totals in tiles of 16 too and this order differs
    (``supports`` caps K at 256).

    Written with explicit additions on ``[B, K/tile, tile]`` views, one column of every tile at
    a time (a masked sum picks the column: exact, the other terms are +0), so every platform
    adds the same numbers in the same order. An earlier version used float32 dots with 0/1
    matrices; on the H100 Triton's dots matched XLA's cumsum on only 84 % of elements
    (experiments/results/bench/pallas_ops_probe_h100_dots.json): they do not add in k order.
    """
    b, k = w.shape
    tile = min(tile, k)
    num_tiles = k // tile
    w3 = w.reshape(b, num_tiles, tile)
    lane = jax.lax.broadcasted_iota(jnp.int32, (b, num_tiles, tile), 2)
    acc = jnp.zeros((b, num_tiles), w.dtype)
    inner = jnp.zeros_like(w3)
    for i in range(tile):
        acc = acc + jnp.sum(jnp.where(lane == i, w3, 0.0), axis=2)
        inner = jnp.where(lane == i, acc[:, :, None], inner)
    if num_tiles == 1:
        return inner.reshape(b, k)
    tile_id = jax.lax.broadcasted_iota(jnp.int32, (b, num_tiles), 1)
    carry = jnp.zeros((b,), w.dtype)
    before = jnp.zeros((b, num_tiles), w.dtype)  # exclusive prefix of the tile totals
    for c in range(1, num_tiles):
        carry = carry + jnp.sum(jnp.where(tile_id == c - 1, acc, 0.0), axis=1)
        before = jnp.where(tile_id == c, carry[:, None], before)
    return (inner + before[:, :, None]).reshape(b, k)


def _segments(config: sim.RunConfig, block: int) -> np.ndarray:
    """``[G, 2]`` int32: per checkpoint segment, its first round and its length (rounds)."""
    grid = sim.checkpoint_times(config)
    starts = np.concatenate([[0], grid[:-1]]).astype(np.int64)
    return np.stack([starts, grid - starts], axis=1).astype(np.int32)


class _State(NamedTuple):
    w: Array  # [B, K] unnormalised weights exp((r̂ − 1)/α)
    cdf: Array  # [B, K] running prefix sums of w (exact at each block start)
    big_w: Array  # [B] cdf[:, K − 1], updated by the same + δ
    n: Array  # [B, K] float32 pulls N_a
    s: Array  # [B, K] float32 summed rewards S_a
    comp: Array  # [B, K] compensator Σ w/W over the current block
    comp_sum: Array  # [B, K] Kahan total of the finished blocks
    comp_err: Array  # [B, K] its compensation
    s_wr: Array  # [B] Σ_a w_a r_a
    reg: Array  # [B] realised regret over the current block
    reg_rb: Array  # [B] Rao–Blackwellised regret over the current block
    reg_sum: Array  # [B] Kahan totals of the finished blocks (realised)
    reg_err: Array  # [B]
    rb_sum: Array  # [B] (Rao–Blackwellised)
    rb_err: Array  # [B]
    min_prob: Array  # [B]


def _check(config: sim.RunConfig, seeds_per_program, num_warps, block, rebase) -> None:
    """``ValueError`` unless the kernel reproduces the engine for ``config`` and the options
    are valid (host-side, before anything is traced)."""
    sim.validate(config)
    if not supports(config):
        raise ValueError(
            f"pallas_softmax supports what fast_softmax supports, in float32, with num_arms a "
            f"power of two in [2, {MAX_ARMS}]; got policy={config.policy!r}, estimator="
            f"{config.estimator!r}, num_contexts={config.num_contexts}, dtype={config.dtype!r}, "
            f"num_arms={config.num_arms}, diagnostics={config.diagnostics}")
    for name, v in (("seeds_per_program", seeds_per_program), ("block", block)):
        if not (isinstance(v, (int, np.integer)) and v >= 1 and v & (v - 1) == 0):
            raise ValueError(f"{name} must be a power of two >= 1, got {v!r}")
    if not (isinstance(num_warps, (int, np.integer)) and num_warps in (1, 2, 4, 8, 16)):
        raise ValueError(f"num_warps must be one of 1, 2, 4, 8, 16, got {num_warps!r}")
    if rebase not in REBASE_MODES:
        raise ValueError(f"rebase must be one of {REBASE_MODES}, got {rebase!r}")


def _div(x, y):
    # Plain ``/``: Triton's float32 division is XLA's; IEEE div.rn.f32 is not always.
    return x / y


def _rhat(estimator: str, n, s, r_true, pin, dtype):
    """The engine's r̂ of each arm from its pulls ``n`` and reward sums ``s`` (clipped)."""
    if estimator == "addhalf":  # the engine's tabular_rhat, with an IEEE division
        r = _div(s + 0.5, n + 1.0)
    elif estimator == "mean":
        r = jnp.where(n > 0, _div(s, jnp.maximum(n, 1.0)), 0.5)
    elif estimator in ("l1median", "l1argmax"):
        from sern_jax.core import estimators as est_lib

        r = est_lib.tabular_rhat(estimator, n, s, dtype)  # no division
    elif estimator == "exact":
        r = r_true
    elif estimator == "pinned":
        r = jnp.where(pin, 0.0, 1.0).astype(dtype)
    else:  # pragma: no cover - supports() rules it out
        raise AssertionError(estimator)
    return jnp.clip(r, 0.0, 1.0)


def _uniform_tile(k1, k2, t0, index: int, shape: tuple[int, int], dtype):
    """``[B, block]``: ``uniform(fold_in(key, t0 + j), ·)[index]`` for rounds j, from the
    key words ``k1, k2`` [B] (the counter-based threefry hashes of ``jax.random``)."""
    t = t0.astype(jnp.uint32) + jax.lax.broadcasted_iota(jnp.uint32, shape, 1)
    f1, f2 = threefry2x32(k1[:, None], k2[:, None], jnp.zeros_like(t), t)
    b1, b2 = threefry2x32(f1, f2, np.uint32(0), np.uint32(index))
    bits = ((b1 ^ b2) >> np.uint32(9)) | np.uint32(0x3F800000)
    return jax.lax.bitcast_convert_type(bits, dtype) - dtype(1.0)


def _make_kernel(config: sim.RunConfig, big_b: int, block: int, rebase_mode: str,
                 num_g: int) -> Callable:
    """The kernel body: one program instance plays all T rounds of its ``big_b`` seeds with
    their ``[B, K]`` state on chip and writes the ``num_g`` checkpoints' outputs."""
    num_arms = config.num_arms
    dtype = jnp.float32
    estimator = config.estimator
    tile = 16 if rebase_mode == "tiled16" else num_arms  # "sequential": one tile

    def rhat(n, s, r_true, pin):
        return _rhat(estimator, n, s, r_true, pin, dtype)

    def uniform_tile(k1, k2, t0, index):
        return _uniform_tile(k1, k2, t0, index, (big_b, block), dtype)

    def kernel(seg_ref, env0_ref, env1_ref, ag0_ref, ag1_ref, means_ref, inva_ref, pin_ref,
               reg_ref, rb_ref, cnt_ref, comp_ref, mp_ref):
        env0, env1 = env0_ref[...], env1_ref[...]  # [B] uint32 key words of the env rounds
        ag0, ag1 = ag0_ref[...], ag1_ref[...]  # [B] key words of the agent rounds
        means = means_ref[...]  # [B, K]
        inv_alpha = inva_ref[...]  # [B]
        iota_k = jax.lax.broadcasted_iota(jnp.int32, (big_b, num_arms), 1)
        iota_j = jax.lax.broadcasted_iota(jnp.int32, (big_b, block), 1)
        pinned = iota_k == pin_ref[...][:, None]  # [B, K]
        best = jnp.max(means, axis=1)  # [B]

        def weights(r):
            return jnp.exp((r - 1.0) * inv_alpha[:, None] if r.ndim == 2
                           else (r - 1.0) * inv_alpha)

        def pick(mask, x):  # [B, N] -> [B]: the one masked element (exact: the rest are +0)
            return jnp.sum(jnp.where(mask, x, 0.0), axis=1)

        def rebase(c: _State) -> _State:
            if rebase_mode == "scan":
                cdf = jnp.cumsum(c.w, axis=1)
            else:
                cdf = _tiled_prefix_sums(c.w, tile)
            return c._replace(cdf=cdf, big_w=pick(iota_k == num_arms - 1, cdf),
                              s_wr=jnp.sum(c.w * means, axis=1))

        def flush(c: _State) -> _State:
            reg_sum, reg_err = sim.kahan_add(c.reg_sum, c.reg_err, c.reg)
            rb_sum, rb_err = sim.kahan_add(c.rb_sum, c.rb_err, c.reg_rb)
            comp_sum, comp_err = sim.kahan_add(c.comp_sum, c.comp_err, c.comp)
            zero = jnp.zeros_like(c.reg)
            return c._replace(reg=zero, reg_rb=zero, comp=jnp.zeros_like(c.comp),
                              reg_sum=reg_sum, reg_err=reg_err, rb_sum=rb_sum, rb_err=rb_err,
                              comp_sum=comp_sum, comp_err=comp_err)

        def play(j, u_a_tile, u_r_tile, c: _State) -> _State:
            col = iota_j == j
            u_a = pick(col, u_a_tile)  # [B]
            u_r = pick(col, u_r_tile)
            x = u_a * c.big_w
            arm = jnp.minimum(jnp.sum((c.cdf <= x[:, None]).astype(jnp.int32), axis=1),
                              num_arms - 1)
            onehot = iota_k == arm[:, None]  # [B, K]
            n_old = pick(onehot, c.n)
            s_old = pick(onehot, c.s)
            r_arm = pick(onehot, means)
            pin = pick(onehot, pinned.astype(dtype)) > 0.5 if estimator == "pinned" else None
            reward = (u_r < r_arm).astype(dtype)
            inv_w = _div(jnp.ones_like(c.big_w), c.big_w)
            reg = c.reg + (best - r_arm)
            reg_rb = c.reg_rb + (best - c.s_wr * inv_w)
            min_prob = jnp.minimum(c.min_prob, jnp.min(c.w, axis=1) * inv_w)
            comp = c.comp + c.w * inv_w[:, None]
            w_old = weights(rhat(n_old, s_old, r_arm, pin))
            w_new = weights(rhat(n_old + 1.0, s_old + reward, r_arm, pin))
            delta = w_new - w_old
            cdf = c.cdf + jnp.where(iota_k >= arm[:, None], delta[:, None], 0.0)
            return c._replace(
                w=jnp.where(onehot, w_new[:, None], c.w), cdf=cdf, big_w=c.big_w + delta,
                n=c.n + onehot.astype(dtype), s=c.s + jnp.where(onehot, reward[:, None], 0.0),
                comp=comp, s_wr=c.s_wr + delta * r_arm, reg=reg, reg_rb=reg_rb,
                min_prob=min_prob)

        def sub_block(t0, length, c: _State) -> _State:
            u_a_tile = uniform_tile(ag0, ag1, t0, 0)
            u_r_tile = uniform_tile(env0, env1, t0, 1)
            c = jax.lax.fori_loop(0, length, lambda j, c: play(j, u_a_tile, u_r_tile, c),
                                  rebase(c))
            return flush(c)

        def segment(g, c: _State) -> _State:
            start, length = seg_ref[g, 0], seg_ref[g, 1]
            num_blocks = length // block

            def one(i, c):  # sub-block i: a full block, or the remainder (i = num_blocks)
                n_i = jnp.where(i < num_blocks, block, length - num_blocks * block)
                return sub_block(start + i * block, n_i, c)

            c = jax.lax.fori_loop(0, num_blocks + 1, one, c)
            reg_ref[:, g] = c.reg_sum - c.reg_err
            rb_ref[:, g] = c.rb_sum - c.rb_err
            mp_ref[:, g] = c.min_prob
            cnt_ref[:, g, :] = c.n.astype(jnp.int32)
            comp_ref[:, g, :] = c.comp_sum - c.comp_err
            return c

        r0 = rhat(jnp.zeros_like(means), jnp.zeros_like(means), means, pinned)
        w0 = weights(r0)
        zk = jnp.zeros_like(means)
        zb = jnp.zeros((big_b,), dtype)
        c0 = _State(w=w0, cdf=zk, big_w=zb, n=zk, s=zk, comp=zk, comp_sum=zk, comp_err=zk,
                    s_wr=zb, reg=zb, reg_rb=zb, reg_sum=zb, reg_err=zb, rb_sum=zb, rb_err=zb,
                    min_prob=jnp.ones((big_b,), dtype))
        jax.lax.fori_loop(0, num_g, segment, c0)

    return kernel


def _make_launch(kernel: Callable, num_arms: int, num_g: int, big_b: int, num_warps: int,
                 interpret: bool) -> Callable:
    """``launch(seg, env0, env1, ag0, ag1, means, inv_alpha, pinned_arm)``: the
    ``pallas_call`` of ``kernel`` over the seeds, ``big_b`` per program instance; returns
    (regret [S, G], Rao–Blackwellised regret [S, G], counts [S, G, K], compensator
    [S, G, K], min π [S, G])."""
    from jax.experimental import pallas as pl

    def launch(seg, env0, env1, ag0, ag1, means, inv_alpha, pinned_arm):
        num_seeds = env0.shape[0]
        row = lambda i: (i,)
        row2 = lambda i: (i, 0)
        row3 = lambda i: (i, 0, 0)
        kwargs = {}
        if not interpret:
            from jax.experimental.pallas import triton as pltriton

            kwargs["compiler_params"] = pltriton.CompilerParams(num_warps=num_warps,
                                                                num_stages=1)
        f32 = jnp.float32
        out_shape = (jax.ShapeDtypeStruct((num_seeds, num_g), f32),
                     jax.ShapeDtypeStruct((num_seeds, num_g), f32),
                     jax.ShapeDtypeStruct((num_seeds, num_g, num_arms), jnp.int32),
                     jax.ShapeDtypeStruct((num_seeds, num_g, num_arms), f32),
                     jax.ShapeDtypeStruct((num_seeds, num_g), f32))
        return pl.pallas_call(
            kernel, out_shape=out_shape, grid=(num_seeds // big_b,),
            in_specs=[pl.BlockSpec((num_g, 2), lambda i: (0, 0))]
            + [pl.BlockSpec((big_b,), row)] * 4
            + [pl.BlockSpec((big_b, num_arms), row2)]
            + [pl.BlockSpec((big_b,), row)] * 2,
            out_specs=(pl.BlockSpec((big_b, num_g), row2), pl.BlockSpec((big_b, num_g), row2),
                       pl.BlockSpec((big_b, num_g, num_arms), row3),
                       pl.BlockSpec((big_b, num_g, num_arms), row3),
                       pl.BlockSpec((big_b, num_g), row2)),
            interpret=interpret, name="sern_softmax_fused", **kwargs,
        )(seg, env0, env1, ag0, ag1, means, inv_alpha, pinned_arm)

    return launch


def make_pallas_run(
    config: sim.RunConfig,
    *,
    seeds_per_program: int = DEFAULT_SEEDS_PER_PROGRAM,
    num_warps: int = DEFAULT_NUM_WARPS,
    block: int = fast_softmax.DEFAULT_BLOCK,
    rebase: str = "tiled16",
    interpret: bool = False,
) -> Callable[[Array, sim.RunParams], sim.RunOutput]:
    """Builds ``fn(keys [S], params) -> RunOutput`` (each field with a leading S), to be jitted.

    Args:
      config: with ``supports(config)``; otherwise ``ValueError``.
      seeds_per_program: B, a power of two ≥ 1: seeds per program instance (S is padded to a
        multiple; the padding seeds are dropped).
      num_warps: Triton warps per program (GPU only).
      block: rounds between rebases (the engine's ``DEFAULT_BLOCK``: change it only to
        compare with an engine built with the same block), a power of two.
      rebase: the order of the prefix sums at each rebase: ``"tiled16"`` (XLA's order for the
        engine's cumsum, :func:`_tiled_prefix_sums`), ``"sequential"`` (left to right) or
        ``"scan"`` (``jnp.cumsum``: XLA's in the interpreter, Triton's scan on a GPU, whose
        order differs from XLA's); the last two are kept for measurements.
      interpret: run the kernel in Pallas' interpreter (CPU, tests).

    Returns:
      ``fn``: key is consumed per seed exactly as in ``simulate.make_run``; outputs on
      ``simulate.checkpoint_times(config)``; ``diag`` None. α below
      ``fast_softmax.min_alpha`` gives NaN outputs, as the engine.
    """
    _check(config, seeds_per_program, num_warps, block, rebase)
    dtype = jnp.float32
    big_b = int(seeds_per_program)
    segs = _segments(config, block)
    amin = fast_softmax.min_alpha(config.dtype)
    kernel = _make_kernel(config, big_b, block, rebase, segs.shape[0])
    launch = _make_launch(kernel, config.num_arms, segs.shape[0], big_b, num_warps, interpret)

    def per_seed_inputs(key: Key, params: sim.RunParams):
        # The engine's key derivation (fast_softmax.make_fast_run), once per seed, outside.
        key_env = jax.random.fold_in(key, sim.ENV_STREAM)
        key_agent = jax.random.fold_in(key, sim.AGENT_STREAM)
        key_problem = jax.random.fold_in(key_env, sim.PROBLEM_STREAM)
        kd_env = jax.random.key_data(jax.random.fold_in(key_env, sim.ROUNDS_STREAM))
        kd_agent = jax.random.key_data(jax.random.fold_in(key_agent, sim.ROUNDS_STREAM))
        problem = params.problem
        if config.random_means:
            problem = problem._replace(
                means=jax.random.uniform(key_problem, problem.means.shape, dtype))
        return kd_env, kd_agent, problem.means[0].astype(dtype)

    def fn(keys: Array, params: sim.RunParams) -> sim.RunOutput:
        num_seeds = keys.shape[0]
        padded = pad_seeds(num_seeds, big_b)
        if padded != num_seeds:  # padding seeds reuse seed 0's key; their outputs are dropped
            keys = jnp.concatenate([keys, jnp.broadcast_to(keys[:1], (padded - num_seeds,))])
        kd_env, kd_agent, means = jax.vmap(per_seed_inputs, (0, None))(keys, params)
        alpha = schedules.alpha_t(config.schedule, 0, config.horizon, params.alpha0,
                                  params.p)
        inv_alpha = jnp.broadcast_to((1.0 / alpha).astype(dtype), (padded,))
        pinned_arm = jnp.broadcast_to(params.oracle.pinned_arm.astype(jnp.int32), (padded,))
        reg, rb, counts, comp, min_prob = launch(
            jnp.asarray(segs), kd_env[:, 0], kd_env[:, 1], kd_agent[:, 0], kd_agent[:, 1],
            means, inv_alpha, pinned_arm)
        ok = alpha >= amin
        poison = lambda x: jnp.where(ok, x[:num_seeds], jnp.nan)
        reg, rb = poison(reg), poison(rb)
        return sim.RunOutput(regret=reg, regret_paper=reg, regret_rb=rb, regret_rb_paper=rb,
                             counts=counts[:num_seeds], compensator=poison(comp),
                             min_prob=poison(min_prob), diag=None)

    fn.info = {"seeds_per_program": big_b, "num_warps": int(num_warps), "block": block,
               "rebase": rebase, "interpret": interpret}  # how it was built (records)
    return fn
