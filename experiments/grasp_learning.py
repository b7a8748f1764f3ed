"""Online grasp learning experiments: the paper's setting, a strong one, the ablations and
the regret accounting, with their per-seed results kept.

Each setting is a list of runs of ``driver.run`` (one run directory each under ``--out``,
resumable round by round) on the shipped hard set. Every run writes its per-seed results,
the command and the machine to ``--results`` (default ``experiments/results/<setting>/``):
one small JSON per run label (``<label>.json``; ``<label>.part-<objects>.json`` when
``--only`` ran a subset of the objects, which ``summarise`` joins back along the object
axis). ``summarise`` computes everything the docs quote from those files alone: Table I
rows (mean, population SD ``std``, sample ``sd`` and ``se`` over seeds), per-policy pooled
figures per round, and the paired comparisons of the final round with Student-t intervals
over seeds (n − 1 dof, ``sern_jax.analysis.stats``) and Holm's correction over the comparisons
reported together (one family per setting, named in ``summary.json``).

    python -m experiments.grasp_learning paper            # 6 objects x 3 policies x 5 seeds
    python -m experiments.grasp_learning strong           # 20 seeds, 8 poses x 16 trials eval
    python -m experiments.grasp_learning alpha            # SERN alpha in {0.01, 0.05, 0.2, 1}
    python -m experiments.grasp_learning core_set         # core set none / random / DPP
    python -m experiments.grasp_learning loss             # BCE vs the printed L1 (control)
    python -m experiments.grasp_learning schedule         # constant alpha vs alpha0/ln(T^p)
    python -m experiments.grasp_learning ablations        # the four, each distinct run once
    python -m experiments.grasp_learning regret           # 3 objects, independent oracle
                                                          # (4 + 4 trials, first 5 grasps)
    python -m experiments.grasp_learning summarise experiments/results/paper
    python -m experiments.grasp_learning collect runs/grasp_strong experiments/results/strong

``collect`` writes the per-seed file of a run that was stopped (``timeout``) from its last
checkpoint, marked with the rounds it finished (``rounds_done``).

Options: --objects N (first N of the hard set), --only a,b (those hard-set objects),
--seeds S, --rounds R, --out DIR, --results DIR, --backend native|mjx (trial physics).
"""

from __future__ import annotations

import dataclasses
import shlex
import sys
import time
from pathlib import Path

import numpy as np

SETTINGS = ("paper", "strong", "alpha", "core_set", "loss", "schedule", "regret")
ABLATIONS = ("alpha", "core_set", "loss", "schedule")
PAPER_LABELS = ("alpha=0.05", "core=dpp", "loss=bce")  # an ablation's reference run
FIELDS = ("lowvar_eval", "paper_eval", "explore_success", "pseudo_regret")
AXES = "[round 0..R, object, policy, seed]; round 0 = θ0 before learning"

__all__ = ["SETTINGS", "runs_of", "per_seed_doc", "save_per_seed", "load_results",
           "summarise", "collect", "table1_markdown", "fixed_pose_markdown",
           "pooled_markdown", "comparisons_markdown", "regret_markdown", "main"]


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
    if setting == "regret":
        return [("regret", r(base, regret_trials=base.regret_trials or 4,
                             regret_grasps=base.regret_grasps or 5))]
    raise ValueError(f"unknown setting {setting!r}; choose from {SETTINGS}")


def _arr(a) -> list:
    """Rounded values; NaN (not measured) stored as -1 (load_results: only success
    fractions and round 0 / disabled regret read -1 back as NaN)."""
    a = np.asarray(a, np.float64)
    return np.round(np.where(np.isfinite(a), a, -1.0), 6).tolist()


