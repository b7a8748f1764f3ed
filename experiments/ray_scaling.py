"""Scaling of D0 generation on Ray: the same objects, 1, 4 and 8 workers.

D0's unit of work is a shard; here every shard is one object (``objects_per_shard=1``), so
the workers can be compared on equal work: object i of this run is object i of the default D0
(seed 0, 16 poses, 64 candidates, one trial: its keys are ``fold_in(key(seed), i)`` whatever
the shard size), and its shard holds exactly the arrays the default D0 holds for it.

Two ways to measure, both on a local Ray started before the clock (as a cluster would be):

* ``--mode weak`` (default): N workers get ``--per-worker`` objects each (objects
  ``0 .. N*per_worker - 1``); efficiency ``E(N) = T(1) / T(N)`` on equal per-worker work.
* ``--mode strong``: the same ``--objects`` objects for every N; ``E(N) = T(1) / (N T(N))``.

* ``--mode default-d0``: the default D0's size (``--objects 200 --poses 16``, one object per
  shard) with ``--full-workers`` (default 8 and 4) workers, each run over every object, and one
  worker over a systematic sample (every ``--sample-every``-th object, from object 0): the
  one-worker run of the whole D0 (~30 min) is too long for one time-limited job. The runs go at the
  same time, each on a local Ray of its own, every worker pinned to a core of its own (13 of
  the 16 cores for 8 + 4 + 1). The one-worker time of the whole D0 is *estimated* as

      T1_est = sum_sample t1(i) * sum_all t8(i) / sum_sample t8(i)

  (t1: the sample's task seconds on the one worker; t8: the task seconds of every object on the
  largest run, whose ratio scales the sample to the whole D0 by the objects' own costs). It
  counts task time only (no Ray start, no driver work), so it underestimates a real
  one-worker run, and the efficiencies ``E(N) = T1_est / (N T(N))``, with T(N) the measured
  wall time of the whole ``dataset.generate`` call, err low.

* ``--mode d0-sampled``: the default D0 at ``--full-workers`` (default 8) workers over every
  object, and one worker over a uniformly random sample of ``--sample-size`` objects drawn
  without replacement by ``numpy.random.default_rng(--sample-seed)``, the runs one after the
  other (never side by side), so each sees the host as the others left it. The one-worker time
  of the whole D0 is estimated from the sample's own per-object task seconds,

      T1_est = n_objects * mean_sample t1(i),   95 % Student-t interval over the sample
                                                 (n - 1 dof, no finite-population factor:
                                                 wider than needed)

  which needs no figure of the full runs; a ratio estimate (Cochran's, from the residuals
  t1(i) - R t8(i), R = sum_sample t1 / sum_sample t8) and the per-object slowdown t8(i)/t1(i)
  are given beside it. T1_est counts task time only (no worker start, no driver work), so it
  is below a real one-worker run's wall time and E(N) = T1_est / (N T(N)) errs low.

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
    from sern_jax.infra import io

    arrays = io.load_npz(path)
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = arrays[name]
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _run(n_objects: int, workers: int, poses: int, out: Path, cache: str,
         pin: bool = True, sample: list[int] | None = None) -> dict:
    """One timed run on a local Ray of ``workers`` CPUs: ``dataset.generate`` (the command's
    path) over objects ``0 .. n_objects - 1``, or, with ``sample``, only those objects'
    shards (``dataset.write_shard``, the same unit function, through ``run_units``)."""
    import ray

    from sern_jax.infra import distributed
    from sern_jax.grasp.model import dataset

    config = dataset.DatasetConfig(num_objects=n_objects, poses_per_object=poses,
                                   objects_per_shard=1)
    shutil.rmtree(out, ignore_errors=True)
    tasks: dict = {}
    run_units = distributed.run_units

    def recording(*a, **kw):  # the command's own path, with the tasks' reports kept
        tasks.update(run_units(*a, **kw))
        return tasks

    t0 = time.perf_counter()
    # a small object store: the tasks return a few numbers (shards go to disk), and several
    # of these Rays may run at once on one host (--mode default-d0)
    ray.init(address="local", num_cpus=workers, include_dashboard=False,
             logging_level="ERROR", object_store_memory=512 * 2**20)
    t_init = time.perf_counter() - t0
    distributed.run_units = recording
    ray_config = distributed.RayConfig(cache_dir=cache, pin_cores=pin)
    try:
        t0 = time.perf_counter()
        if sample is None:
            summary = dataset.generate(config, out, progress=False, log=lambda s: None,
                                       ray=ray_config)
        else:
            out.mkdir(parents=True, exist_ok=True)
            specs = dataset.dataset_objects(config)
            paths = dataset.shard_paths(out, config)
            recording([distributed.Unit(paths[i].name, dataset.write_shard,
                                        (config, i, specs[i:i + 1], str(out.resolve())))
                       for i in sample], ray_config, out, log=lambda s: None,
                      progress=False, desc="shards")
            summary = {"labelled_grasps": int(sum(
                _load_npz(paths[i])["valid"].sum() for i in sample))}
        seconds = time.perf_counter() - t0
    finally:
        distributed.run_units = run_units
        ray.shutdown()
    hashes = {p.name: _digest(p) for p in dataset.shard_paths(out, config) if p.exists()}
    per_task = sorted(t["seconds"] for t in tasks.values())
    return {"workers": workers, "objects": n_objects if sample is None else len(sample),
            "sample": sample, "poses": poses, "pin_cores": pin,
            "seconds": seconds, "ray_init_seconds": t_init,
            "labelled_grasps": summary["labelled_grasps"],
            "task_seconds": {name: t["seconds"] for name, t in sorted(tasks.items())},
            "cores": sorted({c for t in tasks.values() for c in (t["cores"] or [])}),
            "task_seconds_sum": sum(per_task),
            "task_seconds_min_median_max": [per_task[0], per_task[len(per_task) // 2],
                                            per_task[-1]],
            "task_cpu_seconds_sum": sum(t["cpu_seconds"] for t in tasks.values()),
            "worker_processes": len({(t["host"], t["pid"]) for t in tasks.values()}),
            "threads_per_worker_max": max(t["threads"] or 0 for t in tasks.values()),
            "shard_sha256": hashes}


def _load_npz(path: Path) -> dict:
    from sern_jax.infra import io

    return io.load_npz(path)


def _child(args) -> int:
    """One run of ``--mode default-d0`` in a process (and a local Ray) of its own."""
    sample = None
    if args.child_sample:
        sample = list(range(0, args.objects, args.child_sample))
    r = _run(args.objects, args.child_workers, args.poses, args.child_out, args.cache,
             sample=sample)
    Path(args.child_json).write_text(json.dumps(r))
    print(f"run of {r['workers']} worker(s) over {r['objects']} objects: {r['seconds']:.1f} s "
          f"(task seconds {r['task_seconds_sum']:.1f}); wrote {args.child_json}", flush=True)
    return 0


def _child_json(args, name: str) -> Path:
    """Where a run of ``--mode default-d0`` writes its figures: beside ``--json-out`` (so a
    run that finished is kept when a later one does not), else under ``--out``."""
    folder = args.json_out.parent if args.json_out else args.out
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{name}.json"


def _default_d0(args, argv, cache: str, started: float) -> int:
    """The default D0 at ``--full-workers`` workers and a one-worker sample, all at once."""
    import subprocess

    from sern_jax.infra import io

    full = [int(w) for w in args.full_workers.split(",") if w]
    if not full or any(w < 2 for w in full):
        raise SystemExit("--full-workers: worker counts >= 2")
    oversubscribed = sum(full) + 1 > (os.cpu_count() or 1)
    if oversubscribed:  # the pins then fail for some workers, which run unpinned
        print(f"note: {sum(full) + 1} workers on {os.cpu_count()} cores: oversubscribed, "
              "not a scaling measurement", flush=True)
    warm = _run(1, 1, args.poses, args.out / "warmup", cache)  # fills the compile cache
    print(f"warm-up (1 object, fills the compile cache): {warm['seconds']:.1f} s", flush=True)
    load_start = os.getloadavg()
    procs = []
    plan = [(n, 0) for n in full] + [(1, args.sample_every)]
    for n, every in plan:
        name = f"workers{n}" + (f"-every{every}" if every else "")
        child = [sys.executable, "-m", "experiments.ray_scaling", "--child-json",
                 str(_child_json(args, name)), "--child-workers", str(n), "--child-out",
                 str(args.out / name), "--child-sample", str(every), "--objects",
                 str(args.objects), "--poses", str(args.poses), "--cache", cache]
        procs.append((name, subprocess.Popen(child)))
    for name, proc in procs:
        if proc.wait() != 0:
            raise SystemExit(f"run {name} failed (exit {proc.returncode})")
    load_end = os.getloadavg()
    runs = [json.loads(_child_json(args, name).read_text()) for name, _ in procs]
    by = {(r["workers"], r["sample"] is not None): r for r in runs}
    largest = by[(max(full), False)]
    one = by[(1, True)]
    names = list(one["task_seconds"])
    t8_all = sum(largest["task_seconds"].values())
    t8_sample = sum(largest["task_seconds"][n] for n in names)
    t1_sample = sum(one["task_seconds"].values())
    t1_est = t1_sample * t8_all / t8_sample
    for r in runs:
        if r["sample"] is None:
            r["efficiency"] = t1_est / (r["workers"] * r["seconds"])
        r["objects_per_second"] = r["objects"] / r["seconds"]
    # the same object gives the same shard bytes whatever the run
    mismatches = _shard_mismatches(runs)
    doc = {
        "what": ("the default D0's size (objects x poses, one object per shard, seed 0) on "
                 "local Rays of N pinned one-core workers; the N >= 2 runs cover every "
                 "object, the one-worker run a systematic sample; the runs went at the same "
                 "time on disjoint cores"),
        "mode": "default-d0",
        "efficiency_definition": (
            "E(N) = T1_est / (N T(N)); T(N) the wall seconds of the whole dataset.generate "
            "call over every object (worker start-up included, Ray start excluded); T1_est = "
            "sum_sample t1 * sum_all tL / sum_sample tL, t1 the one-worker run's task "
            "seconds, tL the task seconds of the largest run (task time only: a real "
            "one-worker run would add its worker start and driver time, so E errs low)"),
        "t1_estimate_seconds": t1_est,
        "t1_sample_task_seconds": t1_sample,
        "largest_run_task_seconds_all": t8_all,
        "largest_run_task_seconds_sample": t8_sample,
        "sample_task_slowdown_largest_vs_one": t8_sample / t1_sample,
        "load_average_1m_5m_15m_before_and_after": [list(load_start), list(load_end)],
        **_provenance(argv, warm, runs),
        "oversubscribed": oversubscribed,
        "shards_identical_across_runs": not mismatches,
        "shard_sha256": largest["shard_sha256"],
        "total_seconds": time.perf_counter() - started,
    }
    for r in runs:
        print(f"N={r['workers']} {r['objects']} objects: {r['seconds']:.1f} s"
              + (f", efficiency {r['efficiency']:.3f}" if "efficiency" in r else
                 f" (sample: task seconds {t1_sample:.1f})"), flush=True)
    print(f"T1 estimate {t1_est:.1f} s; shards identical across runs: {not mismatches}")
    if args.json_out:
        io.save_json(args.json_out, doc)
        print(f"wrote {args.json_out}")
    return 0 if not mismatches else 1


def _shard_mismatches(runs: list[dict]) -> list[str]:
    """Shard names whose bytes (SHA-256) differ between any two runs: the same object must
    give the same shard whatever the run or worker count."""
    return sorted({n for a in runs for b in runs for n, h in a["shard_sha256"].items()
                   if n in b["shard_sha256"] and b["shard_sha256"][n] != h})


def _provenance(argv, warm: dict, runs: list[dict]) -> dict:
    """What every scaling record states about how it was made: the command line, machine,
    environment, versions, the warm-up's seconds and the runs (without their shard hashes)."""
    from sern_jax.infra import io

    return {"command": " ".join([Path(sys.executable).name, "-m", "experiments.ray_scaling",
                                 *(argv if argv is not None else sys.argv[1:])]),
            "machine": io.machine(),
            "env": {k: os.environ.get(k) for k in ("JAX_PLATFORMS", "XLA_FLAGS")},
            "versions": io.run_metadata()["versions"],
            "ray_version": __import__("ray").__version__,
            "warmup_seconds": warm["seconds"],
            "runs": [{k: v for k, v in r.items() if k != "shard_sha256"} for r in runs]}


