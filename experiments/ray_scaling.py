"""Scaling of D0 generation on Ray (issue 20): the same objects, 1, 4 and 8 workers.

D0's unit of work is a shard; here every shard is one object (``objects_per_shard=1``), so
the workers can be compared on equal work: object i of this run is object i of the default D0
(seed 0, 16 poses, 64 candidates, one trial: its keys are ``fold_in(key(seed), i)`` whatever
the shard size), and its shard holds exactly the arrays the default D0 holds for it.

Two ways to measure, both on a local Ray started before the clock (as a cluster would be):

* ``--mode weak`` (default): N workers get ``--per-worker`` objects each (objects
  ``0 .. N*per_worker - 1``); efficiency ``E(N) = T(1) / T(N)`` on equal per-worker work.
* ``--mode strong``: the same ``--objects`` objects for every N; ``E(N) = T(1) / (N T(N))``.

Before the timed runs a one-object run fills the JAX compilation cache (``--cache``) that every
worker reads. Each timed run writes its own directory; the shards of the objects that two runs
share are compared by SHA-256 (the same bytes whatever N). Writes one JSON (command, machine,
seconds per run, efficiencies, hashes)::

    python -m experiments.ray_scaling --workers 1,4,8 --per-worker 8 --out runs/ray-scaling \\
        --json-out ray_scaling.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import sys
import time
from pathlib import Path

__all__ = ["main"]


def _digest(path: Path) -> str:
    from sern_jax import io

    arrays = io.load_npz(path)
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = arrays[name]
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _run(n_objects: int, workers: int, poses: int, out: Path, cache: str,
         pin: bool = True) -> dict:
    import ray

    from sern_jax import distributed
    from sern_jax.grasp import dataset

    config = dataset.DatasetConfig(num_objects=n_objects, poses_per_object=poses,
                                   objects_per_shard=1)
    shutil.rmtree(out, ignore_errors=True)
    tasks: dict = {}
    run_units = distributed.run_units

    def recording(*a, **kw):  # the command's own path, with the tasks' reports kept
        tasks.update(run_units(*a, **kw))
        return tasks

    t0 = time.perf_counter()
    ray.init(address="local", num_cpus=workers, include_dashboard=False,
             logging_level="ERROR")
    t_init = time.perf_counter() - t0
    distributed.run_units = recording
    try:
        t0 = time.perf_counter()
        summary = dataset.generate(config, out, progress=False, log=lambda s: None,
                                   ray=distributed.RayConfig(cache_dir=cache, pin_cores=pin))
        seconds = time.perf_counter() - t0
    finally:
        distributed.run_units = run_units
        ray.shutdown()
    hashes = {p.name: _digest(p) for p in dataset.shard_paths(out, config)}
    per_task = sorted(t["seconds"] for t in tasks.values())
    return {"workers": workers, "objects": n_objects, "poses": poses, "pin_cores": pin,
            "seconds": seconds, "ray_init_seconds": t_init,
            "labelled_grasps": summary["labelled_grasps"],
            "task_seconds_sum": sum(per_task),
            "task_seconds_min_median_max": [per_task[0], per_task[len(per_task) // 2],
                                            per_task[-1]],
            "task_cpu_seconds_sum": sum(t["cpu_seconds"] for t in tasks.values()),
            "worker_processes": len({(t["host"], t["pid"]) for t in tasks.values()}),
            "threads_per_worker_max": max(t["threads"] or 0 for t in tasks.values()),
            "shard_sha256": hashes}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--workers", default="1,4,8", help="comma list of worker counts")
    p.add_argument("--mode", choices=("weak", "strong"), default="weak")
    p.add_argument("--per-worker", type=int, default=8, help="weak: objects per worker")
    p.add_argument("--objects", type=int, default=16, help="strong: objects in every run")
    p.add_argument("--poses", type=int, default=16, help="poses per object (D0: 16)")
    p.add_argument("--unpinned", type=lambda t: [int(w) for w in t.split(",") if w],
                   default=[], help="worker counts to run again without core pinning")
    p.add_argument("--out", type=Path, default=Path("runs/ray-scaling"))
    p.add_argument("--cache", default=None,
                   help="JAX compilation cache (default <out>/.jax_cache)")
    p.add_argument("--json-out", type=Path, default=None)
    args = p.parse_args(argv)
    workers = [int(w) for w in args.workers.split(",")]
    if 1 not in workers or any(w < 1 for w in workers):
        p.error("--workers must include 1 (the reference) and be positive")
    cache = args.cache or str((args.out / ".jax_cache").resolve())
    from sern_jax import io

    started = time.perf_counter()
    warm = _run(1, 1, args.poses, args.out / "warmup", cache)  # fills the compile cache
    print(f"warm-up (1 object, fills the compile cache): {warm['seconds']:.1f} s", flush=True)
    runs = []
    plan = [(n, True) for n in workers] + [(n, False) for n in args.unpinned]
    for n, pin in plan:
        objs = n * args.per_worker if args.mode == "weak" else args.objects
        r = _run(objs, n, args.poses, args.out / f"workers{n}{'' if pin else '-unpinned'}",
                 cache, pin)
        runs.append(r)
        print(f"{n} worker(s){'' if pin else ' unpinned'}, {objs} objects x {args.poses} "
              f"poses: {r['seconds']:.1f} s ({r['seconds'] / objs:.2f} s per object; tasks "
              f"{r['task_seconds_sum']:.1f} s wall, {r['task_cpu_seconds_sum']:.1f} s CPU, "
              f"min/median/max {', '.join(f'{v:.2f}' for v in r['task_seconds_min_median_max'])}"
              f" s; {r['worker_processes']} processes, <= {r['threads_per_worker_max']} "
              f"threads; Ray start {r['ray_init_seconds']:.1f} s, not counted)", flush=True)
    t1 = next(r["seconds"] for r in runs if r["workers"] == 1 and r["pin_cores"])
    for r in runs:
        r["efficiency"] = (t1 / r["seconds"] if args.mode == "weak"
                           else t1 / (r["workers"] * r["seconds"]))
        r["objects_per_second"] = r["objects"] / r["seconds"]
    # the same object gives the same shard bytes whatever the worker count
    mismatches = []
    for a in runs:
        for b in runs:
            for name, h in a["shard_sha256"].items():
                if name in b["shard_sha256"] and b["shard_sha256"][name] != h:
                    mismatches.append(name)
    doc = {
        "what": "D0 generation on a local Ray: seconds for N workers (objects_per_shard=1, "
                "seed 0, the default D0's objects 0..n-1)",
        "mode": args.mode,
        "efficiency_definition": ("T(1)/T(N), N workers doing N times the work of one "
                                  "(equal per-worker work)" if args.mode == "weak"
                                  else "T(1)/(N T(N)), the same objects for every N"),
        "command": " ".join([Path(sys.executable).name, "-m", "experiments.ray_scaling",
                             *(argv if argv is not None else sys.argv[1:])]),
        "machine": io.machine(),
        "env": {k: os.environ.get(k) for k in ("JAX_PLATFORMS", "XLA_FLAGS")},
        "versions": io.run_metadata()["versions"],
        "ray_version": __import__("ray").__version__,
        "warmup_seconds": warm["seconds"],
        "runs": [{k: v for k, v in r.items() if k != "shard_sha256"} for r in runs],
        "shards_identical_across_worker_counts": not mismatches,
        "shard_sha256": runs[-1]["shard_sha256"],
        "total_seconds": time.perf_counter() - started,
    }
    for r in doc["runs"]:
        print(f"N={r['workers']}{'' if r['pin_cores'] else ' unpinned'}: {r['seconds']:.1f} s,"
              f" efficiency {r['efficiency']:.3f}")
    print(f"shards identical across worker counts: {not mismatches}")
    if args.json_out:
        io.save_json(args.json_out, doc)
        print(f"wrote {args.json_out}")
    return 0 if not mismatches else 1


if __name__ == "__main__":
    sys.exit(main())
