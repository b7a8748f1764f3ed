"""``sern reproduce [--quick]``: the main job, the paper end to end in one run directory.

1. the quick theory checks of Theorems 1-5 (``sern check --quick``);
2. a regret-curve experiment (``sern regret`` defaults: SERN and four peers, 2,000 seeds);
3. online grasp learning on the hard objects (``sern grasp learn``: the paper's Table I
   setting, 6 objects x 3 policies x 5 seeds x 5 rounds of 20 + 5 grasps; ``--quick``: 3
   objects x 3 seeds x 3 rounds);

then one ``report.md`` with the three parts and their figures, and a one-screen summary.

This module owns the arguments and the composition; the check runner, the regret experiment
and the figure makers live in the script folders and are handed in by :mod:`sern_jax.commands.main`.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import time
from pathlib import Path
from typing import Callable

from sern_jax.infra import validate

__all__ = ["add_parser", "run", "LEARN_FULL", "LEARN_QUICK"]

LEARN_FULL = {"objects": 6, "seeds": 5, "rounds": 5}
LEARN_QUICK = {"objects": 3, "seeds": 3, "rounds": 3}
# Expected wall times of each part, for the estimate printed before a run starts
# (calibrated from experiments/results/reproduce).
EXPECTED_S = {"check": 120, "regret": 50, "learn_full": 300, "learn_quick": 120}


def add_parser(subparsers, *, check_run: Callable, regret_defaults, run_regret: Callable,
               regret_figures: Callable, learn_figures: Callable) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "reproduce",
        help="the main job: theory checks, regret curves and the grasp Table I in one report",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description=(
            "Runs the quick theory checks (sern check --quick), a regret-curve experiment "
            "(sern regret defaults) and online grasp learning on the hard objects with SERN, "
            "eps-greedy and greedy (the paper's Table I setting; --quick: fewer objects, "
            "seeds and rounds), and writes one report.md with figures into the run directory "
            "plus a summary on the terminal. Each part saves its own results and resumes "
            "when rerun with the same --out."))
    p.add_argument("--quick", action="store_true",
                   help="3 objects x 3 seeds x 3 rounds of grasp learning")
    p.add_argument("--out", default=None, help="run directory (default runs/reproduce-<time>)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=lambda args: run(
        args, check_run=check_run, regret_defaults=regret_defaults, run_regret=run_regret,
        regret_figures=regret_figures, learn_figures=learn_figures))
    return p


def run(args, *, check_run, regret_defaults, run_regret, regret_figures, learn_figures) -> int:
    from sern_jax.commands import grasp_learn as learn_cli

    name = "reproduce-" + _dt.datetime.now().strftime("%Y%m%d-%H%M%S") + (
        "-quick" if args.quick else "")
    out = Path(args.out) if args.out else Path("runs") / name
    learn_cli._check_out(str(out))
    from sern_jax.grasp.model import artifacts

    theta0 = artifacts.load_theta0()  # fails early, with a message, if θ0 is missing
    size = LEARN_QUICK if args.quick else LEARN_FULL
    hard = artifacts.hard_set(theta0, size["objects"])
    # `sern grasp learn`'s own parser, so every other flag keeps its documented default;
    # its values and sizes are checked now, before the checks and regret parts run
    learn_parser = argparse.ArgumentParser(add_help=False)
    learn_cli.add_learn_parser(learn_parser.add_subparsers())
    learn_args = learn_parser.parse_args(
        ["learn", *hard["objects"], "--seeds", str(size["seeds"]), "--rounds",
         str(size["rounds"]), "--out", str(out / "learn")]
        + (["--no-progress"] if args.no_progress else []))
    learn_cli.check_learn_args(learn_args, len(hard["objects"]))
    with validate.locked_run_dir(out):
        return _run_locked(args, out, theta0, size, hard, learn_args, check_run=check_run,
                           regret_defaults=regret_defaults, run_regret=run_regret,
                           regret_figures=regret_figures, learn_figures=learn_figures)


def _run_locked(args, out, theta0, size, hard, learn_args, *, check_run, regret_defaults,
                run_regret, regret_figures, learn_figures) -> int:
    from sern_jax.infra import io
    from sern_jax.commands import grasp_learn as learn_cli

    expected = EXPECTED_S["check"] + EXPECTED_S["regret"] + EXPECTED_S[
        "learn_quick" if args.quick else "learn_full"]
    print(f"sern reproduce{' --quick' if args.quick else ''}: theory checks, regret curves, "
          f"grasp learning on {', '.join(hard['objects'])} ({size['seeds']} seeds x "
          f"{size['rounds']} rounds); expected about {expected / 60:.0f} min on 2 CPU cores. "
          f"Output: {out}", flush=True)
    out.mkdir(parents=True, exist_ok=True)
    timings = {}

    # 1. theory checks
    t = time.perf_counter()
    check_args = argparse.Namespace(
        quick=True, only=None, seeds=None, json_out=None, out=str(out), name="check",
        alpha=0.01, seed=0, wrong_bounds=False, no_figures=False, list=False)
    check_status = check_run(check_args)
    timings["check_s"] = time.perf_counter() - t
    check_doc = io.load_json(out / "check" / "report.json")

    # 2. regret curves
    t = time.perf_counter()
    regret_dir = run_regret(regret_defaults, out / "regret", progress=not args.no_progress)
    regret_figs = regret_figures(regret_dir)
    timings["regret_s"] = time.perf_counter() - t

    # 3. grasp learning (Table I)
    t = time.perf_counter()
    learn_cli.run_learn(learn_args, make_figures=learn_figures, log=lambda *_: None)
    timings["learn_s"] = time.perf_counter() - t
    table = json.loads((out / "learn" / "table.json").read_text())["table"]

    report = _report(out, check_doc, check_status, regret_dir, regret_figs, table, hard,
                     size, timings, args.quick)
    io.save_text(out / "report.md", report)
    io.save_json(out / "metadata.json", io.run_metadata(timings=timings, quick=args.quick))
    print(_summary(check_doc, check_status, regret_dir, table, timings, out,
                   learn_dir=out / "learn"))
    return 0 if check_status == 0 else 1


def _demote(markdown: str) -> str:
    """A sub-report's headings two levels down, to nest it under this report's sections."""
    return "\n".join("##" + line if line.startswith("#") else line
                     for line in markdown.splitlines())


def _checks(check_doc: dict) -> list[dict]:
    """The per-check rows of ``sern check``'s report.json; refuses a report without any."""
    rows = check_doc.get("checks")
    if not rows:
        raise ValueError("the theory checks' report.json lists no checks; rerun "
                         "`sern check --quick` to see what went wrong")
    return rows