def _uptime() -> str:
    import subprocess

    try:
        return subprocess.run(["uptime"], check=False, capture_output=True, text=True,
                              timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError) as e:  # uptime missing: say so
        return f"uptime failed: {e}"


def sampled_estimate(t1_sample: dict, t_full: dict, num_objects: int,
                     level: float = 0.95) -> dict:
    """The one-worker time of all ``num_objects`` objects from a uniform random sample.

    Args:
      t1_sample: object shard name -> task seconds on the lone worker (the sample).
      t_full: shard name -> task seconds of every object in a full run (N workers).
      num_objects: the population size (D0's objects).

    Returns: the expansion estimate ``num_objects * mean(t1)`` with its Student-t interval,
    the ratio estimate ``R * sum(t_full)`` (R = sum_sample t1 / sum_sample t_full; interval
    from the residuals t1 - R t_full, n - 1 dof), and the per-object slowdown of the full
    run's tasks, t_full / t1, with its Student-t interval.
    """
    import numpy as np

    from sern_jax.analysis import stats

    names = sorted(t1_sample)
    t1 = np.array([t1_sample[n] for n in names], np.float64)
    tf = np.array([t_full[n] for n in names], np.float64)
    n = len(names)
    expansion = stats.t_interval(t1, level)
    ratio = t1.sum() / tf.sum()
    residual_sd = float(np.std(t1 - ratio * tf, ddof=1))
    ratio_half = num_objects * stats.t_half_width(residual_sd, n, level)
    ratio_est = ratio * sum(t_full.values())
    slow = stats.t_interval(tf / t1, level)
    return {
        "level": level, "sample_size": n, "population": num_objects,
        "t1_mean_task_seconds": expansion.mean, "t1_sd_task_seconds": expansion.sd,
        "t1_estimate_seconds": num_objects * expansion.mean,
        "t1_estimate_interval": [num_objects * expansion.lower, num_objects * expansion.upper],
        "t1_ratio_estimate_seconds": ratio_est,
        "t1_ratio_estimate_interval": [ratio_est - ratio_half, ratio_est + ratio_half],
        "full_over_one_task_ratio_mean": slow.mean,
        "full_over_one_task_ratio_interval": [slow.lower, slow.upper],
    }


