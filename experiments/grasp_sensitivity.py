"""Sensitivity of the policy comparison to the simulated world, and sim-to-sim transfer.

The shipped θ0 was pretrained in world A, today's trial (since 2026-11-24, commit f5ac209):
``scene.SceneConfig()`` (20 N per finger, a Robotiq 2F-85 at its lowest force setting),
``sim.TrialConfig()`` (object friction ~ U[0.3, 0.8]), no depth noise. Each cell of the grid
is a world B that differs in

* the finger force: 20 N (A) or 10 N (a weaker grip),
* the object friction range: U[0.3, 0.8] (A) or U[0.2, 0.5] (slipperier objects),
* the depth sensor: noise-free (A) or RealSense D435-like noise with missing pixels
  (``depth.CameraConfig(noise_model="realsense")``),

and θ0 learns online there (the paper's protocol: today's hard set, SERN / ε-greedy /
greedy, 5 rounds of 20 exploration + 5 evaluation grasps, the fixed-pose evaluation). Cell
``20N_mu0.3-0.8_clean`` is world A itself. Each cell's name says its force, and each cell
writes ``experiments.grasp_learning``'s per-seed format (θ0's digest, the trial and scene
configurations, the command and the machine inside), so a file of another trial or θ0 is
refused by ``summarise``; ``<out>/grid.json`` pins the grid's seeds, rounds, objects and θ0,
and a ``cell`` or ``run`` with other settings in the same ``--out`` is refused (exit 2).
Per cell, ``summarise`` computes the paired differences SERN − each peer of the final
round's fixed-pose success, pooled over the objects per seed, with Student-t intervals over
seeds and Holm's correction over every finished cell's comparisons together; and, for
transfer, per policy how far θ0 falls in B against A (round 0) and how much of that online
learning recovers by round 1 and round 5.

    python -m experiments.grasp_sensitivity run --seeds 10 --workers 8 \\
        --out runs/sensitivity                        # the grid, one process per cell
    python -m experiments.grasp_sensitivity cell 10N_mu0.2-0.5_d435 --out runs/sensitivity
    python -m experiments.grasp_sensitivity summarise runs/sensitivity
    python -m figures.make_sensitivity_fig runs/sensitivity

``run`` gives each worker an equal share of the machine's cores (``--workers``), stops
workers still running at ``--deadline`` seconds, and writes ``<out>/<cell>.json`` per
finished cell (a stopped cell resumes from its last finished round when rerun with the same
command; ``python -m experiments.grasp_learning collect <out>/runs <out>`` writes the
finished rounds of a stopped cell, marked ``stopped_early``, which ``summarise`` lists but
leaves out of the comparisons) and ``<out>/summary.json``.

The grid made under the previous trial (6 N per finger, its θ0 in
``results/transfer/theta0_6N``; cells ``6N_*`` and ``20N_*``, the latter a 6 N network meeting
a 20 N grip) is kept as a record in ``results/sensitivity_6N``, in its own older per-seed
format; ``summarise`` reads it with the previous grid's cells (``CELLS_6N``) and refuses a
directory that mixes the two formats.

Sim-to-sim transfer over 20 rounds (``TRANSFER_CELLS``: world A itself, lower friction,
heavier objects, D435 depth noise, a 6 N grip, MJX physics, and the previous trial's θ0
meeting world A), per-seed files in ``experiments.grasp_learning``'s format:

    python -m experiments.grasp_sensitivity transfer --seeds 5 --rounds 20 --objects 3 \
        --workers 6 --deadline 440 --out runs/transfer     # or transfer-cell CELL
    python -m experiments.grasp_sensitivity transfer-summarise runs/transfer
    python -m figures.make_transfer_fig runs/transfer docs/img/transfer.png

``transfer-summarise`` gives per cell the gap θ0(A) − θ0(B) (paired by seed), per policy the
gain by rounds 1, 5 and 20 (and the last finished round of a stopped cell) with t intervals,
the share of the gap recovered, the distance to the same policy learning in A, and SERN −
peer in B with Holm over every cell, peer and round.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

# Today's grid (the 20 N trial): world A = CELLS[0].
FORCES = {"20N": 20.0, "10N": 10.0}
FRICTIONS = {"mu0.3-0.8": (0.3, 0.8), "mu0.2-0.5": (0.2, 0.5)}
NOISES = ("clean", "d435")
CELLS = tuple(f"{f}_{m}_{n}" for f, m, n in itertools.product(FORCES, FRICTIONS, NOISES))
WORLD_A = CELLS[0]  # 20N_mu0.3-0.8_clean: the world the shipped θ0 was pretrained in
GRID = "20N trial"  # grid.json's and every cell file's "grid"
# The previous trial's grid (6 N θ0), a record in results/sensitivity_6N: its cells, in its
# order, and its world A; its files have the older per-seed format (no "label").
FORCES_6N = {"6N": 6.0, "20N": 20.0}
CELLS_6N = tuple(f"{f}_{m}_{n}" for f, m, n in itertools.product(FORCES_6N, FRICTIONS, NOISES))
WORLD_A_6N = CELLS_6N[0]  # 6N_mu0.3-0.8_clean
PEERS = ("greedy", "egreedy")

__all__ = ["CELLS", "WORLD_A", "CELLS_6N", "WORLD_A_6N", "TRANSFER_CELLS", "world",
           "transfer_world", "run_cell", "run_transfer_cell", "summarise",
           "summarise_transfer", "sensitivity_markdown", "transfer_markdown", "main"]


def world(cell: str):
    """(ContextConfig, TrialConfig) of a cell name ``<force>_<friction>_<noise>``: today's
    defaults with the cell's force, friction range and depth sensor. The previous grid's
    cells (``CELLS_6N``) are accepted too: they differ from today's defaults in the same
    three settings only where the name says so (their files record their own configs)."""
    from sern_jax.grasp.world import context, sim

    force, friction, noise = (cell.split("_") + ["", "", ""])[:3]
    if cell not in CELLS and cell not in CELLS_6N:
        raise ValueError(f"unknown cell {cell!r}; choose from {', '.join(CELLS)}")
    r = dataclasses.replace
    ctx, trial = context.ContextConfig(), sim.TrialConfig()
    ctx = r(ctx, scene=r(ctx.scene, finger_force={**FORCES_6N, **FORCES}[force]))
    if noise == "d435":
        ctx = r(ctx, noise=True, camera=r(ctx.camera, noise_model="realsense"))
    trial = r(trial, friction_range=FRICTIONS[friction])
    return ctx, trial


def _machine() -> dict:
    import jax

    model = ""
    try:
        with open("/proc/cpuinfo") as f:
            model = next((ln.split(":", 1)[1].strip() for ln in f
                          if ln.startswith("model name")), "")
    except OSError:
        pass
    return {"platform": platform.platform(), "processor": model or platform.processor(),
            "cpu_count": os.cpu_count(), "cores_used": len(os.sched_getaffinity(0)),
            "jax": jax.__version__, "jax_devices": [str(d) for d in jax.devices()],
            "python": platform.python_version()}


class GridMismatch(ValueError):
    """``--out`` holds a grid made with other settings (seeds, rounds, objects, θ0)."""


def _grid_settings(seeds: int, rounds: int, num_objects: int) -> dict:
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.world import sim

    theta0 = artifacts.load_theta0()
    return {"grid": GRID, "seeds": int(seeds), "rounds": int(rounds),
            "objects": artifacts.hard_set(theta0, num_objects)["objects"],
            "theta0_digest": theta0.fingerprint,
            "physics_defaults": sim.physics_settings()}


def check_grid(out: Path, seeds: int, rounds: int, num_objects: int,
               write: bool = True) -> dict:
    """Pins ``out/grid.json`` to these settings (written on first use); raises
    :class:`GridMismatch` naming what differs when ``out`` holds another grid, or the
    previous trial's files (no grid.json, per-seed files without a label)."""
    from sern_jax.infra import io

    want = json.loads(json.dumps(_grid_settings(seeds, rounds, num_objects)))
    f = Path(out) / "grid.json"
    if f.exists():
        have = io.load_json(f)
        diff = sorted(k for k in set(want) | set(have) if want.get(k) != have.get(k))
        if diff:
            raise GridMismatch(f"--out {out} holds a grid made with other {', '.join(diff)} "
                               "(choose another --out)")
    else:
        old = [p.name for p in Path(out).glob("*.json")
               if p.name != "summary.json" and "label" not in io.load_json(p)]
        if old:
            raise GridMismatch(f"--out {out} holds the previous trial's grid ({old[0]}, ...); "
                               "choose another --out")
        if write:
            io.save_json(f, want)
    return want


