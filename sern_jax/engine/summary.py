"""On-device statistics over seeds: what ``run_seeds(..., summary=True)`` returns.

Each jitted call of the seed driver (:mod:`sern_jax.engine.drive`) reduces its seeds on the
device (:func:`summarize_outputs`): per output field the mean and the sum of squared
deviations (both compensated: pairwise TwoSum, see :func:`compensated_sum`), the exact min and
max and a fixed histogram. The host merges calls with Chan et al.'s parallel formula in
float64 (:func:`merge_stats`), in seed order. Means, variances, min and max of the merged
summary equal those of the per-seed arrays up to float rounding, whatever the chunking.
Quantiles are the one approximation: exact quantiles across chunks need the values, so they
come from the merged histograms, on fixed bins uniform in log(1 + x) over [0, t_g] (rewards
and gaps lie in [0, 1], so regret and counts at checkpoint t_g do too);
:meth:`SeedStats.quantile` returns the estimate with a bracket ``[lo, hi]`` that is guaranteed
to hold the exact empirical quantile (NumPy's ``method="inverted_cdf"``).
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.engine import simulate as sim
from sern_jax.engine.simulate import RunConfig, RunOutput

__all__ = [
    "SUMMARY_FIELDS",
    "SUMMARY_BINS",
    "SUMMARY_QUANTILES",
    "SeedStats",
    "Quantile",
    "RunSummary",
    "compensated_sum",
    "summary_edges",
    "summarize_outputs",
    "host_stats",
    "merge_stats",
    "merge_summaries",
    "summary_arrays",
    "summary_from_arrays",
]

SUMMARY_FIELDS = ("regret", "regret_paper", "regret_rb", "regret_rb_paper", "counts",
                  "compensator", "min_prob")
# Histogram bins per field; 0 keeps no histogram (no quantiles; exact min and max are kept).
# 512 bins in log(1 + x) over [0, 10^4] are 1.8% wide (relative) above x ~ 1; 64 for counts
# (one histogram per arm) are 15% wide. On a [G = 32, K = 64] run one call returns ~0.8 MB.
SUMMARY_BINS = {"regret": 512, "regret_paper": 512, "regret_rb": 512, "regret_rb_paper": 512,
                "counts": 64, "compensator": 0, "min_prob": 0}
SUMMARY_QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)


class Quantile(NamedTuple):
    """A quantile over seeds from a histogram (:meth:`SeedStats.quantile`)."""

    estimate: np.ndarray  # [...] linear interpolation inside the bin holding the quantile
    lo: np.ndarray  # [...] lower end of that bin (tightened by the exact min): exact >= lo
    hi: np.ndarray  # [...] upper end (tightened by the exact max): exact <= hi


class SeedStats(NamedTuple):
    """Statistics over seeds of one per-seed output (host, numpy), mergeable across chunks.

    ``[...]`` is the output's per-seed shape: ``[G]`` (regret, min_prob) or ``[G, K]``.
    """

    count: int  # seeds n
    mean: np.ndarray  # [...] float64
    m2: np.ndarray  # [...] Σ_i (x_i − mean)², float64
    min: np.ndarray  # [...] exact minimum over seeds
    max: np.ndarray  # [...] exact maximum over seeds
    hist: Optional[np.ndarray]  # [..., B] int64 seeds per bin, or None (no quantiles)
    edges: Optional[np.ndarray]  # [G, B + 1] float64 bin edges (shared by trailing axes)

    @property
    def var(self) -> np.ndarray:
        """Sample variance over seeds (ddof = 1; NaN for one seed)."""
        if self.count < 2:
            return np.full_like(self.mean, np.nan)
        return self.m2 / (self.count - 1)

    @property
    def sd(self) -> np.ndarray:
        """Sample standard deviation over seeds (ddof = 1)."""
        return np.sqrt(self.var)

    def quantile(self, q: float) -> Quantile:
        """The q-quantile over seeds, from the histogram.

        The exact empirical quantile (the ⌈q·n⌉-th smallest value, NumPy's
        ``method="inverted_cdf"``) lies in ``[lo, hi]``, the bin that holds it narrowed by the
        exact min and max; ``estimate`` interpolates linearly inside it.
        """
        if self.hist is None:
            raise ValueError("this field keeps no histogram (SUMMARY_BINS is 0): no quantiles")
        if not 0.0 <= float(q) <= 1.0:
            raise ValueError(f"q must lie in [0, 1], got {q!r}")
        hist = self.hist
        num_bins = hist.shape[-1]
        rank = max(1, int(math.ceil(self.count * float(q))))
        cum = np.cumsum(hist, axis=-1)
        b = np.argmax(cum >= rank, axis=-1)  # [...] first bin reaching the rank
        edges = self.edges.reshape(self.edges.shape[:1] + (1,) * (hist.ndim - 2)
                                   + self.edges.shape[1:])
        edges = np.broadcast_to(edges, hist.shape[:-1] + (num_bins + 1,))
        lo = np.take_along_axis(edges, b[..., None], -1)[..., 0]
        hi = np.take_along_axis(edges, b[..., None] + 1, -1)[..., 0]
        lo = np.where(b == 0, -np.inf, lo)  # bin 0 also holds values below 0
        hi = np.where(b == num_bins - 1, np.inf, hi)  # the last bin those above t_g
        lo = np.maximum(lo, self.min)
        hi = np.minimum(hi, self.max)
        below = np.where(b > 0, np.take_along_axis(cum, np.maximum(b - 1, 0)[..., None],
                                                   -1)[..., 0], 0)
        in_bin = np.take_along_axis(hist, b[..., None], -1)[..., 0]
        frac = (rank - below - 0.5) / np.maximum(in_bin, 1)
        return Quantile(np.clip(lo + (hi - lo) * frac, lo, hi), lo, hi)


class RunSummary(NamedTuple):
    """What ``run_seeds(..., summary=True)`` returns: :class:`SeedStats` per output field."""

    regret: SeedStats  # [G]
    regret_paper: SeedStats  # [G]
    regret_rb: SeedStats  # [G]
    regret_rb_paper: SeedStats  # [G]
    counts: SeedStats  # [G, K]
    compensator: SeedStats  # [G, K]
    min_prob: SeedStats  # [G]

    @property
    def num_seeds(self) -> int:
        return self.regret.count


class _DeviceStats(NamedTuple):
    mean: jax.Array  # [...]
    m2: jax.Array  # [...]
    min: jax.Array  # [...]
    max: jax.Array  # [...]
    hist: Optional[jax.Array]  # [..., B] int32


def _two_sum(a, b):
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


def compensated_sum(x: jax.Array) -> jax.Array:
    """Σ over axis 0 in compensated arithmetic of ``x``'s float type (jit-friendly).

    Pairwise halving with Knuth's TwoSum at every addition; the rounding errors are summed
    alongside and added at the end, so the error does not grow with the number of terms
    (2^25 float32 increments of 1e-3 sum exactly, where a sequential float32 sum stalls). The
    additions are elementwise, so the result does not depend on how XLA orders a reduction.

    Args:
      x: [S, ...] floats.

    Returns:
      [...] the sum.
    """
    s, c = x, jnp.zeros_like(x)
    rest = []
    level = 0
    while s.shape[0] > 1:
        if s.shape[0] % 2:
            rest.append((s[-1], c[-1]))
            s, c = s[:-1], c[:-1]
        h = s.shape[0] // 2
        s, e = _two_sum(s[:h], s[h:])
        c = c[:h] + c[h:] + e
        level += 1
        # a barrier every 4 levels: fused across all levels, each output would inline a
        # 2^levels-leaf expression tree, which XLA:GPU takes minutes to compile for 10^5
        # seeds; the barriers do not change the result (the same additions, bit for bit)
        if level % 4 == 0:
            s, c = jax.lax.optimization_barrier((s, c))
    total, comp = s[0], c[0]
    for s_r, c_r in rest:
        total, e = _two_sum(total, s_r)
        comp = comp + c_r + e
    return total + comp


def summary_edges(config: RunConfig, grid: np.ndarray | None = None) -> dict:
    """Histogram bin edges per summarised field: ``{field: [G, B + 1] float64}``.

    Edges are uniform in ``log(1 + x)`` over ``[0, t_g]`` at checkpoint ``g`` and rounded to
    the config's float type (the device compares against exactly these values). ``grid``:
    the config's ``checkpoint_times`` where the caller has them already.
    """
    grid = sim.checkpoint_times(config) if grid is None else np.asarray(grid)
    grid = grid.astype(np.float64)
    np_dtype = np.float64 if config.dtype == "float64" else np.float32
    out = {}
    for field, bins in SUMMARY_BINS.items():
        if not bins:
            continue
        steps = np.arange(bins + 1) / bins
        edges = np.expm1(np.log1p(grid)[:, None] * steps[None, :])
        edges[:, 0] = 0.0
        edges[:, -1] = grid
        out[field] = edges.astype(np_dtype).astype(np.float64)
    return out


def _bin_index(x, edges, dtype):
    """Bin of each value: ``[C, G, R]`` values, ``[G, B + 1]`` edges -> ``[C, G, R]`` int32."""
    num_bins = edges.shape[1] - 1
    top = edges[:, -1]  # [G] = t_g
    scale = (num_bins / jnp.log1p(top))[None, :, None]
    guess = jnp.floor(jnp.log1p(jnp.maximum(x, 0.0)) * scale)
    idx = jnp.clip(jnp.nan_to_num(guess), 0, num_bins - 1).astype(jnp.int32)
    # one correction step against the stored edges: float error in log1p moves a value by at
    # most one bin, and the histogram must agree exactly with the edges the host reports
    g = jnp.arange(edges.shape[0])[None, :, None]
    idx = idx - (x < edges[g, idx]).astype(jnp.int32)
    idx = idx + (x >= edges[g, jnp.minimum(idx + 1, num_bins)]).astype(jnp.int32)
    return jnp.clip(idx, 0, num_bins - 1)


# Integer fields (counts) whose bin table has at most this many entries look their bin up in
# a [G, t_max + 1] table instead of computing it (log1p, two edge gathers, two compares): the
# same bins for one gather.
_BIN_TABLE_MAX = 1 << 22


def _bin_table(edges: np.ndarray) -> np.ndarray:
    """``[G, t_max + 1]`` int32: the bin of each integer value 0..t_max at each checkpoint,
    the same bins as :func:`_bin_index` (``edges[i] <= x < edges[i + 1]``, the top value in
    the last bin), computed exactly on the host from the stored edges."""
    num_bins = edges.shape[1] - 1
    top = int(np.floor(edges[:, -1].max()))
    values = np.arange(top + 1, dtype=np.float64)
    table = np.stack([np.searchsorted(e, values, side="right") - 1 for e in edges])
    return np.clip(table, 0, num_bins - 1).astype(np.int32)


def _seed_block(top: int) -> int:
    """Seeds per exact int32 partial sum of an integer field bounded by ``top``."""
    return max(1, (2**31 - 1) // max(1, top))


def _int_field_sum(x: jax.Array, valid: jax.Array, top: int, dtype) -> jax.Array:
    """Σ over seeds of an integer field ``x`` [C, ...] (values in [0, top]) in exact int32
    partial sums (blocks of seeds small enough not to overflow), each split exactly into two
    floats and added in compensated arithmetic: the correctly rounded sum, like
    :func:`compensated_sum` of the values as floats, for one pass over ``x``."""
    size = x.shape[0]
    block = min(size, _seed_block(top))
    xi = jnp.where(valid.reshape((size,) + (1,) * (x.ndim - 1)), x, 0)
    pad = -size % block
    if pad:
        xi = jnp.concatenate([xi, jnp.zeros((pad,) + x.shape[1:], xi.dtype)])
    part = jnp.sum(xi.reshape((-1, block) + x.shape[1:]), axis=1)  # [nb, ...] exact
    hi = (part >> 12) << 12  # both halves exact in float32 (≤ 2^31 and < 2^12)
    lo = part - hi
    halves = jnp.concatenate([hi.astype(dtype), lo.astype(dtype)])
    return compensated_sum(halves)


def summarize_outputs(out: RunOutput, num_valid: jax.Array, edges: dict) -> dict:
    """Reduces a batch of per-seed outputs over its seed axis, on the device (traceable).

    Args:
      out: :class:`RunOutput` with leading axis C (a call's seeds, padding included).
      num_valid: [] int32; seeds ``[0, num_valid)`` count, the rest is padding.
      edges: :func:`summary_edges` (closed over as constants).

    Returns:
      ``{field: _DeviceStats}``: compensated mean and Σ(x − mean)², exact min and max, and
      the histogram counts, over the valid seeds.
    """
    dtype = out.regret.dtype
    size = out.regret.shape[0]
    valid = jnp.arange(size) < num_valid  # [C]
    n = num_valid.astype(dtype)
    stats = {}
    for field in SUMMARY_FIELDS:
        raw = getattr(out, field)
        x = raw.astype(dtype)  # counts are exact in float32 below 2^24
        mask = valid.reshape((size,) + (1,) * (x.ndim - 1))
        integer = jnp.issubdtype(raw.dtype, jnp.integer) and field in edges
        top = int(np.floor(edges[field][:, -1].max())) if integer else 0
        if integer and top < 2**24:
            # exact integer partial sums: one pass instead of the pairwise tree's levels
            mean = _int_field_sum(raw, valid, top, dtype) / n
        else:
            mean = compensated_sum(jnp.where(mask, x, 0.0)) / n
        m2 = compensated_sum(jnp.where(mask, jnp.square(x - mean[None]), 0.0))
        lo = jnp.min(jnp.where(mask, x, jnp.inf), axis=0)
        hi = jnp.max(jnp.where(mask, x, -jnp.inf), axis=0)
        hist = None
        if SUMMARY_BINS[field]:
            e = jnp.asarray(edges[field], dtype)  # [G, B + 1]
            num_g, bins = e.shape[0], e.shape[1] - 1
            x3 = x.reshape(size, x.shape[1], -1)  # [C, G, R]
            if integer and num_g * (top + 1) <= _BIN_TABLE_MAX:
                table = jnp.asarray(_bin_table(edges[field]))  # [G, top + 1]
                g = jnp.arange(num_g, dtype=jnp.int32)[None, :, None]
                r3 = jnp.clip(raw.reshape(x3.shape), 0, top)
                idx = table.reshape(-1)[g * (top + 1) + r3]
            else:
                idx = _bin_index(x3, e, dtype)
            cols = jnp.arange(x3.shape[1] * x3.shape[2], dtype=jnp.int32).reshape(x3.shape[1:])
            num_cols = x3.shape[1] * x3.shape[2]
            # padding seeds go to an index past the end, which the scatter drops
            flat = jnp.where(valid[:, None, None], cols[None] * bins + idx, num_cols * bins)
            hist = jnp.zeros(num_cols * bins, jnp.int32).at[flat.reshape(-1)].add(
                1, mode="drop").reshape(x.shape[1:] + (bins,))
        stats[field] = _DeviceStats(mean, m2, lo, hi, hist)
    return stats


def host_stats(dev: dict, count: int, edges: dict) -> RunSummary:
    """The device statistics of one call (:func:`summarize_outputs`) over ``count`` seeds as
    a host :class:`RunSummary` (float64 / int64)."""
    fields = {}
    dev = jax.device_get(dev)  # one call: every transfer in flight at once
    for field in SUMMARY_FIELDS:
        d = dev[field]
        fields[field] = SeedStats(
            count=int(count), mean=np.asarray(d.mean, np.float64),
            m2=np.asarray(d.m2, np.float64), min=np.asarray(d.min, np.float64),
            max=np.asarray(d.max, np.float64),
            hist=None if d.hist is None else np.asarray(d.hist, np.int64),
            edges=edges.get(field))
    return RunSummary(**fields)


def merge_stats(a: SeedStats, b: SeedStats) -> SeedStats:
    """Statistics of the union of two disjoint seed sets (Chan, Golub & LeVeque's parallel
    update for the mean and Σ(x − mean)², in float64; histograms add; min/max combine)."""
    if a.count == 0:
        return b
    if b.count == 0:
        return a
    if (a.hist is None) != (b.hist is None) or (
            a.edges is not None and not np.array_equal(a.edges, b.edges)):
        raise ValueError("cannot merge summaries with different histogram bins")
    n = a.count + b.count
    delta = b.mean - a.mean
    return SeedStats(
        count=n, mean=a.mean + delta * (b.count / n),
        m2=a.m2 + b.m2 + np.square(delta) * (a.count * b.count / n),
        min=np.minimum(a.min, b.min), max=np.maximum(a.max, b.max),
        hist=None if a.hist is None else a.hist + b.hist, edges=a.edges)


def merge_summaries(parts) -> RunSummary:
    """Merges :class:`RunSummary` objects of disjoint seed sets, in the order given (merge in
    a fixed order, e.g. by first seed, for bitwise-reproducible float64 results)."""
    parts = list(parts)
    if not parts:
        raise ValueError("merge_summaries needs at least one summary")
    out = parts[0]
    for p in parts[1:]:
        out = RunSummary(*(merge_stats(x, y) for x, y in zip(out, p)))
    return out


_STAT_NAMES = ("count", "mean", "m2", "min", "max", "hist", "edges")


def summary_arrays(summary: RunSummary, prefix: str = "") -> dict:
    """Flat ``{prefix + field + "__" + stat: array}`` for ``np.savez`` (None entries left out)."""
    out = {}
    for field in SUMMARY_FIELDS:
        stats = getattr(summary, field)
        for name in _STAT_NAMES:
            value = getattr(stats, name)
            if value is not None:
                out[f"{prefix}{field}__{name}"] = np.asarray(value)
    return out


def summary_from_arrays(arrays, prefix: str = "") -> RunSummary:
    """The inverse of :func:`summary_arrays`."""
    fields = {}
    for field in SUMMARY_FIELDS:
        got = {name: arrays.get(f"{prefix}{field}__{name}") for name in _STAT_NAMES}
        if got["count"] is None or got["mean"] is None:
            raise ValueError(f"no summary of {prefix}{field} in these arrays")
        got["count"] = int(got["count"])
        fields[field] = SeedStats(**{k: (np.asarray(v) if v is not None and k != "count"
                                         else v) for k, v in got.items()})
    return RunSummary(**fields)


