"""``sern bench grasp``: throughput of the grasp pipeline, one JSON object.

Measures, on the scene of one object (default ``small_box``):

* grasp trials/s for each backend (native ``mujoco.rollout``, MJX) at a few batch sizes,
  best of ``--repeats`` timed calls after one warm-up call (whose extra time is
  ``compile_s`` for MJX), and trials per CPU-second of this process (all its threads;
  a figure that other load on a shared machine distorts less than wall-clock time);
* depth images/s (``depth.make_renderer``) and candidate sets/s
  (``candidates.make_sampler``) at ``--depth-batch`` images;
* whole grasp contexts/s (``context.make_contexts``: resting poses, depth, candidates)
  at ``--context-poses`` poses per call (different poses each call, one shared scene);
* a time split per stage (first context incl. compiles, depth per image, candidates per
  set, one context, one trial per backend);
* optionally (``--agreement N``) the paired native-vs-MJX agreement of trial outcomes on
  N trials per object over ``--agreement-objects`` (one MJX compile per object shape).

Every figure is measured in this run on this machine (``machine`` in the output).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

__all__ = ["add_parser", "measure_agreement", "random_grasps", "run", "main"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Registers ``grasp`` under the ``sern bench`` subcommands."""
    p = subparsers.add_parser(
        "grasp",
        help="grasp simulator throughput (trials/s per backend, depth, candidates)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", action="store_true", help="print only the JSON object")
    p.add_argument(
        "--object", default="small_box", help="object name or .obj/.stl path"
    )
    p.add_argument("--native-batch", default="64,256", help="native batch sizes (csv)")
    p.add_argument(
        "--mjx-batch", default="16,64", help="MJX batch sizes (csv); '' skips"
    )
    p.add_argument("--depth-batch", type=int, default=16, help="images per depth call")
    p.add_argument(
        "--context-poses",
        default="16",
        help="poses per context.make_contexts call for contexts/s (csv); '' skips",
    )
    p.add_argument("--threads", type=int, default=None, help="native threads")
    p.add_argument("--repeats", type=int, default=2, help="timed calls per setting")
    p.add_argument(
        "--agreement",
        type=int,
        default=0,
        help="paired native/MJX trials per object (0 = skip)",
    )
    p.add_argument(
        "--agreement-objects",
        default="small_box,sphere,capsule,l_shape,cylinder,triangular_prism",
        help="objects for --agreement (csv)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="small sizes: native 32, MJX 8, depth 4, contexts 4, 1 repeat",
    )
    p.add_argument("--quality-sets", type=int, default=16,
                   help="64-candidate sets per quality-network scoring call (0 = skip)")
    p.add_argument("--quality-batch", type=int, default=64,
                   help="minibatch of the quality-network training-step timing")
    p.add_argument("--out", default=None, help="also write the JSON to this file")
    p.set_defaults(func=run)
    return p


_MAX_BATCH = 65_536  # trials or poses per call: far above any useful benchmark size


def _csv_ints(text: str, name: str) -> list[int]:
    if not text.strip():
        return []
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError as e:
        raise ValueError(f"{name} must be comma-separated ints, got {text!r}") from e
    if min(values) < 1 or max(values) > _MAX_BATCH:
        raise ValueError(f"{name} values must lie in [1, {_MAX_BATCH}], got {text!r}")
    return values