def per_seed_doc(results, *, label: str, setting: str, objects: list[str],
                 all_objects: list[str], config, rounds_done: int, seconds: float,
                 command: str, theta0, extra: dict | None = None,
                 trial_config=None, scene_config=None) -> dict:
    """The per-seed record of one run: every figure per round, object, policy and seed
    (-1 = not measured: round 0's exploration, or regret accounting off), the command, the
    machine, θ0's digest and the trial configuration it was made with."""
    from sern_jax.infra import io
    from sern_jax.grasp.world import scene, sim

    get = results._asdict() if hasattr(results, "_asdict") else dict(results)
    k = rounds_done + 1
    doc = {"label": label, "setting": setting, "objects": list(objects),
           "all_objects": list(all_objects), "policies": list(config.policies),
           "seeds": int(config.num_seeds), "rounds": int(config.rounds),
           "rounds_done": int(rounds_done), "axes": AXES}
    for f in FIELDS:
        doc[f] = _arr(np.asarray(get[f])[:k])
    doc.update({
        "config": dataclasses.asdict(config),
        "theta0_digest": theta0.fingerprint,
        "trial_config": (trial_config if isinstance(trial_config, dict) else
                         dataclasses.asdict(trial_config or sim.TrialConfig())),
        "scene_config": (scene_config if isinstance(scene_config, dict) else
                         dataclasses.asdict(scene_config or scene.SceneConfig())),
        "command": command, "seconds": round(float(seconds), 1),
        "machine": io.machine(devices=True),
        "git_commit": io.run_metadata().get("git_commit"),
    })
    doc.update(extra or {})
    return doc


def save_per_seed(path, doc: dict) -> None:
    """Writes a per-seed record as compact JSON (atomically)."""
    import json

    from sern_jax.infra import io

    io.save_text(path, json.dumps(io.to_jsonable(doc), separators=(",", ":")) + "\n")


def _file_name(label: str, objects, all_objects) -> str:
    stem = label.replace("=", "_")
    if list(objects) == list(all_objects):
        return f"{stem}.json"
    return f"{stem}.part-{'+'.join(objects)}.json"


def load_results(results_dir) -> dict:
    """{label: doc} with the parts of a label joined along the object axis (in the hard
    set's order); arrays as float64 numpy arrays with NaN where -1 was stored."""
    from sern_jax.infra import io

    results_dir = Path(results_dir)
    groups: dict[str, list[dict]] = {}
    for f in sorted(results_dir.glob("*.json")):
        if f.name == "summary.json":
            continue
        d = io.load_json(f)
        if "label" not in d:
            continue
        groups.setdefault(d["label"], []).append(d)
    if not groups:
        raise ValueError(f"no per-seed results in {results_dir}")
    out = {}
    for label, parts in groups.items():
        order = parts[0]["all_objects"]
        parts.sort(key=lambda d: order.index(d["objects"][0]))
        names = [n for d in parts for n in d["objects"]]
        if len(set(names)) != len(names):
            raise ValueError(f"{label}: an object appears in two part files")
        for key in ("policies", "seeds", "rounds_done", "theta0_digest"):
            if len({repr(d[key]) for d in parts}) != 1:
                raise ValueError(f"{label}: parts differ in {key}")
        doc = dict(parts[0])
        doc["objects"] = names
        for f in FIELDS:
            a = np.concatenate([np.asarray(d[f], np.float64) for d in parts], axis=1)
            if f == "pseudo_regret":
                # a pseudo-regret can be negative (the policy's expected value above the
                # independent oracle's chosen candidate): not measured = accounting off, or
                # round 0
                if not doc.get("config", {}).get("regret_trials", 0):
                    a = np.full(a.shape, np.nan)
                a[:1] = np.nan
                doc[f] = a
            else:
                doc[f] = np.where(a < 0, np.nan, a)  # success fractions: -1 = not measured
        doc["seconds"] = max(d["seconds"] for d in parts)
        doc["parts"] = [{"objects": d["objects"], "seconds": d["seconds"],
                         "command": d["command"], "machine": d["machine"]} for d in parts]
        out[label] = doc
    return out


def _ci(x) -> dict:
    from sern_jax.analysis import stats

    c = stats.t_interval(np.asarray(x, np.float64))
    return {"mean": c.mean, "sd": c.sd, "se": c.se, "n": c.n, "half": c.half,
            "lower": c.lower, "upper": c.upper}


def _comparisons(names, diffs) -> list[dict]:
    from sern_jax.analysis import stats

    rows = stats.paired_differences(np.stack(diffs), names=names)
    return [r._asdict() for r in rows]


