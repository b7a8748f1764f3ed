"""Makes the shipped θ0 and core set: D0, pretraining, held-out metrics, hard-set screen.

The same steps as ``sern grasp dataset``, ``sern grasp pretrain`` and ``sern grasp screen``
with their defaults, in one process (used to make ``sern_jax/grasp/data/`` on one machine).

    python -m experiments.make_theta0 --out runs/theta0 [--objects 200 --poses 16]

The manifest it leaves in ``OUT/theta0`` also records how it was made: this command, the
equivalent ``sern grasp`` commands, the seeds, the machine, the simulated world
(``sim.physics_settings()``: the gripper and the trial) and the seconds of each step, beside
the sha256 of θ0 and of the screen (``artifacts.save_screen``), which loading checks.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

# the config fields behind the flags, for the configs' messages
_FLAGS = {"num_objects": "--objects", "poses_per_object": "--poses", "epochs": "--epochs",
          "heldout_objects": "--heldout-objects", "heldout_poses": "--heldout-poses",
          "heldout_trials": "--heldout-trials", "core_k": "--core-k"}


def main(argv=None) -> int:
    from sern_jax.infra import validate

    # bad input: one line naming the flag, exit 2, before any compile (validate's parser)
    parser = validate.script_parser(__spec__, description=__doc__.splitlines()[0])
    count = validate.int_at_least(1)
    parser.add_argument("--out", default="runs/theta0")
    parser.add_argument("--objects", type=count, default=200)
    parser.add_argument("--poses", type=count, default=16)
    parser.add_argument("--epochs", type=count, default=8)
    parser.add_argument("--screen-poses", type=count, default=8)
    parser.add_argument("--screen-trials", type=count, default=16)
    parser.add_argument("--fresh-trials", type=count, default=None,
                        help="trials that value each pose's chosen best candidate, "
                             "independent of the screening trials (default: as many)")
    parser.add_argument("--heldout-objects", type=count, default=12)
    parser.add_argument("--heldout-poses", type=count, default=4)
    parser.add_argument("--heldout-trials", type=count, default=16)
    parser.add_argument("--core-k", type=count, default=172)
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    try:  # the output directory before any work (nothing is left behind by the check)
        validate.out_dir(args.out, "--out")
    except ValueError as exc:
        parser.error(str(exc))

    from sern_jax.infra import io
    from sern_jax.grasp.model import dataset, pretrain
    from sern_jax.grasp.world import objects

    try:  # the configs' own ranges (--core-k above the k-DPP's rank, ...) before any work
        d0_config = dataset.DatasetConfig(num_objects=args.objects, poses_per_object=args.poses)
        pretrain_config = pretrain.PretrainConfig(
            epochs=args.epochs, heldout_objects=args.heldout_objects,
            heldout_poses=args.heldout_poses, heldout_trials=args.heldout_trials,
            core_k=args.core_k)
    except ValueError as exc:
        parser.error(re.sub(r"\b(" + "|".join(_FLAGS) + r")\b",
                            lambda m: _FLAGS[m.group(1)], str(exc)))
    out = Path(args.out)
    timings = {}
    t = time.perf_counter()
    summary = dataset.generate(d0_config, out / "d0", progress=not args.no_progress)
    timings["dataset_s"] = time.perf_counter() - t
    print(json.dumps(summary), flush=True)
    t = time.perf_counter()
    manifest = pretrain.pretrain(out / "d0", pretrain_config, out / "theta0",
                                 progress=not args.no_progress)
    timings["pretrain_s"] = time.perf_counter() - t
    from sern_jax.grasp.model import artifacts

    theta0 = artifacts.load_theta0(out / "theta0")
    t = time.perf_counter()
    specs = [objects.make_object(n) for n in objects.object_names()]
    rows = pretrain.screen(theta0.network, theta0.params, specs, args.screen_poses,
                           args.screen_trials, progress=not args.no_progress,
                           fresh_trials=args.fresh_trials)
    timings["screen_s"] = time.perf_counter() - t
    host = io.run_metadata()["host"]
    screen_settings = {"poses": args.screen_poses, "trials": args.screen_trials,
                       "fresh_trials": args.fresh_trials or args.screen_trials, "seed": 0}
    artifacts.save_screen(out / "theta0", {"rule": pretrain.HARD_RULE, "objects": rows,
                                           "settings": screen_settings, "timings": timings,
                                           "machine": host})  # its sha256 into the manifest
    for r in rows:
        print(f"{r['object']:>20s} greedy {r['greedy_success']:.2f} best {r['best_success']:.2f} "
              f"best fresh {r['best_success_fresh']:.2f} mean {r['mean_success']:.2f} "
              f"{'HARD' if r['hard'] else ''}", flush=True)
    print(json.dumps(timings))
    _record(out / "theta0", argv, args, summary, timings, screen_settings, host)
    return 0


def _record(theta_dir: Path, argv, args, summary, timings, screen_settings, host) -> None:
    """Adds how the artefacts were made to the manifest (the digests of θ0 and the screen
    are kept)."""
    import sys

    import jax
    import mujoco

    from sern_jax.infra import io
    from sern_jax.grasp.world import scene, sim

    path = theta_dir / "manifest.json"
    manifest = io.load_json(path)
    flags = " ".join(argv if argv is not None else sys.argv[1:])
    manifest.update({
        "command": f"python -m experiments.make_theta0 {flags}".strip(),
        "equivalent_commands": [
            f"sern grasp dataset --out runs/d0 --objects {args.objects} --poses {args.poses}",
            "sern grasp pretrain --data runs/d0 --out runs/theta0 --install "
            f"--screen-poses {args.screen_poses} --screen-trials {args.screen_trials}"],
        "seeds": {"dataset": 0, "pretrain": 0, "screen": 0,
                  "heldout": manifest["heldout"].get("heldout_seed")},
        "gripper": scene.GRIPPER,
        "physics": sim.physics_settings(),
        "screen": screen_settings,
        "machine": {**host, "jax": jax.__version__, "jax_backend": jax.default_backend(),
                    "mujoco": mujoco.__version__},
        "timings_s": {k: round(v, 1) for k, v in timings.items()},
        "d0_summary": summary,
    })
    io.save_json(path, manifest)


if __name__ == "__main__":
    raise SystemExit(main())
