"""Does the core set stop θ0 from forgetting D0 while it adapts to a new object?

Fine-tunes the shipped θ0 on a small online data set from one hard object (one randomised
trial per grasp, as a robot would collect it) with no core set, a random core set and the
DPP core set (same k = 172, shipped with θ0), for several seeds, and measures

* forgetting: ROC-AUC and BCE on D0-like data (procedural objects of a population seed never
  used for D0 or the held-out set, one trial per grasp);
* adaptation: ROC-AUC and BCE on the new object's other poses, against success frequencies.

    python -m experiments.core_set_forgetting --object tless_part_a --out runs/forgetting
    python -m figures.make_forgetting_fig runs/forgetting

Saves ``results.json`` (per core set and seed), ``summary.json`` (:func:`summarise`: means
with Student-t intervals over seeds, and the core sets' paired differences with Holm) and
``config.json`` (command, machine, trial, θ0's fingerprint, data sizes and success rates).
"""

from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path

from sern_jax.infra import validate

KINDS = ("none", "random", "dpp")
METRICS = (("d0", "roc_auc"), ("d0", "bce"), ("new", "roc_auc"))
PAIRS = (("dpp", "none"), ("random", "none"), ("dpp", "random"))


def summarise(results: dict) -> dict:
    """The quoted summary from ``results.json`` (pure NumPy; the test recomputes it).

    Per core set and metric (D0-like ROC-AUC and BCE, new-object ROC-AUC): the mean over
    seeds with its SD and 95 % Student-t half-width (n − 1 dof). Per metric, the paired
    differences dpp − none, random − none and dpp − random (seed s of every core set uses
    the same fine-tuning key, so seeds pair), with t intervals and Holm's correction over
    all nine comparisons together (``sern_jax.analysis.stats.paired_differences``).
    """
    import numpy as np

    from sern_jax.analysis import stats

    def per_seed(kind, part, metric):
        return np.array([r[part][metric] for r in results[kind]], float)

    out = {"theta0": {f"{p}_{m}": float(results["theta0"][p][m]) for p, m in METRICS},
           "per_kind": {}, "differences": []}
    for kind in KINDS:
        row = {}
        for part, metric in METRICS:
            ti = stats.t_interval(per_seed(kind, part, metric))
            row[f"{part}_{metric}"] = {"mean": float(ti.mean), "sd": float(ti.sd),
                                       "half": float(ti.half), "seeds": len(results[kind])}
        out["per_kind"][kind] = row
    names, diffs = [], []
    for part, metric in METRICS:
        for a, b in PAIRS:
            names.append(f"{part}_{metric}: {a} - {b}")
            diffs.append(per_seed(a, part, metric) - per_seed(b, part, metric))
    for d in stats.paired_differences(np.stack(diffs), names=names):
        out["differences"].append({"name": d.name, "mean": d.mean, "half": d.half,
                                   "pvalue": d.pvalue, "pvalue_holm": d.pvalue_holm,
                                   "resolved": bool(d.resolved)})
    return out