def summarise(results_dir, write: bool = True) -> dict:
    """Everything the docs quote from a setting's per-seed files (see the module doc)."""
    from sern_jax.infra import io
    from sern_jax.grasp.online import checkpoint

    results_dir = Path(results_dir)
    docs = load_results(results_dir)
    labels = list(docs)
    runs, finals = {}, {}
    for label, d in docs.items():
        lv, pe = d["lowvar_eval"], d["paper_eval"]
        ex, pr = d["explore_success"], d["pseudo_regret"]
        has_lv = np.isfinite(lv).all()
        has_pr = np.isfinite(pr[1:]).all() and pr.shape[0] > 1
        rows = checkpoint.table_rows(d["objects"], tuple(d["policies"]), pe,
                                     lv if has_lv else None, pr if has_pr else None)
        pol = {}
        for q, p in enumerate(d["policies"]):
            lvq, peq = lv[:, :, q, :].mean(1), pe[:, :, q, :].mean(1)  # [R+1, S] pooled
            rec = {"lowvar_by_round": lvq.mean(1).tolist() if has_lv else None,
                   "paper_by_round": peq.mean(1).tolist(),
                   "explore_success": float(np.nanmean(ex[1:, :, q, :])) if len(ex) > 1
                   else None,
                   "final_minus_theta0_lowvar": _ci(lvq[-1] - lvq[0]) if has_lv else None,
                   "final_lowvar": _ci(lvq[-1]) if has_lv else None}
            if has_pr:
                rec["regret_total"] = {o: _ci(pr[1:, i, q, :].sum(0))
                                       for i, o in enumerate(d["objects"])}
            pol[p] = rec
            finals[(label, p)] = {"lowvar": lv[-1, :, q, :], "paper": pe[-1, :, q, :],
                                  "explore": np.nanmean(ex[1:, :, q, :], axis=(0, 1)),
                                  "regret": pr[1:, :, q, :].sum(0) if has_pr else None}
        runs[label] = {"objects": d["objects"], "policies": d["policies"],
                       "seeds": d["seeds"], "rounds": d["rounds"],
                       "rounds_done": d["rounds_done"], "seconds": d["seconds"],
                       "parts": d["parts"], "theta0_digest": d["theta0_digest"],
                       "table": rows, "policies_pooled": pol}
    # the comparisons reported together: SERN - each peer (one run of several policies), or
    # each (label, policy) against the first one (an ablation)
    keys = list(finals)
    if len(labels) == 1 and "sern" in docs[labels[0]]["policies"] and len(keys) > 1:
        ref = (labels[0], "sern")
        others = [k for k in keys if k != ref]
    else:  # an ablation: against the paper's configuration where it is one of the runs
        ref = next((k for k in keys if k[0] in PAPER_LABELS), keys[0])
        others = [k for k in keys if k != ref]
    comps = {}
    ablation = not (len(labels) == 1 and ref[1] == "sern")
    if others and docs[labels[0]]["seeds"] > 1:
        objects = docs[ref[0]]["objects"]
        lv_ok = not np.isnan(finals[ref]["lowvar"]).any()
        names, diffs, ex_names, ex_diffs, rg_names, rg_diffs = [], [], [], [], [], []
        for k in others:
            # SERN - peer within one run; variant - first variant across an ablation's runs
            a, b = (finals[k], finals[ref]) if ablation else (finals[ref], finals[k])
            left, right = (k, ref) if ablation else (ref, k)
            tag = f"{left[0]}:{left[1]} - {right[0]}:{right[1]}"
            if lv_ok:
                names.append(f"{tag} | fixed-pose, pooled")
                diffs.append(a["lowvar"].mean(0) - b["lowvar"].mean(0))
            names.append(f"{tag} | 5-grasp, pooled")
            diffs.append(a["paper"].mean(0) - b["paper"].mean(0))
            if not ablation and lv_ok:
                for o, n in enumerate(objects):
                    names.append(f"{tag} | fixed-pose, {n}")
                    diffs.append(a["lowvar"][o] - b["lowvar"][o])
            ex_names.append(tag)
            ex_diffs.append(a["explore"] - b["explore"])
            if a["regret"] is not None:
                for o, n in enumerate(objects):
                    rg_names.append(f"{tag} | {n}")
                    rg_diffs.append(a["regret"][o] - b["regret"][o])
        comps["final_round"] = _comparisons(names, diffs)
        comps["explore_success"] = _comparisons(ex_names, ex_diffs)
        if rg_names:
            comps["regret_total"] = _comparisons(rg_names, rg_diffs)
    summary = {
        "runs": runs,
        "reference": list(ref),
        "comparisons": comps,
        "interval": ("95 % Student t over seeds (n - 1 dof) per comparison; pvalue_holm: "
                     "Holm over the comparisons of the same list (one family each)"),
        "metric": ("final-round greedy success per seed (fixed-pose: mean over the eval "
                   "poses and trials; 5-grasp: the paper's evaluation); pooled = mean over "
                   "the objects per seed"),
    }
    summary = io.to_jsonable(summary)
    if write:
        io.save_json(results_dir / "summary.json", summary)
    return summary