def _rel(path: Path, root: Path) -> str:
    return str(Path(path).resolve().relative_to(root.resolve()))


def _paired_lines(learn_dir: Path) -> list[str]:
    """The summary's first lines: SERN − each peer in the final round, pooled over the
    objects per seed, with Student-t intervals over the seeds and Holm over every
    difference listed (both evaluations, both peers). Win counts on unresolved differences
    are not evidence and are not printed."""
    import numpy as np

    from sern_jax.infra import io
    from sern_jax.analysis import stats

    res = io.load_npz(learn_dir / "results.npz")
    policies = io.load_json(learn_dir / "config.json")["config"]["policies"]
    if "sern" not in policies or len(policies) < 2:
        return []
    s = policies.index("sern")
    evals = [("fixed-pose evaluation", res["lowvar_eval"]),
             ("5-grasp evaluation", res["paper_eval"])]
    evals = [(n, a) for n, a in evals if np.isfinite(a[-1]).all()]
    names, diffs = [], []
    for label, a in evals:
        pooled = a[-1].mean(0)  # [Q, S]: final round, mean over objects, per seed
        for q, peer in enumerate(policies):
            if q != s:
                names.append(f"SERN − {peer}, {label}")
                diffs.append(100.0 * (pooled[s] - pooled[q]))
    num_s = len(diffs[0]) if diffs else 0
    if num_s < 2:
        return [f"grasp learning: {num_s} seed: no interval for SERN − peer (needs >= 2)"]
    rows = stats.paired_differences(np.stack(diffs), names=names, level=0.95)
    num_o = res["paper_eval"].shape[1]
    lines = [f"grasp learning: SERN − peer, final round, mean over {num_o} objects, paired "
             f"over {num_s} seeds (± is the 95 % Student-t half-width, as docs/RESULTS.md "
             f"prints it; Holm over the {len(rows)} differences listed):"]
    for r in rows:
        verdict = "sign resolved" if r.resolved else "not resolved after Holm"
        lines.append(f"                {r.name}: {r.mean:+.1f} ± {r.half:.1f} points, "
                     f"Holm p = {r.pvalue_holm:.2f}: {verdict}")
    return lines


