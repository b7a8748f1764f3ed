"""Determinantal point processes on feature vectors: the SERN core set (paper Sec. IV-B).

SERN keeps a core set C of k = 172 pretraining examples chosen by a DPP on the quality
network's features (paper Sec. IV-B, Algorithm 1's first line, ref. [20] = Kulesza & Taskar
2012). Everything here uses the *linear* L-ensemble ``L = F F^T`` on features ``F [N, d]`` and
never forms the ``N x N`` kernel:

* :func:`sample_kdpp` draws an exact k-DPP sample (``P(S) ∝ det L_S``, ``|S| = k``) through
  the dual ``d x d`` kernel ``C = F^T F`` (Kulesza & Taskar 2012, Alg. 3 for the dual
  eigenvectors, Alg. 8 for the elementary-symmetric-polynomial choice of k eigenvectors, then
  the sequential phase of Alg. 1).
* :func:`greedy_map` is Chen, Zhang & Zhou 2018 ("Fast greedy MAP inference for DPP",
  Alg. 1): incremental Cholesky, ``O(N d k)``, with the Cholesky vectors of the low-rank
  kernel kept implicitly in feature space (no ``N x N`` and no ``N x k`` matrix).
* :func:`random_fourier_features` lifts features to ``num_features`` dims (an RBF kernel),
  since a linear kernel on ``d`` dims has rank ``<= d`` and cannot hold ``k > d`` items.
* :func:`select_core_set` = standardise, lift, select.

Precision: all public functions compute in float64 inside ``with jax.enable_x64():`` (the
global flag is never touched) and return float64 / int32 arrays. Inputs are validated on the
host (shape, ``k``, finiteness) before anything is compiled; the jitted cores take ``k`` as
a static argument, so repeated calls with the same shapes and ``k`` do not recompile.

Shape legend: ``N`` ground-set items, ``d`` feature dims, ``k`` selected items.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "GreedyMapResult",
    "greedy_map",
    "kdpp_eigen_select",
    "median_lengthscale",
    "random_fourier_features",
    "sample_kdpp",
    "sample_kdpp_batch",
    "select_core_set",
    "standardize",
]

# Relative eigenvalue (resp. pivot) threshold below which a direction counts as rank-deficient:
# max(N, d) * eps * largest eigenvalue, the usual numerical-rank rule (numpy.linalg.matrix_rank).
_EPS64 = float(np.finfo(np.float64).eps)


class GreedyMapResult(NamedTuple):
    """Output of :func:`greedy_map`."""

    indices: jax.Array  # [k] int32, in selection order
    log_det_gains: (
        jax.Array
    )  # [k] float64; gains[t] = log det L_{S_t+1} - log det L_{S_t}


# --------------------------------------------------------------------------------------
# Host-side validation (runs before any compile).
# --------------------------------------------------------------------------------------


def _check_features(features, k: int | None, name: str = "features") -> tuple[int, int]:
    shape = np.shape(features)
    if len(shape) != 2:
        raise ValueError(f"{name} must be a 2-D array [N, d]; got shape {shape}.")
    num, dim = shape
    if num < 1 or dim < 1:
        raise ValueError(f"{name} must be non-empty; got shape {shape}.")
    if k is not None:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
            raise ValueError(f"k must be an int; got {k!r}.")
        if k < 1:
            raise ValueError(f"k must be >= 1; got k={k}.")
        if k > num:
            raise ValueError(f"k={k} exceeds the ground-set size N={num}.")
        if k > dim:
            raise ValueError(
                f"k={k} exceeds the rank of the linear kernel L = F F^T, which is at most "
                f"d={dim} (the feature dimension): lift the features first, e.g. with "
                f"random_fourier_features(..., num_features>=k)."
            )
    if isinstance(features, jax.Array):
        finite = bool(jnp.isfinite(features).all())
    else:
        finite = bool(np.isfinite(np.asarray(features)).all())
    if not finite:
        raise ValueError(f"{name} contain NaN or inf.")
    return num, dim


def _numerical_rank(eigvals: np.ndarray, num: int, dim: int) -> int:
    eigvals = np.asarray(eigvals)
    tol = max(num, dim) * _EPS64 * max(float(eigvals.max()), 0.0)
    return int((eigvals > tol).sum())


def _rank_error(k: int, rank: int, dim: int) -> ValueError:
    return ValueError(
        f"k={k} exceeds the numerical rank {rank} of the linear kernel L = F F^T "
        f"(features have d={dim} dims): no {k} items have det L_S > 0. Lift the features "
        f"(random_fourier_features) or lower k."
    )


# --------------------------------------------------------------------------------------
# Jitted cores (float64; call inside jax.enable_x64()).
# --------------------------------------------------------------------------------------


@jax.jit
def _dual_eigh(features: jax.Array) -> tuple[jax.Array, jax.Array]:
    gram = features.T @ features  # [d, d] = C, the dual kernel
    return jnp.linalg.eigh(gram)


def _log_esp_table(eigvals: jax.Array, k: int) -> jax.Array:
    """log e_l^n, n = 0..d, l = 0..k (Kulesza & Taskar 2012, Alg. 7) in log space."""
    log_lam = jnp.log(eigvals)  # -inf for zeroed eigenvalues
    row0 = jnp.full((k + 1,), -jnp.inf).at[0].set(0.0)

    def step(prev, log_l):
        shifted = jnp.concatenate([jnp.full((1,), -jnp.inf), prev[:-1] + log_l])
        row = jnp.logaddexp(prev, shifted)
        return row, row

    _, rows = jax.lax.scan(step, row0, log_lam)
    return jnp.concatenate([row0[None], rows], axis=0)  # [d + 1, k + 1]


def kdpp_eigen_select(key: jax.Array, eigvals: jax.Array, k: int) -> jax.Array:
    """Chooses k eigenvectors of an L-ensemble for a k-DPP (Kulesza & Taskar 2012, Alg. 8).

    Index ``n`` is kept with the probability that makes ``P(J) ∝ prod_{n in J} lambda_n``
    over ``|J| = k``; elementary symmetric polynomials are carried in log space, so large
    spectra do not overflow. Jittable with ``k`` static. key is consumed.

    Args:
      key: PRNG key.
      eigvals: [d] non-negative eigenvalues (zeros are never chosen); at least k positive.
      k: number of eigenvectors to choose (static).

    Returns:
      [d] bool mask with exactly k True entries.
    """
    dim = eigvals.shape[0]
    log_e = _log_esp_table(eigvals, k)  # [d + 1, k + 1]
    log_lam = jnp.log(eigvals)
    uniforms = jax.random.uniform(key, (dim,), dtype=eigvals.dtype)

    def step(remaining, n):  # n runs d .. 1 (1-based, as in Alg. 8)
        lm1 = jnp.maximum(remaining - 1, 0)
        log_p = log_lam[n - 1] + log_e[n - 1, lm1] - log_e[n, remaining]
        prob = jnp.where(remaining > 0, jnp.exp(jnp.minimum(log_p, 0.0)), 0.0)
        prob = jnp.where(jnp.isnan(prob), 0.0, prob)
        take = uniforms[n - 1] < prob
        return remaining - take.astype(remaining.dtype), take

    _, take_rev = jax.lax.scan(step, jnp.asarray(k), jnp.arange(dim, 0, -1))
    return take_rev[::-1]


@functools.partial(jax.jit, static_argnames=("k",))
def _sample_kdpp_core(key, features, eigvals, eigvecs, rank_tol, k: int):
    key_eig, key_seq = jax.random.split(key)
    eigvals = jnp.where(eigvals > rank_tol, eigvals, 0.0)
    mask = kdpp_eigen_select(key_eig, eigvals, k)  # [d]
    (chosen,) = jnp.nonzero(mask, size=k)  # [k]
    # Dual eigenvectors (Alg. 3): u_n = F v_n / sqrt(lambda_n) are orthonormal in R^N.
    basis = eigvecs[:, chosen] / jnp.sqrt(eigvals[chosen])[None, :]  # [d, k]
    rows = features @ basis  # [N, k]; rows of the orthonormal N x k matrix U
    row_norm2 = jnp.sum(
        rows * rows, axis=1
    )  # [N] = diag of the projection kernel U U^T
    cdf = jnp.cumsum(row_norm2)
    total = cdf[-1]

    # Sequential phase of Alg. 1 for the projection DPP K = U U^T: item t is drawn with
    # P(i | S) ∝ K_ii - K_iS K_SS^-1 K_Si = ||U_i||^2 - ||Q^T U_i||^2 (Q = orthonormal basis
    # of the chosen rows). That residual never exceeds ||U_i||^2, so draw i ∝ ||U_i||^2 (one
    # fixed CDF, binary search) and accept with probability residual / ||U_i||^2: an exact
    # draw from the conditional, with acceptance rate (k - t) / k, i.e. about k * H_k
    # proposals in all instead of k passes over N.
    def draw(carry):
        q, t, selected, key_t, _ = carry
        key_t, key_i, key_a = jax.random.split(key_t, 3)
        u_i = jax.random.uniform(key_i, (), dtype=total.dtype) * total
        i = jnp.searchsorted(cdf, u_i, side="right").astype(jnp.int32)
        i = jnp.minimum(i, cdf.shape[0] - 1)
        y = rows[i]
        resid = y - q.T @ (q @ y)
        resid = resid - q.T @ (q @ resid)  # re-orthogonalise (Gram-Schmidt twice)
        res2 = jnp.sum(resid * resid)
        accept = jax.random.uniform(key_a, (), dtype=total.dtype) * row_norm2[i] < res2
        accept = (
            accept
            & (row_norm2[i] > 0)
            & ~jnp.any((selected == i) & (jnp.arange(k) < t))
        )
        q_new = q.at[t].set(resid / jnp.sqrt(jnp.where(accept, res2, 1.0)))
        q = jnp.where(accept, q_new, q)
        selected = jnp.where(accept, selected.at[t].set(i), selected)
        return q, t + accept.astype(t.dtype), selected, key_t, i

    init = (
        jnp.zeros((k, k), features.dtype),  # q: rows are orthonormal vectors in R^k
        jnp.asarray(0),
        jnp.zeros((k,), jnp.int32),
        key_seq,
        jnp.asarray(0, jnp.int32),
    )
    _, _, selected, _, _ = jax.lax.while_loop(lambda c: c[1] < k, draw, init)
    return selected


@functools.partial(jax.jit, static_argnames=("k",))
def _greedy_map_core(features: jax.Array, k: int):
    # Chen et al. 2018, Alg. 1, with the Cholesky vectors kept implicit: for L = F F^T,
    # c_i = Q^T F_i where Q [d, t] is the Gram-Schmidt basis of the chosen features, so
    # eq. (9) e_i = (L_ji - <c_j, c_i>) / d_j becomes e = F q_t with
    # q_t = (I - Q Q^T) F_j / d_j. Same recurrence and pivots; one pass over F per step
    # and no [N, k] matrix (an explicit one costs a second pass and 275 MB at N=200k).
    num, dim = features.shape
    d2 = jnp.sum(features * features, axis=1)  # [N] = diag L, then the running d_i^2
    basis = jnp.zeros((dim, k), features.dtype)  # columns q_0..q_{t-1}, zeros after
    taken = jnp.zeros((num,), bool)

    def step(carry, t):
        basis, d2, taken = carry
        j = jnp.argmax(jnp.where(taken, -jnp.inf, d2))
        dj2 = d2[j]
        resid = features[j] - basis @ (basis.T @ features[j])
        resid = resid - basis @ (basis.T @ resid)  # re-orthogonalise (twice is enough)
        q = resid / jnp.sqrt(jnp.sum(resid * resid))
        # [N, 1] matmul, not a matvec: XLA:CPU runs the matvec F @ v markedly slower.
        e = (features @ q[:, None])[:, 0]  # [N] = e_i of eq. (9)
        d2 = d2 - e * e  # eq. (10)
        basis = basis.at[:, t].set(q)
        taken = taken.at[j].set(True)
        return (basis, d2, taken), (j.astype(jnp.int32), dj2)

    _, (idx, pivots) = jax.lax.scan(step, (basis, d2, taken), jnp.arange(k))
    return idx, pivots


# --------------------------------------------------------------------------------------
# Public API.
# --------------------------------------------------------------------------------------


def sample_kdpp(key: jax.Array, features, k: int) -> jax.Array:
    """Draws an exact k-DPP sample for the linear L-ensemble ``L = F F^T``.

    ``P(S) = det L_S / e_k(L)`` over subsets with ``|S| = k`` (Kulesza & Taskar 2012, Sec. 5),
    computed through the dual kernel ``C = F^T F`` [d, d] (Alg. 3), the elementary symmetric
    polynomial eigenvector choice (Alg. 8) and the sequential item phase of Alg. 1 (done by
    exact rejection from the marginal diagonal; see ``_sample_kdpp_core``). Cost
    ``O(N d^2 + N d k + k^3 log k)``; never forms ``N x N``. Computes in float64 under a
    local ``jax.enable_x64()``. key is consumed.

    Args:
      key: PRNG key (``jax.random.key``).
      features: [N, d] finite real features (numpy or JAX; cast to float64).
      k: sample size, ``1 <= k <= min(N, rank F)``.

    Returns:
      [k] int32 distinct item indices, in draw order.

    Raises:
      ValueError: bad shape, ``k`` out of range, non-finite features, or ``k`` above the
        (numerical) rank of ``F``.

    Reference: paper Sec. IV-B ("DPP(D0, k)", ref. [20]).
    """
    with jax.enable_x64():
        feats, eigvals, eigvecs, rank_tol = _prepare_dual(features, k)
        return _sample_kdpp_core(key, feats, eigvals, eigvecs, rank_tol, k)


@functools.partial(jax.jit, static_argnames=("k",))
def _sample_kdpp_batch_core(keys, features, eigvals, eigvecs, rank_tol, k: int):
    return jax.vmap(_sample_kdpp_core, (0, None, None, None, None, None))(
        keys, features, eigvals, eigvecs, rank_tol, k
    )


def _prepare_dual(features, k: int):
    """Validates, casts to float64 and eigendecomposes C = F^T F; checks the rank."""
    num, dim = _check_features(features, k)
    feats = jnp.asarray(features, jnp.float64)
    eigvals, eigvecs = _dual_eigh(feats)
    eigvals_host = np.asarray(eigvals)
    rank = _numerical_rank(eigvals_host, num, dim)
    if rank < k:
        raise _rank_error(k, rank, dim)
    rank_tol = max(num, dim) * _EPS64 * float(eigvals_host.max())
    return feats, eigvals, eigvecs, rank_tol


def sample_kdpp_batch(keys: jax.Array, features, k: int) -> jax.Array:
    """Draws S independent k-DPP samples on one ground set (one eigendecomposition).

    Row s equals ``sample_kdpp(keys[s], features, k)`` (same key, same draw). keys are
    consumed.

    Args:
      keys: [S] PRNG keys, e.g. ``vmap(lambda i: fold_in(root, i))(arange(S))``.
      features: [N, d] finite real features.
      k: sample size, as in :func:`sample_kdpp`.

    Returns:
      [S, k] int32 indices; each row distinct, in draw order.
    """
    if np.ndim(keys) != 1:
        raise ValueError(
            f"keys must be a 1-D array of keys; got shape {np.shape(keys)}."
        )
    with jax.enable_x64():
        feats, eigvals, eigvecs, rank_tol = _prepare_dual(features, k)
        return _sample_kdpp_batch_core(keys, feats, eigvals, eigvecs, rank_tol, k)


def greedy_map(features, k: int) -> GreedyMapResult:
    """Greedy MAP for the linear DPP ``L = F F^T`` by incremental Cholesky.

    Chen, Zhang & Zhou 2018, Alg. 1: at step t pick ``j = argmax_i d_i^2`` (``d_i^2`` =
    ``det L_{S+i} / det L_S``), then update every item's Cholesky row
    ``e_i = (L_ji - <c_j, c_i>) / d_j`` and ``d_i^2 -= e_i^2``. For ``L = F F^T`` the
    Cholesky vectors are ``c_i = Q^T F_i`` (``Q`` the Gram-Schmidt basis of the chosen
    features), so ``e = F q_t`` is one pass over ``F``: memory ``O(N d)``, time
    ``O(N d k)``, no ``N x N`` or ``N x k`` matrix. Ties go to the lowest index. Computes
    in float64 under a local ``jax.enable_x64()``; outputs stay float64 arrays (reduce
    them under x64 or in numpy to keep the precision).

    Args:
      features: [N, d] finite real features.
      k: number of items, ``1 <= k <= min(N, rank F)``.

    Returns:
      ``GreedyMapResult(indices [k] int32, log_det_gains [k] float64)``; the gains are
      ``log d_j^2`` at each pick and sum to ``log det L_S``.

    Raises:
      ValueError: bad shape, ``k`` out of range, non-finite features, or ``k`` above the
        (numerical) rank of ``F``.
    """
    num, dim = _check_features(features, k)
    with jax.enable_x64():
        feats = jnp.asarray(features, jnp.float64)
        idx, pivots = _greedy_map_core(feats, k)
        pivots_host = np.asarray(pivots)
        # pivots[0] = max_i L_ii; a later pivot at roundoff level means rank F < k.
        tol = max(num, dim) * _EPS64 * max(float(pivots_host[0]), 0.0)
        if not np.all(pivots_host > tol):
            eigvals, _ = _dual_eigh(feats)
            raise _rank_error(k, _numerical_rank(np.asarray(eigvals), num, dim), dim)
        return GreedyMapResult(idx, jnp.log(pivots))


def standardize(x) -> jax.Array:
    """Per-column zero mean, unit variance (constant columns are only centred).

    Args:
      x: [N, d] features.

    Returns:
      [N, d] float64 array.
    """
    _check_features(x, None, "x")
    with jax.enable_x64():
        return _standardize(jnp.asarray(x, jnp.float64))


@jax.jit
def _standardize(x):
    mean = jnp.mean(x, axis=0, keepdims=True)
    std = jnp.std(x, axis=0, keepdims=True)
    return (x - mean) / jnp.where(std > 0, std, 1.0)


@functools.partial(jax.jit, static_argnames=("num_sub",))
def _median_lengthscale(key, x, num_sub: int):
    sub = x[jax.random.choice(key, x.shape[0], (num_sub,), replace=False)]
    sq = jnp.sum(sub * sub, axis=1)
    dist2 = jnp.maximum(sq[:, None] + sq[None, :] - 2.0 * sub @ sub.T, 0.0)
    iu = jnp.triu_indices(num_sub, 1)
    return jnp.sqrt(jnp.median(dist2[iu]))


def median_lengthscale(key: jax.Array, x, num_subsample: int = 1000) -> float:
    """Median pairwise Euclidean distance on a random subsample (the median heuristic).

    Args:
      key: PRNG key; consumed.
      x: [N, d] features.
      num_subsample: at most this many rows are used (``min(N, num_subsample)``).

    Returns:
      The median distance as a Python float (> 0).

    Raises:
      ValueError: bad input, or all subsampled points coincide.
    """
    num, _ = _check_features(x, None, "x")
    with jax.enable_x64():
        ell = float(
            _median_lengthscale(
                key, jnp.asarray(x, jnp.float64), min(num, num_subsample)
            )
        )
    if not ell > 0.0:
        raise ValueError(
            "median pairwise distance is 0: points coincide; pass a lengthscale."
        )
    return ell


@functools.partial(jax.jit, static_argnames=("num_features",))
def _rff(key, x, lengthscale, num_features: int):
    omega = jax.random.normal(key, (x.shape[1], num_features // 2), x.dtype)
    proj = (x / lengthscale) @ omega
    scale = 1.0 / math.sqrt(num_features // 2)
    return scale * jnp.concatenate([jnp.cos(proj), jnp.sin(proj)], axis=1)


def random_fourier_features(
    key: jax.Array, x, num_features: int, lengthscale: float | None = None
) -> jax.Array:
    """Random Fourier features of the RBF kernel ``exp(-||x - y||^2 / (2 lengthscale^2))``.

    Rahimi & Recht 2007 with paired cos/sin features: ``phi(x) = [cos(W^T x / l),
    sin(W^T x / l)] / sqrt(M / 2)``, ``W ~ N(0, I)`` [d, M/2], so ``phi(x)^T phi(y)`` is an
    unbiased estimate of the RBF kernel and ``||phi(x)||^2 = 1`` exactly (every item has the
    same DPP quality; only diversity matters). A linear DPP on ``phi`` has rank up to M.
    key is consumed.

    Args:
      key: PRNG key.
      x: [N, d] finite features (standardise them first if their scales differ).
      num_features: M, even, ``>= 2``; the lifted dimension (take ``M >= k``).
      lengthscale: RBF lengthscale; default: :func:`median_lengthscale` on up to 1000 rows.

    Returns:
      [N, M] float64 features.
    """
    _check_features(x, None, "x")
    if isinstance(num_features, bool) or not isinstance(
        num_features, (int, np.integer)
    ):
        raise ValueError(f"num_features must be an int; got {num_features!r}.")  # noqa: TRY004 (one error type for bad input)
    if num_features < 2 or num_features % 2:
        raise ValueError(f"num_features must be even and >= 2; got {num_features}.")
    key_ell, key_w = jax.random.split(key)
    del key
    if lengthscale is None:
        lengthscale = median_lengthscale(key_ell, x)
    if not (np.isfinite(lengthscale) and lengthscale > 0):
        raise ValueError(f"lengthscale must be finite and > 0; got {lengthscale}.")
    with jax.enable_x64():
        return _rff(
            key_w, jnp.asarray(x, jnp.float64), float(lengthscale), int(num_features)
        )


def select_core_set(
    key: jax.Array,
    features,
    k: int,
    method: str = "greedy",
    num_rff: int | None = 512,
    lengthscale: float | None = None,
) -> jax.Array:
    """Chooses a diverse core set of k items (paper Sec. IV-B: ``C = DPP(D0, k)``).

    Standardises the features per column, lifts them with :func:`random_fourier_features`
    (``num_rff`` dims; ``None`` keeps the standardised features, then ``k <= d`` is needed)
    and selects with :func:`greedy_map` (deterministic given the lift) or
    :func:`sample_kdpp`. key is consumed.

    Args:
      key: PRNG key.
      features: [N, d] features, e.g. the quality network's penultimate layer on D0.
      k: core-set size (the paper uses 172).
      method: ``"greedy"`` (MAP) or ``"sample"`` (exact k-DPP draw).
      num_rff: lifted dimension (even, ``>= k``) or ``None`` for no lift.
      lengthscale: RBF lengthscale on standardised features; default median heuristic.

    Returns:
      [k] int32 distinct indices into ``features``.
    """
    if method not in ("greedy", "sample"):
        raise ValueError(f"method must be 'greedy' or 'sample'; got {method!r}.")
    num, dim = _check_features(features, None)
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= num:
        raise ValueError(f"k must be an int in [1, N={num}]; got {k!r}.")
    lifted_dim = dim if num_rff is None else num_rff
    if k > lifted_dim:
        raise ValueError(
            f"k={k} exceeds the rank of the linear kernel, at most {lifted_dim} "
            f"({'feature dims' if num_rff is None else 'num_rff'}): raise num_rff."
        )
    key_rff, key_dpp = jax.random.split(key)
    del key
    feats = standardize(features)
    if num_rff is not None:
        feats = random_fourier_features(key_rff, feats, num_rff, lengthscale)
    if method == "greedy":
        return greedy_map(feats, k).indices
    return sample_kdpp(key_dpp, feats, k)