# ----------------------------------------------------------------------------- markdown
# Markdown renderings of a summary, for a run's own report (the docs' tables are built by
# figures/doc_tables.py from the same per-seed files).


def _pts(x, digits: int = 1, sign: bool = True) -> str:
    """100 x, rounded, without a negative zero."""
    v = round(100 * float(x), digits) + 0.0
    return f"{v:+.{digits}f}" if sign else f"{v:.{digits}f}"


def _pm(c, digits: int = 1) -> str:
    return f"{_pts(c['mean'], digits)} ± {_pts(c['half'], digits, False)}"


def _short(name: str) -> str:
    """'strong:sern - strong:greedy | fixed-pose, pooled' -> 'sern − greedy, fixed-pose,
    pooled' (labels kept where they differ: ablations)."""
    pair, _, what = name.partition(" | ")
    a, _, b = pair.partition(" - ")
    (la, pa), (lb, pb) = a.partition(":")[::2], b.partition(":")[::2]
    if pa and pb:
        pair = f"{pa} − {pb}" if la == lb else f"{la} − {lb}"
    return f"{pair}, {what}" if what else pair


def _holm_note(c) -> str:
    return f"{c['pvalue_holm']:.2f}" if c["pvalue_holm"] >= 0.01 else f"{c['pvalue_holm']:.0e}"


def table1_markdown(summary: dict, label: str) -> str:
    """Table I in the paper's layout: 5-grasp success % per round, mean over seeds (± SE =
    sd/√n over the seeds, ddof 1: the statistic the paper prints), Max and Imprv."""
    run = summary["runs"][label]
    r = run["rounds_done"]
    head = ("| Obj. | Alg. | θ0 | " + " | ".join(f"Round {k}" for k in range(1, r + 1))
            + " | Max. | Imprv. |")
    lines = [head, "|" + "---|" * (r + 5)]
    for row in run["table"]:
        cells = [f"{m:.0f}% (±{se:.2f})" for m, se in zip(row["rounds"], row["se"])]
        imprv = f"{100 * row['imprv']:.0f}%" if row["imprv"] is not None else "n/a"
        lines.append(f"| {row['object']} | {row['policy']} | {row['theta0']:.0f}% | "
                     + " | ".join(cells) + f" | {row['max']:.0f}% | {imprv} |")
    return "\n".join(lines)