def _d0_sampled(args, argv, cache: str, started: float) -> int:
    """``--mode d0-sampled``: the full runs and the one-worker random sample, one after the
    other on one host."""
    import numpy as np

    from sern_jax.infra import io

    full = [int(w) for w in args.full_workers.split(",") if w]
    if not full or any(w < 2 for w in full):
        raise SystemExit("--full-workers: worker counts >= 2")
    if not 2 <= args.sample_size <= args.objects:
        raise SystemExit(f"--sample-size: 2 .. --objects ({args.objects})")
    sample = sorted(int(i) for i in np.random.default_rng(args.sample_seed).choice(
        args.objects, args.sample_size, replace=False))
    warm = _run(1, 1, args.poses, args.out / "warmup", cache)  # fills the compile cache
    print(f"warm-up (1 object, fills the compile cache): {warm['seconds']:.1f} s", flush=True)
    runs = []
    plan = [(1, sample)] + [(n, None) for n in full]
    for n, chosen in plan:
        up, load = _uptime(), list(os.getloadavg())
        r = _run(args.objects, n, args.poses,
                 args.out / (f"workers{n}" + ("-sample" if chosen else "")), cache,
                 sample=chosen)
        r["uptime_before"], r["load_average_before"] = up, load
        r["uptime_after"], r["load_average_after"] = _uptime(), list(os.getloadavg())
        runs.append(r)
        print(f"N={n} over {r['objects']} objects: {r['seconds']:.1f} s (task seconds "
              f"{r['task_seconds_sum']:.1f}); before: {r['uptime_before']}; after: "
              f"{r['uptime_after']}", flush=True)
    one = runs[0]
    largest = max(runs[1:], key=lambda r: r["workers"])
    est = sampled_estimate(one["task_seconds"], largest["task_seconds"], args.objects)
    for r in runs[1:]:
        r["efficiency"] = est["t1_estimate_seconds"] / (r["workers"] * r["seconds"])
        r["efficiency_interval"] = [t / (r["workers"] * r["seconds"])
                                    for t in est["t1_estimate_interval"]]
        r["efficiency_ratio_estimate"] = (est["t1_ratio_estimate_seconds"]
                                          / (r["workers"] * r["seconds"]))
    for r in runs:
        r["objects_per_second"] = r["objects"] / r["seconds"]
    mismatches = _shard_mismatches(runs)
    doc = {
        "what": ("the default D0's size (objects x poses, one object per shard, seed 0) on "
                 "local Rays of pinned one-core workers, one run after the other: one worker "
                 "over a uniformly random sample of objects, then every object at each of "
                 "--full-workers"),
        "mode": "d0-sampled",
        "sample_seed": args.sample_seed,
        "sample_rule": ("sorted(numpy.random.default_rng(sample_seed).choice(objects, "
                        "sample_size, replace=False))"),
        "efficiency_definition": (
            "E(N) = T1_est / (N T(N)); T(N) the wall seconds of the whole dataset.generate "
            "call over every object (worker start-up included, Ray start excluded); T1_est = "
            "objects * mean task seconds of the one-worker sample, 95 % Student-t interval "
            "(n - 1 dof); task time only, so E errs low"),
        **est,
        **_provenance(argv, warm, runs),
        "shards_identical_across_runs": not mismatches,
        "shard_sha256": largest["shard_sha256"],
        "total_seconds": time.perf_counter() - started,
    }
    for r in runs[1:]:
        print(f"N={r['workers']}: {r['seconds']:.1f} s, efficiency {r['efficiency']:.3f} "
              f"[{r['efficiency_interval'][0]:.3f}, {r['efficiency_interval'][1]:.3f}] "
              f"(ratio estimate {r['efficiency_ratio_estimate']:.3f})", flush=True)
    print(f"T1 estimate {est['t1_estimate_seconds']:.1f} s "
          f"[{est['t1_estimate_interval'][0]:.1f}, {est['t1_estimate_interval'][1]:.1f}]; "
          f"full/one task ratio {est['full_over_one_task_ratio_mean']:.3f}; shards identical "
          f"across runs: {not mismatches}", flush=True)
    if args.json_out:
        io.save_json(args.json_out, doc)
        print(f"wrote {args.json_out}")
    return 0 if not mismatches else 1


