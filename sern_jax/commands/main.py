"""The ``sern`` command line.

Subcommands live in their own modules, each exposing ``add_parser(subparsers)``; heavy imports
(jax, mujoco) happen inside the command, so ``sern --help`` is instant.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from sern_jax.infra.validate import OneLineParser

__all__ = ["main", "build_parser", "add_regret_parser", "add_reproduce_parser",
           "add_learn_parser"]

# (module, attribute) contributing top-level commands.
_TOP_LEVEL = (
    ("sern_jax.commands.main", "add_reproduce_parser"),  # sern reproduce (the main job)
    ("sern_jax.commands.main", "add_regret_parser"),  # sern regret (wires experiments/ and figures/)
    ("sern_jax.commands.check", "add_parser"),  # sern check
    ("sern_jax.commands.experiment", "add_parser"),  # sern experiment NAME (experiments/)
)
# Commands under `sern bench ...`.
_BENCH = (
    ("sern_jax.commands.bench_bandit", "add_parser"),  # sern bench bandit
    ("sern_jax.commands.bench_grasp", "add_parser"),  # sern bench grasp
    ("sern_jax.commands.bench_neural", "add_parser"),  # sern bench neural
)
# Commands under `sern grasp ...`.
_GRASP = (
    ("sern_jax.commands.grasp_show", "add_parser"),  # sern grasp show
    ("sern_jax.commands.grasp_learn", "add_dataset_parser"),  # sern grasp dataset
    ("sern_jax.commands.grasp_learn", "add_pretrain_parser"),  # sern grasp pretrain
    ("sern_jax.commands.grasp_learn", "add_screen_parser"),  # sern grasp screen
    ("sern_jax.commands.main", "add_learn_parser"),  # sern grasp learn (wires figures/)
)


def add_regret_parser(subparsers) -> None:
    """``sern regret``: the command modules are the only modules that import the script folders
    (``experiments/``, ``figures/``); this hands their functions to
    :mod:`sern_jax.commands.regret`."""
    from sern_jax.commands import regret as regret_cmd
    from sern_jax.commands.scripts import script_module

    from sern_jax.experiment import regret
    make_regret_figs = script_module("figures", "make_regret_figs")

    regret_cmd.add_parser(subparsers, defaults=regret.RegretExperiment(),
                          run_experiment=regret.run_experiment,
                          make_figures=make_regret_figs.make_figures)


def add_learn_parser(subparsers) -> None:
    """``sern grasp learn``, with its figure maker from ``figures/``."""
    from sern_jax.commands import grasp_learn
    from sern_jax.commands.scripts import script_module

    make_learn_figs = script_module("figures", "make_learn_figs")

    grasp_learn.add_learn_parser(subparsers, make_figures=make_learn_figs.make_figures)


def add_reproduce_parser(subparsers) -> None:
    """``sern reproduce``: the check runner, the regret experiment and the figure makers are
    handed to :mod:`sern_jax.commands.reproduce` from the script folders here."""
    from sern_jax.commands import check as check_cli
    from sern_jax.commands import reproduce
    from sern_jax.commands.scripts import script_module

    from sern_jax.experiment import regret
    make_learn_figs = script_module("figures", "make_learn_figs")
    make_regret_figs = script_module("figures", "make_regret_figs")

    reproduce.add_parser(subparsers, check_run=check_cli.run,
                         regret_defaults=regret.RegretExperiment(),
                         run_regret=regret.run_experiment,
                         regret_figures=make_regret_figs.make_figures,
                         learn_figures=make_learn_figs.make_figures)


def _register(subparsers, entries) -> None:
    for module_name, attr in entries:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name and module_name.startswith(exc.name):
                continue  # that part of the toolkit is not installed in this checkout
            raise
        getattr(module, attr)(subparsers)


def build_parser() -> argparse.ArgumentParser:
    # OneLineParser: usage errors are one line (subparsers inherit the class); --help unchanged
    parser = OneLineParser(
        prog="sern",
        description=(
            "sern_jax: SERN (Shannon-entropy-regularised neural contextual bandits) in JAX. "
            "`sern reproduce` runs the paper end to end (theory checks, regret curves, online "
            "grasp learning); regret experiments over thousands of seeds, numerical checks of "
            "the paper's Theorems 1-5, an MJX grasp simulator, a grasp-quality network and "
            "SERN's online learner."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _register(sub, _TOP_LEVEL)
    bench = sub.add_parser(
        "bench", help="throughput benchmarks (one JSON object with --json)",
        description="Throughput benchmarks, each side by side with a reference in the same run.",
    )
    bench_sub = bench.add_subparsers(dest="bench_command", metavar="WHAT")
    _register(bench_sub, _BENCH)
    bench.set_defaults(func=lambda args: _missing(bench))
    grasp = sub.add_parser(
        "grasp", help="grasp simulator, quality network and online learning",
        description=("The grasp pipeline: objects, depth images, candidates, trials (show); "
                     "pretraining data (dataset), the quality network θ0 and core set "
                     "(pretrain), the hard-set rule (screen), online learning (learn)."),
    )
    grasp_sub = grasp.add_subparsers(dest="grasp_command", metavar="WHAT")
    _register(grasp_sub, _GRASP)
    grasp.set_defaults(func=lambda args: _missing(grasp))
    return parser


def _missing(parser: argparse.ArgumentParser) -> int:
    """No subcommand given: one line naming the choices (the bad-input promise)."""
    choices = [name for action in parser._actions
               if isinstance(action, argparse._SubParsersAction) for name in action.choices]
    print(f"{parser.prog}: error: choose a command: {', '.join(choices)} "
          f"(see {parser.prog} --help)", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    from sern_jax.infra import hosts

    hosts.use_deterministic_xla()  # before any JAX backend starts: reruns on a GPU give the same bits
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        return _missing(parser)
    from sern_jax.infra.distributed import UnitFailedError  # imports no ray

    try:
        return int(args.func(args) or 0)
    except UnitFailedError as exc:  # a --ray unit that failed for good: one line, exit 1
        print(f"sern: error: {exc}", file=sys.stderr)
        return 1
    except (ValueError, OverflowError) as exc:
        print(f"sern: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a path that cannot be read or written: one line, no traceback
        print(f"sern: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "),
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sern: interrupted; completed chunks are saved, rerun the same command to resume",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