def fixed_pose_markdown(summary: dict, label: str) -> str:
    """Fixed-pose success % per round 0..R, mean over seeds (± SE over the seeds)."""
    run = summary["runs"][label]
    r = run["rounds_done"]
    lines = ["| Obj. | Alg. | " + " | ".join(f"R{k}" for k in range(r + 1)) + " |",
             "|" + "---|" * (r + 3)]
    n = run["seeds"]
    for row in run["table"]:
        se = [sd * (n / (n - 1)) ** 0.5 / n ** 0.5 for sd in row["lowvar_std"]]
        cells = [f"{m:.0f}% (±{e:.1f})" for m, e in zip(row["lowvar_rounds"], se)]
        lines.append(f"| {row['object']} | {row['policy']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def pooled_markdown(summary: dict, label: str) -> str:
    """Per policy, pooled over the objects: θ0, round 1 and round R success (5-grasp /
    fixed-pose), round R − θ0 (fixed-pose, t interval), exploration success."""
    run = summary["runs"][label]
    lines = ["| | θ0 | round 1 | round R | round R − θ0 (fixed-pose) | exploration success |",
             "|---|---|---|---|---|---|"]
    for pol, rec in run["policies_pooled"].items():
        pe, lv = rec["paper_by_round"], rec["lowvar_by_round"]
        lines.append(f"| {pol} | {100 * pe[0]:.1f} % / {100 * lv[0]:.1f} % | "
                     f"{100 * pe[1]:.1f} % / {100 * lv[1]:.1f} % | "
                     f"{100 * pe[-1]:.1f} % / {100 * lv[-1]:.1f} % | "
                     f"{_pm(rec['final_minus_theta0_lowvar'])} | "
                     f"{100 * rec['explore_success']:.1f} % |")
    return "\n".join(lines).replace("round R", f"round {run['rounds_done']}")


def comparisons_markdown(summary: dict, family: str = "final_round") -> str:
    """One family of paired comparisons: mean ± 95 % t half-width, the t interval's ends,
    the two-sided p and its Holm adjustment over the family (success differences in
    percentage points; ``regret_total`` in expected successes)."""
    rows = summary["comparisons"][family]
    regret = family == "regret_total"
    unit = "successes" if regret else "points"
    lines = [f"| comparison | difference ({unit}) | 95 % t interval | p | Holm p |",
             "|---|---|---|---|---|"]
    for c in rows:
        if regret:
            diff = f"{c['mean'] + 0.0:+.1f} ± {c['half']:.1f}"
            ends = f"[{c['lower'] + 0.0:+.1f}, {c['upper'] + 0.0:+.1f}]"
        else:
            diff, ends = _pm(c), f"[{_pts(c['lower'])}, {_pts(c['upper'])}]"
        lines.append(f"| {_short(c['name'])} | {diff} | {ends} | {c['pvalue']:.3f} | "
                     f"{_holm_note(c)} |")
    return "\n".join(lines)


def regret_markdown(summary: dict, label: str) -> str:
    """Pseudo-regret per round (expected successes lost to the independent oracle's best
    candidate over a round's exploration grasps; mean over seeds) and the run's total with
    its 95 % Student-t interval over the seeds."""
    run = summary["runs"][label]
    r = run["rounds_done"]
    lines = ["| object | policy | " + " | ".join(f"round {k}" for k in range(1, r + 1))
             + f" | total ({r} rounds), 95 % t |", "|" + "---|" * (r + 3)]
    for row in run["table"]:
        tot = run["policies_pooled"][row["policy"]]["regret_total"][row["object"]]
        lines.append(f"| {row['object']} | {row['policy']} | "
                     + " | ".join(f"{v:.2f}" for v in row["pseudo_regret"])
                     + f" | {tot['mean']:.1f} ± {tot['half']:.1f} |")
    return "\n".join(lines)


def _machine_line() -> str:
    from sern_jax.infra import io

    m = io.machine(devices=True)
    return (f"{m['cpu']} ({m['cores_usable']} of {m['cpu_count']} cores usable), "
            f"jax {m.get('jax_backend')} {m.get('jax_devices')}")


def collect(out, results) -> list[Path]:
    """Per-seed files of the runs under ``out`` that stopped before their last round (from
    their checkpoints); finished runs already wrote theirs."""
    from sern_jax.infra import io
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.online import config as config_lib

    written = []
    for meta_file in sorted(Path(out).glob("*/run_meta.json")):
        meta = io.load_json(meta_file)
        ckpt = meta_file.parent / "checkpoint.npz"
        if not ckpt.exists():
            continue
        saved = io.load_npz(ckpt)
        done = int(saved["next_round"]) - 1
        targets = meta.get("targets") or [{"file": meta["file"], "label": meta["label"],
                                           "setting": meta["setting"]}]
        theta0 = artifacts.load_theta0(meta.get("theta0_dir"))
        config = config_lib.OnlineConfig(**{k: tuple(v) if isinstance(v, list) else v
                                            for k, v in meta["config"].items()})
        res = {f: saved[f] for f in FIELDS}
        for tg in targets:
            target = Path(results) / tg["file"]
            if done < 0 or (target.exists() and io.load_json(target)["rounds_done"] >= done):
                continue  # nothing finished, or the file already has these rounds
            doc = per_seed_doc(res, label=tg["label"], setting=tg["setting"],
                               objects=meta["objects"], all_objects=meta["all_objects"],
                               config=config, rounds_done=done,
                               seconds=meta.get("seconds", 0.0), command=meta["command"],
                               theta0=theta0, trial_config=meta.get("trial_config"),
                               scene_config=meta.get("scene_config"),
                               extra={"stopped_early": True,
                                                     **meta.get("extra", {}),
                                                     **tg.get("extra", {})})
            target.parent.mkdir(parents=True, exist_ok=True)
            save_per_seed(target, doc)
            written.append(target)
    return written


def main(argv=None) -> int:
    from sern_jax.infra import validate

    # bad input: one line naming the flag, exit 2, before any compile (validate's parser)
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("summarise", "collect"):
        p = validate.script_parser(__spec__)
        p.prog = f"{p.prog} {argv[0]}"
        p.add_argument("dirs", nargs=1 if argv[0] == "summarise" else 2)
        a = p.parse_args(argv[1:])
        # the directory read must exist (a typo is one line, not an exit 0 that did nothing);
        # collect's results directory must be one this process can write
        read = Path(a.dirs[0])
        if not read.is_dir():
            what = "runs" if argv[0] == "collect" else "results"
            p.error(f"{read}: no such directory (the {what} directory to {argv[0]})")
        if argv[0] == "collect":
            if not any(read.glob("*/run_meta.json")):
                p.error(f"{read} holds no run of `python -m experiments.grasp_learning` (no "
                        "*/run_meta.json)")
            try:
                validate.out_dir(a.dirs[1], "results directory")
            except ValueError as exc:
                p.error(str(exc))
        if argv[0] == "collect":
            for f in collect(*a.dirs):
                print(f"wrote {f} (from the checkpoint)")
            return 0
        s = summarise(a.dirs[0])
        for name, fam in s["comparisons"].items():
            for c in fam:
                print(f"{name}: {c['name']}: {100 * c['mean']:+.1f} ± {100 * c['half']:.1f} "
                      f"(95% t, n = {c['n']}; Holm p = {c['pvalue_holm']:.3f} over {len(fam)})")
        print(f"wrote {Path(a.dirs[0]) / 'summary.json'}")
        return 0

    parser = validate.script_parser(__spec__, description=__doc__.splitlines()[0])
    parser.add_argument("setting", choices=SETTINGS + ("ablations",))
    parser.add_argument("--labels", default=None,
                        help="comma-separated run labels (or setting/label) to run of the "
                             "setting's list (default: all)")
    parser.add_argument("--objects", type=validate.int_at_least(1), default=None,
                        help="first N objects of the hard set (default 6; regret 3)")
    parser.add_argument("--only", default=None, help="comma-separated hard-set objects")
    parser.add_argument("--seeds", type=validate.int_at_least(1), default=5)
    parser.add_argument("--rounds", type=validate.int_at_least(1), default=5)
    parser.add_argument("--out", default=None)
    parser.add_argument("--results", default=None,
                        help="per-seed results directory (default experiments/results/SETTING)")
    parser.add_argument("--backend", choices=("native", "mjx"), default="native",
                        help="trial physics: native MuJoCo (CPU) or MJX (GPU)")
    parser.add_argument("--regret-trials", type=validate.int_at_least(0), default=0,
                        help="regret: oracle trials per candidate, each set (default 4)")
    parser.add_argument("--regret-grasps", type=validate.int_at_least(0), default=0,
                        help="regret: oracle on the first G grasps of each phase (default 5)")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    num = args.objects if args.objects is not None else (3 if args.setting == "regret" else 6)
    for name, v, lo in (("--objects", num, 1), ("--seeds", args.seeds, 1),
                        ("--rounds", args.rounds, 1)):
        if v < lo:
            parser.error(f"{name} must be >= {lo}")
    out = Path(args.out or f"runs/grasp_{args.setting}")
    results = Path(args.results or ("experiments/results" if args.setting == "ablations"
                                    else f"experiments/results/{args.setting}"))
    try:  # every flag before anything is written or loaded
        validate.out_dir(out, "--out")
        validate.out_dir(results, "--results")
        wanted_labels = (set(validate.comma_list(args.labels, "--labels"))
                         if args.labels is not None else set())
        only = validate.comma_list(args.only, "--only") if args.only is not None else []
    except ValueError as exc:
        parser.error(str(exc))

    from sern_jax.infra import io
    from sern_jax.grasp.model import artifacts
    from sern_jax.grasp.world import objects
    from sern_jax.grasp.online import config as config_lib
    from sern_jax.grasp.online import driver

    theta0 = artifacts.load_theta0()
    hard = artifacts.hard_set(theta0, num)
    all_objects = hard["objects"]
    chosen = all_objects
    if args.only:
        chosen = only
        bad = [n for n in chosen if n not in all_objects]
        if bad:
            parser.error(f"--only: {', '.join(bad)} not in the hard set {all_objects}")
        chosen = [n for n in all_objects if n in chosen]
    specs = [objects.make_object(n) for n in chosen]
    try:
        base = config_lib.OnlineConfig(num_seeds=args.seeds, rounds=args.rounds,
                                       backend=args.backend, regret_trials=args.regret_trials,
                                       regret_grasps=args.regret_grasps)
    except ValueError as exc:
        parser.error(str(exc))
    command = "python -m experiments.grasp_learning " + shlex.join(argv)
    print(f"{command}\nmachine: {_machine_line()}", flush=True)
    # the plan: (setting, label, config); "ablations" runs each distinct configuration of
    # the four ablations once (alpha=0.05, core=dpp and loss=bce are the same run) and
    # writes its per-seed file into every setting that lists it
    if args.setting == "ablations":
        plan = [(st, label, config) for st in ABLATIONS for label, config in runs_of(st, base)]
    else:
        plan = [(args.setting, label, config) for label, config in runs_of(args.setting, base)]
    groups: dict[str, list] = {}
    for st, label, config in plan:
        groups.setdefault(config.fingerprint(), []).append((st, label, config))
    if args.labels:
        want = wanted_labels
        known = {x for g in groups.values() for st, lb, _ in g for x in (lb, f"{st}/{lb}")}
        if want - known:
            parser.error(f"--labels: {', '.join(sorted(want - known))} not in {sorted(known)}")
        groups = {k: g for k, g in groups.items()
                  if any(lb in want or f"{st}/{lb}" in want for st, lb, _ in g)}
    results.mkdir(parents=True, exist_ok=True)  # after every check: nothing written before
    for group in groups.values():
        st0, label0, config = group[0]
        run_dir = out / (f"{st0}.{label0}" if args.setting == "ablations" else label0
                         ).replace("=", "_")
        if args.only:
            run_dir = run_dir.with_name(run_dir.name + "." + "+".join(chosen))
        fname = _file_name(label0, chosen, all_objects)
        # with --labels, write only the folders asked for: a call for alpha=0.05 must not
        # overwrite core=dpp / loss=bce files made by another call, and same_run_as names
        # exactly the folders this call wrote (never a sibling written by a different run)
        if args.labels:
            group = [g for g in group if g[1] in want or f"{g[0]}/{g[1]}" in want]
        shared = [f"{st}/{lb}" for st, lb, _ in group]
        targets = [{"file": (f"{st}/" if args.setting == "ablations" else "")
                    + _file_name(lb, chosen, all_objects), "label": lb, "setting": st,
                    "extra": {"same_run_as": shared} if len(group) > 1 else {}}
                   for st, lb, _ in group]
        io.save_json(run_dir / "run_meta.json", {
            "label": label0, "setting": st0, "objects": chosen, "all_objects": all_objects,
            "config": dataclasses.asdict(config), "command": command, "file": fname,
            "targets": targets})
        t = time.perf_counter()
        res = driver.run(config, specs, run_dir, theta0=theta0,
                         progress=not args.no_progress)
        seconds = time.perf_counter() - t
        for tg in targets:
            doc = per_seed_doc(res["results"], label=tg["label"], setting=tg["setting"],
                               objects=chosen, all_objects=all_objects, config=config,
                               rounds_done=config.rounds, seconds=seconds, command=command,
                               theta0=theta0, extra={"timings": res["timings"],
                                                     "trial_counts": res["trial_counts"],
                                                     **tg["extra"]})
            (results / tg["file"]).parent.mkdir(parents=True, exist_ok=True)
            save_per_seed(results / tg["file"], doc)
            print(f"{tg['setting']}/{tg['label']}: {seconds:.0f} s, wrote "
                  f"{results / tg['file']}", flush=True)
    if args.setting == "ablations" or args.labels:
        return 0
    if not args.only:
        s = summarise(results)
        for c in s["comparisons"].get("final_round", []):
            print(f"{c['name']}: {100 * c['mean']:+.1f} ± {100 * c['half']:.1f} points (95% t "
                  f"over {c['n']} seeds; Holm p = {c['pvalue_holm']:.3f})")
        print(f"wrote {results / 'summary.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