def run_cell(cell: str, out: Path, seeds: int, rounds: int, num_objects: int,
             progress: bool = False) -> dict:
    """Runs (or resumes) one cell of today's grid; writes ``out/<cell>.json``
    (``experiments.grasp_learning``'s per-seed format, with the world) and returns it.
    A cell whose file already holds every round is not rerun."""
    from sern_jax.infra import io
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.world import objects
    from sern_jax.grasp.online import config as config_lib
    from sern_jax.grasp.online import driver

    from . import grasp_learning

    if cell not in CELLS:
        raise ValueError(f"unknown cell {cell!r}; choose from {', '.join(CELLS)}")
    t0 = time.perf_counter()
    out = Path(out)
    grid = check_grid(out, seeds, rounds, num_objects)
    target = out / f"{cell}.json"
    if target.exists():
        done = io.load_json(target)
        if done.get("rounds_done") == rounds and not done.get("stopped_early"):
            return done
    ctx, trial = world(cell)
    theta0 = artifacts.load_theta0()
    names = grid["objects"]
    specs = [objects.make_object(n) for n in names]
    config = config_lib.OnlineConfig(num_seeds=seeds, rounds=rounds)
    command = (f"python -m experiments.grasp_sensitivity cell {cell} --out {out} "
               f"--seeds {seeds} --rounds {rounds} --objects {num_objects}")
    world_doc = {"grid": GRID, "grid_cell": cell,
                 "finger_force_N": ctx.scene.finger_force,
                 "friction_range": list(trial.friction_range),
                 "depth_noise": ctx.camera.noise_model if ctx.noise else "none"}
    run_dir = out / "runs" / cell
    io.save_json(run_dir / "run_meta.json", {
        "label": cell, "setting": "sensitivity", "objects": names, "all_objects": names,
        "config": dataclasses.asdict(config), "command": command, "file": f"{cell}.json",
        "theta0_dir": None, "trial_config": dataclasses.asdict(trial),
        "scene_config": dataclasses.asdict(ctx.scene), "extra": {"world": world_doc}})
    res = driver.run(config, specs, run_dir, theta0=theta0, progress=progress,
                     log=lambda *_: None, context_config=ctx, trial_config=trial)
    doc = grasp_learning.per_seed_doc(
        res["results"], label=cell, setting="sensitivity", objects=names, all_objects=names,
        config=config, rounds_done=rounds, seconds=time.perf_counter() - t0,
        command=command, theta0=theta0, trial_config=trial, scene_config=ctx.scene,
        extra={"world": world_doc, "timings": res["timings"],
               "trial_counts": res["trial_counts"]})
    grasp_learning.save_per_seed(target, doc)
    return doc