def _validate(args) -> None:
    """Every option, before any benchmarking (also those that ``--quick`` replaces)."""
    for flag, text in (("--native-batch", args.native_batch), ("--mjx-batch", args.mjx_batch),
                       ("--context-poses", args.context_poses)):
        _csv_ints(text, flag)
    if not args.native_batch.strip():
        raise ValueError("--native-batch must name at least one batch size")
    for flag, value, low, high in (("--depth-batch", args.depth_batch, 0, 4096),
                                   ("--repeats", args.repeats, 1, 1000),
                                   ("--agreement", args.agreement, 0, 100_000),
                                   ("--quality-sets", args.quality_sets, 0, 100_000),
                                   ("--quality-batch", args.quality_batch, 1, _MAX_BATCH)):
        if not low <= value <= high:
            raise ValueError(f"{flag} must lie in [{low}, {high}], got {value}")
    if args.threads is not None and not 1 <= args.threads <= 4096:
        raise ValueError(f"--threads must lie in [1, 4096], got {args.threads}")
    if args.out is not None:
        from sern_jax.commands import validate

        validate.out_file(args.out, "--out")  # a temporary file is tried where it would go
    if args.agreement:
        from sern_jax.grasp import objects as objects_lib

        names = [n for n in args.agreement_objects.split(",") if n]
        if not names:
            raise ValueError("--agreement-objects is empty")
        for n in names:
            try:
                objects_lib.resolve_object(n)
            except ValueError as e:
                raise ValueError(f"--agreement-objects: {e}") from None


def _first_and_best(call, repeats):
    """(result, first-call seconds, best of ``repeats`` timed calls) of a jitted ``call``."""
    import jax

    t = time.perf_counter()
    result = jax.block_until_ready(call())
    first = time.perf_counter() - t
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        result = jax.block_until_ready(call())
        best = min(best, time.perf_counter() - t)
    return result, first, best


def _machine() -> dict:
    import jax

    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()],
        "python": sys.version.split()[0],
        "load_average_1m": os.getloadavg()[0],
    }


def random_grasps(key, model, n):
    """n grasps near the object: centre + U[±2 cm] in x, y, θ ~ U[-π/2, π/2); key consumed."""
    import jax
    import numpy as np

    from sern_jax.grasp import scene as scene_lib

    data = scene_lib.initial_data(model)
    ids = scene_lib.scene_ids(model)
    centre = data.xipos[ids.object_body]
    u = np.asarray(jax.random.uniform(key, (n, 3)), np.float64)
    g = np.empty((n, 4))
    g[:, 0] = centre[0] + (u[:, 0] * 2 - 1) * 0.02
    g[:, 1] = centre[1] + (u[:, 1] * 2 - 1) * 0.02
    g[:, 2] = centre[2]
    g[:, 3] = (u[:, 2] - 0.5) * np.pi
    return g


def measure_agreement(objects, trials_per_object, seed=0, progress=None) -> dict:
    """Paired native vs MJX outcomes on the same grasps and noise, per object.

    Args:
      objects: object names, mesh paths or ObjectSpecs.
      trials_per_object: N paired trials each (``random_grasps`` + ``sim.sample_noise``).
      seed: root seed; object i uses ``fold_in(key(seed), i)`` and resting pose seed i.
      progress: optional callback(name, stats).

    Returns:
      dict with per-object stats, the total number of trials and the pooled agreement.
    """
    import jax
    import numpy as np

    from sern_jax.grasp import objects as objects_lib
    from sern_jax.grasp import scene as scene_lib
    from sern_jax.grasp import sim

    per_object, agree, total = {}, 0, 0
    root = jax.random.key(seed)
    for i, obj in enumerate(objects):
        is_spec = isinstance(obj, objects_lib.ObjectSpec)
        spec = obj if is_spec else objects_lib.resolve_object(obj)
        name = spec.name
        model = scene_lib.build_scene(spec, seed=i)
        key = jax.random.fold_in(root, i)
        k_grasp, k_noise = jax.random.split(key)
        grasps = random_grasps(k_grasp, model, trials_per_object)
        noise = sim.sample_noise(k_noise, trials_per_object)
        t0 = time.perf_counter()
        native = sim.GraspSimulator(model, "native").run_trials(grasps, noise)
        t1 = time.perf_counter()
        mjx = sim.GraspSimulator(model, "mjx").run_trials(grasps, noise)
        t2 = time.perf_counter()
        stats = sim.agreement(native, mjx)
        stats.update(native_s=round(t1 - t0, 3), mjx_s_incl_compile=round(t2 - t1, 3))
        per_object[name] = stats
        agree += int(np.sum(native.success == mjx.success))
        total += trials_per_object
        if progress:
            progress(name, stats)
    return {
        "objects": per_object,
        "num_trials": total,
        "agreement": agree / total if total else None,
    }


