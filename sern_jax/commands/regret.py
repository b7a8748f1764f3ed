"""``sern regret``: regret curves for several policies over many seeds.

This module owns the command's arguments only. The experiment lives in
:mod:`sern_jax.experiment.regret` and the figures in the script folder
(``figures/make_regret_figs.py``), which library modules never import:
:mod:`sern_jax.commands.main` imports both and hands them to :func:`add_parser`.
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
      defaults: a default experiment (``sern_jax.experiment.regret.RegretExperiment()``, a frozen
        dataclass): its fields are the options' defaults, and the run replaces them.
      run_experiment: ``run_experiment(exp, out_dir, progress=bool) -> run_dir``.
      make_figures: ``make_figures(run_dir) -> [paths]``, or None (no figures).
    """
    d = defaults
    _NEURAL = _neural().NeuralRegretExperiment()
    p = subparsers.add_parser(
        "regret",
        help="regret curves of SERN and peers over many seeds (saves a run directory + figures)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description=(
            "Runs each policy on the same Bernoulli (or finite-context) bandit for many seeds "
            "with common random numbers, saves config.json, metadata.json, results.npz, "
            "summary.json and report.md in the run directory, and draws figures/regret.png "
            "(log-log regret with 95% bands and fitted slopes) and figures/exploration.png "
            "(N_a(t)/t against Theorem 1's floor c = e^{-1/alpha}/K). Finished seed chunks are "
            "saved as they complete: rerunning the same command resumes an interrupted run."
        ),
    )
    p.add_argument("--policies", default=None,
                   help=f"comma list from: softmax, greedy, epsilon_greedy, ucb1, thompson, "
                        f"boltzmann_gumbel, exp3 (default {','.join(d.policies)}); with "
                        f"--estimator neural the learner registry's names (sern, sern_log, "
                        f"egreedy, greedy, normalized, neural_linucb, neural_lints, "
                        f"ensemble_ts, neural_ucb, uniform; softmax and epsilon_greedy are "
                        f"aliases of sern and egreedy; default {','.join(_NEURAL.policies)})")
    p.add_argument("--estimator", default=d.estimator,
                   help="exact, addhalf, mean, adv, adv_low, rademacher, gauss, flip, pinned, "
                        "l1median, l1argmax; or neural (an MLP fine-tuned by each learner, on "
                        "--problem wheel|finite|linear)")
    p.add_argument("--problem", default="bernoulli",
                   help="bernoulli (the tabular engine's K-armed / finite-context problem); "
                        "with --estimator neural: wheel (Riquelme et al. 2018, --delta), "
                        "finite (--contexts feature vectors, gap --gap), linear")
    p.add_argument("--delta", type=float, default=None,
                   help=f"the wheel bandit's δ in (0, 1) (Riquelme et al.: 0.5, 0.7, 0.9, "
                        f"0.95, 0.99; default {_NEURAL.delta})")
    p.add_argument("--update-every", type=int, default=None,
                   help=f"neural: decisions between network updates (divides --horizon; "
                        f"default {_NEURAL.update_every})")
    p.add_argument("--hidden", default=None,
                   help=f"neural: the MLP's hidden widths, comma list (default "
                        f"{','.join(map(str, _NEURAL.hidden))})")
    p.add_argument("--fit-steps", type=int, default=None,
                   help=f"neural: Adam minibatch steps per update (default "
                        f"{_NEURAL.fit_steps})")
    p.add_argument("--batch-size", type=int, default=None,
                   help=f"neural: rows per minibatch step (default {_NEURAL.batch_size})")
    p.add_argument("--learning-rate", type=float, default=None,
                   help=f"neural: Adam step size (default {_NEURAL.learning_rate})")
    p.add_argument("--deltas", default=None,
                   help="neural wheel: a comma list of δ, one run directory each under --out "
                        "(d<δ>), one compilation for all (δ is a traced argument); replaces "
                        "--delta (refused together)")
    p.add_argument("--nl-prior-mean", default=None,
                   help=f"neural: neural_lints/neural_linucb centre their regression on the "
                        f"network's r̂ (network) or on 0 (zero) (default {_NEURAL.nl_prior_mean})")
    p.add_argument("--nl-sigma2", default=None,
                   help=f"neural: neural_lints/neural_linucb share one noise variance σ² "
                        f"across arms (pooled) or keep one per arm (arm) (default "
                        f"{_NEURAL.nl_sigma2}; a Neural-Linear folder made before the "
                        f"pooled default resumes with arm)")
    p.add_argument("--context-dim", type=int, default=None,
                   help=f"neural finite/linear problems: context feature dimension d "
                        f"(default {_NEURAL.context_dim})")
    p.add_argument("--arms", type=int, default=None,
                   help=f"number of arms K (default {d.num_arms}; neural: {_NEURAL.num_arms}, "
                        f"the wheel has 5)")
    p.add_argument("--means", default=d.means,
                   help="'linspace' (0.9 down to 0.1), 'random' (U[0,1] per seed) or a comma "
                        "list of K success probabilities")
    p.add_argument("--contexts", type=int, default=None,
                   help=f"number of i.i.d. contexts M (M > 1: random problem with gap --gap; "
                        f"default {d.num_contexts}; neural finite: {_NEURAL.num_contexts})")
    p.add_argument("--gap", type=float, default=None,
                   help=f"Assumption-1 gap Δ2 when M > 1 (default {d.gap}; neural finite: "
                        f"{_NEURAL.gap})")
    p.add_argument("--horizon", "-T", type=int, default=None,
                   help=f"rounds T (default {d.horizon}; neural: {_NEURAL.horizon})")
    p.add_argument("--seeds", "-S", type=int, default=None,
                   help=f"number of seeds S (default {d.num_seeds}; neural: "
                        f"{_NEURAL.num_seeds})")
    p.add_argument("--schedule", default=d.schedule,
                   help="constant (α = α0), log (α0/ln(T^p), Algorithm 1), theorem4")
    p.add_argument("--alpha", type=float, default=None,
                   help=f"SERN temperature α0 > 0 (default {d.alpha0}; neural: "
                        f"{_NEURAL.alpha0})")
    p.add_argument("--p", type=float, default=None,
                   help=f"schedule exponent p > 0, for --schedule log and theorem4 (neural: "
                        f"--policies sern_log) (default {d.p})")
    p.add_argument("--epsilon", type=float, default=None,
                   help=f"ε of ε-greedy, in [0, 1] (default {d.epsilon})")
    p.add_argument("--seed", type=int, default=d.seed, help="root seed")
    p.add_argument("--checkpoints", type=int, default=d.num_checkpoints,
                   help="log-spaced checkpoints of t")
    p.add_argument("--chunk-size", type=int, default=None,
                   help=f"seeds per compiled call (memory bound; resume granularity; "
                        f"default {d.chunk_size}; neural: {_NEURAL.chunk_size})")
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
    from sern_jax.infra import distributed  # --ray [ADDRESS]: seed chunks as Ray tasks

    distributed.add_arguments(p)
    p.set_defaults(func=functools.partial(run, defaults=defaults, run_experiment=run_experiment,
                                          make_figures=make_figures))
    return p


