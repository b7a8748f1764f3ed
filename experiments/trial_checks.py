"""Is the grasp trial defensible? Two checks on one fixed set of paired trials.

* ``timestep``: the same grasps, poses and trial noise simulated at the default physics
  step (5 ms) and at half and a quarter of it (``sim.refine``: the same physical schedule
  in 2x / 4x as many steps); the fraction of trials whose outcome (success or failure)
  agrees with the default step's, with Clopper–Pearson 95 % intervals. Target: >= 95 %.
* ``grip``: the same trials with the default grip (``SceneConfig().finger_force``: 20 N
  per finger since 2026-11-24, a Robotiq 2F-85 at its lowest setting) and with other
  grips (``--forces``, default 6 N, the trial before, and 40 N): how many outcomes flip,
  in each direction, and the success rates, overall and per object.

The fixed set: ``--objects`` (default: the six objects of the first check, which were
the hard set of the 6 N θ0, and the five solid-steel industrial parts), ``--poses``
resting poses each (``context.make_contexts`` with key ``fold_in(key(seed), object
index)``), up to ``--candidates`` valid candidates per pose drawn without replacement
(numpy ``default_rng([seed, object, pose])``), one randomised trial each
(``sim.sample_noise`` with key ``fold_in(fold_in(key(seed), object index), 1)``): common
random numbers across settings, so each trial is paired with itself. The first six
objects use the seeds of the 6 N check (``experiments/results/trial_checks/trial_checks_6N.json``), but
their resting poses, and so the grasps, differ from it: the drop that makes a resting pose
runs with the scene's solver settings, which changed with the grip (20 / 20 Newton
iterations). Contexts are made with the default scene; only the trials change setting.

    python -m experiments.trial_checks --out experiments/results/trial_checks/trial_checks.json
"""

from __future__ import annotations

import os
import platform
import sys
import time

import numpy as np

DEFAULT_OBJECTS = ("triangular_prism", "pipe_tee", "tless_part_a", "handle_jug",
                   "tless_part_b", "tless_part_c", "pipe_tee_steel", "bracket_steel",
                   "tless_part_a_steel", "tless_part_b_steel", "tless_part_c_steel")


def fixed_trials(names, poses: int, candidates: int, seed: int):
    """[(spec, grasps [n, 4], object poses [n, 7], TrialNoise [n])] per object."""
    import jax

    from sern_jax.grasp.world import context, objects, sim

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
             threads: int | None = None, backend: str = "native") -> np.ndarray:
    """[N] bool successes of the fixed trials in one setting (all objects, concatenated);
    ``backend="mjx"``: the MJX backend's one program for every object (uniform scenes)."""
    import dataclasses

    from sern_jax.grasp.world import context, scene, sim

    base = scene.SceneConfig()
    cfg = dataclasses.replace(base, timestep=base.timestep / timestep_factor,
                              finger_force=finger_force or base.finger_force)
    trial = sim.refine(sim.TrialConfig(), timestep_factor)
    res = []
    for spec, g, p, noise in trials:
        model = context.scene_model(spec, context.ContextConfig(scene=cfg))
        simulator = sim.GraspSimulator(model, backend, config=trial,
                                       num_threads=threads if backend == "native" else None)
        r = simulator.run_trials(g, noise, object_pose=p)
        res.append(r.success & ~r.nan)
    return np.concatenate(res)


def _agree(a, b) -> dict:
    from sern_jax.analysis import stats

    k, n = int(np.sum(a == b)), len(a)
    lo, hi = stats.clopper_pearson(k, n, 0.95)
    return {"agree": k, "n": n, "fraction": k / n, "ci95": [float(lo), float(hi)],
            "a_only": int(np.sum(a & ~b)), "b_only": int(np.sum(~a & b))}


def _per_object(sizes, names, *outs) -> dict:
    edges = np.cumsum([0] + list(sizes))
    return {n: [float(o[edges[i]:edges[i + 1]].mean()) for o in outs]
            for i, n in enumerate(names)}


