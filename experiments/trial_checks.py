"""Is the grasp trial defensible? Two checks on one fixed set of paired trials.

* ``timestep``: the same grasps, poses and trial noise simulated at the default physics
  step (5 ms) and at half and a quarter of it (``sim.refine``: the same physical schedule
  in 2x / 4x as many steps); the fraction of trials whose outcome (success or failure)
  agrees with the default step's, with Clopper–Pearson 95 % intervals. Target: >= 95 %.
* ``grip``: the same trials with 6 N per finger (the default) and with stronger grips
  (20 N, 40 N): how many outcomes flip, in each direction, and the success rates.

The fixed set: the hard set's objects (``artifacts.hard_set``), ``--poses`` resting poses
each (``context.make_contexts`` with key ``fold_in(key(seed), object index)``), up to
``--candidates`` valid candidates per pose drawn without replacement (numpy
``default_rng([seed, object, pose])``), one randomised trial each (``sim.sample_noise`` with
key ``fold_in(fold_in(key(seed), object index), 1)``): common random numbers across
settings, so each trial is paired with itself.

    python -m experiments.trial_checks --out experiments/results/trial_checks.json
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np


def fixed_trials(num_objects: int, poses: int, candidates: int, seed: int):
    """[(spec, grasps [n, 4], object poses [n, 7], TrialNoise [n])] per object."""
    import jax

    from sern_jax.grasp import artifacts, context, objects, sim

    theta0 = artifacts.load_theta0()
    names = artifacts.hard_set(theta0, num_objects)["objects"]
    root = jax.random.key(seed)
    out = []
    for o, name in enumerate(names):
        spec = objects.make_object(name)
        key = jax.random.fold_in(root, o)
        ctx = context.make_contexts(key, spec, poses, context.ContextConfig(renderer="native"))
        valid = np.asarray(ctx.candidates.valid, bool)
        grasps = np.asarray(ctx.candidates.grasps, np.float64)
        g, p = [], []
        for i in range(poses):
            idx = np.flatnonzero(valid[i])
            rng = np.random.default_rng([seed, o, i])
            pick = rng.choice(idx, size=min(candidates, len(idx)), replace=False)
            g.append(grasps[i, pick])
            p.append(np.repeat(np.asarray(ctx.poses)[i][None], len(pick), 0))
        g, p = np.concatenate(g), np.concatenate(p)
        noise = sim.sample_noise(jax.random.fold_in(key, 1), len(g))
        out.append((spec, g, p, noise))
    return out


def outcomes(trials, timestep_factor: int = 1, finger_force: float | None = None,
             threads: int | None = None) -> np.ndarray:
    """[N] bool successes of the fixed trials in one setting (all objects, concatenated)."""
    import dataclasses

    from sern_jax.grasp import context, scene, sim

    base = scene.SceneConfig()
    cfg = dataclasses.replace(base, timestep=base.timestep / timestep_factor,
                              finger_force=finger_force or base.finger_force)
    trial = sim.refine(sim.TrialConfig(), timestep_factor)
    res = []
    for spec, g, p, noise in trials:
        model = context.scene_model(spec, context.ContextConfig(scene=cfg))
        simulator = sim.GraspSimulator(model, "native", config=trial, num_threads=threads)
        r = simulator.run_trials(g, noise, object_pose=p)
        res.append(r.success & ~r.nan)
    return np.concatenate(res)


def _agree(a, b) -> dict:
    from sern_jax import stats

    k, n = int(np.sum(a == b)), len(a)
    lo, hi = stats.clopper_pearson(k, n, 0.95)
    return {"agree": k, "n": n, "fraction": k / n, "ci95": [float(lo), float(hi)],
            "a_only": int(np.sum(a & ~b)), "b_only": int(np.sum(~a & b))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", type=int, default=6)
    ap.add_argument("--poses", type=int, default=4)
    ap.add_argument("--candidates", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--forces", default="20,40", help="grips to compare with 6 N (newtons)")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    for name in ("objects", "poses", "candidates"):
        if getattr(args, name) < 1:
            ap.error(f"--{name} must be >= 1")
    forces = [float(f) for f in args.forces.split(",") if f]

    from sern_jax import io

    t0 = time.perf_counter()
    trials = fixed_trials(args.objects, args.poses, args.candidates, args.seed)
    sizes = [len(t[1]) for t in trials]
    base = outcomes(trials, 1, threads=args.threads)
    times = {}
    res = {"objects": [t[0].name for t in trials], "trials_per_object": sizes,
           "default_success": float(base.mean()), "timestep": {}, "grip": {}}
    by_dt = {1: base}
    for k in (2, 4):
        t = time.perf_counter()
        by_dt[k] = outcomes(trials, k, threads=args.threads)
        times[f"dt/{k}"] = time.perf_counter() - t
        res["timestep"][f"5ms_vs_{5 / k:g}ms"] = _agree(base, by_dt[k])
    res["timestep"]["2.5ms_vs_1.25ms"] = _agree(by_dt[2], by_dt[4])
    res["timestep"]["success"] = {f"{5 / k:g}ms": float(v.mean()) for k, v in by_dt.items()}
    for f in forces:
        out_f = outcomes(trials, 1, finger_force=f, threads=args.threads)
        row = _agree(base, out_f)
        row["success"] = float(out_f.mean())
        row["fail_at_6N_success_at_f"] = row.pop("b_only")
        row["success_at_6N_fail_at_f"] = row.pop("a_only")
        # per object: where the flips are
        edges = np.cumsum([0] + sizes)
        row["per_object_success"] = {
            t[0].name: [float(base[edges[i]:edges[i + 1]].mean()),
                        float(out_f[edges[i]:edges[i + 1]].mean())]
            for i, t in enumerate(trials)}
        res["grip"][f"{f:g}N"] = row
    res["seconds"] = round(time.perf_counter() - t0, 1)
    res["command"] = "python -m experiments.trial_checks " + " ".join(
        argv if argv is not None else sys.argv[1:])
    res["machine"] = {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                      "load_average": os.getloadavg()}
    for k, v in res["timestep"].items():
        if "agree" in v:
            print(f"time step {k}: {v['agree']}/{v['n']} agree ({100 * v['fraction']:.1f} %, "
                  f"95 % CI {100 * v['ci95'][0]:.1f}-{100 * v['ci95'][1]:.1f} %)")
    print("success by step:", res["timestep"]["success"])
    for k, v in res["grip"].items():
        print(f"6 N vs {k}: success {100 * res['default_success']:.1f} % -> "
              f"{100 * v['success']:.1f} %; {v['fail_at_6N_success_at_f']} failures become "
              f"successes, {v['success_at_6N_fail_at_f']} successes become failures "
              f"(of {v['n']})")
    if args.out:
        io.save_json(args.out, res)
        print(f"wrote {args.out} ({res['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
