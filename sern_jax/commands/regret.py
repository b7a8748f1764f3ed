"""``sern regret``: regret curves for several policies over many seeds.

This module owns the command's arguments only. The experiment and the figures live in the
script folders (``experiments/regret.py``, ``figures/make_regret_figs.py``), which library
modules never import: :mod:`sern_jax.commands.main` imports them and hands them to :func:`add_parser`.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
from pathlib import Path
from typing import Any, Callable

__all__ = ["add_parser", "run"]


def add_parser(subparsers, *, defaults: Any, run_experiment: Callable,
               make_figures: Callable | None = None) -> argparse.ArgumentParser:
    """Registers ``regret`` under ``subparsers``.

    Args:
      subparsers: from ``ArgumentParser.add_subparsers``.
      defaults: a default experiment (``experiments.regret.RegretExperiment()``, a frozen
        dataclass): its fields are the options' defaults, and the run replaces them.
      run_experiment: ``run_experiment(exp, out_dir, progress=bool) -> run_dir``.
      make_figures: ``make_figures(run_dir) -> [paths]``, or None (no figures).
    """
    d = defaults
    p = subparsers.add_parser(
        "regret",
        help="regret curves of SERN and peers over many seeds (saves a run directory + figures)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description=(
            "Runs each policy on the same Bernoulli (or finite-context) bandit for many seeds "
            "with common random numbers, saves config.json, metadata.json, results.npz, "
            "summary.json and report.md in the run directory, and draws figures/regret.png "
            "(log-log regret with 95%% bands and fitted slopes) and figures/exploration.png "
            "(N_a(t)/t against Theorem 1's floor c = e^{-1/alpha}/K). Finished seed chunks are "
            "saved as they complete: rerunning the same command resumes an interrupted run."
        ),
    )
    p.add_argument("--policies", default=",".join(d.policies),
                   help="comma list from: softmax, greedy, epsilon_greedy, ucb1, thompson, "
                        "boltzmann_gumbel, exp3")
    p.add_argument("--estimator", default=d.estimator,
                   help="exact, addhalf, mean, adv, adv_low, rademacher, gauss, flip, pinned, "
                        "l1median, l1argmax")
    p.add_argument("--arms", type=int, default=d.num_arms, help="number of arms K")
    p.add_argument("--means", default=d.means,
                   help="'linspace' (0.9 down to 0.1), 'random' (U[0,1] per seed) or a comma "
                        "list of K success probabilities")
    p.add_argument("--contexts", type=int, default=d.num_contexts,
                   help="number of i.i.d. contexts M (M > 1: random problem with gap --gap)")
    p.add_argument("--gap", type=float, default=d.gap, help="Assumption-1 gap Δ2 when M > 1")
    p.add_argument("--horizon", "-T", type=int, default=d.horizon, help="rounds T")
    p.add_argument("--seeds", "-S", type=int, default=d.num_seeds, help="number of seeds S")
    p.add_argument("--schedule", default=d.schedule,
                   help="constant (α = α0), log (α0/ln(T^p), Algorithm 1), theorem4")
    p.add_argument("--alpha", type=float, default=d.alpha0, help="SERN temperature α0 > 0")
    p.add_argument("--p", type=float, default=d.p, help="schedule exponent p")
    p.add_argument("--epsilon", type=float, default=d.epsilon, help="ε of ε-greedy, in [0, 1]")
    p.add_argument("--seed", type=int, default=d.seed, help="root seed")
    p.add_argument("--checkpoints", type=int, default=d.num_checkpoints,
                   help="log-spaced checkpoints of t")
    p.add_argument("--chunk-size", type=int, default=d.chunk_size,
                   help="seeds per compiled call (memory bound; resume granularity)")
    p.add_argument("--float64", action="store_true", help="run in float64")
    p.add_argument("--devices", type=int, default=d.devices,
                   help="shard seeds over this many devices")
    p.add_argument("--out", default=None,
                   help="run directory (default runs/regret-<fingerprint>)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    p.add_argument("--no-per-seed", dest="per_seed", action="store_false",
                   help="keep statistics over seeds reduced on the device (means, variances, "
                        "min/max, histogram quantiles: kilobytes per chunk) instead of "
                        "per-seed arrays; for very many seeds (no slope interval, no figures)")
    p.set_defaults(func=functools.partial(run, defaults=defaults, run_experiment=run_experiment,
                                          make_figures=make_figures))
    return p


def run(args, *, defaults: Any, run_experiment: Callable,
        make_figures: Callable | None = None) -> int:
    """Runs the experiment described by ``args`` (see :func:`add_parser` for the rest)."""
    exp = dataclasses.replace(
        defaults, policies=tuple(s.strip() for s in args.policies.split(",") if s.strip()),
        estimator=args.estimator, num_arms=args.arms, means=args.means,
        num_contexts=args.contexts, gap=args.gap, horizon=args.horizon, num_seeds=args.seeds,
        schedule=args.schedule, alpha0=args.alpha, p=args.p, epsilon=args.epsilon,
        seed=args.seed, num_checkpoints=args.checkpoints, chunk_size=args.chunk_size,
        float64=args.float64, devices=args.devices,
        **({"per_seed": False} if not args.per_seed else {}))
    out = Path(args.out) if args.out else Path("runs") / f"regret-{exp.fingerprint()}"
    run_dir = run_experiment(exp, out, progress=not args.no_progress)
    print((run_dir / "report.md").read_text())
    if not args.per_seed and not args.no_figures:
        print("figures need per-seed arrays: none drawn with --no-per-seed")
    elif not args.no_figures and make_figures is not None:
        for path in make_figures(run_dir):
            print(f"wrote {path}")
    print(f"run directory: {run_dir}")
    return 0