def _report(out, check_doc, check_status, regret_dir, regret_figs, table, hard, size, timings,
            quick) -> str:
    results = _checks(check_doc)
    ok = sum(1 for r in results if r.get("ok"))
    lines = [
        f"# sern reproduce{' --quick' if quick else ''}", "",
        f"Made {_dt.datetime.now().isoformat(timespec='seconds')}; wall time "
        f"{sum(timings.values()):.0f} s (checks {timings['check_s']:.0f} s, regret "
        f"{timings['regret_s']:.0f} s, grasp learning {timings['learn_s']:.0f} s).", "",
        "## 1. Theory checks (`sern check --quick`)", "",
        f"{ok}/{len(results)} verdicts as expected (exit status {check_status}). "
        f"Full table: [check/report.md](check/report.md).", "",
        "## 2. Regret curves (`sern regret` defaults)", "",
        _demote((Path(regret_dir) / "report.md").read_text()), "",
    ]
    lines += [f"![{Path(f).stem}]({_rel(f, out)})" for f in regret_figs]
    rule = ", ".join(f"{o} ({'meets the rule' if m else 'does not meet the rule'})"
                     for o, m in zip(hard["objects"], hard["meets_rule"]))
    lines += [
        "", "## 3. Online grasp learning (Algorithm 1, the paper's Table I)", "",
        f"Objects: {rule}. The hard-set rule: θ0's greedy choice succeeds at most 60 % of the "
        "time and the best of the 64 candidates at least 80 %, the best candidate valued on "
        "fresh trials independent of those that chose it (the screen shipped with θ0); "
        "objects that do not meet it fill the set by lowest θ0 greedy success among those "
        "whose fresh best candidate reaches 80 %. "
        f"{size['seeds']} seeds x {size['rounds']} rounds of 20 exploration + 5 evaluation "
        "grasps; SERN α = 0.05, ε-greedy ε = 0.1. Round i = after i updates; θ0 = before "
        "learning.", "",
        _table_markdown(table), "",
        "![success](learn/figures/success.png)", "",
        "![paired](learn/figures/paired.png)", "",
    ]
    return "\n".join(lines) + "\n"


def _table_markdown(rows: list[dict]) -> str:
    """Table I as docs/RESULTS.md prints it: per round the 5-grasp success, mean over the
    seeds, with its standard error over the seeds (SE = sd/√seeds, ddof 1) in parentheses,
    the statistic the paper's Table I prints; then the fixed-pose evaluation's means."""
    num_r = len(rows[0]["rounds"])
    head = ["object", "policy", "θ0"] + [f"round {i + 1}" for i in range(num_r)] + [
        "max", "Imprv"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        se = r.get("se") or [None] * num_r
        cells = [r["object"], r["policy"], f"{r['theta0']:.0f} %"]
        cells += [f"{m:.0f} %" + (f" (SE {e:.2f})" if e is not None else "")
                  for m, e in zip(r["rounds"], se)]
        cells += [f"{r['max']:.0f} %", "n/a" if r["imprv"] is None
                  else f"{100 * r['imprv']:.0f} %"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "(SE: standard error over the seeds, sd/√seeds with ddof 1, as "
              "docs/RESULTS.md and the paper's Table I print it.)"]
    if "lowvar_rounds" in rows[0]:
        lines += ["", "Fixed-pose evaluation (greedy success on fixed poses, mean over the "
                  "seeds; round 0 = θ0):", ""]
        head = ["object", "policy"] + [f"R{i}" for i in range(num_r + 1)]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in rows:
            lines.append("| " + " | ".join([r["object"], r["policy"]] + [
                f"{m:.0f} %" for m in r["lowvar_rounds"]]) + " |")
    return "\n".join(lines)


def _summary(check_doc, check_status, regret_dir, table, timings, out,
             learn_dir: Path | None = None) -> str:
    results = _checks(check_doc)
    ok = sum(1 for r in results if r.get("ok"))
    summary = json.loads((Path(regret_dir) / "summary.json").read_text())
    lines = ["", "=" * 72, "sern reproduce: summary", "=" * 72,
             f"theory checks : {ok}/{len(results)} verdicts as expected"
             + ("" if check_status == 0 else "  <-- NOT ALL AS EXPECTED"),
             f"regret curves : {_regret_line(summary)}"]
    if learn_dir is not None and (Path(learn_dir) / "results.npz").exists():
        lines += _paired_lines(Path(learn_dir))
    final = {}
    for r in table:
        final.setdefault(r["policy"], []).append(r["rounds"][-1])
    lines.append("                final-round greedy success, mean over objects (5-grasp "
                 "evaluation): " + ", ".join(f"{p} {sum(v) / len(v):.0f}%"
                                             for p, v in final.items()))
    lowvar = {}
    for r in table:
        if "lowvar_rounds" in r:
            lowvar.setdefault(r["policy"], []).append(r["lowvar_rounds"][-1])
    if lowvar:
        lines.append("                fixed-pose evaluation (greedy success on fixed poses, many "
                     "trials), final round: " + ", ".join(f"{p} {sum(v) / len(v):.0f}%"
                                           for p, v in lowvar.items()))
    lines += [f"time          : {sum(timings.values()):.0f} s",
              f"report        : {out / 'report.md'}", "=" * 72]
    return "\n".join(lines)


def _regret_line(summary: dict) -> str:
    rows = summary.get("policies") or summary.get("results") or {}
    try:
        parts = [f"{name} R_T={vals['regret_T_mean']:.1f}" for name, vals in rows.items()]
        return ", ".join(parts)
    except (AttributeError, KeyError, TypeError):
        return "see regret/report.md"
