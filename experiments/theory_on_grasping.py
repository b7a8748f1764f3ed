"""The paper's assumptions and theorems on the grasp pipeline, ground truth's error corrected.

For each object, C resting poses are tabulated with per-trial outcomes (trial i of every
candidate of a context uses ``fold_in(fold_in(key, 1 + c), i)``, as ``env.make_params`` does,
so the first 16 trials are the table the pipeline uses). Every valid candidate gets
``--trials`` (16) trials; the ``--top`` candidates with the highest 16-trial frequency get more,
up to ``--deep-trials`` (256). The ground truth r is therefore a frequency with its own
binomial error, and this script corrects for it:

* **Assumption 3 for the neural estimator**: θ0 fine-tuned on n labelled grasps of the object
  (n = 0, 10, 20, 40, 80, 160; one trial each, uniformly random valid candidates of 6 other
  poses, nested subsets per seed). Per context s and seed, the squared error of r̂ against the
  frequency f of m trials is debiased by the unbiased estimate of the frequency's variance,
  f(1 − f)/(m − 1) (E[(r̂ − f)²] = (r̂ − r)² + r(1 − r)/m for a fixed r̂, and
  E[f(1 − f)/(m − 1)] = r(1 − r)/m):
  err_s(n) = sqrt(max(0, mean_a[(r̂ − f)² − f(1 − f)/(m − 1)])) (root mean square over the
  context's valid candidates). The floor, the RMS error a perfect r̂
  would show against f, is sqrt(mean_a f(1 − f)/(m − 1)). Assumption 3 is a statement for every
  context, so β_s = sup_n err_s(n)·sqrt(n + 1) and the log-log slope of err_s against n + 1
  (n ≥ 10) are fitted per context (seed means), and their distribution is reported; a
  bound β_s/sqrt(n + 1) above 1 says nothing (errors are at most 1).
* **Assumption 1 / Δ2** at several trial counts M (16, 64, 256 by default): Δ2(s) = best −
  second-best frequency of the first M trials (M = 16 over all valid candidates, larger M over
  the ``--top`` candidates, the only ones with that many trials). Because the maximum of noisy
  frequencies is biased, Δ2 is also judged on independent trials: the best and second-best are
  ranked on the first half of the deep trials and their gap is valued on the second half, with
  a one-sided Fisher exact test per context and Holm over the contexts.
* **Theorems 1 and 4 for K = 64**: c = e^{−1/α}/K and π_min at α = 0.05 and at Algorithm 1's
  α(T), and Theorem 4's T* where the median Δ2 (at the deepest M) is above 0.

    python -m experiments.theory_on_grasping --out runs/theory_grasping

Saves ``results.json`` (summary, config, command, machine) and ``per_context.npz`` (per object,
context and seed); ``figures/make_theory_grasping_fig.py`` draws them.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

NS = (0, 10, 20, 40, 80, 160)
DELTA2_MS = (16, 64, 256)


def summarise(err, floor, err_raw, d2, split, names, ns=NS, ms=DELTA2_MS):
    """The quoted summary from the per-context arrays (pure NumPy; the test recomputes it).

    Args:
      err: [O, C, len(ns), S] debiased RMS error per object, context, n, seed.
      floor: [O, C] the ground truth's own RMS error (what a perfect r̂ would show).
      err_raw: [O, C, len(ns), S] uncorrected RMS error against the frequency.
      d2: [O, C, len(ms)] Δ2 at each trial count (NaN where a context has < 2 candidates).
      split: [O, C, 3] (gap on the second half of the deep trials between the candidates
        ranked 1st and 2nd on the first half, its one-sided p-value, trials per half).
      names: O object names.
    """
    import numpy as np

    from sern_jax.analysis import stats

    err, floor, err_raw = np.asarray(err), np.asarray(floor), np.asarray(err_raw)
    d2, split = np.asarray(d2), np.asarray(split)
    ns = np.asarray(ns, float)
    o, c, _, s = err.shape
    root = np.sqrt(ns + 1)
    fit = ns >= 10
    x = np.log(ns[fit] + 1)

    def slope(e):  # e: [n, ...]; log-log slope over n >= 10 (errors corrected to 0 -> 1e-3)
        y = np.log(np.maximum(e[fit], 1e-3))
        return np.polyfit(x, y.reshape(len(x), -1), 1)[0].reshape(y.shape[1:])

    em = err.mean(-1)  # [O, C, n] seed means
    beta_ctx = (em * root).max(-1)  # [O, C]
    slope_ctx = slope(np.moveaxis(em, -1, 0))  # [O, C]
    slope_ctx_raw = slope(np.moveaxis(err_raw.mean(-1), -1, 0))
    # per object and seed: the slope of the context-mean error (for an interval over seeds)
    slope_obj_seed = slope(np.moveaxis(err.mean(1), 1, 0))  # [O, S]
    tests = stats.paired_differences(slope_obj_seed, np.full(s, -0.5),
                                     names=[f"{n} slope - (-1/2)" for n in names])
    per_object = {}
    for i, name in enumerate(names):
        ti = stats.t_interval(slope_obj_seed[i])
        per_object[name] = {
            "slope_mean": float(ti.mean), "slope_half": float(ti.half), "seeds": int(s),
            "slope_minus_half_pvalue_holm": float(tests[i].pvalue_holm),
            "beta_ctx": beta_ctx[i].tolist(), "slope_ctx": slope_ctx[i].tolist(),
            "floor_ctx": floor[i].tolist(),
            "error_n0": float(em[i, :, 0].mean()), "error_n160": float(em[i, :, -1].mean()),
        }
    bc, sc = beta_ctx.ravel(), slope_ctx.ravel()
    out = {
        "contexts": int(o * c), "objects": list(names), "seeds": int(s),
        "floor_median": float(np.median(floor)), "floor_min": float(floor.min()),
        "floor_max": float(floor.max()),
        "beta_ctx_median": float(np.median(bc)), "beta_ctx_min": float(bc.min()),
        "beta_ctx_max": float(bc.max()),
        "beta_ctx_above_1_fraction": float(np.mean(bc > 1)),
        "slope_ctx_median": float(np.median(sc)), "slope_ctx_min": float(sc.min()),
        "slope_ctx_max": float(sc.max()),
        "slope_ctx_raw_median": float(np.median(slope_ctx_raw)),
        "slope_ctx_at_or_below_half_fraction": float(np.mean(sc <= -0.5)),
        "error_below_floor_fraction_n160": float(np.mean(em[..., -1] < floor)),
        "corrected_to_zero_fraction": float(np.mean(err == 0)),
        "per_object": per_object,
        "holm_resolved_slopes": [t.name for t in tests if t.pvalue_holm < 0.05],
    }
    d2f = d2.reshape(-1, d2.shape[-1])
    keep = ~np.isnan(d2f).any(1)
    d2f = d2f[keep]
    out["delta2"] = {
        str(m): {"median": float(np.median(d2f[:, j])),
                 "zero_fraction": float(np.mean(d2f[:, j] == 0)),
                 "below_0.05_fraction": float(np.mean(d2f[:, j] < 0.05))}
        for j, m in enumerate(ms)}
    sp = split.reshape(-1, 3)[keep]
    reject, _ = stats.holm(sp[:, 1], alpha=0.05)
    out["delta2_split"] = {
        "trials_per_half": int(sp[0, 2]), "gap_median": float(np.median(sp[:, 0])),
        "gap_nonpositive_fraction": float(np.mean(sp[:, 0] <= 0)),
        "resolved_holm": int(reject.sum()), "contexts": len(sp),
    }
    return out


def rms_errors(p, f, m, valid):
    """Per-context RMS error of estimates against frequencies, with and without the ground
    truth's binomial variance.

    Args:
      p: [C, K] estimates r̂; f: [C, K] success frequencies of m trials; m: [C, K] trials
        (>= 2 where valid); valid: [C, K] bool.

    Returns:
      (debiased [C], raw [C], floor [C]):
      sqrt(max(0, mean_a[(p − f)² − f(1 − f)/(m − 1)])), sqrt(mean_a (p − f)²) and
      sqrt(mean_a f(1 − f)/(m − 1)) over each context's valid candidates. f(1 − f)/(m − 1)
      is unbiased for Var f = r(1 − r)/m, so the debiased square is unbiased for
      mean_a (p − r)² when p does not depend on the trials behind f.
    """
    import numpy as np

    p, f, m = (np.asarray(a, np.float64) for a in (p, f, m))
    valid = np.asarray(valid, bool)
    var_hat = np.where(valid & (m > 1), f * (1 - f) / np.maximum(m - 1, 1), 0.0)
    nv = np.maximum(valid.sum(-1), 1)
    sq = np.where(valid, (p - f) ** 2, 0.0)
    return (np.sqrt(np.maximum((sq - var_hat).sum(-1) / nv, 0)), np.sqrt(sq.sum(-1) / nv),
            np.sqrt(var_hat.sum(-1) / nv))


def summarise_file(path):
    """``summarise`` of a saved per_context.npz (what results.json's summary is made from)."""
    import numpy as np

    z = np.load(path)
    return summarise(z["err"], z["floor"], z["err_raw"], z["delta2"], z["split"],
                     [str(n) for n in z["objects"]], tuple(int(n) for n in z["ns"]),
                     tuple(int(m) for m in z["delta2_ms"]))


def _run_trials(simulator, grasps, pose, noise, cand, lo, hi):
    """Outcomes [len(cand), hi − lo] of trials lo..hi−1 (noise[i] for trial i) of candidates
    ``cand`` of one context."""
    import numpy as np

    from sern_jax.grasp.world import sim as sim_lib

    g = np.repeat(np.asarray(grasps)[cand], hi - lo, axis=0)
    tn = sim_lib.TrialNoise(*(np.tile(a[lo:hi], (len(cand),) + (1,) * (a.ndim - 1))
                              for a in noise))
    res = simulator.run_trials(g, tn, pose)
    return res.success.reshape(len(cand), hi - lo).astype(float)


def half_counts(outcomes, deep_idx):
    """Successes [top, 2] of the deep candidates on the first and second half of their trials,
    and the trials of the second half."""
    import numpy as np

    y = np.asarray(outcomes)[deep_idx]  # [top, M]
    h = y.shape[1] // 2
    return np.stack([y[:, :h].sum(1), y[:, h:].sum(1)], -1), h, y.shape[1] - h


def split_test(counts, n1, n2):
    """Rank candidates on the first half's successes ``counts[:, 0]`` (of n1), compare the top
    two on the second half's ``counts[:, 1]`` (of n2, independent trials): (gap of the second
    half's frequencies, one-sided Fisher exact p-value for "the first-ranked is better", n2)."""
    import numpy as np
    from scipy import stats as sps

    counts = np.asarray(counts)
    order = np.argsort(-counts[:, 0] / n1, kind="stable")
    a, b = int(counts[order[0], 1]), int(counts[order[1], 1])
    p = sps.fisher_exact([[a, n2 - a], [b, n2 - b]], alternative="greater").pvalue
    return (a - b) / n2, float(p), n2


def main(argv=None) -> int:
    from sern_jax.infra import validate

    # bad input: one line naming the flag, exit 2, before any work (validate's parser)
    parser = validate.script_parser(__spec__, description=__doc__.splitlines()[0])
    count = validate.int_at_least(1)
    parser.add_argument("--objects", default=None,
                        help="comma-separated names (default: the shipped hard set)")
    parser.add_argument("--contexts", type=count, default=8)
    parser.add_argument("--trials", type=count, default=16,
                        help="trials of every valid candidate (the pipeline's table)")
    parser.add_argument("--top", type=validate.int_in(2, 10_000), default=8,
                        help="candidates (best on --trials) that get --deep-trials")
    parser.add_argument("--deep-trials", type=count, default=256)
    parser.add_argument("--seeds", type=count, default=4)
    parser.add_argument("--steps", type=count, default=100)
    parser.add_argument("--out", default="runs/theory_grasping")
    args = parser.parse_args(argv)
    bad = parser.error
    try:  # the output directory and the object list before any work (nothing is left behind)
        validate.out_dir(args.out, "--out")
        if args.objects is not None:
            validate.comma_list(args.objects, "--objects")
    except ValueError as exc:
        bad(str(exc))
    if args.top < 2:
        bad("--top must be >= 2")
    if args.deep_trials < args.trials or args.trials < 2:
        bad("--deep-trials must be >= --trials >= 2")
    if args.seeds < 2:
        bad("--seeds must be >= 2 (intervals over seeds)")
    ms = tuple(m for m in DELTA2_MS if m <= args.deep_trials and m >= args.trials)

    import jax
    import jax.numpy as jnp
    import numpy as np
    import optax

    from sern_jax.infra import io
    from sern_jax.core import schedules
    from sern_jax.analysis import theory
    from sern_jax.grasp.model import artifacts, dataset, pretrain
    from sern_jax.grasp.world import objects
    from sern_jax.grasp.world import context as context_lib
    from sern_jax.grasp.world import crops as crops_lib
    from sern_jax.grasp.model import quality_net as qn
    from sern_jax.grasp.world import sim as sim_lib

    if args.objects:
        for name in args.objects.split(","):
            try:
                objects.resolve_object(name)
            except ValueError:
                bad(f"--objects: unknown object {name!r} (see sern grasp show --list)")
    t0 = time.perf_counter()
    theta0 = artifacts.load_theta0()
    net = theta0.network
    names = (args.objects.split(",") if args.objects
             else artifacts.hard_set(theta0)["objects"])
    root = jax.random.key(31337)
    optimizer = optax.adam(3e-4)
    fit = qn.make_fit(net, optimizer, "bce", 32, args.steps)
    core = artifacts.core_set_data("dpp", theta0)
    predict = jax.jit(net.apply)

    def tune(key, w, image, depth, label):
        d = qn.TrainData(image, depth, label, w)
        d = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), d, core)
        return fit(key, theta0.params, qn.init_opt_state(optimizer, theta0.params), d)[0]

    tune_seeds = jax.jit(jax.vmap(tune, (0, 0, None, None, None)))
    n_o, n_c, n_s = len(names), args.contexts, args.seeds
    err = np.full((n_o, n_c, len(NS), n_s), np.nan)
    err_raw = np.full_like(err, np.nan)
    floor = np.full((n_o, n_c), np.nan)
    d2 = np.full((n_o, n_c, len(ms)), np.nan)
    split = np.full((n_o, n_c, 3), np.nan)
    halves = np.full((n_o, n_c, args.top, 2), np.nan)  # deep candidates' successes per half
    succ_all, m_all = [], []  # per object: [C, K] successes and trials per candidate
    for o, name in enumerate(names):
        spec = objects.resolve_object(name)
        key_o = jax.random.fold_in(jax.random.fold_in(root, 0), o)  # stream 0: contexts
        ctx = context_lib.make_contexts(jax.random.fold_in(key_o, 0), spec, n_c,
                                        context_lib.ContextConfig())
        simulator = sim_lib.GraspSimulator(ctx.model, backend="native")
        cands = ctx.candidates
        valid = np.asarray(cands.valid)
        succ = np.zeros(valid.shape, float)  # successes over each candidate's trials
        m_of = np.zeros(valid.shape, float)  # trials per candidate
        for c in range(n_c):
            idx = np.flatnonzero(valid[c])
            if len(idx) == 0:
                continue
            noise = sim_lib.sample_noise(jax.random.fold_in(key_o, 1 + c), args.deep_trials)
            outcomes = np.full((valid.shape[1], args.deep_trials), np.nan)
            outcomes[idx, :args.trials] = _run_trials(
                simulator, cands.grasps[c], ctx.poses[c], noise, idx, 0, args.trials)
            f16 = outcomes[idx, :args.trials].mean(1)
            deep = idx[np.argsort(-f16, kind="stable")[:args.top]]
            if args.deep_trials > args.trials:
                outcomes[deep, args.trials:] = _run_trials(
                    simulator, cands.grasps[c], ctx.poses[c], noise, deep, args.trials,
                    args.deep_trials)
            m = np.where(np.isin(np.arange(valid.shape[1]), deep), args.deep_trials,
                         args.trials)
            succ[c] = np.nansum(outcomes, 1)
            m_of[c] = m
            if len(idx) >= 2:
                for j, mm in enumerate(ms):
                    pool = idx if mm == args.trials else deep
                    v = np.sort(outcomes[pool, :mm].mean(1))[::-1]
                    d2[o, c, j] = v[0] - v[1]
                hc, n1, n2 = half_counts(outcomes, deep)
                halves[o, c, :len(deep)] = hc
                split[o, c] = split_test(hc[:len(deep)], n1, n2)
            print(f"  {name} pose {c}: {len(idx)} valid, best16 {f16.max():.2f}, "
                  f"Δ2 {np.round(d2[o, c], 3).tolist()} ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
        succ_all.append(succ)
        m_all.append(m_of)
        crops = crops_lib.extract_batch(jnp.asarray(ctx.depth), cands)
        f = np.where(m_of > 0, succ / np.maximum(m_of, 1), 0.0)
        floor[o] = rms_errors(f, f, m_of, valid)[2]
        # labelled pool: fresh poses, one trial per valid candidate (stream 1)
        lc = dataset.label_contexts(jax.random.fold_in(jax.random.fold_in(root, 1), o), spec,
                                    6, 1)
        arrays = {k: getattr(lc, k) for k in ("depth", "center_px", "angle_px",
                                              "grasp_depth", "valid")}
        image, depth, cx, slot = pretrain.crops_of(arrays)
        label = jnp.asarray(lc.label[cx, slot].astype(np.float32))

        for i, n in enumerate(NS):
            if n == 0:
                p = np.asarray(predict(theta0.params, crops.image, crops.depth))
                deb, raw, _ = rms_errors(p, f, m_of, valid)
                err_raw[o, :, i] = raw[:, None]
                err[o, :, i] = deb[:, None]
                continue
            w = np.zeros((n_s, len(label)), np.float32)
            for s in range(n_s):  # nested subsets: seed s's first n grasps of one order
                order = np.random.default_rng([o, s]).permutation(len(label))
                w[s, order[:min(n, len(label))]] = 1.0
            keys = jax.vmap(lambda s: jax.random.fold_in(jax.random.fold_in(root, 2), s))(
                jnp.arange(n_s))
            tuned = tune_seeds(keys, jnp.asarray(w), image, depth, label)
            for s in range(n_s):
                p1 = jax.tree.map(lambda x, s=s: x[s], tuned)
                p = np.asarray(predict(p1, crops.image, crops.depth))
                err[o, :, i, s], err_raw[o, :, i, s], _ = rms_errors(p, f, m_of, valid)
        print(f"{name:>18s}: floor {floor[o].min():.3f}-{floor[o].max():.3f}, error (debiased) "
              f"n=0 {err[o, :, 0].mean():.3f} -> n=160 {err[o, :, -1].mean():.3f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out_dir / "per_context.npz", err=err, err_raw=err_raw, floor=floor,
                        delta2=d2, split=split, halves=halves,
                        successes=np.stack(succ_all), trials=np.stack(m_all),
                        trials_per_half=np.asarray([args.deep_trials // 2,
                                                    args.deep_trials - args.deep_trials // 2]),
                        ns=np.asarray(NS), delta2_ms=np.asarray(ms), objects=np.asarray(names))
    summary = summarise_file(out_dir / "per_context.npz")
    k = 64
    horizon = 100
    alpha_log = float(schedules.alpha_of_horizon("log", horizon, 1.0, 0.3))
    consts = {
        "K": k, "alpha_paper": 0.05,
        "c_paper": float(theory.thm1_c(0.05, k)),
        "pi_min_paper": float(theory.thm1_pi_min(0.05, k)),
        "alpha_schedule_T100": alpha_log,
        "c_schedule_T100": float(theory.thm1_c(alpha_log, k)),
    }
    d2_deep = summary["delta2"][str(ms[-1])]["median"]
    if d2_deep > 0:
        consts["thm4_log10_T_star_median_beta"] = float(
            theory.thm4_crossing(k, summary["beta_ctx_median"], d2_deep, 1.0, 0.3))
    out = {"command": "python -m experiments.theory_on_grasping " + " ".join(
               sys.argv[1:] if argv is None else argv),
           "machine": io.machine(), "config": vars(args),
           "theta0_digest": theta0.fingerprint, "physics": sim_lib.physics_settings(),
           "metadata": io.run_metadata(),
           "load_average_end": list(os.getloadavg()), "ns": list(NS),
           "delta2_ms": list(ms), "summary": summary, "theory": consts,
           "seconds": time.perf_counter() - t0}
    io.save_json(out_dir / "results.json", out)
    print({k2: v for k2, v in summary.items() if k2 != "per_object"})
    print(consts)
    print(f"wrote {out_dir} ({out['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
