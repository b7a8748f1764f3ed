"""Online grasp learning experiments: the paper's setting, a strong one, and the ablations.

Each setting is a list of runs of ``online.run`` (one run directory each, resumable) on the
shipped hard set; ``summary.json`` gathers the final-round success of every run with paired
95 % intervals over seeds (common random numbers make the seeds paired across policies and
across the ablation's variants, which share keys).

    python -m experiments.grasp_learning paper            # 6 objects x 3 policies x 5 seeds
    python -m experiments.grasp_learning strong           # 20 seeds, low-variance evaluation
    python -m experiments.grasp_learning alpha            # SERN alpha in {0.01, 0.05, 0.2, 1}
    python -m experiments.grasp_learning core_set         # core set none / random / DPP
    python -m experiments.grasp_learning loss             # BCE vs the printed L1 (control)
    python -m experiments.grasp_learning schedule         # constant alpha vs alpha0/ln(T^p)

Options: --objects N (first N of the hard set), --seeds S, --rounds R, --out DIR,
--backend native|mjx (trial physics; mjx for a GPU).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path

SETTINGS = ("paper", "strong", "alpha", "core_set", "loss", "schedule")


def runs_of(setting: str, base):
    """(label, OnlineConfig) pairs of a setting."""
    r = dataclasses.replace
    if setting == "paper":
        return [("paper", base)]
    if setting == "strong":
        return [("strong", r(base, num_seeds=max(base.num_seeds, 20), eval_poses=8,
                             eval_trials=16))]
    if setting == "alpha":
        return [(f"alpha={a}", r(base, policies=("sern",), alpha=a))
                for a in (0.01, 0.05, 0.2, 1.0)]
    if setting == "core_set":
        return [(f"core={c}", r(base, policies=("sern",), core_set=c))
                for c in ("none", "random", "dpp")]
    if setting == "loss":
        return [(f"loss={l}", r(base, policies=("sern",), loss=l)) for l in ("bce", "l1")]
    if setting == "schedule":
        return [("schedule", r(base, policies=("sern", "sern_log")))]
    raise ValueError(f"unknown setting {setting!r}; choose from {SETTINGS}")


def _paired(a, b):
    """Mean and 95 % half-width of the per-seed difference a - b."""
    import numpy as np

    d = np.asarray(a) - np.asarray(b)
    half = 1.96 * d.std(ddof=1) / math.sqrt(len(d)) if len(d) > 1 else float("nan")
    return float(d.mean()), float(half)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("setting", choices=SETTINGS)
    parser.add_argument("--objects", type=int, default=6)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", default=None)
    parser.add_argument("--backend", choices=("native", "mjx"), default="native",
                        help="trial physics: native MuJoCo (CPU) or MJX (GPU)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    if args.objects < 1:
        raise SystemExit("--objects must be >= 1")

    import numpy as np

    from sern_jax import io
    from sern_jax.grasp import artifacts, objects, online

    theta0 = artifacts.load_theta0()
    hard = artifacts.hard_set(theta0, args.objects)
    specs = [objects.make_object(n) for n in hard["objects"]]
    base = online.OnlineConfig(num_seeds=args.seeds, rounds=args.rounds,
                               backend=args.backend)
    out = Path(args.out or f"runs/grasp_{args.setting}")
    summary = {"setting": args.setting, "objects": hard["objects"],
               "meets_rule": hard["meets_rule"], "runs": {}}
    finals = {}
    for label, config in runs_of(args.setting, base):
        t = time.perf_counter()
        res = online.run(config, specs, out / label.replace("=", "_"), theta0=theta0,
                         progress=not args.no_progress)
        seconds = time.perf_counter() - t
        io.save_npz(out / label.replace("=", "_") / "results.npz",
                    **res["results"]._asdict())
        lv = res["results"].lowvar_eval if config.eval_poses else res["results"].paper_eval
        for q, pol in enumerate(config.policies):
            finals[(label, pol)] = lv[-1, :, q, :]  # [O, S]
        summary["runs"][label] = {"table": res["table"], "timings": res["timings"],
                                  "trial_counts": res["trial_counts"], "seconds": seconds,
                                  "config": dataclasses.asdict(config)}
    # paired comparisons of every (label, policy) against the first one, per object and pooled
    keys = list(finals)
    ref = keys[0]
    comps = []
    for key in keys[1:]:
        a, b = finals[ref], finals[key]
        row = {"a": list(ref), "b": list(key),
               "pooled": _paired(a.mean(0), b.mean(0)),
               "per_object": {n: _paired(a[o], b[o]) for o, n in enumerate(hard["objects"])}}
        comps.append(row)
    summary["paired_final_round"] = comps
    summary["metric"] = "final-round greedy success (low-variance evaluation where run)"
    summary["metadata"] = io.run_metadata()
    io.save_json(out / "summary.json", summary)
    for c in comps:
        m, h = c["pooled"]
        print(f"{c['a']} - {c['b']}: {100 * m:+.1f} ± {100 * h:.1f} points (pooled, 95% CI)")
    print(f"wrote {out / 'summary.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