def run(args) -> int:
    from sern_jax.commands.grasp_show import import_mjx_quietly

    import_mjx_quietly()
    _validate(args)
    import jax
    import numpy as np

    from sern_jax.grasp import context as context_lib
    from sern_jax.grasp import objects as objects_lib
    from sern_jax.grasp import scene as scene_lib
    from sern_jax.grasp import sim

    try:
        native_batches = (
            [32] if args.quick else _csv_ints(args.native_batch, "--native-batch")
        )
        mjx_batches = [8] if args.quick else _csv_ints(args.mjx_batch, "--mjx-batch")
        depth_batch = 4 if args.quick else args.depth_batch
        context_poses = (
            [4] if args.quick else _csv_ints(args.context_poses, "--context-poses")
        )
        repeats = 1 if args.quick else args.repeats
        if depth_batch < 0 or repeats < 1:
            raise ValueError(
                f"--depth-batch >= 0 and --repeats >= 1, got {depth_batch}, {repeats}"
            )
        spec = objects_lib.resolve_object(args.object)
    except ValueError as e:
        print(f"sern bench grasp: {e}", file=sys.stderr)
        return 2

    def log(msg):
        if not args.json:
            print(msg, file=sys.stderr, flush=True)

    out = {"benchmark": "grasp", "object": spec.name, "machine": _machine()}
    config = sim.TrialConfig()
    out["trial_steps"] = config.num_steps
    key = jax.random.key(0)
    t0 = time.perf_counter()
    ctx = context_lib.make_context(key, spec)  # scene, resting pose, depth, candidates
    model = ctx.model
    stages = {"context_first_s": time.perf_counter() - t0}
    out["timestep"] = float(model.opt.timestep)
    grasp = scene_lib.centred_grasp(model)
    grasps_all = np.tile(grasp, (max(native_batches + mjx_batches + [1]), 1))

    def time_backend(backend, batches, **kw):
        results, compile_s = [], None
        simulator = sim.GraspSimulator(model, backend, **kw)
        for b in batches:
            noise = sim.sample_noise(jax.random.fold_in(key, b), b)
            g = grasps_all[:b]
            t = time.perf_counter()
            res = simulator.run_trials(g, noise)
            first = time.perf_counter() - t
            best, best_cpu = np.inf, np.inf
            for _ in range(repeats):
                t, c = time.perf_counter(), time.process_time()
                res = simulator.run_trials(g, noise)
                best = min(best, time.perf_counter() - t)
                best_cpu = min(best_cpu, time.process_time() - c)
            if compile_s is None:
                compile_s = max(first - best, 0.0)
            row = {
                "batch": b,
                "trials_per_s": b / best,
                "physics_steps_per_s": b * config.num_steps / best,
                "seconds": best,
                "cpu_seconds": best_cpu,
                "trials_per_cpu_s": b / best_cpu,
                "first_call_s": first,
                "success_rate": float(res.success.mean()),
                "nan": int(res.nan.sum()),
            }
            log(
                f"{backend:6s} batch {b:6d}: {row['trials_per_s']:9.1f} trials/s "
                f"(first call {first:.1f} s, success {row['success_rate']:.2f})"
            )
            results.append(row)
        return results, compile_s

    backends = {}
    threads = args.threads or os.cpu_count()
    if native_batches:
        rows, _ = time_backend("native", native_batches, num_threads=threads)
        backends["native"] = {"threads": threads, "batches": rows}
        stages["native_trial_s"] = rows[-1]["seconds"] / rows[-1]["batch"]
    if mjx_batches:
        rows, compile_s = time_backend("mjx", mjx_batches)
        backends["mjx"] = {"batches": rows, "compile_s": compile_s}
        stages["mjx_trial_s"] = rows[-1]["seconds"] / rows[-1]["batch"]
    out["backends"] = backends

    # Depth images and candidate sets (depth.py and candidates.py on this scene).
    if depth_batch:
        from sern_jax.grasp import candidates as cand_lib
        from sern_jax.grasp import depth as depth_lib

        cam = depth_lib.CameraConfig()
        params = ctx.camera
        mx = depth_lib.camera_model(model)
        poses = depth_lib.geom_poses(scene_lib.initial_data(model))
        batch_poses = jax.tree.map(
            lambda a: jax.numpy.broadcast_to(a, (depth_batch, *a.shape)), poses
        )
        batch_params = jax.tree.map(
            lambda a: jax.numpy.broadcast_to(a, (depth_batch, *jax.numpy.shape(a))),
            params,
        )
        render = depth_lib.make_renderer(cam)
        img, first, best = _first_and_best(
            lambda: render(mx, batch_poses, batch_params), repeats
        )
        out["depth"] = {
            "batch": depth_batch,
            "shape": list(cam.shape),
            "images_per_s": depth_batch / best,
            "compile_s": max(first - best, 0.0),
        }
        stages["depth_image_s"] = best / depth_batch
        log(f"depth  batch {depth_batch:6d}: {depth_batch / best:9.1f} images/s")
        sampler = cand_lib.make_sampler(cand_lib.CandidateConfig())
        keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(
            jax.numpy.arange(depth_batch)
        )
        c, first, best = _first_and_best(
            lambda: sampler(keys, img.depth, params), repeats
        )
        out["candidates"] = {
            "batch": depth_batch,
            "num_candidates": int(c.grasps.shape[-2]),
            "sets_per_s": depth_batch / best,
            "valid_fraction": float(np.mean(c.valid)),
            "compile_s": max(first - best, 0.0),
        }
        stages["candidate_set_s"] = best / depth_batch
        log(f"cands  batch {depth_batch:6d}: {depth_batch / best:9.1f} sets/s")
    # Whole contexts (scene poses + depth + candidates) per second, context.make_contexts.
    if context_poses:
        rows = []
        for num in context_poses:
            keys = [jax.random.fold_in(key, 1000 + r) for r in range(repeats + 1)]
            call = iter(keys)
            _, first, best = _first_and_best(
                lambda: context_lib.make_contexts(next(call), spec, num, model=model),
                repeats,
            )
            rows.append(
                {"poses": num, "contexts_per_s": num / best, "first_call_s": first}
            )
            log(f"contexts P {num:6d}: {num / best:9.1f} contexts/s")
        out["contexts"] = rows
        stages["context_s"] = 1.0 / rows[-1]["contexts_per_s"]
    if args.quality_sets > 0:
        # The quality network beside the simulator in the same run: 64-candidate sets
        # scored per second (crops + network, batched) and Adam steps per second.
        from sern_jax.grasp import quality_net

        qn = quality_net.benchmark(num_sets=args.quality_sets,
                                   batch_size=args.quality_batch)
        out["quality_net"] = qn
        log(f"quality net: {qn['sets_scored_per_s']:.0f} sets of 64 scored/s, "
            f"{qn['train_steps_per_s']:.0f} train steps/s (batch {args.quality_batch})")
    out["stages"] = stages

    if args.agreement:
        names = [n for n in args.agreement_objects.split(",") if n]
        out["agreement"] = measure_agreement(
            names,
            args.agreement,
            progress=lambda n, s: log(
                f"agreement {n}: {s['agreement']:.3f} "
                f"(native {s['success_native']:.2f}, "
                f"mjx {s['success_mjx']:.2f})"
            ),
        )
        log(f"agreement overall: {out['agreement']['agreement']:.3f}")

    text = json.dumps(out, indent=None if args.json else 2, default=float)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    return 0


def main(argv=None) -> int:
    """``python -m sern_jax.commands.bench_grasp grasp ...`` (the same as ``sern bench grasp ...``)."""
    parser = argparse.ArgumentParser(prog="sern bench")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    raise SystemExit(main())