def _final_pooled(doc: dict, policy: str, metric: str = "lowvar_eval",
                  round_index: int = -1) -> np.ndarray:
    """[S] per-seed success of ``policy`` at ``round_index``, mean over objects."""
    a = np.asarray(doc[metric], np.float64)  # [R+1, O, Q, S]
    return a[round_index, :, doc["policies"].index(policy), :].mean(0)


def summarise(out: str | Path, level: float = 0.95) -> dict:
    """Paired differences per cell (t over seeds, Holm over every finished cell's
    comparisons) and the transfer table, from the saved ``<cell>.json`` files; writes
    ``summary.json``. Today's grid (per-seed files with a ``label``) or the previous
    trial's (``results/sensitivity_6N``, the older format); a directory holding both, or
    cells of another θ0, seeds, rounds, objects or world than its grid's, is refused."""
    from sern_jax.infra import io

    out = Path(out)
    files = [f for f in sorted(out.glob("*.json")) if f.name not in ("summary.json",
                                                                      "grid.json")]
    kinds = {"label" in io.load_json(f) for f in files}
    if not files:
        raise ValueError(f"no cell results in {out}")
    if kinds == {True, False}:
        raise ValueError(f"{out} mixes today's cell files with the previous trial's "
                         "(older format, no label): keep them in separate directories")
    if kinds == {False}:
        return _summarise_6N(out, level)
    return _summarise_today(out, level)


def _summarise_today(out: Path, level: float = 0.95) -> dict:
    from sern_jax.infra import io

    from . import grasp_learning

    docs = grasp_learning.load_results(out)
    unknown = sorted(set(docs) - set(CELLS))
    if unknown:
        raise ValueError(f"{out}: {unknown} are not cells of today's grid {CELLS}")
    docs = {c: docs[c] for c in CELLS if c in docs}
    first = next(iter(docs.values()))
    for cell, d in docs.items():
        ctx, trial = world(cell)
        want = json.loads(json.dumps({"setting": "sensitivity", "grid": GRID,
                                      "trial_config": dataclasses.asdict(trial),
                                      "scene_config": dataclasses.asdict(ctx.scene)}))
        have = {"setting": d["setting"], "grid": (d.get("world") or {}).get("grid"),
                "trial_config": d["trial_config"], "scene_config": d["scene_config"]}
        bad = [k for k in want if want[k] != have[k]]
        bad += [k for k in ("theta0_digest", "seeds", "rounds", "objects", "policies")
                if d[k] != first[k]]
        if bad:
            raise ValueError(f"{out}/{cell}.json differs from its grid in {', '.join(bad)}: "
                             "a cell of another trial, θ0 or run")
    grid_file = out / "grid.json"
    if grid_file.exists():
        g = io.load_json(grid_file)
        pinned = {"seeds": g["seeds"], "rounds": g["rounds"], "objects": g["objects"],
                  "theta0_digest": g["theta0_digest"]}
        if any(first[k] != v for k, v in pinned.items()):
            raise ValueError(f"{out}: the cells differ from grid.json")
    finished = {c: d for c, d in docs.items() if d["rounds_done"] == d["rounds"]}
    stopped = {c: int(d["rounds_done"]) for c, d in docs.items() if c not in finished}
    if not finished:
        raise ValueError(f"no finished cell in {out} (stopped: {stopped})")
    policies = first["policies"]
    peers = [p for p in PEERS if p in policies] + [p for p in policies
                                                    if p not in PEERS + ("sern",)]

    def pooled(d, pol, r):
        return d["lowvar_eval"][r, :, d["policies"].index(pol), :].mean(0)  # [S]

    names, diffs = [], []
    for cell, d in finished.items():
        for peer in peers:
            names.append(f"{cell}: sern - {peer}")
            diffs.append(pooled(d, "sern", -1) - pooled(d, peer, -1))
    comps = grasp_learning._comparisons(names, diffs)
    cells = {}
    for cell, d in finished.items():
        per_policy = {}
        for pol in policies:
            by_round = d["lowvar_eval"][:, :, policies.index(pol), :].mean((1, 2))
            per_policy[pol] = {
                "lowvar_by_round": [float(v) for v in by_round],
                "final": grasp_learning._ci(pooled(d, pol, -1)),
                "final_minus_theta0": grasp_learning._ci(pooled(d, pol, -1)
                                                         - pooled(d, pol, 0)),
            }
        cells[cell] = {
            "world": d["world"], "seeds": d["seeds"], "rounds": d["rounds"],
            "comparisons": {c["name"].split(": ")[1]: {k: v for k, v in c.items()
                                                       if k != "name"}
                            for c in comps if c["name"].startswith(cell + ":")},
            "policies": per_policy, "theta0": grasp_learning._ci(pooled(d, policies[0], 0)),
            "seconds": d["seconds"], "command": d["parts"][0]["command"],
            "machine": d["parts"][0]["machine"]}
    transfer = None
    if WORLD_A in finished:
        a0 = pooled(finished[WORLD_A], policies[0], 0)  # θ0 in A, per seed (policy-free)
        transfer = {}
        for cell, d in finished.items():
            b0 = pooled(d, policies[0], 0)
            gap = grasp_learning._ci(a0 - b0)
            row = {"theta0_A": float(a0.mean()), "theta0_B": float(b0.mean()), "gap": gap,
                   "policies": {}}
            for pol in policies:
                rec = {}
                for r in (1, d["rounds"]):
                    g = grasp_learning._ci(pooled(d, pol, r) - b0)
                    rec[f"gain_round{r}"] = g
                    rec[f"recovered_round{r}"] = (g["mean"] / gap["mean"]
                                                  if gap["mean"] > 0.02 else None)
                row["policies"][pol] = rec
            transfer[cell] = row
    summary = io.to_jsonable({
        "grid": GRID, "objects": first["objects"], "seeds": first["seeds"],
        "rounds": first["rounds"], "theta0_digest": first["theta0_digest"],
        "metric": "final-round fixed-pose greedy success, mean over the objects, per seed",
        "interval": (f"Student t over seeds (n - 1 dof), {level:.0%} per comparison; Holm "
                     f"over all {len(comps)} comparisons of the finished cells "
                     "(pvalue_holm, resolved)"),
        "cells": cells,
        "cells_stopped": stopped,
        "cells_missing": [c for c in CELLS if c not in docs],
        "sign_of_mean": {p: sorted({int(np.sign(round(c["comparisons"][f"sern - {p}"]
                                                      ["mean"], 9)))
                                    for c in cells.values()}) for p in peers},
        "resolved": [c["name"] for c in comps if c["resolved"]],
        "transfer": transfer,
        "transfer_note": ("gap = θ0's pooled fixed-pose success in world A minus in B "
                          "(round 0, paired by seed); gain_roundR = a policy's round-R "
                          "success in B minus θ0's in B (per seed); recovered_roundR = mean "
                          "gain / mean gap, only where the gap exceeds 2 points"),
    })
    io.save_json(out / "summary.json", summary)
    return summary


