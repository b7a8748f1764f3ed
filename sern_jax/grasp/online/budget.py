"""Up-front size estimates of the grasp commands: memory, disk, trials, time.

Every size flag of ``sern grasp dataset | pretrain | screen | learn`` and ``sern reproduce``
goes through one function here before anything is written, compiled or simulated (as
``sern regret``'s ``check_fits``): the estimate is compared with this machine's available
memory (``executor.available_memory_bytes``), the free disk under the output directory and a
time limit, and a run that cannot fit is refused with one line naming the flags that drive
the exceeded figure and the figure itself.

The estimates are upper bounds from array shapes (what the code holds at once: images of
H x W = 96 x 96 float32, K = 64 candidate slots, crops of 32 x 32 float32, one trial row per
simulated grasp), not measurements; times use per-core rates calibrated from
experiments/results/trial_rate and the commands' recorded run times, scaled by the cores this
process may use. They only need to be right within a small factor: their job is to turn
``--eval-poses 1000000000`` into a refusal in milliseconds instead of a
``RESOURCE_EXHAUSTED`` after a long compile, and ``--regret-trials 100000000`` into a refusal
instead of a run that never ends.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
from pathlib import Path

from sern_jax.infra import hosts
from sern_jax.infra.io import fmt_bytes, fmt_time  # noqa: F401  (re-exported: budget.fmt_*)

__all__ = [
    "Estimate",
    "MAX_DAYS",
    "dataset",
    "pretrain",
    "screen",
    "learn",
    "check",
    "fmt_bytes",
    "fmt_time",
]

MAX_DAYS = 7.0  # the limit `sern regret` uses too
K = 64  # candidate slots per context
IMAGE_BYTES = 96 * 96 * 4  # one depth image, float32
CROP_BYTES = 32 * 32 * 4  # one crop, float32
SLOT_BYTES = 4 * 4 + 1 + 2 * 4 + 4 + 4 + 4 + 4 + 1  # grasp, valid, centre, angle, depth, ...
CONTEXT_BYTES = IMAGE_BYTES + 7 * 8 + K * SLOT_BYTES  # one context as stored / held
TRIAL_ROW_BYTES = 1024  # grasp, pose, noise, result and the simulator's per-trial state
TRIALS_PER_CORE_S = 115.0  # native MuJoCo trials per second per core (calibrated)
CONTEXT_CORE_S = 0.013  # core seconds per resting pose + depth image + candidates (calibrated)
# The quality network is small (GQCNN-lite: ~10k parameters); a copy with Adam's two moments
PARAM_COPY_BYTES = 3 * 4 * 20_000


@dataclasses.dataclass(frozen=True)
class Estimate:
    """What a run will hold and do (upper bounds from shapes; rates calibrated, see module).

    Attributes:
      memory_bytes: peak host memory.
      disk_bytes: bytes written under the output directory.
      trials: simulated grasp trials.
      contexts: resting poses rendered (each: settle, depth image, 64 candidates).
      seconds: estimated wall time on this machine.
      memory_flags: the flags that drive ``memory_bytes`` (named in a refusal).
      work_flags: the flags that drive ``seconds``.
      disk_flags: the flags that drive ``disk_bytes``.
    """

    memory_bytes: int
    disk_bytes: int
    trials: int
    contexts: int
    seconds: float
    memory_flags: str
    work_flags: str
    disk_flags: str = ""


def _largest(parts: dict[str, float]) -> str:
    """The flags of the largest part (what a refusal names)."""
    return max(parts.items(), key=lambda kv: kv[1])[0]


def _cores() -> int:
    return hosts.usable_cores()


def _seconds(trials: float, contexts: float, extra: float = 0.0) -> float:
    return (trials / TRIALS_PER_CORE_S + contexts * CONTEXT_CORE_S) / _cores() + extra


def dataset(*, objects: int, poses: int, trials: int, objects_per_shard: int = 10) -> Estimate:
    """``sern grasp dataset``: one object's poses x 64 candidates x trials are simulated in
    one batch; a shard of ``objects_per_shard`` objects is held before it is saved."""
    contexts = objects * poses
    num_trials = contexts * K * trials  # upper bound: every slot valid
    shard = min(objects, objects_per_shard) * poses * CONTEXT_BYTES
    per_object = poses * (CONTEXT_BYTES + K * trials * TRIAL_ROW_BYTES)
    return Estimate(
        memory_bytes=int(2 * shard + per_object), disk_bytes=int(contexts * CONTEXT_BYTES),
        trials=int(num_trials), contexts=int(contexts),
        seconds=_seconds(num_trials, contexts),
        memory_flags="--poses x --trials" if trials > 1 else "--poses",
        work_flags="--objects x --poses x --trials" if trials > 1 else "--objects x --poses",
        disk_flags="--objects x --poses")


def pretrain(*, grasps: int, epochs: int, batch_size: int, heldout_objects: int,
             heldout_poses: int, heldout_trials: int, core_k: int, screen_objects: int = 0,
             screen_poses: int = 0, screen_trials: int = 0, contexts: int | None = None,
             num_rff: int = 512) -> Estimate:
    """``sern grasp pretrain``: D0 (``contexts``, ``grasps`` labelled grasps, from its
    config.json) in memory with one crop per grasp, the k-DPP's lifted features (float64,
    ``num_rff`` columns per grasp), the held-out evaluation and the screen."""
    contexts = contexts if contexts is not None else math.ceil(grasps / K)
    data = contexts * CONTEXT_BYTES + grasps * (CROP_BYTES + 16)
    dpp = grasps * num_rff * 8 * 2
    heldout = heldout_poses * (CONTEXT_BYTES + K * (heldout_trials * TRIAL_ROW_BYTES
                                                    + CROP_BYTES))
    screen_mem = screen_poses * (CONTEXT_BYTES + K * (screen_trials * TRIAL_ROW_BYTES
                                                      + CROP_BYTES))
    batch = batch_size * (CROP_BYTES * 4 + 64)  # crops, activations and gradients
    trials = (heldout_objects * heldout_poses * K * heldout_trials
              + screen_objects * screen_poses * K * screen_trials)
    ctx = heldout_objects * heldout_poses + screen_objects * screen_poses
    # training: calibrated seconds per epoch of 18k grasps on two cores, scaled by the cores
    train_s = epochs * grasps / 18_000.0 * 2 / _cores()
    memory_parts = {"--data (D0's grasps)": data + dpp, "--batch-size": batch,
                    "--heldout-poses x --heldout-trials": heldout,
                    "--screen-poses x --screen-trials": screen_mem}
    work_parts = {"--epochs": train_s * TRIALS_PER_CORE_S * _cores(),
                  "--heldout-objects x --heldout-poses x --heldout-trials":
                      heldout_objects * heldout_poses * K * heldout_trials,
                  "--screen-poses x --screen-trials": screen_objects * screen_poses * K
                      * screen_trials}
    return Estimate(
        memory_bytes=int(data + dpp + max(heldout, screen_mem) + batch),
        disk_bytes=int(core_k * 2 * CROP_BYTES + 4 * PARAM_COPY_BYTES + 1e6),
        trials=int(trials), contexts=int(ctx), seconds=_seconds(trials, ctx, train_s),
        memory_flags=_largest(memory_parts), work_flags=_largest(work_parts),
        disk_flags="--core-k")


def screen(*, objects: int, poses: int, trials: int) -> Estimate:
    """``sern grasp screen``: per object, ``poses`` x 64 candidates x ``trials`` trials."""
    per_object = poses * (CONTEXT_BYTES + K * (trials * TRIAL_ROW_BYTES + CROP_BYTES))
    num_trials = objects * poses * K * trials
    return Estimate(memory_bytes=int(per_object), disk_bytes=0, trials=int(num_trials),
                    contexts=int(objects * poses),
                    seconds=_seconds(num_trials, objects * poses),
                    memory_flags="--poses x --trials",
                    work_flags="OBJECTS x --poses x --trials")


def learn(*, objects: int, policies: int, seeds: int, rounds: int, explore: int,
          evaluate: int, eval_poses: int, eval_trials: int, regret_trials: int,
          fit_steps: int = 40, batch_size: int = 32,
          network_copies: int | None = None, regret_grasps: int = 0) -> Estimate:
    """``sern grasp learn``: O objects x Q policies x S seeds, R rounds of E exploration
    grasps, V greedy evaluations, the low-variance evaluation (P fixed poses x M trials) and
    the regret oracle (every valid candidate of the first ``regret_grasps`` exploration poses
    of each phase, 0 = all, regret_trials times to choose and as many to value).

    Memory: the learner's buffer [O, S, Q, R*E] crops, the O*S*Q network copies with Adam
    moments, one round's exploration
    contexts and crops [O, S, E, K], the fixed evaluation poses [O, S, P] with their crops,
    their repeated trials [O, S, Q, P*M] and one object's oracle batch [S, E, K, regret].
    ``network_copies``: networks (with Adam moments) per (object, seed) over all learners,
    default one per learner (an ensemble learner holds ``--ensemble-size``)."""
    o, q, s, r, e = objects, policies, seeds, rounds, explore
    buffer = o * s * q * r * e * (CROP_BYTES + 12)
    copies = o * s * (q if network_copies is None else network_copies) * PARAM_COPY_BYTES
    round_ctx = o * s * e * (CONTEXT_BYTES + K * (CROP_BYTES + 8 * q))
    eval_ctx = o * s * evaluate * (CONTEXT_BYTES + K * (CROP_BYTES + 8 * q))
    lowvar = o * s * eval_poses * (CONTEXT_BYTES + K * (CROP_BYTES + 8 * q))
    lowvar_trials = o * s * q * eval_poses * eval_trials * TRIAL_ROW_BYTES
    g = regret_grasps or e  # the oracle's grasps per phase
    oracle = s * g * K * regret_trials * TRIAL_ROW_BYTES
    fit = o * s * q * batch_size * CROP_BYTES * 4
    memory_parts = {
        "objects x --seeds x policies x --rounds x --explore": 3 * buffer + round_ctx + fit,
        "objects x --seeds x policies (x --ensemble-size)": 3 * copies,
        "objects x --seeds x --evaluate": eval_ctx,
        "objects x --seeds x --eval-poses": lowvar,
        "--eval-poses x --eval-trials": lowvar_trials,
        "--regret-trials": oracle,
    }
    memory = sum(memory_parts.values())
    trial_parts = {
        "objects x --seeds x --rounds x --explore": r * e * o * s * q,
        "--evaluate": (r + 1) * evaluate * o * s * q,
        "--eval-poses x --eval-trials": (r + 1) * o * s * q * eval_poses * eval_trials,
        "--regret-trials": 2 * r * o * s * g * K * regret_trials,
    }
    trials = sum(trial_parts.values())
    contexts = o * s * (r * e + (r + 1) * evaluate + eval_poses)
    trial_parts["objects x --seeds x --eval-poses"] = o * s * eval_poses * (
        CONTEXT_CORE_S * TRIALS_PER_CORE_S)
    # updates: calibrated seconds for the paper's 6 x 3 x 5 copies x 5 rounds x 40 steps on
    # two cores, scaled by the copies, rounds, steps, batch size and cores
    update_s = r * o * s * q * fit_steps * batch_size * 31.0 / (6 * 3 * 5 * 5 * 40 * 32)
    return Estimate(
        # the checkpoint: results and per-grasp rewards (the states are replayed on resume)
        memory_bytes=int(memory), disk_bytes=int((r + 1) * o * s * q * (e + 8) * 8 + 1e6),
        trials=int(trials), contexts=int(contexts),
        seconds=_seconds(trials, contexts, update_s * 2 / _cores()),
        memory_flags=_largest(memory_parts), work_flags=_largest(trial_parts),
        disk_flags="objects x --seeds x policies x --rounds x --explore")  # results


def _free_disk(out: str | os.PathLike | None) -> int | None:
    if out is None:
        return None
    probe = Path(out)
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        return shutil.disk_usage(probe).free
    except OSError:
        return None


def check(est: Estimate, *, out: str | os.PathLike | None = None,
          available_memory: int | None = None, max_days: float = MAX_DAYS) -> Estimate:
    """Refuses (``ValueError``, one line naming the flags) a run that cannot fit.

    Args:
      est: an estimate from this module.
      out: the output directory (its filesystem's free space is checked), or None.
      available_memory: bytes (default: ``executor.available_memory_bytes()``).
      max_days: the time limit.

    Returns:
      ``est`` (for chaining).
    """
    if available_memory is None:
        from sern_jax.engine import drive as executor

        available_memory = executor.available_memory_bytes()
    if est.memory_bytes > available_memory:
        raise ValueError(
            f"{est.memory_flags}: the run needs about {fmt_bytes(est.memory_bytes)} of "
            f"memory, more than the {fmt_bytes(available_memory)} available; use smaller "
            "values")
    free = _free_disk(out)
    if free is not None and est.disk_bytes > free:
        raise ValueError(
            f"{est.disk_flags or est.memory_flags}: the run writes up to "
            f"{fmt_bytes(est.disk_bytes)} under {out}, more than the {fmt_bytes(free)} free; "
            "use smaller values or another --out")
    if est.seconds > max_days * 86400:
        raise ValueError(
            f"{est.work_flags}: {est.trials:,} trials and {est.contexts:,} poses, estimated at "
            f"{fmt_time(est.seconds)} on this machine ({_cores()} cores), over the "
            f"{max_days:g}-day limit; use smaller values")
    return est