def main(argv=None) -> int:
    from sern_jax.infra import validate

    # bad input: one line naming the flag, exit 2, before any compile (validate's parser)
    p = validate.script_parser(__spec__, description=__doc__.splitlines()[0])
    count = validate.int_at_least(1)
    p.add_argument("--workers", default="1,4,8", help="comma list of worker counts")
    p.add_argument("--mode", choices=("weak", "strong", "default-d0", "d0-sampled"),
                   default="weak")
    p.add_argument("--full-workers", default="8,4",
                   help="default-d0: worker counts that run every object")
    p.add_argument("--sample-every", type=count, default=8,
                   help="default-d0: the one-worker run takes every k-th object")
    p.add_argument("--sample-size", type=validate.int_at_least(2), default=24,
                   help="d0-sampled: objects in the one-worker run's random sample")
    p.add_argument("--sample-seed", type=validate.int_at_least(0), default=20261124,
                   help="d0-sampled: numpy.random.default_rng seed of the sample")
    for hidden in ("--child-json", "--child-out"):
        p.add_argument(hidden, default=None, help=argparse.SUPPRESS)
    p.add_argument("--child-workers", type=int, default=1, help=argparse.SUPPRESS)
    p.add_argument("--child-sample", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--per-worker", type=count, default=8, help="weak: objects per worker")
    p.add_argument("--objects", type=count, default=None,
                   help="strong: objects in every run (default 16); default-d0: D0's "
                        "objects (default 200, the default D0)")
    p.add_argument("--poses", type=count, default=16, help="poses per object (D0: 16)")
    p.add_argument("--unpinned", type=lambda t: [int(w) for w in t.split(",") if w],
                   default=[], help="worker counts to run again without core pinning")
    p.add_argument("--out", type=Path, default=Path("runs/ray-scaling"))
    p.add_argument("--cache", default=None,
                   help="JAX compilation cache (default <out>/.jax_cache)")
    p.add_argument("--json-out", type=Path, default=None)
    args = p.parse_args(argv)
    if args.objects is None:
        args.objects = 200 if args.mode in ("default-d0", "d0-sampled") else 16
    if args.child_json:
        args.child_out = Path(args.child_out)
        return _child(args)
    try:
        workers = [int(w) for w in args.workers.split(",")]
    except ValueError:
        p.error(f"--workers must be a comma list of integers, got {args.workers!r}")
    if 1 not in workers or any(w < 1 for w in workers):
        p.error("--workers must include 1 (the reference) and be positive")
    if args.mode in ("default-d0", "d0-sampled"):
        try:
            full = [int(w) for w in args.full_workers.split(",") if w]
        except ValueError:
            full = []
        if not full or any(w < 2 for w in full):
            p.error(f"--full-workers must be a comma list of worker counts >= 2, got "
                    f"{args.full_workers!r}")
    if args.mode == "d0-sampled" and args.sample_size > args.objects:
        p.error(f"--sample-size must be <= --objects ({args.objects}), got {args.sample_size}")
    cache = args.cache or str((args.out / ".jax_cache").resolve())
    from sern_jax.infra import io

    started = time.perf_counter()
    if args.mode == "default-d0":
        return _default_d0(args, argv, cache, started)
    if args.mode == "d0-sampled":
        return _d0_sampled(args, argv, cache, started)
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
    mismatches = _shard_mismatches(runs)
    doc = {
        "what": "D0 generation on a local Ray: seconds for N workers (objects_per_shard=1, "
                "seed 0, the default D0's objects 0..n-1)",
        "mode": args.mode,
        "efficiency_definition": ("T(1)/T(N), N workers doing N times the work of one "
                                  "(equal per-worker work)" if args.mode == "weak"
                                  else "T(1)/(N T(N)), the same objects for every N"),
        **_provenance(argv, warm, runs),
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
