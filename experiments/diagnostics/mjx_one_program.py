"""One MJX program for every object: compiles, speed, backend agreement and shape change.

For each object: its exact scene (``scene.build_scene(spec, seed=0)``), ``--trials`` paired
trials (the centred grasp shifted by up to 15 mm and turned by up to 0.6 rad, noise drawn
per object), all from the exact scene's resting pose, run

* natively on the exact scene (the reference),
* natively on the uniform scene (``uniform.uniform_scene``: the object as padded convex
  mesh parts with the exact inertia),
* with MJX on the uniform scenes of all objects at once (``sim.UniformBatch``: one
  ``jit(vmap(vmap(execute)))`` program over objects x trials).

Reports, per object and pooled: (a) native vs MJX agreement on the uniform scene, (b) exact vs
uniform agreement on the native backend (the shape change), as fractions of paired trials
with the same outcome, with Clopper-Pearson 95 % intervals and the direction of the
disagreements; the farthest any exact part lies outside its resampled hull; the number of
distinct compiled MJX trial programs (``mjx_compiles``, after a second batch of the objects in
reverse order); compile and run seconds and trials/s per backend.

Run from the repository root, e.g.
    python experiments/diagnostics/mjx_one_program.py --objects small_box,sphere,tless_part_a \\
        --trials 256 --out mjx_one_program.json
    python experiments/diagnostics/mjx_one_program.py --tiny --trials 2 --out /tmp/m.json  (CPU)
``--tiny`` shortens the trial to a few steps (a smoke run; outcomes are all failures).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT)]

import jax  # noqa: E402
import numpy as np  # noqa: E402

from sern_jax.analysis import stats  # noqa: E402
from sern_jax.grasp.world import objects, scene, sim, uniform  # noqa: E402

DEFAULT_OBJECTS = ",".join(objects.HARD_SET + ("small_box", "sphere", "capsule", "handle"))


def _grasps(model, n: int, rng: np.random.Generator) -> np.ndarray:
    g = scene.centred_grasp(model)
    off = np.zeros((n, 4))
    off[1:, :3] = rng.uniform(-0.015, 0.015, (n - 1, 3)) * [1, 1, 0.5]
    off[1:, 3] = rng.uniform(-0.6, 0.6, n - 1)
    out = g + off
    out[:, 2] = np.maximum(out[:, 2], sim.MIN_GRASP_Z)
    return out


def _pair(a: np.ndarray, b: np.ndarray) -> dict:
    a, b = np.asarray(a, bool).ravel(), np.asarray(b, bool).ravel()
    same = int((a == b).sum())
    lo, hi = stats.clopper_pearson(same, a.size, level=0.95)
    return {"n": int(a.size), "same": same, "agreement": same / a.size,
            "ci95": [float(lo), float(hi)], "first_only": int((a & ~b).sum()),
            "second_only": int((~a & b).sum()), "success_first": float(a.mean()),
            "success_second": float(b.mean())}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", default=DEFAULT_OBJECTS, help="comma-separated object names")
    p.add_argument("--trials", type=int, default=128, help="paired trials per object")
    p.add_argument("--parts", type=int, default=None, help="uniform parts (default: auto)")
    p.add_argument("--vertices", type=int, default=32, help="uniform vertices per part")
    p.add_argument("--batch", type=int, default=None,
                   help="MJX trials per object per call (default: --trials)")
    p.add_argument("--threads", type=int, default=None, help="native threads")
    p.add_argument("--tiny", action="store_true", help="a few-step trial (CPU smoke run)")
    p.add_argument("--out", required=True, help="JSON report path")
    args = p.parse_args(argv)
    names = [s for s in args.objects.split(",") if s]
    if len(names) < 1 or args.trials < 1:
        p.error("need at least one object and --trials >= 1")

    trial = sim.TrialConfig()
    if args.tiny:
        trial = sim.TrialConfig(approach_steps=2, settle_steps=1, close_steps=3, lift_steps=3,
                                shake_steps=0, hold_steps=0)
    t0 = time.perf_counter()
    exact = [scene.build_scene(objects.make_object(n), seed=0) for n in names]
    parts = args.parts or max(uniform.shape_for(m).parts for m in exact)
    shape = uniform.UniformShape(parts=parts, vertices=args.vertices)
    rng = np.random.default_rng(0)
    grasps = np.stack([_grasps(m, args.trials, rng) for m in exact])
    noise = [sim.sample_noise(jax.random.key(1000 + i), args.trials, trial)
             for i in range(len(names))]
    poses = np.stack([scene.object_pose(m) for m in exact])
    build_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    batch = sim.UniformBatch(exact, trial, shape, trials=args.batch or args.trials)
    put_s = time.perf_counter() - t0
    stacked = sim.TrialNoise(*(np.stack([n[k] for n in noise]) for k in range(3)))
    t0 = time.perf_counter()
    mjx_res = batch.run_trials(grasps, stacked, poses)
    first_s = time.perf_counter() - t0
    rev = slice(None, None, -1)
    batch_rev = sim.UniformBatch(exact[rev], trial, shape, trials=args.batch or args.trials)
    t0 = time.perf_counter()
    again = batch_rev.run_trials(grasps[rev], sim.TrialNoise(*(a[rev] for a in stacked)),
                                 poses[rev])[::-1]
    second_s = time.perf_counter() - t0
    # Equal on a CPU; XLA's GPU reductions need not be deterministic (counted, not asserted).
    reorder_differ = int(sum((a.success != b.success).sum() for a, b in zip(mjx_res, again)))

    native = {"exact": [], "uniform": []}
    native_s = {"exact": 0.0, "uniform": 0.0}
    for i, m in enumerate(exact):
        for which, model in (("exact", m), ("uniform", batch.uniform[i])):
            simulator = sim.GraspSimulator(model, "native", trial, num_threads=args.threads)
            t0 = time.perf_counter()
            native[which].append(simulator.run_trials(grasps[i], noise[i], poses[i]))
            native_s[which] += time.perf_counter() - t0

    per_object = {}
    for i, n in enumerate(names):
        per_object[n] = {
            "native_vs_mjx_uniform": _pair(native["uniform"][i].success, mjx_res[i].success),
            "exact_vs_uniform_native": _pair(native["exact"][i].success,
                                             native["uniform"][i].success),
            "nan": {"native_exact": int(native["exact"][i].nan.sum()),
                    "native_uniform": int(native["uniform"][i].nan.sum()),
                    "mjx_uniform": int(mjx_res[i].nan.sum())},
            "resample": uniform.resample_distances(exact[i], shape),
        }
    cat = lambda rs: np.concatenate([r.success for r in rs])  # noqa: E731
    n_total = len(names) * args.trials
    report = {
        "objects": names,
        "trials_per_object": args.trials,
        "trial": "tiny" if args.tiny else "default",
        "shape": {"parts": shape.parts, "vertices": shape.vertices, "faces": shape.faces,
                  "edges": shape.edges, "face_vertices": shape.face_vertices},
        "mjx_compiles": batch_rev.compiles,
        "mjx_reversed_order_differing_trials": reorder_differ,
        "pooled": {
            "native_vs_mjx_uniform": _pair(cat(native["uniform"]), cat(mjx_res)),
            "exact_vs_uniform_native": _pair(cat(native["exact"]), cat(native["uniform"])),
        },
        "max_resample_relative": max(d["relative"] for o in per_object.values()
                                     for d in o["resample"]),
        "seconds": {"build_scenes": round(build_s, 3), "mjx_models": round(put_s, 3),
                    "mjx_first_call_incl_compile": round(first_s, 3),
                    "mjx_second_call": round(second_s, 3),
                    "native_exact": round(native_s["exact"], 3),
                    "native_uniform": round(native_s["uniform"], 3)},
        "trials_per_s": {"mjx": round(n_total / second_s, 2),
                         "native_exact": round(n_total / native_s["exact"], 2),
                         "native_uniform": round(n_total / native_s["uniform"], 2)},
        "per_object": per_object,
        "machine": {"jax_backend": jax.default_backend(),
                    "devices": [d.device_kind for d in jax.devices()],
                    "python": platform.python_version(), "jax": jax.__version__},
    }
    Path(args.out).write_text(json.dumps(report, indent=1))
    pooled = report["pooled"]
    print(f"mjx_compiles={report['mjx_compiles']} "
          f"native-vs-mjx={pooled['native_vs_mjx_uniform']['agreement']:.3f} "
          f"exact-vs-uniform={pooled['exact_vs_uniform_native']['agreement']:.3f} "
          f"trials/s mjx={report['trials_per_s']['mjx']} "
          f"native={report['trials_per_s']['native_exact']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