def _summarise_6N(out: Path, level: float = 0.95) -> dict:
    """The previous trial's grid (``results/sensitivity_6N``, older per-seed format), as it
    was summarised when it was made (its committed summary.json is this output)."""
    from sern_jax.infra import io
    from sern_jax.analysis import stats

    CELLS, WORLD_A = CELLS_6N, WORLD_A_6N  # the previous grid's
    docs = {c: io.load_json(out / f"{c}.json") for c in CELLS if (out / f"{c}.json").exists()}
    if not docs:
        raise ValueError(f"no cell results in {out}")
    names, diffs = [], []
    for cell, doc in docs.items():
        sern = _final_pooled(doc, "sern")
        for peer in PEERS:
            names.append(f"{cell}: sern - {peer}")
            diffs.append(sern - _final_pooled(doc, peer))
    seeds = {len(d) for d in diffs}
    if len(seeds) != 1:
        raise ValueError(f"cells have different seed counts {sorted(seeds)}")
    rows = stats.paired_differences(np.stack(diffs), names=names, level=level)
    cells = {}
    for cell, doc in docs.items():
        comp = {row.name.split(": ")[1]: {k: (round(v, 6) if isinstance(v, float) else v)
                                         for k, v in row._asdict().items() if k != "name"}
                for row in rows if row.name.startswith(cell + ":")}
        lv = np.asarray(doc["lowvar_eval"], np.float64)  # [R+1, O, Q, S]
        per_policy = {}
        for q, pol in enumerate(doc["policies"]):
            pooled = lv[:, :, q, :].mean(1)  # [R+1, S]
            per_policy[pol] = {
                "lowvar_by_round": [round(float(v), 5) for v in pooled.mean(1)],
                "round5_minus_theta0": t_dict(stats.t_interval(pooled[-1] - pooled[0], level)),
            }
        cells[cell] = {"world": doc["world"], "seeds": doc["seeds"], "comparisons": comp,
                       "policies": per_policy, "seconds": doc["seconds"],
                       "machine": doc["machine"]}
    transfer = None
    if WORLD_A in docs:
        a0 = _final_pooled(docs[WORLD_A], "greedy", round_index=0)  # θ0 in A, per seed
        transfer = {}
        for cell, doc in docs.items():
            b0 = _final_pooled(doc, "greedy", round_index=0)  # θ0 in B (policy-free)
            gap = float(a0.mean() - b0.mean())
            row = {"theta0_A": round(float(a0.mean()), 5), "theta0_B": round(float(b0.mean()), 5),
                   "gap": round(gap, 5), "policies": {}}
            for pol in doc["policies"]:
                rec = {}
                for r in (1, doc["rounds"]):
                    gain = float(_final_pooled(doc, pol, round_index=r).mean() - b0.mean())
                    rec[f"gain_round{r}"] = round(gain, 5)
                    rec[f"recovered_round{r}"] = (round(gain / gap, 3) if gap > 0.02 else None)
                row["policies"][pol] = rec
            transfer[cell] = row
    signs = {peer: sorted({int(np.sign(round(c["comparisons"][f"sern - {peer}"]["mean"], 9)))
                           for c in cells.values()}) for peer in PEERS}
    summary = {
        "metric": "final-round low-variance greedy success, mean over the objects, per seed",
        "interval": (f"Student t over seeds (n - 1 dof), {level:.0%} per comparison; Holm "
                     f"over all {len(rows)} comparisons (pvalue_holm, resolved); half_family "
                     "= Bonferroni simultaneous half-width"),
        "cells": cells,
        "cells_missing": [c for c in CELLS if c not in docs],
        "sign_of_mean": signs,
        "resolved": [r.name for r in rows if r.resolved],
        "transfer": transfer,
        "transfer_note": ("gap = θ0's pooled low-variance success in world A minus in B "
                          "(round 0); recovered_roundR = (policy's round-R success in B - "
                          "θ0's in B) / gap, reported only where the gap exceeds 2 points"),
    }
    io.save_json(out / "summary.json", summary)
    return summary


# ----------------------------------------------------------------------------- transfer

