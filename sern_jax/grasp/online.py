"""Compatibility names for code written before issue 18 split the online learner.

The batched runner is :mod:`sern_jax.grasp.runner` (``OnlineConfig``, ``run``,
``table_rows``, ...), the robot loop :mod:`sern_jax.grasp.asktell` (``AskTell``), and the
learners themselves :mod:`sern_jax.learners`. New code imports those; this module only
re-exports them (patching a name here does not reach the runner).
"""

from sern_jax.grasp import runner as _runner
from sern_jax.grasp.asktell import AskTell, AskTellState
from sern_jax.grasp.runner import (
    EXPLORE_CONTEXT,
    EXPLORE_TRIAL,
    FIT,
    MJX_BATCH,
    POLICY_UNIFORM,
    OnlineConfig,
    RoundResults,
    _stream,
    copies_network,
    object_key,
    run_fingerprint,
    table_rows,
)
from sern_jax.learners.registry import names as _names


def run(*args, **kwargs):
    """``runner.run`` (looked up at each call, so patching ``runner.run`` reaches here)."""
    return _runner.run(*args, **kwargs)


POLICIES = _names()

__all__ = [
    "EXPLORE_CONTEXT",
    "EXPLORE_TRIAL",
    "FIT",
    "MJX_BATCH",
    "POLICIES",
    "POLICY_UNIFORM",
    "AskTell",
    "AskTellState",
    "OnlineConfig",
    "RoundResults",
    "_stream",
    "copies_network",
    "object_key",
    "run",
    "run_fingerprint",
    "table_rows",
]