def main(argv=None) -> int:
    # bad input: one line naming the flag, exit 2, before any compile (validate's parser)
    parser = validate.script_parser(__spec__, description=__doc__.splitlines()[0])
    count = validate.int_at_least(1)
    parser.add_argument("--object", default="tless_part_a")
    parser.add_argument("--online-poses", type=count, default=4,
                        help="poses of the new object whose grasps form the online data")
    parser.add_argument("--test-poses", type=count, default=4)
    parser.add_argument("--test-trials", type=count, default=8)
    parser.add_argument("--d0-objects", type=count, default=6)
    parser.add_argument("--d0-poses", type=count, default=2)
    parser.add_argument("--seeds", type=count, default=4)
    parser.add_argument("--steps", type=count, default=200)
    parser.add_argument("--batch-size", type=count, default=32)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--out", default="runs/forgetting")
    args = parser.parse_args(argv)
    bad = parser.error
    try:  # the output directory before any work (nothing is left behind by the check)
        validate.out_dir(args.out, "--out")
    except ValueError as exc:
        bad(str(exc))
    if not (math.isfinite(args.lr) and args.lr > 0):
        bad(f"--lr must be a finite number > 0 (got {args.lr})")

    from sern_jax.grasp.world import objects

    try:
        spec = objects.make_object(args.object)
    except ValueError:
        bad(f"--object: unknown object {args.object!r} (see sern grasp show --list)")

    import jax
    import jax.numpy as jnp
    import numpy as np
    import optax

    from sern_jax.infra import io
    from sern_jax.grasp.model import artifacts, dataset, pretrain
    from sern_jax.grasp.world import sim
    from sern_jax.grasp.model import quality_net as qn

    t0 = time.perf_counter()
    theta0 = artifacts.load_theta0()
    net, params0 = theta0.network, theta0.params
    root = jax.random.key(20261123)

    def labelled(key, spec, poses, trials):
        lc = dataset.label_contexts(key, spec, poses, trials)
        arrays = {f: getattr(lc, f) for f in ("depth", "center_px", "angle_px", "grasp_depth",
                                               "valid")}
        image, depth, ctx, slot = pretrain.crops_of(arrays)
        return image, depth, lc.label[ctx, slot].astype(np.float32), \
            lc.successes[ctx, slot] / trials

    on_img, on_dep, on_lab, _ = labelled(jax.random.fold_in(root, 0), spec,
                                         args.online_poses, 1)
    te_img, te_dep, te_lab, te_freq = labelled(jax.random.fold_in(root, 1), spec,
                                               args.test_poses, args.test_trials)
    d0_specs = objects.sample_population(777, args.d0_objects)
    parts = [labelled(jax.random.fold_in(root, 100 + i), s, args.d0_poses, 1)
             for i, s in enumerate(d0_specs)]
    d0_img, d0_dep, d0_lab = (np.concatenate([p[k] for p in parts]) for k in range(3))

    optimizer = optax.adam(args.lr)
    fit = qn.make_fit(net, optimizer, "bce", args.batch_size, args.steps)
    online = qn.TrainData(on_img, on_dep, on_lab, np.ones_like(on_lab))

    def run(core, key):
        data = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), online, core)
        params, _, _ = fit(key, params0, qn.init_opt_state(optimizer, params0), data)
        return params

    run_seeds = jax.jit(jax.vmap(run, (None, 0)))
    predict = jax.jit(net.apply)

    def metrics(params, image, depth, label, freq=None):
        p = np.asarray(predict(params, image, depth), np.float64)
        m = pretrain.classification_metrics(p, label > 0.5, freq)
        eps = 1e-7
        bce = -np.mean(label * np.log(p + eps) + (1 - label) * np.log(1 - p + eps))
        return {"roc_auc": m["roc_auc"], "accuracy": m["accuracy"], "bce": float(bce),
                "ece": m["ece"]}

    results = {"theta0": {"d0": metrics(params0, d0_img, d0_dep, d0_lab),
                          "new": metrics(params0, te_img, te_dep, te_lab, te_freq)}}
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.fold_in(root, 2), i))(
        jnp.arange(args.seeds))
    for kind in artifacts.CORE_SET_KINDS:
        core = artifacts.core_set_data(kind, theta0)
        params = run_seeds(core, keys)
        rows = []
        for s in range(args.seeds):
            p_s = jax.tree.map(lambda x, s=s: x[s], params)
            rows.append({"seed": s, "d0": metrics(p_s, d0_img, d0_dep, d0_lab),
                         "new": metrics(p_s, te_img, te_dep, te_lab, te_freq)})
        results[kind] = rows
        print(f"{kind:>6s}: D0 AUC {np.mean([r['d0']['roc_auc'] for r in rows]):.3f}, "
              f"new-object AUC {np.mean([r['new']['roc_auc'] for r in rows]):.3f}", flush=True)
    out = Path(args.out)
    io.save_json(out / "results.json", results)
    io.save_json(out / "summary.json", summarise(results))
    io.save_json(out / "config.json", {
        "command": "python -m experiments.core_set_forgetting " + " ".join(
            sys.argv[1:] if argv is None else argv),
        "machine": io.machine(), "load_average_end": list(os.getloadavg()),
        "physics": sim.physics_settings(), "metadata": io.run_metadata(),
        "args": vars(args), "online_grasps": int(len(on_lab)),
        "online_success_rate": float(on_lab.mean()), "test_grasps": int(len(te_lab)),
        "test_success_rate": float(te_lab.mean()),
        "test_mean_frequency": float(np.mean(te_freq)),
        "d0_success_rate": float(d0_lab.mean()), "d0_failures": int((d0_lab < 0.5).sum()),
        "d0_grasps": int(len(d0_lab)), "theta0": theta0.fingerprint,
        "seconds": time.perf_counter() - t0})
    print(f"wrote {out / 'results.json'} ({time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