# Sim-to-sim transfer: θ0 pretrained in world A (the shipped trial, whatever its defaults
# are) meets a world B and learns online there for 20 rounds. Each cell is one world B (or A
# itself, the reference); every cell uses the first --objects of the shipped θ0's hard set.
TRANSFER_CELLS = ("A", "friction_low", "heavy", "d435", "grip_6N", "mjx", "theta0_6N")
THETA0_6N_DIR = Path(__file__).resolve().parent / "results" / "transfer" / "theta0_6N"
TRANSFER_NOTES = {
    "A": "world A itself: the shipped trial and θ0 (the reference)",
    "friction_low": "object friction ~ U[0.2, 0.5] instead of the default range",
    "heavy": "object mass scale ~ U[1.6, 2.5] instead of the default range (about twice "
             "as heavy)",
    "d435": "RealSense D435-like depth noise with missing pixels (contexts and evaluation)",
    "grip_6N": "6 N per finger instead of the default force (a weaker gripper)",
    "mjx": "MJX physics (mujoco-mjx on the GPU) instead of native MuJoCo for every trial",
    "theta0_6N": ("world A, met by the θ0 pretrained under the previous trial (6 N per "
                  "finger; its own core set), experiments/results/transfer/theta0_6N"),
}


def transfer_world(cell: str):
    """(ContextConfig, TrialConfig, backend, θ0 directory or None) of a transfer cell."""
    from sern_jax.grasp.world import context, sim

    if cell not in TRANSFER_CELLS:
        raise ValueError(f"unknown transfer cell {cell!r}; choose from {TRANSFER_CELLS}")
    ctx, trial = context.ContextConfig(), sim.TrialConfig()
    backend, theta0_dir = "native", None
    r = dataclasses.replace
    if cell == "friction_low":
        trial = r(trial, friction_range=(0.2, 0.5))
    elif cell == "heavy":
        trial = r(trial, mass_scale_range=(1.6, 2.5))
    elif cell == "d435":
        ctx = r(ctx, noise=True, camera=r(ctx.camera, noise_model="realsense"))
    elif cell == "grip_6N":
        ctx = r(ctx, scene=r(ctx.scene, finger_force=6.0))
    elif cell == "mjx":
        backend = "mjx"
    elif cell == "theta0_6N":
        theta0_dir = str(THETA0_6N_DIR)
    return ctx, trial, backend, theta0_dir


def run_transfer_cell(cell: str, out: Path, seeds: int, rounds: int, num_objects: int,
                      progress: bool = False) -> dict:
    """Runs one transfer cell; writes ``out/<cell>.json`` (grasp_learning's per-seed format,
    with the world) and returns it. A stopped run is turned into a file of the rounds it
    finished by ``experiments.grasp_learning collect out/runs out``."""
    from sern_jax.infra import io
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.world import objects
    from sern_jax.grasp.online import config as config_lib
    from sern_jax.grasp.online import driver

    from . import grasp_learning

    t0 = time.perf_counter()
    ctx, trial, backend, theta0_dir = transfer_world(cell)
    shipped = artifacts.load_theta0()
    names = artifacts.hard_set(shipped, num_objects)["objects"]  # the same objects everywhere
    theta0 = artifacts.load_theta0(theta0_dir) if theta0_dir else shipped
    specs = [objects.make_object(n) for n in names]
    config = config_lib.OnlineConfig(num_seeds=seeds, rounds=rounds, backend=backend)
    command = (f"python -m experiments.grasp_sensitivity transfer-cell {cell} --out {out} "
               f"--seeds {seeds} --rounds {rounds} --objects {num_objects}")
    world_doc = {"cell": cell, "note": TRANSFER_NOTES[cell],
                 "finger_force_N": ctx.scene.finger_force,
                 "friction_range": list(trial.friction_range),
                 "mass_scale_range": list(trial.mass_scale_range),
                 "depth_noise": ctx.camera.noise_model if ctx.noise else "none",
                 "backend": backend, "theta0_digest": theta0.fingerprint,
                 "shipped_theta0_digest": shipped.fingerprint}
    run_dir = out / "runs" / cell
    io.save_json(run_dir / "run_meta.json", {
        "label": cell, "setting": "transfer", "objects": names, "all_objects": names,
        "config": dataclasses.asdict(config), "command": command, "file": f"{cell}.json",
        "theta0_dir": theta0_dir, "trial_config": dataclasses.asdict(trial),
        "scene_config": dataclasses.asdict(ctx.scene),
        "extra": {"world": world_doc}})
    res = driver.run(config, specs, run_dir, theta0=theta0, progress=progress,
                     log=lambda *_: None, context_config=ctx, trial_config=trial)
    doc = grasp_learning.per_seed_doc(
        res["results"], label=cell, setting="transfer", objects=names, all_objects=names,
        config=config, rounds_done=rounds, seconds=time.perf_counter() - t0, command=command,
        theta0=theta0, trial_config=trial, scene_config=ctx.scene,
        extra={"world": world_doc, "timings": res["timings"],
               "trial_counts": res["trial_counts"]})
    grasp_learning.save_per_seed(out / f"{cell}.json", doc)
    return doc