def main(argv=None) -> int:
    from sern_jax.infra import validate

    # bad input: one line naming the flag, exit 2, before any compile (validate's parser)
    ap = validate.script_parser(__spec__, description=__doc__.splitlines()[0])
    count = validate.int_at_least(1)
    ap.add_argument("--objects", default=",".join(DEFAULT_OBJECTS),
                    help="comma-separated object names")
    ap.add_argument("--poses", type=count, default=4)
    ap.add_argument("--candidates", type=count, default=16)
    ap.add_argument("--seed", type=validate.int_in(0, 2**31 - 1), default=0)
    ap.add_argument("--forces", default="6,40",
                    help="grips (newtons per finger) to compare with the default")
    ap.add_argument("--steps", default="2,4",
                    help="time-step divisors to compare with the default 5 ms step")
    ap.add_argument("--mjx", action="store_true",
                    help="also run the trials with MJX (one program for every object) and "
                         "report its agreement with native MuJoCo")
    ap.add_argument("--threads", type=count, default=None)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    try:  # the output file before any work (nothing is left behind by the check)
        validate.out_file(args.out, "--out")
        names = validate.comma_list(args.objects, "--objects")
    except ValueError as exc:
        ap.error(str(exc))
    try:
        forces = (validate.comma_list_of(args.forces, "--forces", float, "numbers")
                  if args.forces else [])
        steps = validate.comma_list_of(args.steps, "--steps", int, "integers")
    except ValueError as exc:
        ap.error(str(exc))
    if not steps or any(not (2 <= k <= 16) for k in steps):
        ap.error("--steps must list integers in [2, 16]")
    if any(not (0 < f < 1e6) for f in forces):
        ap.error("--forces must lie in (0, 1e6) newtons")
    from sern_jax.grasp.world import objects as objects_lib

    if not names:
        ap.error("--objects must name at least one object")
    for n in names:
        try:
            objects_lib.make_object(n)
        except ValueError:
            ap.error(f"--objects: unknown object {n!r}")

    from sern_jax.infra import io
    from sern_jax.grasp.world import scene, sim

    default_force = scene.SceneConfig().finger_force
    t0 = time.perf_counter()
    trials = fixed_trials(names, args.poses, args.candidates, args.seed)
    sizes = [len(t[1]) for t in trials]
    base = outcomes(trials, 1, threads=args.threads)
    res = {"objects": names, "trials_per_object": sizes,
           "default_force_N": default_force, "gripper": scene.GRIPPER,
           "physics": sim.physics_settings(),
           "default_success": float(base.mean()),
           "default_success_per_object": _per_object(sizes, names, base),
           "timestep": {}, "grip": {}}
    by_dt = {1: base}
    for k in steps:
        by_dt[k] = outcomes(trials, k, threads=args.threads)
        res["timestep"][f"5ms_vs_{5 / k:g}ms"] = _agree(base, by_dt[k])
    if 2 in by_dt and 4 in by_dt:
        res["timestep"]["2.5ms_vs_1.25ms"] = _agree(by_dt[2], by_dt[4])
    res["timestep"]["success"] = {f"{5 / k:g}ms": float(v.mean()) for k, v in by_dt.items()}
    res["timestep"]["success_per_object"] = _per_object(sizes, names, *by_dt.values())
    if args.mjx:
        out_mjx = outcomes(trials, 1, backend="mjx")
        row = _agree(base, out_mjx)
        row["success"] = {"native": float(base.mean()), "mjx": float(out_mjx.mean())}
        row["per_object_success"] = _per_object(sizes, names, base, out_mjx)
        row["per_object_agree"] = _per_object(sizes, names, base == out_mjx)
        row["native_only"], row["mjx_only"] = row.pop("a_only"), row.pop("b_only")
        res["mjx"] = row
    for f in forces:
        out_f = outcomes(trials, 1, finger_force=f, threads=args.threads)
        row = _agree(base, out_f)
        row["success"] = float(out_f.mean())
        row["fail_at_default_success_at_f"] = row.pop("b_only")
        row["success_at_default_fail_at_f"] = row.pop("a_only")
        # per object: [success at the default grip, success at f]
        row["per_object_success"] = _per_object(sizes, names, base, out_f)
        res["grip"][f"{f:g}N"] = row
    res["seconds"] = round(time.perf_counter() - t0, 1)
    res["command"] = "python -m experiments.trial_checks " + " ".join(
        argv if argv is not None else sys.argv[1:])
    res["machine"] = {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                      "load_average": os.getloadavg()}
    print(f"default grip {default_force:g} N: success {100 * res['default_success']:.1f} % "
          f"of {len(base)} trials")
    for n, (v,) in res["default_success_per_object"].items():
        print(f"  {n:>20s} {100 * v:5.1f} %")
    for k, v in res["timestep"].items():
        if "agree" in v:
            print(f"time step {k}: {v['agree']}/{v['n']} agree ({100 * v['fraction']:.1f} %, "
                  f"95 % CI {100 * v['ci95'][0]:.1f}-{100 * v['ci95'][1]:.1f} %)")
    print("success by step:", res["timestep"]["success"])
    if "mjx" in res:
        v = res["mjx"]
        print(f"native vs MJX: {v['agree']}/{v['n']} agree ({100 * v['fraction']:.1f} %, 95 % CI "
              f"{100 * v['ci95'][0]:.1f}-{100 * v['ci95'][1]:.1f} %)")
    for k, v in res["grip"].items():
        print(f"{default_force:g} N vs {k}: success {100 * res['default_success']:.1f} % -> "
              f"{100 * v['success']:.1f} %; {v['fail_at_default_success_at_f']} failures "
              f"become successes, {v['success_at_default_fail_at_f']} successes become "
              f"failures (of {v['n']})")
    if args.out:
        io.save_json(args.out, res)
        print(f"wrote {args.out} ({res['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
