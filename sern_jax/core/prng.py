"""Counter-based random variates that vectorise: unrolled threefry and an exact Beta sampler.

:func:`threefry2x32` is JAX's threefry-2x32 hash written out (bit-identical to
``jax.random``'s; on CPU JAX lowers it to a rolled loop that does not fuse).

:func:`sample_beta` draws Beta(a, b) for a, b ≥ 1 (Thompson sampling's Beta(1 + S, 1 + F)
posteriors) *exactly*, in a form that suits ``vmap`` and SIMD lanes. ``jax.random.beta`` draws
two Gammas by rejection in a ``while_loop`` per element, so under ``vmap`` every lane waits for
the slowest one and each try re-derives keys. Here:

* min(a, b) ∈ {1, 2} has an exact form with no rejection, by order statistics (Rényi's
  representation; for m = 1 it is the inversion Beta(1, b) = 1 − U^{1/b},
  Beta(a, 1) = U^{1/a}); m = 2 too, one of the commonest
  Thompson posteriors (one success or one failure), where BB accepted only ~0.80;
* otherwise Cheng's (1978) algorithm BB, the rejection sampler R's ``rbeta`` uses: one pair
  of uniforms per try, accepted with probability 0.80–0.96; a lane is one case or the
  other, so all share two logs and one exp (arguments selected per lane), and BB's
  squeezes, which only accept early what its exact test accepts, are left out (every lane
  of a vector computes the exact test anyway): per try one hash, three logs and one exp;
* the uniforms of try ``i`` of lane ``j`` are ``threefry(key, (i, j))``: every (lane, try)
  has its own independent bits, so a lane's sequence of tries does not depend on the others,
  and the result is the first accepted try, as in the scalar algorithm: exact in distribution
  (up to float rounding, like any sampler);
* every lane runs try 0; only the rejected lanes keep the next tries (:func:`sample_beta`
  loops while any lane is rejected; :mod:`sern_jax.engine.fast_thompson` lets a seed whose lanes
  are not all accepted retry in its next loop step while the others play on).

Both forms give the same draws for the same key: lane ``j`` of a seed always takes its own
tries ``0, 1, 2, …`` in order.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.core.types import Array, Key

__all__ = ["threefry2x32", "open_unit", "hold", "hold_bits", "beta_try", "beta_try_packed",
           "REJECTED", "sample_beta"]

_ROT = ((13, 15, 26, 6), (17, 29, 16, 24))
_LOG4 = 1.3862944  # log 4 (Cheng's BB constants)


def _rotl(x: Array, d: int) -> Array:
    return (x << np.uint32(d)) | (x >> np.uint32(32 - d))


def threefry2x32(k1: Array, k2: Array, x1: Array, x2: Array) -> tuple[Array, Array]:
    """Threefry-2x32 (20 rounds), unrolled; bit-identical to JAX's ``threefry2x32_p``.

    Args:
      k1, k2: uint32 key words (broadcastable).
      x1, x2: uint32 counter words (broadcastable).

    Returns:
      The two uint32 output words.
    """
    ks = (k1, k2, k1 ^ k2 ^ np.uint32(0x1BD11BDA))
    x = [x1 + ks[0], x2 + ks[1]]
    for i in range(5):
        for r in _ROT[i % 2]:
            x[0] = x[0] + x[1]
            x[1] = _rotl(x[1], r)
            x[1] = x[0] ^ x[1]
        x[0] = x[0] + ks[(i + 1) % 3]
        x[1] = x[1] + ks[(i + 2) % 3] + np.uint32(i + 1)
    return x[0], x[1]


def open_unit(bits: Array, dtype) -> Array:
    """A uniform in the open interval (0, 1) from 32 random bits: ``(m + ½)·2^-k`` with the
    top k bits m (k = 23 in float32, 32 in float64): never 0 or 1, so logs stay finite."""
    if dtype == jnp.float64:
        return (bits.astype(jnp.float64) + 0.5) * (2.0**-32)
    m = (bits >> np.uint32(9)).astype(jnp.float32)
    return (m + 0.5) * jnp.float32(2.0**-23)


def hold(u: Array) -> Array:
    """``u`` itself (u > 0), computed once.

    ``sqrt(4u·u)/2`` equals ``u`` exactly for every positive float whose square neither
    overflows nor underflows (4 and 1/2 only move the exponent; checked for all 2^23 float32
    values of :func:`open_unit`). XLA counts ``sqrt`` as expensive, so it computes the hash
    behind ``u`` once and stores it, instead of copying the integer-only threefry into every
    fusion that reads ``u``, as XLA:CPU otherwise does (several hashes per lane and try in
    :mod:`sern_jax.engine.fast_thompson`). Plain ``sqrt(u·u)`` is simplified to ``|u|`` by XLA.

    Applied on the CPU backend only, whose ``sqrt`` is correctly rounded and where the
    identity is tested exact: a GPU's ``sqrt`` need not be correctly rounded, and there
    ``sqrt(4u·u)/2`` differs from ``u`` for some uniforms and the fast Thompson runner's arms
    would no longer match the general runner's; elsewhere ``u`` is returned as it is.
    """
    if jax.default_backend() != "cpu":
        return u
    return jnp.sqrt((4.0 * u) * u) * 0.5


def hold_bits(x: Array) -> Array:
    """uint32 ``x`` itself, computed once (:func:`hold` on its two 16-bit halves, exact: the
    halves are integers below 2^16, checked for all of them). For key words computed per seed
    and read by every lane: XLA would otherwise recompute the hash in each lane."""
    if jax.default_backend() != "cpu":
        return x
    one = jnp.float32(1.0)
    hi = hold((x >> np.uint32(16)).astype(jnp.float32) + one) - one
    lo = hold((x & np.uint32(0xFFFF)).astype(jnp.float32) + one) - one
    return (hi.astype(jnp.uint32) << np.uint32(16)) | lo.astype(jnp.uint32)


def _expm1(y: Array, e: Array) -> Array:
    """``expm1(y)`` to float32 accuracy from ``e = exp(y)`` (one exp shared with other uses):
    a degree-5 Taylor polynomial for |y| < 1/16 (truncation < 2e-9 relative), ``e − 1``
    beyond, where the subtraction costs at most ~1.5e-6 relative. float64: ``jnp.expm1``."""
    if y.dtype == jnp.float64:
        return jnp.expm1(y)
    p = y * (1.0 + y * (0.5 + y * (1.0 / 6.0 + y * (1.0 / 24.0 + y * (1.0 / 120.0)))))
    return jnp.where(jnp.abs(y) < 0.0625, p, e - 1.0)


def beta_try(k1: Array, k2: Array, a: Array, b: Array, try_index: Array,
             lane: Array) -> tuple[Array, Array]:
    """One try of the exact Beta(a, b) sampler on each lane (elementwise, broadcasting).

    min(a, b) = m ∈ {1, 2}: order statistics, never rejected. With n = a + b − 1, the m-th
    smallest of n uniforms is Beta(m, n − m + 1), and by Rényi's representation
    ``1 − X_(1) = U1^{1/n}``, ``1 − X_(2) = U1^{1/n} U2^{1/(n − 1)}`` (for real n too:
    Beta(n, 1)·Beta(n − 1, 1) is Beta(n − 1, 2)); so Beta(m, ·) = −expm1(y) and
    Beta(·, m) = e^y with y = log U1 / n (+ log U2 / (n − 1) for m = 2). Otherwise Cheng's
    BB. A lane is one case or the other, so they share the same two uniforms, two logs
    (log u1 or log(u1 / (1 − u1)); log u2 or log(u1² u2)) and one exp, arguments selected
    per lane, and BB's squeezes are left out: they only accept early what its exact test
    accepts, and a vector computes every lane's exact test anyway. Per try: one threefry
    hash, three logs (the third for BB's test), one exp.

    Args:
      k1, k2: uint32 key words.
      a, b: float shape parameters, a, b ≥ 1 (NaN is returned for a or b < 1).
      try_index: uint32 try number of each lane (0 for the first try).
      lane: uint32 lane number (the arm).

    Returns:
      ``(theta, accepted)``: the candidate draw and whether this try accepts it (always for
      min(a, b) ∈ {1, 2}).
    """
    dtype = a.dtype
    w1, w2 = threefry2x32(k1, k2, try_index, lane)
    u1, u2 = open_unit(w1, dtype), open_unit(w2, dtype)
    lo, hi = jnp.minimum(a, b), jnp.maximum(a, b)
    two = lo == 2.0
    bb = (lo > 1.0) & ~two  # Cheng's BB (its constants harmless on the other lanes)
    lo_s = jnp.where(bb, lo, 3.0)
    hi_s = jnp.where(bb, hi, 3.0)
    alpha = lo_s + hi_s
    beta = jnp.sqrt((alpha - 2.0) / (2.0 * lo_s * hi_s - alpha))
    gamma = lo_s + 1.0 / beta
    n = a + b - 1.0
    # order statistics: y = log u1 / n (+ log u2 / (n − 1));
    # BB: v = β log(u1 / (1 − u1)), w = lo·e^v, and its test reads log(u1² u2)
    x = jnp.log(jnp.where(bb, u1 / (1.0 - u1), u1))
    t = jnp.log(jnp.where(bb, u1 * u1 * u2, u2))
    y = jnp.where(bb, beta * x, x / n + jnp.where(two, t / (n - 1.0), 0.0))
    e = jnp.exp(y)
    theta_os = jnp.where(a == lo, -_expm1(y, e), e)
    w = lo_s * e
    # BB's exact test: γv − log 4 + α log(α / (hi + w)) ≥ log(u1² u2)
    accept = gamma * y - _LOG4 + alpha * jnp.log(alpha / (hi_s + w)) >= t
    theta_bb = jnp.where(a == lo_s, w, hi_s) / (hi_s + w)
    theta = jnp.where(bb, theta_bb, theta_os)
    theta = jnp.where(lo < 1.0, jnp.nan, theta)
    return theta.astype(dtype), accept | ~bb


REJECTED = 2.0  # what beta_try_packed returns for a rejected try (draws lie in [0, 1])


def beta_try_packed(k1: Array, k2: Array, a: Array, b: Array, try_index: Array,
                    lane: Array) -> Array:
    """:func:`beta_try` as one value per lane: the draw if accepted, else ``REJECTED``
    (test ``x > 1``: NaN, for a or b < 1, counts as accepted), computed once (:func:`hold`).

    One output, held: XLA:CPU then compiles the whole try (hash, logs, exp, test) into one
    loop. With two outputs, or one that several consumers read, it does not duplicate the
    logs and exps into each consumer but materialises each of them, and every shared value
    besides, as an array of its own (many passes over [C, K] per try instead of one)."""
    theta, accept = beta_try(k1, k2, a, b, try_index, lane)
    return hold(jnp.where(accept, theta, REJECTED))


def sample_beta(key: Key, a: Array, b: Array) -> Array:
    """Exact Beta(a, b) draws for a, b ≥ 1 (see the module docstring), unbatched.

    Args:
      key: PRNG key (threefry), consumed.
      a, b: [K] float shape parameters ≥ 1.

    Returns:
      [K] independent Beta(a_j, b_j) draws (NaN where a or b < 1).
    """
    kd = jax.random.key_data(key)
    k1, k2 = kd[0], kd[1]
    lane = jnp.arange(a.size, dtype=jnp.uint32).reshape(a.shape)
    theta = beta_try_packed(k1, k2, a, b, jnp.zeros_like(lane), lane)

    def body(carry):
        theta, i = carry
        cand = beta_try_packed(k1, k2, a, b, jnp.broadcast_to(i, lane.shape), lane)
        return jnp.where(theta > 1.0, cand, theta), i + np.uint32(1)

    theta, _ = jax.lax.while_loop(lambda c: jnp.any(c[0] > 1.0), body, (theta, jnp.uint32(1)))
    return theta
