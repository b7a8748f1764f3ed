"""Tuning for a grasp-exploration benchmark: each learner's knob on the benchmark's tuning
objects, never on its scored objects.

The grid and the rule are the pre-registration's (``experiments/results/benchmark/
prereg.md``): each knobbed learner gets five values; setting ``i`` runs value ``i`` of every
learner in one ``driver.run`` (a learner's results depend only on its own value and the run's
keys, so learners may share a run); the score is the mean fixed-pose greedy success over
rounds 1..R, the tuning objects and the seeds; ties go to the value listed first. A value
chosen at a grid edge extends the grid by the next value of its progression, which runs on its
own (``run --values``), until the choice is interior or two extensions were made.

    python -m experiments.benchmark_tune run --benchmark wedges --setting 0 --out runs/tune
    python -m experiments.benchmark_tune run --benchmark wedges --values sern=0.16 --out runs/tune
    python -m experiments.benchmark_tune choose --benchmark wedges --out runs/tune \\
        --record experiments/results/benchmark/tuning

Each run directory (``<out>/<learner-value_...>``) resumes after its last finished round.
``choose`` reads every finished run under ``--out`` and writes ``tuned.json`` (scores, choice,
edges, the next values to run when a choice is at an edge) and ``tune_per_seed.npz`` to
``--record``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

# learner -> (OnlineConfig field or registry hyperparameter, the pre-registered grid)
GRID = {
    "sern": ("alpha", (0.005, 0.01, 0.02, 0.04, 0.08)),
    "egreedy": ("epsilon", (0.0125, 0.025, 0.05, 0.1, 0.2)),
    "neural_lints": ("lambda_prior", (0.3125, 0.625, 1.25, 2.5, 5.0)),
    "ensemble_ts": ("ensemble_size", (2, 3, 5, 8, 12)),
}
# the next values beyond each edge (×2 / ÷2; ensemble sizes: 20 above, none below 2)
EXTEND = {
    "sern": ((0.0025, 0.00125), (0.16, 0.32)),
    "egreedy": ((0.00625, 0.003125), (0.4, 0.8)),
    "neural_lints": ((0.15625, 0.078125), (10.0, 20.0)),
    "ensemble_ts": ((), (20, 32)),
}
_CONFIG_FIELDS = ("alpha", "epsilon", "alpha0", "p")  # OnlineConfig's own fields


def _label(values: dict) -> str:
    """The run directory's name: letters, digits, '.', '_' and '-' only."""
    return "_".join(f"{n}-{values[n]:g}" for n in sorted(values))


def _config(bench, values: dict, seeds: int):
    """The OnlineConfig of one tuning run: the benchmark's protocol, ``seeds`` seeds, the
    learners of ``values`` (learner -> value of its knob)."""
    from sern_jax.grasp.online import benchmark as bench_lib

    config = bench_lib.online_config(bench, tuple(values))
    own, hyper = {}, dict(config.hyper)
    for name, value in values.items():
        field = GRID[name][0]
        if field in _CONFIG_FIELDS:
            own[field] = value
        else:
            hyper[field] = value
    import dataclasses

    return dataclasses.replace(config, num_seeds=seeds, hyper=tuple(hyper.items()), **own)


def run(bench_name: str, values: dict, seeds: int, out: Path, progress: bool) -> Path:
    """Runs (or resumes) one tuning run; returns its directory."""
    from sern_jax.grasp.online import benchmark as bench_lib
    from sern_jax.grasp.online import driver

    bench = bench_lib.resolve(bench_name)
    config = _config(bench, values, seeds)
    run_dir = out / _label(values)
    t = time.perf_counter()
    res = driver.run(config, list(bench.tuning_objects), run_dir, progress=progress,
                     context_config=bench.world[0], trial_config=bench.world[1])
    np.savez_compressed(run_dir / "tune_result.npz",
                        lowvar_eval=np.asarray(res["results"].lowvar_eval, np.float32),
                        explore_success=np.asarray(res["results"].explore_success, np.float32))
    (run_dir / "tune_result.json").write_text(json.dumps(
        {"values": values, "policies": list(config.policies), "seeds": seeds,
         "objects": [s.name for s in bench.tuning_objects], "seconds": time.perf_counter() - t,
         "fingerprint": res["fingerprint"]}, indent=1))
    return run_dir


