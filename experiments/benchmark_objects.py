"""A benchmark's objects from two independent screens, by the pre-registered rule.

The selection screen (``sern grasp screen FAMILY... --seed 0 --json-out select.json``) names
the candidates: the objects it marks hard (θ0's greedy choice succeeds at most 60 % of the
time; the best candidate, chosen on the screen's trials, succeeds at least 80 % of the time on
fresh trials). The confirmation screen (``sern grasp screen <candidates> --seed 1 ...``), on new
poses and trials, must mark them hard again: those *qualify*. In index order, the first
``--objects`` qualified objects are scored and the next ``--tuning`` are the tuning objects
(if too few are left for tuning, ``--fallback-tuning`` names objects to add; if fewer than
``--objects`` qualify, nothing is written and the exit status is 1).

    python -m experiments.benchmark_objects candidates --select select.json
    python -m experiments.benchmark_objects write --select select.json --confirm confirm.json \\
        --name wedges --out sern_jax/grasp/data/benchmarks/wedges.json

``write`` makes the benchmark file: objects, world (θ0's), the pre-registered protocol and
seeds, the learners (hyperparameters empty until tuning fills them), the metrics, the θ0
digest and the screen's rule; it prints the assignment.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

LEARNERS = ("sern", "egreedy", "greedy", "ensemble_ts", "neural_lints")
PROTOCOL = {"rounds": 5, "explore": 20, "evaluate": 5, "eval_poses": 8, "eval_trials": 16,
            "fit_steps": 40, "core_set": "dpp", "loss": "bce", "seed": 0, "backend": "native"}
METRICS = {"primary": ["curve_area", "explore_success"],
           "secondary": ["round5", "grasps_to_80"]}


def _index(name: str) -> int:
    m = re.fullmatch(r"[A-Za-z_]+?_(\d+)", name)
    return int(m.group(1)) if m else sys.maxsize


def _hard(path: Path) -> list[str]:
    rows = json.loads(path.read_text())["objects"]
    return sorted((r["object"] for r in rows if r["hard"]), key=_index)


def assign(select: Path, confirm: Path, num_objects: int, num_tuning: int,
           fallback: list[str]) -> tuple[list[str], list[str], list[str]]:
    """(qualified, scored objects, tuning objects) by the rule of the module doc."""
    candidates = _hard(select)
    confirmed = set(_hard(confirm))
    qualified = [n for n in candidates if n in confirmed]
    scored = qualified[:num_objects]
    tuning = qualified[num_objects:num_objects + num_tuning]
    if len(tuning) < num_tuning:
        tuning += [n for n in fallback if n not in tuning][:num_tuning - len(tuning)]
    return qualified, scored, tuning


def main(argv=None) -> int:
    from sern_jax.infra import validate

    p = validate.script_parser(__spec__, description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    c = sub.add_parser("candidates", help="print the selection screen's hard objects")
    c.add_argument("--select", type=Path, required=True)
    w = sub.add_parser("write", help="assign the objects and write the benchmark file")
    w.add_argument("--select", type=Path, required=True, help="the selection screen's JSON")
    w.add_argument("--confirm", type=Path, required=True,
                   help="the confirmation screen's JSON")
    w.add_argument("--name", required=True, help="the benchmark's name")
    w.add_argument("--description", default="")
    w.add_argument("--objects", type=validate.int_at_least(1), default=12)
    w.add_argument("--tuning", type=validate.int_at_least(1), default=3)
    w.add_argument("--fallback-tuning", default="triangular_prism",
                   help="objects that complete the tuning set when too few qualify")
    w.add_argument("--seeds", type=validate.int_at_least(2), default=40)
    w.add_argument("--record", default="experiments/results/benchmark/screen",
                   help="the folder holding the screens, named in the file")
    w.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    for flag in ("select", "confirm"):
        path = getattr(args, flag, None)
        if path is not None and not path.is_file():
            p.error(f"--{flag} {path}: no such file")
    if args.what == "candidates":
        print(" ".join(_hard(args.select)))
        return 0
    fallback = validate.comma_list(args.fallback_tuning, "--fallback-tuning")
    qualified, scored, tuning = assign(args.select, args.confirm, args.objects, args.tuning,
                                       fallback)
    print(f"qualified ({len(qualified)}): {' '.join(qualified)}")
    if len(scored) < args.objects:
        print(f"fewer than {args.objects} objects qualify: no benchmark written")
        return 1
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.online import benchmark as bench_lib

    theta0 = artifacts.load_theta0()
    rule = json.loads(args.confirm.read_text())["rule"]
    doc = {"schema": bench_lib.SCHEMA, "name": args.name, "version": 1,
           "description": args.description,
           "objects": [bench_lib.object_entry(n) for n in scored],
           "tuning_objects": [bench_lib.object_entry(n) for n in tuning],
           "world": {"context": {}, "trial": {}},
           "protocol": dict(PROTOCOL), "seeds": args.seeds,
           "learners": {n: {} for n in LEARNERS}, "metrics": METRICS,
           "theta0": {"sha256": theta0.manifest["theta0_sha256"]},
           "screen": {"rule": {"max_greedy_success": rule["max_greedy_success"],
                               "min_best_success": rule["min_best_success"]},
                      "record": args.record}}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    bench_lib.load_file(args.out)  # the file reads back under the schema
    print(f"scored ({len(scored)}): {' '.join(scored)}")
    print(f"tuning ({len(tuning)}): {' '.join(tuning)}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
