"""``sern grasp show``: pictures of one object's grasp context.

For one object (a name from ``objects.object_names()`` or ``--mesh PATH``) at a random
resting pose (``--seed``), this writes into ``--out``:

* ``figures/depth_candidates.png``: the overhead depth image with the K = 64 antipodal
  candidates drawn as parallel jaws (two bars at the contacts joined by the closing axis),
  coloured by their simulated success probability (M randomised trials each, native
  MuJoCo by default);
* ``figures/scene.png``: MuJoCo's own renderer, an oblique view of the table and object,
  and the same view with the gripper posed (open) at the best candidate;
* ``results.npz`` (depth, candidates, probabilities), ``config.json``, ``metadata.json``.

Rendering needs an OpenGL backend. Headless Linux: ``MUJOCO_GL=egl`` (Mesa's software EGL
works without a GPU) or ``MUJOCO_GL=osmesa`` (needs Debian's ``libosmesa6``). ``--gl``
sets MUJOCO_GL for this run; by default an already set MUJOCO_GL is kept, otherwise EGL is
tried on Linux.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

__all__ = ["TRIAL_STREAM", "add_parser", "run"]

# fold_in id of the trials' key under the root key; the context (make_context(root, ...))
# uses context.POSE_STREAM, DEPTH_NOISE_STREAM and CANDIDATE_STREAM (0, 1, 2).
TRIAL_STREAM = 3

_DESCRIPTION = """\
Pictures of one grasp context: an object at a random resting pose on the table, the
overhead depth image with its 64 antipodal grasp candidates drawn as gripper jaws and
coloured by simulated success probability (M randomised trials per candidate), and a
MuJoCo-rendered view of the scene with the gripper at the best candidate.

Writes OUT/figures/depth_candidates.png, OUT/figures/scene.png, OUT/results.npz,
OUT/config.json and OUT/metadata.json.

Examples:
  sern grasp show box
  sern grasp show slim_bottle --seed 3 --trials 32 --out runs/show_bottle
  sern grasp show --mesh part.stl --mesh-units mm
"""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Registers ``show`` under ``sern grasp``."""
    p = subparsers.add_parser(
        "show",
        help="PNGs of an object's depth image, 64 grasp candidates and a rendered scene",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "object",
        nargs="?",
        help="object name (see `sern grasp show --list`) or a path to an .obj/.stl mesh",
    )
    p.add_argument(
        "--mesh", metavar="PATH", help="a user mesh (.obj/.stl) instead of a name"
    )
    p.add_argument(
        "--mesh-units",
        choices=("auto", "m", "cm", "mm"),
        default="auto",
        help="units of the mesh file's coordinates (default auto: guessed from the size; "
        "the guess and the resulting size are printed)",
    )
    p.add_argument("--list", action="store_true", help="list the object names and exit")
    p.add_argument(
        "--out",
        default=None,
        help="output directory (default: runs/show_<object>_s<seed>)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="resting pose, sampling and trial seed (default 0)",
    )
    p.add_argument(
        "--trials",
        type=int,
        default=16,
        help="randomised trials per candidate for the success probability (default 16); "
        "0 skips simulation and colours candidates by validity only",
    )
    p.add_argument(
        "--backend",
        choices=("native", "mjx"),
        default="native",
        help="simulator for the trials (default native: MuJoCo C, fastest on CPU)",
    )
    p.add_argument(
        "--noise", action="store_true", help="add Dex-Net-style depth sensor noise"
    )
    p.add_argument(
        "--gl",
        choices=("auto", "egl", "osmesa", "glfw"),
        default="auto",
        help="OpenGL backend for MuJoCo's renderer (sets MUJOCO_GL); auto keeps an existing "
        "MUJOCO_GL, else uses egl on Linux",
    )
    p.add_argument(
        "--no-render", action="store_true", help="skip the MuJoCo-rendered scene.png"
    )
    p.set_defaults(func=run)
    return p


def import_mjx_quietly() -> None:
    """Imports ``mujoco.mjx`` (through ``sern_jax.grasp.world._mjx``) dropping its "Failed to import
    warp / mujoco_warp" notices (the optional warp backend is not used); other output passes."""
    import contextlib
    import io as _io

    buf = _io.StringIO()
    with contextlib.redirect_stderr(buf):
        from sern_jax.grasp.world import _mjx  # noqa: F401
    for line in buf.getvalue().splitlines():
        if not line.startswith(("Failed to import warp", "Failed to import mujoco_warp")):
            print(line, file=sys.stderr)


_MAX_TRIALS = 4096  # 64 candidates x 4096 trials = 262,144 grasps: bounds one call's time and memory


def _check_arguments(args) -> None:
    """The flags' own errors (one line naming the flag), before any import of MuJoCo or OpenGL:
    a machine without a GL library still hears about a bad --trials first."""
    if not 0 <= args.trials <= _MAX_TRIALS:
        raise ValueError(
            f"--trials must lie in [0, {_MAX_TRIALS}] (64 candidates x {args.trials} trials "
            f"would be {64 * args.trials:,} simulated grasps), got {args.trials}")
    if not 0 <= args.seed <= 2**32 - 1:
        raise ValueError(f"--seed must lie in [0, 2^32 - 1], got {args.seed}")
    if (args.object is None) == (args.mesh is None):
        raise ValueError(
            "give exactly one of OBJECT or --mesh PATH (see --help, --list)"
        )