def choose(out: Path) -> dict:
    """Scores every (learner, value) run under ``out``; the choice and the edges."""
    per_value: dict[str, dict[float, np.ndarray]] = {n: {} for n in GRID}
    runs = []
    for meta_path in sorted(out.glob("*/tune_result.json")):
        meta = json.loads(meta_path.read_text())
        arrays = np.load(meta_path.parent / "tune_result.npz")
        lowvar = arrays["lowvar_eval"]  # [R + 1, O, Q, S]
        runs.append({"dir": meta_path.parent.name, **meta})
        for q, name in enumerate(meta["policies"]):
            per_value[name][meta["values"][name]] = lowvar[1:, :, q, :]
    learners = {}
    for name, (field, grid) in GRID.items():
        if not per_value[name]:
            continue
        tried = sorted(per_value[name])
        scores = [float(per_value[name][v].mean()) for v in tried]
        best = tried[int(np.argmax(scores))]  # ties: the smaller value (listed first)
        lo_ext, hi_ext = EXTEND[name]
        edge = "low" if best == tried[0] else "high" if best == tried[-1] else None
        extensions = [v for v in tried if v not in grid]
        pending = None
        if edge == "low" and len(extensions) < 2 and lo_ext:
            pending = next((v for v in lo_ext if v not in tried), None)
        if edge == "high" and len(extensions) < 2:
            pending = next((v for v in hi_ext if v not in tried), None)
        learners[name] = {"field": field, "values": tried, "scores": scores, "chosen": best,
                          "edge": edge, "extensions": extensions, "next_value": pending}
    return {"criterion": ("mean fixed-pose greedy success over rounds 1..R, the tuning "
                          "objects and seeds; ties: the value listed first"),
            "learners": learners, "runs": runs}


def main(argv=None) -> None:
    from sern_jax.infra import validate

    p = validate.script_parser(__spec__, description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    r = sub.add_parser("run", help="one tuning run (a grid setting, or given values)")
    r.add_argument("--benchmark", required=True, help="benchmark name (sern_jax/grasp/data/"
                   "benchmarks/NAME.json) or a path to a benchmark file")
    r.add_argument("--setting", type=validate.int_in(0, 4), default=None,
                   help="run value SETTING (0-4) of every knobbed learner's grid")
    r.add_argument("--values", default=None,
                   help="learner=value pairs, comma-separated (an extension beyond an edge)")
    r.add_argument("--seeds", type=validate.int_at_least(1), default=10)
    r.add_argument("--out", type=Path, required=True, help="folder of the tuning runs")
    r.add_argument("--no-progress", action="store_true")
    c = sub.add_parser("choose", help="score the finished runs; write tuned.json")
    c.add_argument("--out", type=Path, required=True, help="folder of the tuning runs")
    c.add_argument("--record", type=Path, required=True, help="folder for tuned.json")
    args = p.parse_args(argv)
    if args.what == "run":
        if (args.setting is None) == (args.values is None):
            p.error("give exactly one of --setting and --values")
        if args.setting is not None:
            values = {n: g[args.setting] for n, (_, g) in GRID.items()}
        else:
            values = {}
            for item in args.values.split(","):
                name, _, value = item.partition("=")
                if name not in GRID or not value:
                    p.error(f"--values: {item!r} is not learner=value with learner in "
                            f"{', '.join(GRID)}")
                try:
                    values[name] = type(GRID[name][1][0])(value)
                except ValueError:
                    p.error(f"--values: {value!r} is not a value of {GRID[name][0]}")
        run(args.benchmark, values, args.seeds, args.out, not args.no_progress)
        return
    doc = choose(args.out)
    from sern_jax.infra import io

    doc.update(machine=io.machine(), command="python -m experiments.benchmark_tune "
               + " ".join(sys.argv[1:]))
    args.record.mkdir(parents=True, exist_ok=True)
    (args.record / "tuned.json").write_text(json.dumps(doc, indent=1, default=str))
    print(json.dumps({n: (v["chosen"], v["edge"], v["next_value"])
                      for n, v in doc["learners"].items()}))


if __name__ == "__main__":
    main()