def _neural():
    """The neural-learner regret experiment (``--estimator neural``)."""
    from sern_jax.experiment import neural_regret

    return neural_regret


def _or(value, default):
    return default if value is None else value


# Flags of one estimator family only, by argparse dest: given with the other, they would do
# nothing, so they are refused (a flag that has no effect is a mistake the user wants to hear
# about).
_NEURAL_ONLY = {"update_every": None, "hidden": None, "fit_steps": None, "batch_size": None,
                "learning_rate": None, "context_dim": None, "nl_prior_mean": None,
                "nl_sigma2": None, "deltas": None, "delta": None}
_TABULAR_ONLY = {"float64": False, "devices": 1, "per_seed": True, "means": "linspace",
                 "schedule": "constant"}


def _policies(text: str | None, default: tuple[str, ...]) -> tuple[str, ...]:
    """``--policies``: a comma list with no empty item and no name twice."""
    from sern_jax.infra import validate

    return default if text is None else tuple(validate.comma_list(text, "--policies"))


def _check_schedule_flags(args, *, uses_p: bool, uses_epsilon: bool, mode: str) -> None:
    """``--p`` and ``--epsilon`` given where nothing reads them: one line naming the flag."""
    if args.p is not None and not uses_p:
        raise ValueError(f"--p has no effect {mode}; leave it out")
    if args.epsilon is not None and not uses_epsilon:
        raise ValueError(f"--epsilon has no effect {mode} (no epsilon-greedy policy); leave "
                         "it out")


