"""Hard-object screen: how much is there to learn on each object?

For each object and each of P random resting poses (``scene.build_scene(spec, seed=pose
seed)``), one overhead depth image, its K = 64 antipodal candidates, and each valid
candidate's success probability from M randomised native trials. Per object it reports

* ``mean_candidate``: mean success of the valid candidates over all poses (what a picker
  that cannot tell candidates apart gets; a proxy for a net trained elsewhere),
* ``frac_poses_best_ge_0.8``: fraction of poses whose largest candidate frequency is
  >= 0.8 (biased upward: the maximum of many noisy frequencies),
* ``frac_poses_best_fresh_ge_0.8``: the same with each pose's best candidate (the argmax
  of the screening trials) valued on M fresh, independent trials (there is something to
  learn; the screen uses this one),
* ``frac_candidates_ge_0.8``: fraction of valid candidates >= 0.8 (how rare good grasps
  are),
* the spread: std, quartiles of the valid candidates' success, and the mean per-pose std.

An object is a *screen candidate* when ``mean_candidate <= 0.5`` and
``frac_poses_best_fresh_ge_0.8 >= 0.75``: good grasps exist in most poses but are a
minority.

Deterministic given ``--seed``: pose p of every object uses resting-pose seed
``1000 * seed + p``; its candidate and trial keys are ``fold_in(fold_in(key(seed), p), i)``
for i = 0 (candidates), 1 (trials), 2 (the fresh trials of the best candidate), so two
objects see the same trial noise.

Usage::

    python -m experiments.hard_objects --objects triangular_prism,box --poses 8 \\
        --trials 16 --out runs/hard_objects.json
"""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

__all__ = ["measure_object", "summarise", "main", "DEFAULT_OBJECTS"]

DEFAULT_OBJECTS = "hard,box,cylinder,sphere,l_shape"
GOOD = 0.8


def _pipeline():
    """Jitted depth renderer and candidate sampler (shared across objects)."""
    import jax

    from sern_jax.grasp.world import candidates as cand_lib
    from sern_jax.grasp.world import depth as depth_lib

    camera = depth_lib.CameraConfig()
    params = depth_lib.overhead_params(camera)
    render = jax.jit(lambda m, d, p: depth_lib.render(camera, m, d, p))
    cand_config = cand_lib.CandidateConfig()
    sample = jax.jit(lambda k, d, p: cand_lib.sample(cand_config, k, d, p))
    return camera, params, render, sample


def context(spec, pose_seed: int, key, pipeline=None):
    """(model, Candidates as numpy) for one resting pose of ``spec``."""
    import jax

    from sern_jax.grasp.world import depth as depth_lib
    from sern_jax.grasp.world import scene as scene_lib

    _, params, render, sample = pipeline or _pipeline()
    model = scene_lib.build_scene(spec, seed=pose_seed)
    data = scene_lib.initial_data(model)
    image = render(depth_lib.camera_model(model), depth_lib.geom_poses(data), params)
    cands = sample(key, image.depth, params)
    return model, jax.tree.map(np.asarray, cands)


def measure_object(spec, poses: int, trials: int, seed: int, num_threads=None,
                   pipeline=None) -> dict:
    """Per-pose candidate success probabilities of one object (see the module doc)."""
    import jax

    from sern_jax.grasp.world import sim as sim_lib

    pipeline = pipeline or _pipeline()
    root = jax.random.key(seed)
    out = {"object": spec.name, "category": spec.category, "kind": spec.kind,
           "poses": []}
    t0 = time.perf_counter()
    for p in range(poses):
        kp = jax.random.fold_in(root, p)
        pose_seed = 1000 * seed + p
        model, cands = context(spec, pose_seed, jax.random.fold_in(kp, 0), pipeline)
        valid = np.asarray(cands.valid, bool)
        prob = np.zeros(len(valid))
        nan = 0
        if valid.any():
            est = sim_lib.GraspSimulator(model, "native", num_threads=num_threads)\
                .success_probability(jax.random.fold_in(kp, 1), cands.grasps, trials,
                                     valid=valid)
            prob = np.asarray(est.prob, np.float64)
            nan = int(np.sum(est.nan_count))
            best = int(np.argmax(np.where(valid, prob, -1.0)))
            fresh = sim_lib.GraspSimulator(model, "native", num_threads=num_threads)\
                .success_probability(jax.random.fold_in(kp, 2), cands.grasps[best][None],
                                     trials)
            best_fresh = float(fresh.prob[0])
        out["poses"].append({"pose_seed": pose_seed, "valid": valid.tolist(),
                             "prob": [round(float(v), 4) for v in prob],
                             "best_fresh": round(best_fresh, 4) if valid.any() else 0.0,
                             "nan_trials": nan})
    out["seconds"] = round(time.perf_counter() - t0, 1)
    out.update(summarise(out["poses"]))
    return out