def summarise_transfer(out, rounds=(1, 5, 20), level: float = 0.95) -> dict:
    """Per transfer cell and policy: θ0's pooled fixed-pose success in B against A (the gap,
    paired by seed), the gain online learning makes in B by each reported round (paired
    t-intervals over seeds), the share of the gap it recovers, the distance to the same
    policy learning in A, and SERN − peer in B (Holm over every cell, peer and round)."""
    from sern_jax.infra import io

    from . import grasp_learning

    out = Path(out)
    docs = grasp_learning.load_results(out)
    if "A" not in docs:
        raise ValueError(f"{out} has no world-A cell (A.json): the gap needs it")
    a = docs["A"]

    def pooled(doc, q, r):
        return doc["lowvar_eval"][r, :, q, :].mean(0)  # [S] mean over the objects

    theta_a = pooled(a, 0, 0)
    cells, names, diffs = {}, [], []
    for cell, d in docs.items():
        if d["objects"] != a["objects"] or d["seeds"] != a["seeds"]:
            raise ValueError(f"{cell}: objects or seeds differ from world A's")
        theta_b = pooled(d, 0, 0)
        done = d["rounds_done"]  # a stopped cell also reports its last finished round
        rep = sorted({r for r in rounds if r <= done} | ({done} if done >= 1 else set()))
        gap = grasp_learning._ci(theta_a - theta_b)
        row = {"world": d.get("world"), "rounds": d["rounds"], "rounds_done": d["rounds_done"],
               "rounds_reported": rep, "theta0_A": grasp_learning._ci(theta_a),
               "theta0_B": grasp_learning._ci(theta_b), "gap": gap, "policies": {},
               "seconds": d["seconds"], "machine": d["parts"][0]["machine"]}
        for q, pol in enumerate(d["policies"]):
            rec = {"by_round": [float(v) for v in
                                d["lowvar_eval"][:d["rounds_done"] + 1, :, q, :]
                                .mean((1, 2))],
                   "gain": {}, "recovered": {}, "minus_A": {}}
            qa = a["policies"].index(pol)
            for r in rep:
                g = grasp_learning._ci(pooled(d, q, r) - theta_b)
                rec["gain"][str(r)] = g
                # a share of a gap is reported only where the gap is resolved (its t
                # interval over seeds excludes 0): a share of an unresolved gap of a few
                # points (D435: +2.7 ± 6.2) is noise over noise
                rec["recovered"][str(r)] = (g["mean"] / gap["mean"] if gap["lower"] > 0
                                            else None)
                if r <= a["rounds_done"]:
                    rec["minus_A"][str(r)] = grasp_learning._ci(pooled(d, q, r)
                                                                - pooled(a, qa, r))
            row["policies"][pol] = rec
        if "sern" in d["policies"]:
            s = d["policies"].index("sern")
            for q, pol in enumerate(d["policies"]):
                if q != s:
                    for r in rep[1:] or rep:
                        names.append(f"{cell}: sern - {pol}, round {r}")
                        diffs.append(pooled(d, s, r) - pooled(d, q, r))
        cells[cell] = row
    comps = grasp_learning._comparisons(names, diffs) if names else []
    summary = io.to_jsonable({
        "objects": a["objects"], "seeds": a["seeds"], "cells": cells,
        "cells_missing": [c for c in TRANSFER_CELLS if c not in docs],
        "comparisons": comps,
        "metric": "fixed-pose greedy success, mean over the objects, per seed",
        "note": ("gap = θ0's success in A minus in B per seed (for theta0_6N: the shipped θ0 "
                 "minus the 6 N θ0, both in A); gain[r] = success at round r minus θ0's in B "
                 "per seed; recovered[r] = mean gain / mean gap (only where the gap is "
                 "resolved: its t interval excludes 0); minus_A[r] = success in B minus the same policy's in A at round "
                 "r; intervals 95 % Student t over seeds; comparisons: Holm over all of "
                 "them"),
    })
    io.save_json(out / "summary.json", summary)
    return summary


