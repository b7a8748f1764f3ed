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
over objects x trials). :func:`measure_agreement` is the paired native-vs-MJX agreement of trial
outcomes. Every figure
is measured in the call on this machine (``machine``: :func:`sern_jax.infra.io.machine`); timings
use :func:`sern_jax.infra.timing.time_calls`. The JSON fields are ``sern bench grasp --json``'s.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

from sern_jax.infra import hosts, io, timing

__all__ = ["GraspBenchConfig", "grasp_benchmark", "measure_agreement", "objects_benchmark",
           "quality_net_benchmark", "random_grasps"]


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
                      repeats: int = 2, log: Callable[[str], None] | None = None) -> dict:
    """Trials/s of a batch of different objects per backend, and ``mjx_compiles``.

    Native: each object's ``GraspSimulator`` on ``threads``, one object after another. MJX:
    ``sim.UniformBatch``, one compiled ``jit(vmap(vmap(execute)))`` program over objects x
    trials on the objects' uniform models. ``mjx_compiles`` is the number of distinct compiled
    MJX trial programs after the batch ran in its order and in reverse (a new batch): 1 when
    one program serves every object. Object i: resting pose seed i, ``trials_per_object``
    grasps from ``random_grasps`` and noise from ``sim.sample_noise``.
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
    return {"objects": [s.name for s in specs], "trials_per_object": n,
            "mjx_compiles": reverse.compiles, "native": native, "mjx": mjx}


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
        out["objects"] = objects_benchmark(cfg.objects, cfg.objects_trials, threads, repeats, log)
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