def summarise(pose_records) -> dict:
    """Summary statistics over an object's poses (valid candidates only)."""
    probs = [np.asarray(r["prob"])[np.asarray(r["valid"], bool)] for r in pose_records]
    allp = np.concatenate(probs) if probs else np.zeros(0)
    best = np.array([p.max() if p.size else 0.0 for p in probs])
    fresh = np.array([r.get("best_fresh", np.nan) for r in pose_records], np.float64)
    if allp.size == 0:
        return {"num_valid": 0}
    q1, med, q3 = np.quantile(allp, [0.25, 0.5, 0.75])
    s = {
        "num_valid": int(allp.size),
        "valid_per_pose_min": int(min(p.size for p in probs)),
        "mean_candidate": float(allp.mean()),
        "frac_poses_best_ge_0.8": float(np.mean(best >= GOOD)),
        "frac_poses_best_fresh_ge_0.8": float(np.mean(fresh >= GOOD)),
        "frac_candidates_ge_0.8": float(np.mean(allp >= GOOD)),
        "best_per_pose": [round(float(b), 3) for b in best],
        "mean_per_pose": [round(float(p.mean()), 3) if p.size else None for p in probs],
        "std": float(allp.std()),
        "mean_pose_std": float(np.mean([p.std() for p in probs if p.size])),
        "quartiles": [float(q1), float(med), float(q3)],
        "nan_trials": int(sum(r["nan_trials"] for r in pose_records)),
    }
    s["screen_candidate"] = bool(s["mean_candidate"] <= 0.5
                                 and s["frac_poses_best_fresh_ge_0.8"] >= 0.75)
    return s


def _object_list(text: str) -> list[str]:
    from sern_jax.grasp.world import objects as objects_lib

    names = []
    for item in text.split(","):
        item = item.strip()
        if item == "hard":
            names += list(objects_lib.hard_object_names())
        elif item:
            names.append(item)
    return list(dict.fromkeys(names))


def table(results) -> str:
    rows = ["| object | mean cand. | poses max>=0.8 (biased) | poses best>=0.8 (fresh) | "
            "cand. >=0.8 | std | quartiles | valid | screen |",
            "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        if not r.get("num_valid"):
            rows.append(f"| {r['object']} | no valid candidates | | | | | | 0 | |")
            continue
        q = "/".join(f"{v:.2f}" for v in r["quartiles"])
        rows.append(
            f"| {r['object']} | {r['mean_candidate']:.2f} | "
            f"{r['frac_poses_best_ge_0.8']:.2f} | {r['frac_poses_best_fresh_ge_0.8']:.2f} | "
            f"{r['frac_candidates_ge_0.8']:.2f} | "
            f"{r['std']:.2f} | {q} | {r['num_valid']} | "
            f"{'yes' if r['screen_candidate'] else ''} |")
    return "\n".join(rows)


def main(argv=None) -> int:
    from sern_jax.infra import validate

    # bad input: one line naming the flag, exit 2, before any compile (validate's parser)
    ap = validate.script_parser(__spec__, description=__doc__.split("\n\n")[0])
    count = validate.int_at_least(1)
    ap.add_argument("--objects", default=DEFAULT_OBJECTS,
                    help="comma-separated names; 'hard' expands to the hard set "
                         f"(default {DEFAULT_OBJECTS})")
    ap.add_argument("--poses", type=count, default=8)
    ap.add_argument("--trials", type=count, default=16)
    ap.add_argument("--seed", type=validate.int_in(0, 2**31 - 1), default=0)
    ap.add_argument("--threads", type=count, default=None,
                    help="native threads (default: all cores)")
    ap.add_argument("--out", default=None, help="JSON file to write")
    args = ap.parse_args(argv)
    try:  # --out and the object names before any work
        validate.out_file(args.out, "--out")
        names = _object_list(validate.comma_list(args.objects, "--objects") and args.objects)
        from sern_jax.grasp.world import objects as objects_lib

        for name in names:
            objects_lib.resolve_object(name)
    except ValueError as exc:
        ap.error(f"--objects: {exc}" if "--" not in str(exc) else str(exc))

    pipeline = _pipeline()
    results = []
    t0 = time.perf_counter()
    for name in names:
        spec = objects_lib.make_object(name)
        r = measure_object(spec, args.poses, args.trials, args.seed, args.threads,
                           pipeline)
        results.append(r)
        print(f"{name}: mean {r.get('mean_candidate', float('nan')):.2f}, "
              f"best>=0.8 {r.get('frac_poses_best_ge_0.8', 0):.2f}, "
              f"cand>=0.8 {r.get('frac_candidates_ge_0.8', 0):.2f}, "
              f"{r['seconds']:.0f} s", file=sys.stderr, flush=True)
    print(table(results))
    if args.out:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        payload = {"command": " ".join(["python -m experiments.hard_objects"]
                                       + (argv if argv is not None else sys.argv[1:])),
                   "seed": args.seed, "poses": args.poses, "trials": args.trials,
                   "seconds": round(time.perf_counter() - t0, 1),
                   "load_average": os.getloadavg(), "objects": results}
        with open(args.out, "w") as f:
            json.dump(payload, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