def _run_neural(args, make_figures: Callable | None) -> int:
    """``--estimator neural``: learners of the registry with an MLP on an exact-reward
    problem (sern_jax/experiment/neural_regret.py); the same run-directory layout."""
    from sern_jax.infra import validate

    mod = _neural()
    nd = mod.NeuralRegretExperiment()
    if args.problem == "bernoulli":
        raise ValueError("--estimator neural needs --problem wheel, finite or linear")
    validate.refuse_unused(args, _TABULAR_ONLY, "with --estimator neural (it applies to the "
                           "tabular estimators)")
    if args.problem != "finite":
        validate.refuse_unused(args, {"contexts": None, "gap": None},
                               f"with --problem {args.problem} (it applies to --problem finite)")
    if args.problem == "wheel":
        validate.refuse_unused(args, {"context_dim": None},
                               "with --problem wheel (its contexts are 2-dimensional)")
    else:
        validate.refuse_unused(args, {"delta": None, "deltas": None},
                               f"with --problem {args.problem} (it applies to --problem wheel)")
    hidden = (nd.hidden if args.hidden is None else
              tuple(validate.comma_list_of(args.hidden, "--hidden", int, "integers",
                                           unique=False)))
    policies = _policies(args.policies, nd.policies)
    learners = {mod.ALIASES.get(p, p) for p in policies}
    _check_schedule_flags(args, uses_p="sern_log" in learners,
                          uses_epsilon="egreedy" in learners,
                          mode=f"with --estimator neural and --policies {','.join(policies)}")
    exp = mod.NeuralRegretExperiment(
        policies=policies, problem=args.problem, delta=_or(args.delta, nd.delta),
        num_arms=_or(args.arms, nd.num_arms), num_contexts=_or(args.contexts, nd.num_contexts),
        gap=_or(args.gap, nd.gap), context_dim=_or(args.context_dim, nd.context_dim),
        horizon=_or(args.horizon, nd.horizon),
        num_seeds=_or(args.seeds, nd.num_seeds), update_every=_or(args.update_every,
                                                                   nd.update_every),
        hidden=hidden, fit_steps=_or(args.fit_steps, nd.fit_steps),
        batch_size=_or(args.batch_size, nd.batch_size),
        learning_rate=_or(args.learning_rate, nd.learning_rate),
        alpha0=_or(args.alpha, nd.alpha0), p=_or(args.p, nd.p),
        epsilon=_or(args.epsilon, nd.epsilon),
        schedule=args.schedule, seed=args.seed, num_checkpoints=args.checkpoints,
        chunk_size=_or(args.chunk_size, nd.chunk_size),
        nl_prior_mean=_or(args.nl_prior_mean, nd.nl_prior_mean),
        nl_sigma2=_or(args.nl_sigma2, nd.nl_sigma2))
    if args.deltas is not None:
        if args.delta is not None:
            raise ValueError("--deltas replaces --delta; give one of them")
        deltas = validate.comma_list_of(args.deltas, "--deltas", float, "numbers")
        out = (Path(args.out) if args.out
               else Path("runs") / f"regret-neural-sweep-{exp.fingerprint()}")
        run_dirs = mod.run_delta_sweep(exp, deltas, out, progress=not args.no_progress)
    else:
        out = (Path(args.out) if args.out
               else Path("runs") / f"regret-neural-{exp.fingerprint()}")
        run_dirs = [mod.run_experiment(exp, out, progress=not args.no_progress)]
    for run_dir in run_dirs:
        print((run_dir / "report.md").read_text())
        if not args.no_figures and make_figures is not None:
            for path in make_figures(run_dir):
                print(f"wrote {path}")
        print(f"run directory: {run_dir}")
    return 0


def run(args, *, defaults: Any, run_experiment: Callable,
        make_figures: Callable | None = None) -> int:
    """Runs the experiment described by ``args`` (see :func:`add_parser` for the rest)."""
    from sern_jax.infra import distributed

    ray = distributed.from_args(args)  # None without --ray; bad values: one line, exit 2
    if args.estimator == "neural":
        if ray is not None:
            raise ValueError("--ray applies to the tabular estimators, not --estimator neural")
        return _run_neural(args, make_figures)
    if args.problem != "bernoulli":
        raise ValueError(f"--problem {args.problem} needs --estimator neural (the tabular "
                         f"estimators run --problem bernoulli)")
    from sern_jax.infra import validate

    validate.refuse_unused(args, _NEURAL_ONLY, f"with --estimator {args.estimator} (it applies "
                           "to --estimator neural)")
    d = defaults
    policies = _policies(args.policies, d.policies)
    _check_schedule_flags(args, uses_p=args.schedule in ("log", "theorem4"),
                          uses_epsilon="epsilon_greedy" in policies,
                          mode=f"with --schedule {args.schedule} and --policies "
                               f"{','.join(policies)}")
    if args.gap is not None and _or(args.contexts, d.num_contexts) <= 1:
        raise ValueError("--gap has no effect with one context (it sets the random problem of "
                         "--contexts M > 1); leave it out")
    exp = dataclasses.replace(
        defaults, policies=policies,
        estimator=args.estimator, num_arms=_or(args.arms, d.num_arms), means=args.means,
        num_contexts=_or(args.contexts, d.num_contexts), gap=_or(args.gap, d.gap),
        horizon=_or(args.horizon, d.horizon), num_seeds=_or(args.seeds, d.num_seeds),
        schedule=args.schedule, alpha0=_or(args.alpha, d.alpha0), p=_or(args.p, d.p),
        epsilon=_or(args.epsilon, d.epsilon),
        seed=args.seed, num_checkpoints=args.checkpoints,
        chunk_size=_or(args.chunk_size, d.chunk_size),
        float64=args.float64, devices=args.devices,
        **({"per_seed": False} if not args.per_seed else {}))
    out = Path(args.out) if args.out else Path("runs") / f"regret-{exp.fingerprint()}"
    run_dir = run_experiment(exp, out, progress=not args.no_progress,
                             **({"ray": ray} if ray is not None else {}))
    print((run_dir / "report.md").read_text())
    if not args.per_seed and not args.no_figures:
        print("figures need per-seed arrays: none drawn with --no-per-seed")
    elif not args.no_figures and make_figures is not None:
        for path in make_figures(run_dir):
            print(f"wrote {path}")
    print(f"run directory: {run_dir}")
    return 0
