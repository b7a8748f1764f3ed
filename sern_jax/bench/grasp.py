"""The grasp pipeline's throughput, measured: what ``sern bench grasp`` prints.

:func:`grasp_benchmark` measures, on the scene of one object (default ``small_box``):

* grasp trials/s for each backend (native ``mujoco.rollout``, MJX) at a few batch sizes,
  best of ``repeats`` timed calls after one warm-up call (whose extra time is ``compile_s``
  for MJX), and trials per CPU-second of this process (all its threads; a figure that other
  load on a shared machine distorts less than wall-clock time);
* depth images/s (``depth.make_renderer``) and candidate sets/s (``candidates.make_sampler``)
  at ``depth_batch`` images;
* whole grasp contexts/s (``context.make_contexts``: resting poses, depth, candidates) at
  ``context_poses`` poses per call (different poses each call, one shared scene);
* a time split per stage (first context incl. compiles, depth per image, candidates per set,
  one context, one trial per backend), and the quality network's rates
  (:func:`quality_net_benchmark`).

:func:`objects_benchmark` (``sern bench grasp --objects a,b,c``) times a batch of different
objects per backend and counts the compiled MJX trial programs (``mjx_compiles``: 1, one program
over objects x trials). :func:`dataset_benchmark` (``sern bench grasp --dataset-objects N``)
generates a slice of D0 per backend side by side and projects the full D0 and a Dex-Net-scale
one from the measured rates. :func:`measure_agreement` is the paired native-vs-MJX agreement of
trial outcomes. Every figure
is measured in the call on this machine (``machine``: :func:`sern_jax.infra.io.machine`); timings
use :func:`sern_jax.infra.timing.time_calls`. The JSON fields are ``sern bench grasp --json``'s.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable

from sern_jax.infra import hosts, io, timing

__all__ = ["DATASET_BACKENDS", "DEXNET_GRASPS", "DEXNET_OBJECTS", "GraspBenchConfig",
           "dataset_benchmark", "dataset_rates", "grasp_benchmark", "measure_agreement",
           "objects_benchmark", "quality_net_benchmark", "random_grasps"]

DATASET_BACKENDS = ("native", "mjx")
DEXNET_OBJECTS = 4_000  # a Dex-Net-scale D0: objects ...
DEXNET_GRASPS = 6_700_000  # ... and labelled grasps (Dex-Net 2.0's 6.7M)


@dataclasses.dataclass(frozen=True)
class GraspBenchConfig:
    """What :func:`grasp_benchmark` measures (``sern bench grasp``'s flags)."""

    object: str = "small_box"  # object name or .obj/.stl path
    native_batches: tuple[int, ...] = (64, 256)  # native batch sizes; () skips
    mjx_batches: tuple[int, ...] = (16, 64)  # MJX batch sizes; () skips
    depth_batch: int = 16  # images per depth call (0 skips depth and candidates)
    context_poses: tuple[int, ...] = (16,)  # poses per make_contexts call; () skips
    threads: int | None = None  # native threads (None: all cores)
    repeats: int = 2  # timed calls per setting
    quality_sets: int = 16  # 64-candidate sets per quality-network scoring call (0 skips)
    quality_batch: int = 64  # minibatch of the quality-network training-step timing
    objects: tuple[str, ...] = ()  # a batch of objects for objects_benchmark; () skips
    objects_trials: int = 64  # trials per object of objects_benchmark
    mjx_reference: bool = False  # objects_benchmark: also MJX's own Hessian assembly


def random_grasps(key, model, n):
    """n grasps near the object: centre + U[±2 cm] in x, y, θ ~ U[-π/2, π/2); key consumed."""
    import jax
    import numpy as np

    from sern_jax.grasp.world import scene as scene_lib

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

    from sern_jax.grasp.world import objects as objects_lib
    from sern_jax.grasp.world import scene as scene_lib
    from sern_jax.grasp.world import sim

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


def objects_benchmark(objects, trials_per_object: int, threads: int | None = None,
                      repeats: int = 2, log: Callable[[str], None] | None = None,
                      reference: bool = False) -> dict:
    """Trials/s of a batch of different objects per backend, and ``mjx_compiles``.

    Native: each object's ``GraspSimulator`` on ``threads``, one object after another. MJX:
    ``sim.UniformBatch``, one compiled ``jit(vmap(vmap(execute)))`` program over objects x
    trials on the objects' uniform models. ``mjx_compiles`` is the number of distinct compiled
    MJX trial programs after the batch ran in its order and in reverse (a new batch): 1 when
    one program serves every object. Object i: resting pose seed i, ``trials_per_object``
    grasps from ``random_grasps`` and noise from ``sim.sample_noise``.

    With ``reference``, the same batch also runs with MJX's own assembly of the Newton
    Hessian (``hessian="mjx"``, a second program) under ``"mjx_reference"``, beside the
    block assembly that every MJX trial uses (``"mjx"``), with ``"paired_agreement"``:
    the fraction of trials whose success is the same under both.
    """
    import jax
    import numpy as np

    from sern_jax.grasp.world import objects as objects_lib
    from sern_jax.grasp.world import scene as scene_lib
    from sern_jax.grasp.world import sim

    log = log or (lambda msg: None)
    specs = [objects_lib.resolve_object(o) for o in objects]
    models = [scene_lib.build_scene(spec, seed=i) for i, spec in enumerate(specs)]
    n, key = trials_per_object, jax.random.key(0)
    grasps = np.stack([random_grasps(jax.random.fold_in(key, i), m, n)
                       for i, m in enumerate(models)])
    noise = [sim.sample_noise(jax.random.fold_in(key, 1000 + i), n) for i in range(len(models))]
    stacked = sim.TrialNoise(*(np.stack([z[k] for z in noise]) for k in range(3)))
    total = n * len(models)
    threads = threads or hosts.cpu_threads()
    natives = [sim.GraspSimulator(m, "native", num_threads=threads) for m in models]
    tm = timing.time_calls(lambda: [s.run_trials(g, z) for s, g, z in zip(natives, grasps, noise)],
                           repeats, warmup=1)
    native = {"threads": threads, "trials_per_s": total / tm.best_s, "seconds": tm.best_s,
              "success_rate": float(np.mean([r.success.mean() for r in tm.result]))}
    log(f"objects native: {native['trials_per_s']:9.1f} trials/s ({len(models)} objects)")
    t0 = time.perf_counter()
    batch = sim.UniformBatch(models, sim.TrialConfig(), trials=n)
    models_s = time.perf_counter() - t0
    tm = timing.time_calls(lambda: batch.run_trials(grasps, stacked), repeats, warmup=1)
    reverse = sim.UniformBatch(models[::-1], sim.TrialConfig(), batch.shape, trials=n)
    reverse.run_trials(grasps[::-1], sim.TrialNoise(*(a[::-1] for a in stacked)))
    mjx = {"trials_per_s": total / tm.best_s, "seconds": tm.best_s, "first_call_s": tm.first_s,
           "compile_s": max(tm.first_s - tm.best_s, 0.0), "models_s": models_s,
           "parts": batch.shape.parts, "vertices": batch.shape.vertices,
           "success_rate": float(np.mean([r.success.mean() for r in tm.result]))}
    log(f"objects mjx:    {mjx['trials_per_s']:9.1f} trials/s, {reverse.compiles} compiled "
        f"program(s) (first call {tm.first_s:.1f} s)")
    out = {"objects": [s.name for s in specs], "trials_per_object": n,
           "mjx_compiles": reverse.compiles, "native": native, "mjx": mjx}
    if reference:
        blocks = tm.result
        ref = sim.UniformBatch(models, sim.TrialConfig(), batch.shape, trials=n,
                               hessian="mjx")
        tr = timing.time_calls(lambda: ref.run_trials(grasps, stacked), repeats, warmup=1)
        out["mjx_reference"] = {
            "hessian": "mjx", "trials_per_s": total / tr.best_s, "seconds": tr.best_s,
            "first_call_s": tr.first_s, "compile_s": max(tr.first_s - tr.best_s, 0.0),
            "success_rate": float(np.mean([r.success.mean() for r in tr.result]))}
        out["mjx_speedup"] = mjx["trials_per_s"] / out["mjx_reference"]["trials_per_s"]
        out["paired_agreement"] = float(np.mean(np.concatenate(
            [a.success == b.success for a, b in zip(blocks, tr.result)])))
        log(f"objects mjx (MJX's own Hessian): {total / tr.best_s:9.1f} trials/s; blocks "
            f"{out['mjx_speedup']:.2f}x, paired agreement {out['paired_agreement']:.3f}")
    return out


def dataset_rates(backend: str, stats: list[dict], seconds: float, objects_per_shard: int,
                  trials_per_grasp: int = 1) -> dict:
    """Rates of one D0 generation from its per-shard timings (``dataset.generate(...,
    stats=)``), and projections to the default D0 (``DatasetConfig().num_objects`` objects)
    and a Dex-Net-scale D0 (:data:`DEXNET_OBJECTS` objects; :data:`DEXNET_GRASPS` grasps).

    Native: one object after another, so time scales with objects (``seconds`` per object).
    MJX: the first shard (its contexts and the compile), then shards whose host contexts
    (made ahead, in threads) overlap the device trials of the shard before: the steady cost of
    a shard is the mean wall time of the shards after the first (with one shard measured: the
    larger of its contexts_s and trials_s, the latter incl. the compile, an upper bound).
    ``bound`` names the larger of the steady per-shard host contexts and trial times."""
    from sern_jax.grasp.model import dataset

    objects = sum(st["objects"] for st in stats)
    trials = sum(st["trials"] for st in stats)
    contexts_s = sum(st["contexts_s"] for st in stats)
    trials_s = sum(st["trials_s"] for st in stats)
    grasps_per_object = trials / trials_per_grasp / max(objects, 1)
    row = {"seconds": seconds, "objects": objects, "shards": len(stats), "trials": trials,
           "trials_per_s": trials / seconds if seconds > 0 else None,
           "contexts_s": contexts_s, "trials_s": trials_s,
           "grasps_per_object": grasps_per_object}
    if backend == "mjx":
        first, rest = stats[0], stats[1:]
        row.update(first_shard_s=first["seconds"],
                   rest_s=sum(st["seconds"] for st in rest) if rest else None,
                   mjx_compiles=sum(st.get("compiled") or 0 for st in stats),
                   waited_s=sum(st.get("waited_s", 0.0) for st in stats))
        if rest:
            steady = sum(st["seconds"] for st in rest) / len(rest)
            host = sum(st["contexts_s"] for st in rest) / len(rest)
            device = sum(st["trials_s"] for st in rest) / len(rest)
            rest_trials = sum(st["trials"] for st in rest)
            row["rest_trials_per_s"] = rest_trials / row["rest_s"] if row["rest_s"] else None
            row["compile_s"] = max(first["trials_s"] - device, 0.0)
            row["projection_from"] = "shards after the first"
        else:
            host, device = first["contexts_s"], first["trials_s"]
            steady = max(host, device)
            row["rest_trials_per_s"] = row["compile_s"] = None
            row["projection_from"] = "first shard (incl. compile: an upper bound)"
        row["shard_contexts_s"], row["shard_trials_s"] = host, device
        row["bound"] = "host contexts" if host > device else "device trials"

        def project(num_objects):
            shards = math.ceil(num_objects / objects_per_shard)
            return first["seconds"] + (shards - 1) * steady
    else:
        per_object = seconds / max(objects, 1)
        row["bound"] = "host contexts" if contexts_s > trials_s else "host trials"

        def project(num_objects):
            return num_objects * per_object

    def projection(num_objects):
        secs = project(num_objects)
        return {"objects": num_objects, "grasps": round(num_objects * grasps_per_object),
                "seconds": secs, "hours": secs / 3600}

    dexnet_objects = math.ceil(DEXNET_GRASPS / grasps_per_object) if grasps_per_object else 0
    row["projections"] = {
        "d0_default": projection(dataset.DatasetConfig().num_objects),
        "dexnet_objects": projection(DEXNET_OBJECTS),
        "dexnet_grasps": projection(dexnet_objects) if dexnet_objects else None,
    }
    return row


def dataset_benchmark(num_objects: int, poses: int = 16,
                      backends: tuple[str, ...] = DATASET_BACKENDS,
                      log: Callable[[str], None] | None = None) -> dict:
    """D0 generation per backend, side by side: ``dataset.generate`` of the first
    ``num_objects`` objects of the default population with ``poses`` poses each (other fields:
    ``DatasetConfig``'s defaults) into a temporary directory per backend, in this process.

    Both backends label the same contexts with the same noise (the same keys), so
    ``label_agreement`` is the fraction of valid slots whose labels agree. The candidate
    sampler is compiled before either is timed (``warmup_s``). Per backend
    (:func:`dataset_rates`): total seconds, trials (valid grasps labelled) and trials/s, the
    host seconds making contexts and the seconds in the trials, MJX's first shard (incl. the
    compile) against the rest and ``mjx_compiles``, and projections with their bound.
    """
    import tempfile

    import jax
    import numpy as np

    from sern_jax.grasp.model import dataset
    from sern_jax.grasp.world import context as context_lib

    log = log or (lambda msg: None)
    out = {"objects": num_objects, "poses": poses, "backends": list(backends),
           "objects_per_shard": dataset.DatasetConfig().objects_per_shard,
           "context_threads": hosts.context_threads(), "trial_threads": hosts.cpu_threads(),
           "dexnet_objects": DEXNET_OBJECTS, "dexnet_grasps": DEXNET_GRASPS}
    base = dataset.DatasetConfig(num_objects=num_objects, poses_per_object=poses)
    t0 = time.perf_counter()
    context_lib.make_contexts(jax.random.key(0), dataset.dataset_objects(base)[0], poses,
                              context_lib.ContextConfig(renderer="native"))
    out["warmup_s"] = time.perf_counter() - t0
    labels = {}
    for backend in backends:
        config = dataclasses.replace(base, backend=backend)
        stats: list[dict] = []
        with tempfile.TemporaryDirectory(prefix=f"sern-d0-{backend}-") as d:
            t0 = time.perf_counter()
            dataset.generate(config, d, progress=False, log=lambda *_: None, stats=stats)
            seconds = time.perf_counter() - t0
            _, data = dataset.load(d)
            labels[backend] = data["label"], data["valid"]
        row = dataset_rates(backend, stats, seconds, config.objects_per_shard,
                            config.trials_per_grasp)
        out[backend] = row
        extra = (f", first shard {row['first_shard_s']:.1f} s, {row['mjx_compiles']} compiled "
                 "program(s)") if backend == "mjx" else ""
        log(f"dataset {backend:6s}: {num_objects} objects in {seconds:.1f} s, "
            f"{row['trials_per_s']:.1f} trials/s (contexts {row['contexts_s']:.1f} s, trials "
            f"{row['trials_s']:.1f} s{extra}); default D0 ~"
            f"{row['projections']['d0_default']['hours']:.2f} h, bound: {row['bound']}")
    if len(labels) == 2:
        (a, va), (b, vb) = labels["native"], labels["mjx"]
        out["valid_equal"] = bool(np.array_equal(va, vb))
        both = va & vb
        out["label_agreement"] = float(np.mean(a[both] == b[both])) if both.any() else None
    return out


def grasp_benchmark(cfg: GraspBenchConfig = GraspBenchConfig(),
                    log: Callable[[str], None] | None = None) -> dict:
    """Runs the measurements of ``cfg`` in this process; returns the JSON object of
    ``sern bench grasp --json`` (without ``agreement``). ``log`` receives one line per
    figure as it is measured."""
    import jax
    import numpy as np

    from sern_jax.grasp.world import context as context_lib
    from sern_jax.grasp.world import objects as objects_lib
    from sern_jax.grasp.world import scene as scene_lib
    from sern_jax.grasp.world import sim

    log = log or (lambda msg: None)
    spec = objects_lib.resolve_object(cfg.object)
    native_batches, mjx_batches = list(cfg.native_batches), list(cfg.mjx_batches)
    depth_batch, context_poses, repeats = cfg.depth_batch, list(cfg.context_poses), cfg.repeats
    out = {"benchmark": "grasp", "object": spec.name, "machine": io.machine(devices=True)}
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
            tm = timing.time_calls(lambda: simulator.run_trials(g, noise), repeats, warmup=1)
            res, first, best, best_cpu = tm.result, tm.first_s, tm.best_s, tm.best_cpu_s
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
    threads = cfg.threads or hosts.cpu_threads()
    if native_batches:
        rows, _ = time_backend("native", native_batches, num_threads=threads)
        backends["native"] = {"threads": threads, "batches": rows}
        stages["native_trial_s"] = rows[-1]["seconds"] / rows[-1]["batch"]
    if mjx_batches:
        rows, compile_s = time_backend("mjx", mjx_batches)
        backends["mjx"] = {"batches": rows, "compile_s": compile_s}
        stages["mjx_trial_s"] = rows[-1]["seconds"] / rows[-1]["batch"]
    out["backends"] = backends
    if cfg.objects:
        out["objects"] = objects_benchmark(cfg.objects, cfg.objects_trials, threads, repeats, log,
                                           reference=cfg.mjx_reference)
        out["mjx_compiles"] = out["objects"]["mjx_compiles"]

    # Depth images and candidate sets (depth.py and candidates.py on this scene).
    if depth_batch:
        from sern_jax.grasp.world import candidates as cand_lib
        from sern_jax.grasp.world import depth as depth_lib

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
        tm = timing.time_calls(lambda: render(mx, batch_poses, batch_params), repeats)
        img, first, best = tm.result, tm.first_s, tm.best_s
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
        tm = timing.time_calls(lambda: sampler(keys, img.depth, params), repeats)
        c, first, best = tm.result, tm.first_s, tm.best_s
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
            tm = timing.time_calls(
                lambda: context_lib.make_contexts(next(call), spec, num, model=model), repeats)
            first, best = tm.first_s, tm.best_s
            rows.append(
                {"poses": num, "contexts_per_s": num / best, "first_call_s": first}
            )
            log(f"contexts P {num:6d}: {num / best:9.1f} contexts/s")
        out["contexts"] = rows
        stages["context_s"] = 1.0 / rows[-1]["contexts_per_s"]
    if cfg.quality_sets > 0:
        # The quality network beside the simulator in the same run: 64-candidate sets
        # scored per second (crops + network, batched) and Adam steps per second.
        qn = quality_net_benchmark(num_sets=cfg.quality_sets, batch_size=cfg.quality_batch)
        out["quality_net"] = qn
        log(f"quality net: {qn['sets_scored_per_s']:.0f} sets of 64 scored/s, "
            f"{qn['train_steps_per_s']:.0f} train steps/s (batch {cfg.quality_batch})")
    out["stages"] = stages
    return out


# ----------------------------------------------------------------------------- quality network


def _synthetic_sets(num_sets: int, num_candidates: int, size: int = 96):
    """Depth images of a box on a table and random candidates (host side, fixed seed)."""
    import numpy as np

    rng = np.random.default_rng(0)
    images = np.full((num_sets, size, size), 0.6, np.float32)
    images[:, 30:66, 38:58] = 0.55
    center = rng.uniform(20, size - 20, (num_sets, num_candidates, 2)).astype(np.float32)
    angle = rng.uniform(-np.pi / 2, np.pi / 2, (num_sets, num_candidates))
    gdepth = rng.uniform(0.56, 0.59, (num_sets, num_candidates))
    return images, (center, angle.astype(np.float32), gdepth.astype(np.float32))


def quality_net_benchmark(config=None, num_sets: int = 16, batch_size: int = 64,
                          num_candidates: int = 64, min_time: float = 1.0) -> dict:
    """Measures the quality network's scoring and training rates on this machine (jitted,
    after compiling).

    Scoring: ``num_sets`` 96x96 depth images x ``num_candidates`` candidates per call,
    crops (``crops.extract_batch``) + network, one jitted call. Training: one Adam step
    (``quality_net.make_train_step``, BCE) on a minibatch of ``batch_size`` crops.

    Args:
      config: the network's ``QualityNetConfig`` (None: the default network).
      num_sets: candidate sets (images) scored per call.
      batch_size: training minibatch size.
      num_candidates: candidates per set (K).
      min_time: seconds spent timing each rate.

    Returns:
      dict: sets_scored_per_s, grasps_scored_per_s, sets_per_call, num_candidates,
      train_steps_per_s, train_examples_per_s, train_batch_size, params,
      flops_per_grasp, gqcnn_params, gqcnn_flops_per_grasp, jax_backend.
    """
    import jax
    import jax.numpy as jnp
    import numpy as np
    import optax

    from sern_jax.grasp.model import quality_net as qn
    from sern_jax.grasp.world import crops as crops_lib

    config = qn.QualityNetConfig() if config is None else config
    net = qn.make_quality_network(config)
    params = net.init(jax.random.key(0))
    crop_config = crops_lib.CropConfig(crop_size=config.crop_size)
    images, cands = _synthetic_sets(num_sets, num_candidates)

    @jax.jit
    def score(params, images, cands):
        c = crops_lib.extract_batch(images, cands, crop_config)
        return net.apply(params, c.image, c.depth)

    args = (params, jnp.asarray(images), jax.tree.map(jnp.asarray, cands))
    t_score = timing.time_calls(lambda: score(*args), repeats=3, min_calls=3,
                                min_time=min_time / 3).median_s

    optimizer = optax.adam(1e-3)
    step = jax.jit(qn.make_train_step(net, optimizer))
    crops0 = crops_lib.extract_batch(*args[1:], crop_config)
    rows = np.arange(batch_size) % (num_sets * num_candidates)
    batch = qn.TrainData(
        crops0.image.reshape(-1, config.crop_size, config.crop_size)[rows],
        crops0.depth.reshape(-1)[rows],
        jnp.asarray(rows % 2, jnp.float32),
        jnp.ones((batch_size,), jnp.float32),
    )
    opt_state = qn.init_opt_state(optimizer, params)
    t_step = timing.time_calls(lambda: step(params, opt_state, batch)[2], repeats=3,
                               min_calls=3, min_time=min_time / 3).median_s
    return {
        "sets_scored_per_s": num_sets / t_score,
        "grasps_scored_per_s": num_sets * num_candidates / t_score,
        "sets_per_call": num_sets,
        "num_candidates": num_candidates,
        "train_steps_per_s": 1.0 / t_step,
        "train_examples_per_s": batch_size / t_step,
        "train_batch_size": batch_size,
        "params": qn.param_count(config),
        "flops_per_grasp": qn.flops_per_grasp(config),
        "gqcnn_params": qn.param_count(qn.GQCNN_2_0),
        "gqcnn_flops_per_grasp": qn.flops_per_grasp(qn.GQCNN_2_0),
        "jax_backend": jax.default_backend(),
    }
