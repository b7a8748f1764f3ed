"""Online grasp learning experiments: the paper's setting, a strong one, and the ablations.

Each setting is a list of runs of ``online.run`` (one run directory each, resumable) on the
shipped hard set; ``summary.json`` gathers the final-round success of every run with paired
95 % intervals over seeds (common random numbers make the seeds paired across policies and
across the ablation's variants, which share keys). Intervals are Student t over the seeds
(n − 1 dof, ``sern_jax.stats``); the comparisons of a setting are reported together, so each
row also carries its Holm-adjusted p-value and whether its sign is resolved after Holm.

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
    """Mean and 95 % Student-t half-width (n − 1 dof) of the per-seed difference a - b."""
    import numpy as np

    from sern_jax import stats

    ci = stats.t_interval(np.asarray(a, np.float64) - np.asarray(b, np.float64), 0.95)
    return ci.mean, ci.half


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
    # Holm over the pooled comparisons reported together (the printed lines below)
    if comps and len(finals[ref].T) > 1:
        from sern_jax import stats

        rows = stats.paired_differences(
            np.stack([finals[ref].mean(0) for _ in keys[1:]]),
            np.stack([finals[k].mean(0) for k in keys[1:]]),
            names=[" - ".join(map(str, k)) for k in keys[1:]])
        for c, row in zip(comps, rows):
            c["pooled_t"] = row._asdict()
    summary["paired_final_round"] = comps
    summary["interval"] = ("Student t over seeds (n - 1 dof), 95 %, per comparison; "
                           "pooled_t adds the Holm-adjusted p-value over the pooled rows")
    summary["metric"] = "final-round greedy success (low-variance evaluation where run)"
    summary["metadata"] = io.run_metadata()
    io.save_json(out / "summary.json", summary)
    for c in comps:
        m, h = c["pooled"]
        holm = c.get("pooled_t", {}).get("pvalue_holm", float("nan"))
        print(f"{c['a']} - {c['b']}: {100 * m:+.1f} ± {100 * h:.1f} points (pooled, 95% t "
              f"interval over seeds; Holm-adjusted p = {holm:.3f} over {len(comps)})")
    print(f"wrote {out / 'summary.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
