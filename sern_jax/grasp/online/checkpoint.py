"""The online run's results and its checkpoint (``<run dir>/checkpoint.npz``).

:class:`RoundResults` holds every figure of a run with axes [R + 1, O, Q, S] (round 0: θ0
before learning); :func:`table_rows` makes Table I from them. The checkpoint holds the
results and every exploration grasp's reward (kilobytes: no learner state) through the last
finished round; a resumed run rebuilds the learners' states by replaying init and each
finished round's update on the same inputs (:mod:`sern_jax.grasp.online.driver`).
:func:`state_arrays` and :func:`state_from_arrays` save one learner state (the ask/tell
loop's files).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from sern_jax.analysis import stats
from sern_jax.grasp.model import artifacts
from sern_jax.infra import io
from sern_jax.learners import base as lbase

__all__ = [
    "CHECKPOINT",
    "RoundResults",
    "empty_results",
    "load",
    "save",
    "state_arrays",
    "state_from_arrays",
    "table_rows",
    "through",
]

CHECKPOINT = "checkpoint.npz"  # in the run directory


class RoundResults(NamedTuple):
    """Success figures with axes [R + 1, O, Q, S] (round 0 = θ0 before learning)."""

    paper_eval: np.ndarray  # fraction of `evaluate` greedy grasps that succeeded
    lowvar_eval: np.ndarray  # mean greedy success probability over the fixed eval poses
    explore_success: np.ndarray  # fraction of exploration grasps that succeeded (round 0: NaN)
    explore_action: np.ndarray  # [R + 1, O, Q, S, E] chosen candidate slots (-1: none valid)
    # Expected successes lost to the best candidate over the round's exploration grasps,
    # under the policy's distribution and the oracle of `regret_trials` trials per
    # candidate (NaN: round 0, or accounting off).
    pseudo_regret: np.ndarray  # [R + 1, O, Q, S]


def empty_results(num_rounds: int, num_objects: int, num_learners: int, num_seeds: int,
                  num_explore: int) -> tuple[RoundResults, np.ndarray]:
    """A run's results and rewards before any round: figures NaN, actions -1, rewards
    int8 [R + 1, O, S, Q, E] zero (what :func:`through` resets later rounds to)."""
    shape = (num_rounds + 1, num_objects, num_learners, num_seeds)
    results = RoundResults(np.full(shape, np.nan), np.full(shape, np.nan),
                           np.full(shape, np.nan), np.full(shape + (num_explore,), -1, np.int32),
                           np.full(shape, np.nan))
    rewards = np.zeros((num_rounds + 1, num_objects, num_seeds, num_learners, num_explore),
                       np.int8)
    return results, rewards


def table_rows(objects: list[str], policies: tuple[str, ...], paper_eval: np.ndarray,
               lowvar_eval: np.ndarray | None = None,
               pseudo_regret: np.ndarray | None = None) -> list[dict]:
    """Table I rows: per object and policy, round 1..R success mean ± std over seeds (%),
    Max over rounds and Imprv = (r_R - r_1)/r_1 (the paper's definition).

    ``std`` is the population standard deviation over seeds (ddof 0, as it always was);
    ``sd`` is the sample standard deviation (ddof 1) and ``se`` = sd / √S, the statistic
    the paper's Table I prints in parentheses (``experiments/paper_table1.py``); None
    with one seed."""
    rows = []
    for o, name in enumerate(objects):
        for q, policy in enumerate(policies):
            x = 100.0 * paper_eval[1:, o, q, :]  # [R, S]
            mean, std = x.mean(1), x.std(1)
            spread = stats.t_interval(x, axis=1)  # sd (ddof 1) and se over the seeds
            r1, rr = mean[0], mean[-1]
            row = {
                "object": name,
                "policy": policy,
                "theta0": float(100.0 * paper_eval[0, o, q, :].mean()),
                "rounds": [float(v) for v in mean],
                "std": [float(v) for v in std],
                "sd": [float(v) if np.isfinite(v) else None for v in spread.sd],
                "se": [float(v) if np.isfinite(v) else None for v in spread.se],
                "max": float(mean.max()),
                "imprv": float((rr - r1) / r1) if r1 > 0 else None,
            }
            if lowvar_eval is not None and np.isfinite(lowvar_eval).all():
                lv = 100.0 * lowvar_eval[:, o, q, :]
                row["lowvar_rounds"] = [float(v) for v in lv.mean(1)]
                row["lowvar_std"] = [float(v) for v in lv.std(1)]
            if pseudo_regret is not None and np.isfinite(pseudo_regret[1:]).all():
                pr = pseudo_regret[1:, o, q, :]  # [R, S]
                row["pseudo_regret"] = [float(v) for v in pr.mean(1)]
                row["pseudo_regret_std"] = [float(v) for v in pr.std(1)]
                # Student-t 95 % intervals over the seeds (n - 1 dof), per round and for the
                # run's total; None with one seed
                ci, total = stats.t_interval(pr, axis=1), stats.t_interval(pr.sum(0))
                row["pseudo_regret_sd"] = _finite_list(ci.sd)
                row["pseudo_regret_se"] = _finite_list(ci.se)
                row["pseudo_regret_ci95"] = [
                    [float(lo), float(hi)] if np.isfinite(lo) else None
                    for lo, hi in zip(ci.lower, ci.upper)]
                row["pseudo_regret_total"] = float(total.mean)
                row["pseudo_regret_total_ci95"] = (
                    [float(total.lower), float(total.upper)] if np.isfinite(total.lower)
                    else None)
            rows.append(row)
    return rows


def _finite_list(values) -> list:
    return [float(v) if np.isfinite(v) else None for v in values]


# ----------------------------------------------------------------------------- checkpoint


def load(path: str | Path, fingerprint: str, run_dir: str | Path
         ) -> tuple[RoundResults, np.ndarray, int] | None:
    """The checkpoint at ``path``: (results, rewards, next round), None where there is
    none; a checkpoint of another run (another fingerprint) is a ``ValueError`` naming
    ``run_dir``."""
    path = Path(path)
    if not path.exists():
        return None
    saved = io.load_npz(path, advice="delete it (or choose another --out) and rerun")
    if str(saved.get("fingerprint", "")) != fingerprint:
        raise ValueError(f"{run_dir} holds a different learning run; choose another --out "
                         "or delete it")
    results = RoundResults(*(saved[f] for f in RoundResults._fields))
    return results, np.asarray(saved["explore_reward"], np.int8), int(saved["next_round"])


def save(path, fingerprint, results, rewards, next_round) -> None:
    """The run's checkpoint: results, every exploration grasp's reward (int8 [R + 1, O, S,
    Q, E]) and the next round; the learner states are rebuilt on resume."""
    arrays = {f: np.asarray(getattr(results, f)) for f in results._fields}
    io.save_npz(path, fingerprint=np.asarray(fingerprint), next_round=np.asarray(next_round),
                explore_reward=np.asarray(rewards, np.int8), **arrays)


def through(results: RoundResults, rewards: np.ndarray, next_round: int):
    """Copies of ``results`` and ``rewards`` holding rounds ``< next_round`` only, later
    rounds at their initial fill (NaN, action -1, reward 0): what the checkpoint of a run
    that has finished those rounds holds, whatever the main thread has done since (and what
    ``learn_units`` joins its units' checkpoints to)."""
    def cut(a, fill):
        a = np.array(a, copy=True)
        a[next_round:] = fill
        return a

    fills = {"explore_action": -1}
    return (RoundResults(*(cut(getattr(results, f), fills.get(f, np.nan))
                           for f in RoundResults._fields)),
            cut(rewards, 0))


# ----------------------------------------------------------------------------- learner states


def state_arrays(state: lbase.LearnerState, prefix: str, horizon: int) -> dict:
    """A learner state's leaves as ``{prefix + i: array}``, the buffer cut to its D rows
    (rows [0, T) on the buffer's row axis, after any leading copy axes; C is rebuilt from
    the core set on load)."""
    lead = state.buffer.count.ndim

    def cut(x):
        return np.asarray(x)[(slice(None),) * lead + (slice(0, horizon),)]

    buf = state.buffer
    short = state._replace(buffer=buf._replace(inputs=tuple(cut(x) for x in buf.inputs),
                                               reward=cut(buf.reward), weight=cut(buf.weight)))
    return artifacts.tree_arrays(short, prefix)


def state_from_arrays(saved: dict, prefix: str, template: lbase.LearnerState,
                       horizon: int) -> lbase.LearnerState:
    """The inverse of :func:`state_arrays`: ``template`` (a fresh state of the same learner)
    gives the structure and the core-set rows."""
    lead = template.buffer.count.ndim
    row = (slice(None),) * lead

    def short(x):
        return x[row + (slice(0, horizon),)]

    buf = template.buffer
    short_template = template._replace(buffer=buf._replace(
        inputs=tuple(short(x) for x in buf.inputs), reward=short(buf.reward),
        weight=short(buf.weight)))
    keys = [k for k in saved if k.startswith(prefix)]
    if len(keys) != len(jax.tree.leaves(short_template)):
        raise ValueError(f"the checkpoint's state {prefix!r} does not fit this learner")
    loaded = artifacts.tree_from_arrays(saved, short_template, prefix)

    def full(d, t):
        return jnp.concatenate([jnp.asarray(d, t.dtype), t[row + (slice(horizon, None),)]],
                               axis=lead)

    lb = loaded.buffer
    return loaded._replace(buffer=lb._replace(
        inputs=tuple(full(d, t) for d, t in zip(lb.inputs, buf.inputs)),
        reward=full(lb.reward, buf.reward), weight=full(lb.weight, buf.weight)))
