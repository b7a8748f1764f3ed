"""The online run's random streams: one key per (object, seed), one stream per use.

Common random numbers: within a seed, every learner sees the same poses, the same candidate
sets, the same inverse-CDF uniform and the same trial randomisation (friction, mass,
execution error), so comparisons are paired. Object ``o`` (by name, CRC32) and seed ``s``
use ``key_os = fold_in(fold_in(key(seed), crc32(name)), s)``: independent of which other
objects and seeds run beside it. Each stream below is ``fold_in(key_os, STREAM)``, then
``fold_in(., round)`` (then ``fold_in(., grasp)`` for ``ACT``).

Streams (ids are part of the results: never renumber one):

* ``EXPLORE_CONTEXT``, ``EVAL_CONTEXT``, ``LOWVAR_CONTEXT``: the contexts (pose, depth,
  candidates) of the exploration, the evaluation and the fixed low-variance poses (round 0);
* ``EXPLORE_TRIAL``, ``EVAL_TRIAL``, ``LOWVAR_TRIAL``: their trials' randomisation;
* ``POLICY_UNIFORM``, ``EVAL_UNIFORM``: the inverse-CDF uniforms of acting and of greedy;
* ``FIT``: the learners' update keys; ``INIT``: their init keys (round 0); ``ACT``: their
  act keys (unused by SERN, ε-greedy and greedy);
* ``ORACLE_TRIAL``, ``ORACLE_VALUE``: the regret oracle's selection trials (its argmax)
  and its valuation trials, independent of the selection.

The batched run (:mod:`sern_jax.grasp.online.driver`) and the ask/tell robot loop
(:mod:`sern_jax.grasp.online.asktell`) use the same keys.
"""

from __future__ import annotations

import zlib

import jax
import jax.numpy as jnp

__all__ = [
    "ACT",
    "EVAL_CONTEXT",
    "EVAL_TRIAL",
    "EVAL_UNIFORM",
    "EXPLORE_CONTEXT",
    "EXPLORE_TRIAL",
    "FIT",
    "INIT",
    "LOWVAR_CONTEXT",
    "LOWVAR_TRIAL",
    "ORACLE_TRIAL",
    "ORACLE_VALUE",
    "POLICY_UNIFORM",
    "object_key",
    "object_keys",
    "stream",
    "stream_keys",
]

EXPLORE_CONTEXT, EXPLORE_TRIAL, POLICY_UNIFORM, FIT = 0, 1, 2, 3
EVAL_CONTEXT, EVAL_TRIAL, EVAL_UNIFORM, LOWVAR_CONTEXT, LOWVAR_TRIAL = 4, 5, 6, 7, 8
ORACLE_TRIAL = 9  # the oracle's selection trials (its argmax)
INIT, ACT = 10, 11  # the learner's init key and act keys (unused by SERN, ε-greedy, greedy)
ORACLE_VALUE = 12  # the oracle's valuation trials, independent of the selection


def object_key(root: jax.Array, name: str, seed_index: int) -> jax.Array:
    """The key of (object, seed): independent of which other objects run beside it."""
    return jax.random.fold_in(
        jax.random.fold_in(root, zlib.crc32(name.encode()) & 0x7FFFFFFF), seed_index)


def object_keys(root: jax.Array, names, seeds) -> jax.Array:
    """[O, S] keys: ``object_key(root, names[o], seeds[s])``."""
    return jnp.stack([jnp.stack([object_key(root, n, s) for s in seeds]) for n in names])


def stream(key_os: jax.Array, stream_id: int, round_index: int) -> jax.Array:
    """Stream ``stream_id`` of round ``round_index`` of one (object, seed) key."""
    return jax.random.fold_in(jax.random.fold_in(key_os, stream_id), round_index)


def stream_keys(keys_os, stream_id: int, round_index: int) -> jax.Array:
    """[O, S] keys of one stream and round: :func:`stream` of every (object, seed) key, in
    one jitted call (threefry: the same keys as one eager :func:`stream` per copy, tested;
    eager, the 2 x O x S fold-ins would cost a dispatch each). ``keys_os``: [O, S] keys, or
    lists of keys."""
    if not isinstance(keys_os, jax.Array):
        keys_os = jnp.stack([jnp.stack(list(row)) for row in keys_os])
    return _fold_streams(keys_os, jnp.uint32(stream_id), jnp.uint32(round_index))


@jax.jit
def _fold_streams(keys, stream_id, round_index):
    return jax.vmap(jax.vmap(lambda k: stream(k, stream_id, round_index)))(keys)