def transfer_markdown(summary: dict) -> str:
    """The transfer table of a summary, as markdown:
    per cell θ0's success in B and the gap to A (paired t over seeds), then per policy the
    gain by rounds 5 and 20 (t over seeds) and the share of the gap it recovers."""
    from .grasp_learning import _pm

    cells = summary["cells"]
    pols = list(next(iter(cells.values()))["policies"])
    head = ["world B", "θ0 in B", "gap A − B"]
    for pol in pols:
        head += [f"{pol}: gain by 5 / 20 rounds", f"{pol}: recovered"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cell, c in cells.items():
        stopped = c["rounds_done"] < c["rounds"]
        row = [cell + (f" (stopped after round {c['rounds_done']})" if stopped else ""),
               f"{100 * c['theta0_B']['mean']:.1f} %", _pm(c["gap"])]
        for pol in pols:
            rec = c["policies"][pol]
            last = str(c["rounds_done"])  # a stopped cell: its last finished round
            gains = [_pm(rec["gain"][str(r)]) if str(r) in rec["gain"] else
                     (f"{_pm(rec['gain'][last])} (round {last})" if stopped and r > int(last)
                      and last in rec["gain"] else "n/a") for r in (5, 20)]
            rcv = [f"{100 * rec['recovered'][k]:.0f} %" if rec["recovered"].get(k) is not None
                   else "–" for k in ("5", "20" if "20" in rec["gain"] or not stopped
                                      else last)]
            row += [" / ".join(gains), " / ".join(rcv)]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def grasp_learning_collect(out: Path) -> list:
    """Per-seed files (``stopped_early``) of the grid's cells stopped before their last
    round, from their checkpoints."""
    from . import grasp_learning

    return grasp_learning.collect(Path(out) / "runs", out) if (Path(out) / "runs").exists() \
        else []


def sensitivity_markdown(summary: dict) -> str:
    """The grid's table of a summary, as markdown:
    per finished cell θ0's and SERN's final fixed-pose success and SERN − each peer
    (95 % t half-widths over seeds; Holm-adjusted p over every comparison of the table)."""
    from .grasp_learning import _pm

    cells = summary["cells"]
    pols = next(iter(cells.values()))["policies"]
    peers = [p for p in PEERS if p in pols] + [p for p in pols if p not in PEERS + ("sern",)]
    names = {"greedy": "greedy", "egreedy": "ε-greedy"}
    head = ["cell (force, friction, depth)", "θ0", f"SERN round {summary['rounds']}"]
    for p in peers:
        head += [f"SERN − {names.get(p, p)}", "Holm p"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cell, c in cells.items():
        force, mu, noise = cell.split("_")
        lo, hi = mu[2:].split("-")
        label = (f"{force[:-1]} N, U[{lo}, {hi}], {'D435' if noise == 'd435' else 'clean'}"
                 + (" (world A)" if cell == WORLD_A else ""))
        row = [label, f"{100 * c['theta0']['mean']:.1f} %",
               f"{100 * c['policies']['sern']['final']['mean']:.1f} %"]
        for p in peers:
            comp = c["comparisons"][f"sern - {p}"]
            row += [_pm(comp), f"{comp['pvalue_holm']:.2f}"]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def t_dict(ci) -> dict:
    return {"mean": round(ci.mean, 6), "half": round(ci.half, 6), "n": ci.n}


def _run_grid(args, transfer: bool = False) -> int:
    out = Path(args.out)
    names = TRANSFER_CELLS if transfer else CELLS
    from sern_jax.infra import validate

    try:  # an unknown cell, an empty item or a repeated one: refused before any work
        cells = (validate.comma_list(args.cells, "--cells", choices=names) if args.cells
                 else list(names))
        validate.out_dir(out, "--out")
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    sub = "transfer-cell" if transfer else "cell"
    from sern_jax.infra import distributed

    try:
        ray = distributed.from_args(args)  # --ray [ADDRESS]: cells as Ray tasks
    except ValueError as exc:
        raise SystemExit(str(exc)) from None
    if ray is not None and args.deadline:
        raise SystemExit("--deadline applies to the worker processes, not --ray (stop the "
                         "run and rerun it: finished cells are kept)")
    if transfer:  # the mjx cell on Ray needs GPU tasks (distributed.check_backend)
        try:
            for c in cells:
                distributed.check_backend(transfer_world(c)[2], ray)
        except ValueError:
            print("error: --ray-gpus: the mjx cell on --ray needs --ray-gpus G > 0 (its tasks "
                  "would run MJX on their CPUs); leave it out with --cells", file=sys.stderr)
            return 2
    if not transfer:
        try:  # the grid's settings pinned in out/grid.json (refuses another grid's --out)
            check_grid(out, args.seeds, args.rounds, args.objects, write=False)
        except GridMismatch as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    out.mkdir(parents=True, exist_ok=True)
    if not transfer:
        check_grid(out, args.seeds, args.rounds, args.objects)

    def finished(c):
        f = out / f"{c}.json"
        if not f.exists():
            return False
        d = json.loads(f.read_text())
        return d.get("rounds_done", d.get("rounds")) == d.get("rounds") and not d.get(
            "stopped_early")

    todo = [c for c in cells if not finished(c)]
    if ray is not None and todo:
        # the module by its package name (not __main__), which every worker imports
        import importlib

        mod = importlib.import_module(__spec__.name if __spec__ else __name__)
        fn = mod.run_transfer_cell if transfer else mod.run_cell
        try:
            distributed.run_units(
                [distributed.Unit(f"{c}.json", fn, (c, out.resolve(), args.seeds,
                                                     args.rounds, args.objects))
                 for c in todo], ray, out, progress=False, desc="cells")
        except distributed.UnitFailedError as exc:
            raise SystemExit(str(exc)) from None
        todo = []
    cores = sorted(os.sched_getaffinity(0))
    workers = max(1, min(args.workers, len(todo) or 1))
    share = max(1, len(cores) // workers)
    env = dict(os.environ, XLA_PYTHON_CLIENT_PREALLOCATE="false", PYTHONUNBUFFERED="1")
    t0 = time.perf_counter()
    running: dict[str, tuple[subprocess.Popen, object]] = {}
    slots = list(range(workers))
    log = open(out / "workers.log", "a")
    while todo or running:
        while todo and slots:
            slot = slots.pop(0)
            cell = todo.pop(0)
            mine = cores[slot * share:(slot + 1) * share] or cores
            cmd = [sys.executable, "-m", "experiments.grasp_sensitivity", sub, cell,
                   "--out", str(out), "--seeds", str(args.seeds), "--rounds",
                   str(args.rounds), "--objects", str(args.objects)]
            proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT,
                                    preexec_fn=lambda m=tuple(mine): os.sched_setaffinity(0, m))
            running[cell] = (proc, slot)
            print(f"[{time.perf_counter() - t0:6.0f} s] start {cell} on cores {mine}",
                  flush=True)
        time.sleep(2)
        for cell, (proc, slot) in list(running.items()):
            if proc.poll() is not None:
                print(f"[{time.perf_counter() - t0:6.0f} s] done {cell} (exit "
                      f"{proc.returncode})", flush=True)
                del running[cell]
                slots.append(slot)
        if args.deadline and time.perf_counter() - t0 > args.deadline:
            for cell, (proc, _) in running.items():
                proc.kill()
                print(f"stopped {cell} at the deadline" + ("" if transfer else ": not run"),
                      flush=True)
            running.clear()
            todo.clear()
    log.close()
    if transfer:
        from . import grasp_learning

        for f in grasp_learning.collect(out / "runs", out):
            print(f"wrote {f} from its last checkpoint (stopped early)", flush=True)
        summary = summarise_transfer(out)
        for cell, c in summary["cells"].items():
            last = c["rounds_reported"][-1] if c["rounds_reported"] else None
            parts = [f"{p} {100 * v['gain'][str(last)]['mean']:+.1f}" for p, v in
                     c["policies"].items() if last]
            print(f"{cell:>12s}: θ0 {100 * c['theta0_B']['mean']:.1f} %, gap "
                  f"{100 * c['gap']['mean']:+.1f}; gain at round {last}: " + ", ".join(parts))
        print(f"wrote {out / 'summary.json'} ({time.perf_counter() - t0:.0f} s)")
        return 0
    for f in grasp_learning_collect(out):
        print(f"wrote {f} from its last checkpoint (stopped early)", flush=True)
    summary = summarise(out)
    for cell, c in summary["cells"].items():
        parts = [f"{k} {100 * v['mean']:+.1f} ± {100 * v['half']:.1f}"
                 f"{' *' if v['resolved'] else ''}" for k, v in c["comparisons"].items()]
        print(f"{cell:>22s}: " + "; ".join(parts))
    for cell, done in summary.get("cells_stopped", {}).items():
        print(f"{cell:>22s}: stopped after round {done} (rerun the command to resume)")
    print("(* = sign resolved after Holm over all comparisons; intervals: 95 % t over "
          "seeds)")
    print(f"wrote {out / 'summary.json'} ({time.perf_counter() - t0:.0f} s)")
    return 0


def main(argv=None) -> int:
    from sern_jax.infra import validate

    # bad input: one line naming the flag, exit 2, before any compile (validate's parser;
    # the subcommands' parsers are of its class)
    parser = validate.script_parser(__spec__, description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p_run = sub.add_parser("run", help="run the grid's cells in worker processes")
    p_cell = sub.add_parser("cell", help="run one cell in this process")
    p_cell.add_argument("cell", choices=CELLS)
    for p in (p_run, p_cell):
        p.add_argument("--out", default="runs/sensitivity")
        p.add_argument("--seeds", type=validate.int_in(2, 10_000), default=10)
        p.add_argument("--rounds", type=validate.int_in(1, 10_000), default=5)
        p.add_argument("--objects", type=validate.int_in(1, 1000), default=6)
    p_run.add_argument("--cells", default="", help="comma-separated subset (default: all)")
    p_run.add_argument("--workers", type=validate.int_in(1, 4096), default=8)
    p_run.add_argument("--deadline", type=validate.float_in(0.0), default=0.0,
                       help="seconds after which running cells are stopped (0 = none)")
    from sern_jax.infra import distributed

    distributed.add_arguments(p_run)
    p_sum = sub.add_parser("summarise", help="summary.json from saved cells")
    p_sum.add_argument("out")
    p_tr = sub.add_parser("transfer", help="run the transfer cells in worker processes")
    p_tcell = sub.add_parser("transfer-cell", help="run one transfer cell in this process")
    p_tcell.add_argument("cell", choices=TRANSFER_CELLS)
    for p in (p_tr, p_tcell):
        p.add_argument("--out", default="runs/transfer")
        p.add_argument("--seeds", type=validate.int_in(2, 10_000), default=5)
        p.add_argument("--rounds", type=validate.int_in(1, 10_000), default=20)
        p.add_argument("--objects", type=validate.int_in(1, 1000), default=3)
    p_tr.add_argument("--cells", default="", help="comma-separated subset (default: all)")
    p_tr.add_argument("--workers", type=validate.int_in(1, 4096), default=7)
    p_tr.add_argument("--deadline", type=validate.float_in(0.0), default=0.0,
                      help="seconds after which running cells are stopped and their "
                           "finished rounds collected (0 = none)")
    distributed.add_arguments(p_tr)
    p_tsum = sub.add_parser("transfer-summarise", help="summary.json from saved cells")
    p_tsum.add_argument("out")
    args = parser.parse_args(argv)
    if args.what in ("summarise", "transfer-summarise"):
        try:  # bad input (no cell files, mixed grids, ...): one line, exit 2, nothing written
            s = (summarise if args.what == "summarise" else summarise_transfer)(args.out)
        except (ValueError, OSError) as exc:
            print(f"{args.what} OUT: {exc}", file=sys.stderr)
            return 2
    if args.what == "transfer-summarise":
        print(json.dumps({"cells_missing": s["cells_missing"],
                          "resolved": [c["name"] for c in s["comparisons"] if c["resolved"]]},
                         indent=1))
        return 0
    if args.what == "summarise":
        print(json.dumps({"resolved": s["resolved"], "sign_of_mean": s["sign_of_mean"],
                          "cells_missing": s["cells_missing"]}, indent=1))
        return 0
    for name in ("seeds", "rounds", "objects"):
        if getattr(args, name) < (2 if name == "seeds" else 1):
            parser.error(f"--{name} must be >= {2 if name == 'seeds' else 1}")
    if args.what == "cell":
        try:
            check_grid(Path(args.out), args.seeds, args.rounds, args.objects, write=False)
        except GridMismatch as exc:
            parser.error(str(exc))
        doc = run_cell(args.cell, Path(args.out), args.seeds, args.rounds, args.objects)
        print(f"{args.cell}: {doc['seconds']:.0f} s")
        return 0
    if args.what == "transfer-cell":
        doc = run_transfer_cell(args.cell, Path(args.out), args.seeds, args.rounds,
                                args.objects)
        print(f"{args.cell}: {doc['seconds']:.0f} s")
        return 0
    if args.workers < 1:
        parser.error("--workers must be >= 1")
    return _run_grid(args, transfer=args.what == "transfer")


if __name__ == "__main__":
    raise SystemExit(main())
