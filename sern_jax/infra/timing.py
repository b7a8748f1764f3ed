"""Wall-clock timing of (compiled) calls: the one timing helper of the benchmarks.

``time_calls(call, repeats)`` runs ``call()`` (a function of no arguments: close over the
inputs) ``warmup`` times, timing the first of those calls apart (with a jitted function that
is compile + run), then ``repeats`` timed rounds, each ending in ``jax.block_until_ready`` so
that asynchronous dispatch is not mistaken for speed. A round may hold several calls
(``min_calls``, ``min_time``): its figure is then seconds per call. CPU seconds of this process
(all its threads) are recorded beside wall seconds.

Used by ``sern bench bandit`` (:mod:`sern_jax.bench.bandit`), ``sern bench grasp``
(:mod:`sern_jax.bench.grasp`, its ``quality_net_benchmark`` too).
"""

from __future__ import annotations

import statistics
import time
from typing import Any, Callable, NamedTuple

__all__ = ["Timing", "time_calls", "block"]


def block(x: Any) -> Any:
    """``jax.block_until_ready`` where jax is loaded; anything else is returned as it is."""
    import sys

    jax = sys.modules.get("jax")
    return jax.block_until_ready(x) if jax is not None else x


class Timing(NamedTuple):
    """What :func:`time_calls` measured (seconds)."""

    result: Any  # the last call's output
    first_s: float | None  # the first warm-up call (compile + run for a fresh jit); None: none
    times_s: tuple[float, ...]  # [repeats] wall seconds per call, one per timed round
    cpu_s: tuple[float, ...]  # [repeats] process CPU seconds per call, one per timed round

    @property
    def median_s(self) -> float:
        return statistics.median(self.times_s)

    @property
    def best_s(self) -> float:
        return min(self.times_s)

    @property
    def best_cpu_s(self) -> float:
        return min(self.cpu_s)

    @property
    def overhead_s(self) -> float:
        """First call minus the best timed call (the compile time of a fresh jit), >= 0."""
        return max((self.first_s or 0.0) - self.best_s, 0.0)

    def stats(self) -> dict[str, Any]:
        """``median_s``, ``min_s``, ``max_s``, ``times_s`` (the benchmarks' JSON fields)."""
        return {"median_s": self.median_s, "min_s": min(self.times_s),
                "max_s": max(self.times_s), "times_s": [round(x, 4) for x in self.times_s]}


def time_calls(call: Callable[[], Any], repeats: int = 3, *, warmup: int = 1,
               min_calls: int = 1, min_time: float = 0.0) -> Timing:
    """Times ``call()``.

    Args:
      call: no arguments; its output is blocked on (``jax.block_until_ready``).
      repeats: timed rounds (>= 1).
      warmup: untimed calls first (the first is timed apart as ``first_s``); 0 for a call
        compiled beforehand whose every run should count.
      min_calls: calls per timed round at least.
      min_time: seconds per timed round at least (more calls until it has passed).

    Returns:
      a :class:`Timing`; ``times_s`` holds seconds per call, one figure per round.
    """
    if repeats < 1 or warmup < 0 or min_calls < 1:
        raise ValueError(f"repeats >= 1, warmup >= 0, min_calls >= 1; got {repeats}, "
                         f"{warmup}, {min_calls}")
    first, result = None, None
    for i in range(warmup):
        t0 = time.perf_counter()
        result = block(call())
        if i == 0:
            first = time.perf_counter() - t0
    times, cpus = [], []
    for _ in range(repeats):
        calls, t0, c0 = 0, time.perf_counter(), time.process_time()
        while calls < min_calls or time.perf_counter() - t0 < min_time:
            result = block(call())
            calls += 1
        times.append((time.perf_counter() - t0) / calls)
        cpus.append((time.process_time() - c0) / calls)
    return Timing(result, first, tuple(times), tuple(cpus))