def run(args) -> int:
    """Entry point of ``sern grasp show``; returns the exit code."""
    from sern_jax.grasp.world import pictures  # imports mujoco without OpenGL

    if not args.list:  # pure argument errors first: they need neither MuJoCo nor OpenGL
        _check_arguments(args)
    if not args.no_render and not args.list:  # the backend is loaded and checked before any work
        try:
            pictures.use_gl(None if args.gl == "auto" else args.gl)
        except RuntimeError as exc:
            raise ValueError(f"--gl {args.gl}: {exc} (--no-render)") from None
    import_mjx_quietly()
    from sern_jax.grasp.world import objects as objects_lib

    if args.list:
        print("\n".join(objects_lib.object_names()))
        return 0
    from sern_jax.infra import validate

    validate.out_dir(args.out)  # tried for real (made and removed), before any work
    if args.mesh is not None:
        spec = objects_lib.load_mesh(args.mesh, units=args.mesh_units)
    elif str(args.object).lower().endswith((".obj", ".stl")):
        spec = objects_lib.load_mesh(args.object, units=args.mesh_units)
    else:
        spec = objects_lib.make_object(args.object)

    import jax
    import numpy as np

    from sern_jax.infra import io
    from sern_jax.grasp.world import context as context_lib
    from sern_jax.grasp.world import sim as sim_lib

    safe_name = "".join(c if c.isalnum() or c in "-_" else "_" for c in spec.name)
    out = args.out or os.path.join("runs", f"show_{safe_name}_s{args.seed}")
    try:
        run_dir = io.make_run_dir(
            os.path.dirname(os.path.abspath(out)), os.path.basename(os.path.abspath(out))
        )
    except OSError as exc:
        raise ValueError(f"--out {out}: cannot create the directory ({exc.strerror or exc})") \
            from None
    root = jax.random.key(args.seed)
    key_trials = jax.random.fold_in(root, TRIAL_STREAM)
    timings = {}

    t = time.perf_counter()
    config = context_lib.ContextConfig(noise=bool(args.noise))
    ctx = context_lib.make_context(root, spec, config)
    model, depth, cands = ctx.model, ctx.depth, ctx.candidates
    valid = cands.valid
    timings["context_s"] = time.perf_counter() - t
    print(f"{spec.name}: {int(valid.sum())}/{len(valid)} valid candidates", flush=True)

    prob = valid.astype(np.float64)
    colour_label = "valid (no simulation: --trials 0)"
    backend = None
    if args.trials and valid.any():
        t = time.perf_counter()
        simulator = sim_lib.GraspSimulator(model, backend=args.backend)
        est = simulator.success_probability(
            key_trials, cands.grasps, args.trials, valid=valid
        )
        prob = np.asarray(est.prob, np.float64)
        backend = est.backend
        timings["trials_s"] = time.perf_counter() - t
        colour_label = f"success probability ({args.trials} trials, {backend})"
        nan = int(np.sum(est.nan_count))
        print(
            f"simulated {int(valid.sum()) * args.trials} trials ({backend}) in "
            f"{timings['trials_s']:.1f} s; best p = {prob[valid].max():.2f}, "
            f"mean p = {prob[valid].mean():.2f}, non-finite trials: {nan}",
            flush=True,
        )

    figures = run_dir / "figures"
    title = (
        f"{spec.name} (seed {args.seed}): {int(valid.sum())} valid of {len(valid)} candidates"
        + ("" if backend else "; coloured by validity only")
    )
    pictures.draw_candidates(
        figures / "depth_candidates.png", depth, cands, prob, title, colour_label
    )
    written = [figures / "depth_candidates.png"]

    best = None
    if valid.any():
        best = cands.grasps[int(np.argmax(np.where(valid, prob, -1.0)))]
    status = 0
    if not args.no_render:
        try:
            pictures.render_scene(
                figures / "scene.png", model, best, f"{spec.name} (seed {args.seed})"
            )
            written.append(figures / "scene.png")
        except Exception as e:  # noqa: BLE001 - any GL failure is reported, not hidden
            print(
                f"error: MuJoCo rendering failed with MUJOCO_GL={os.environ.get('MUJOCO_GL')}: "
                f"{type(e).__name__}: {e}. Try --gl egl or --gl osmesa (apt-get install "
                "libosmesa6), or --no-render.",
                file=sys.stderr,
            )
            status = 1

    io.save_npz(
        run_dir / "results.npz",
        depth=depth,
        pose=ctx.pose,
        grasps=cands.grasps,
        valid=valid,
        width=cands.width,
        endpoints=cands.endpoints,
        center_px=cands.center_px,
        angle_px=cands.angle_px,
        grasp_depth=cands.grasp_depth,
        prob=prob if backend else np.full(len(valid), np.nan),
    )
    io.save_json(
        run_dir / "config.json",
        {
            "object": spec.name,
            "seed": args.seed,
            "trials": args.trials,
            "backend": backend,
            "noise": bool(args.noise),
            "pose": ctx.pose,
            "camera": config.camera,
            "candidates": config.candidates,
            "mujoco_gl": os.environ.get("MUJOCO_GL"),
        },
    )
    io.save_json(run_dir / "metadata.json", io.run_metadata(timings=timings))
    for path in written:
        print(f"wrote {path}")
    return status
