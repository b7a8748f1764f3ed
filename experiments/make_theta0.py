"""Makes the shipped θ0 and core set: D0, pretraining, held-out metrics, hard-set screen.

The same steps as ``sern grasp dataset``, ``sern grasp pretrain`` and ``sern grasp screen``
with their defaults, in one process (used to make ``sern_jax/grasp/data/`` on one machine).

    python -m experiments.make_theta0 --out runs/theta0 [--objects 200 --poses 16]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="runs/theta0")
    parser.add_argument("--objects", type=int, default=200)
    parser.add_argument("--poses", type=int, default=16)
    parser.add_argument("--epochs", type=int, default=8)
    parser.add_argument("--screen-poses", type=int, default=8)
    parser.add_argument("--screen-trials", type=int, default=16)
    parser.add_argument("--heldout-objects", type=int, default=12)
    parser.add_argument("--heldout-poses", type=int, default=4)
    parser.add_argument("--heldout-trials", type=int, default=16)
    parser.add_argument("--core-k", type=int, default=172)
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)

    from sern_jax import io
    from sern_jax.grasp import dataset, objects, pretrain

    out = Path(args.out)
    timings = {}
    t = time.perf_counter()
    summary = dataset.generate(
        dataset.DatasetConfig(num_objects=args.objects, poses_per_object=args.poses),
        out / "d0", progress=not args.no_progress)
    timings["dataset_s"] = time.perf_counter() - t
    print(json.dumps(summary), flush=True)
    t = time.perf_counter()
    manifest = pretrain.pretrain(out / "d0", pretrain.PretrainConfig(
        epochs=args.epochs, heldout_objects=args.heldout_objects,
        heldout_poses=args.heldout_poses, heldout_trials=args.heldout_trials,
        core_k=args.core_k),
                                 out / "theta0", progress=not args.no_progress)
    timings["pretrain_s"] = time.perf_counter() - t
    from sern_jax.grasp import artifacts

    theta0 = artifacts.load_theta0(out / "theta0")
    t = time.perf_counter()
    specs = [objects.make_object(n) for n in objects.object_names()]
    rows = pretrain.screen(theta0.network, theta0.params, specs, args.screen_poses,
                           args.screen_trials, progress=not args.no_progress)
    timings["screen_s"] = time.perf_counter() - t
    io.save_json(out / "theta0" / "screen.json", {"rule": pretrain.HARD_RULE, "objects": rows,
                                                   "timings": timings,
                                                   "machine": io.run_metadata()["host"]})
    for r in rows:
        print(f"{r['object']:>20s} greedy {r['greedy_success']:.2f} best {r['best_success']:.2f} "
              f"mean {r['mean_success']:.2f} {'HARD' if r['hard'] else ''}", flush=True)
    print(json.dumps(timings))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
