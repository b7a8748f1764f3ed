"""Temperature schedules α(t, T) for SERN.

All schedule *values* (α0, p) are traced parameters, so a sweep over α is a ``vmap``; only the
schedule *kind* is static.

* ``constant``: α = α0 (the paper's experiments use α = 0.05).
* ``log``: α = α0 / ln(T^p) = α0 / (p ln T) (Algorithm 1 uses α0 = 1; Theorem 4 uses α0).
  Depends on the horizon T only, so it is constant within a run.
* ``theorem4``: α = α0 / (1 + α0 p ln T), the schedule for which Theorem 1's
  ``e^{-1/α}/K`` equals Theorem 4's ``c0 T^{-p}/K`` with ``c0 = e^{-1/α0}`` (audit §3.1).

This module is the one place these formulas are written: :func:`alpha_t` inside traced code,
:func:`alpha_of_horizon` / :func:`alpha_of_log_horizon` on the host (float64 numpy: the fast
runner's α check, the theory checks, the regret experiment's saved Theorem 1 floor).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from sern_jax.core.types import Array

__all__ = ["SCHEDULE_NAMES", "alpha_t", "alpha_of_horizon", "alpha_of_log_horizon",
           "validate_schedule"]

SCHEDULE_NAMES = ("constant", "log", "theorem4")


def _alpha(kind: str, log_t, alpha0, p):
    """α from ln T; plain arithmetic, so it serves jnp (traced) and numpy (host) alike."""
    if kind == "constant":
        return alpha0
    if kind == "log":
        return alpha0 / (p * log_t)
    if kind == "theorem4":
        return alpha0 / (1.0 + alpha0 * p * log_t)
    raise ValueError(f"unknown schedule {kind!r}; choose one of {SCHEDULE_NAMES}")


def alpha_t(kind: str, t: Array, horizon: int, alpha0: Array, p: Array) -> Array:
    """Temperature at round ``t`` of a run with horizon ``horizon``.

    Args:
      kind: static schedule name, one of :data:`SCHEDULE_NAMES`.
      t: [] round number (unused by the built-in schedules, kept for anytime schedules).
      horizon: static horizon T.
      alpha0: [] α0 > 0.
      p: [] exponent p > 0 (``log`` and ``theorem4`` only).

    Returns:
      [] α > 0.
    """
    del t
    if kind == "constant":
        return alpha0
    return _alpha(kind, jnp.log(jnp.asarray(horizon, dtype=jnp.result_type(alpha0))), alpha0, p)


def alpha_of_log_horizon(kind: str, log_t, alpha0, p) -> np.ndarray:
    """Host-side α(T) from ``log_t = ln T`` in float64 (horizons past float range, e.g. 10^80).

    Args:
      kind: one of :data:`SCHEDULE_NAMES`.
      log_t: ln T (any shape; broadcasts with ``alpha0`` and ``p``).
      alpha0: α0 > 0.
      p: exponent p > 0 (``log`` and ``theorem4`` only).

    Returns:
      float64 array of α (the same formula as :func:`alpha_t`).
    """
    f64 = lambda x: np.asarray(x, dtype=np.float64)  # noqa: E731
    return f64(_alpha(kind, f64(log_t), f64(alpha0), f64(p)))


def alpha_of_horizon(kind: str, horizon, alpha0, p) -> np.ndarray:
    """Host-side α(T) for horizon ``T`` in float64: α0 (constant), α0/ln(T^p) (log),
    α0/(1 + α0 p ln T) (theorem4). See :func:`alpha_of_log_horizon`. ``ln T`` is ``math.log``
    per element (correctly rounded libm, the value the theory checks always used)."""
    log_t = np.vectorize(math.log, otypes=[np.float64])(np.asarray(horizon, dtype=np.float64))
    return alpha_of_log_horizon(kind, log_t, alpha0, p)


def validate_schedule(kind: str, horizon: int, alpha0, p) -> None:
    """Raises ``ValueError`` naming the bad value (host-side, before any compile)."""
    if kind not in SCHEDULE_NAMES:
        raise ValueError(f"unknown schedule {kind!r}; choose one of {SCHEDULE_NAMES}")
    a0 = np.asarray(alpha0, dtype=np.float64)
    if not np.all(np.isfinite(a0)) or np.any(a0 <= 0):
        raise ValueError(f"alpha0 must be finite and > 0, got {alpha0!r}")
    if kind in ("log", "theorem4"):
        pp = np.asarray(p, dtype=np.float64)
        if not np.all(np.isfinite(pp)) or np.any(pp <= 0):
            raise ValueError(f"schedule {kind!r} needs p > 0, got p={p!r}")
        if kind == "log" and horizon < 2:
            raise ValueError(
                f"schedule 'log' (α0/ln(T^p)) needs horizon T >= 2, got T={horizon}"
            )
