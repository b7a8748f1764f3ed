"""The ``sern`` command line.

Subcommands live in their own modules, each exposing ``add_parser(subparsers)``; heavy imports
(jax, mujoco) happen inside the command, so ``sern --help`` is instant.
"""

from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["main", "build_parser", "add_regret_parser"]

# (module, attribute) contributing top-level commands.
_TOP_LEVEL = (
    ("sern_jax.cli", "add_regret_parser"),  # sern regret (wires experiments/ and figures/)
    ("proofs_check.cli", "add_parser"),  # sern check
)
# Commands under `sern bench ...`.
_BENCH = (
    ("sern_jax.bench_bandit", "add_parser"),  # sern bench bandit
    ("sern_jax.grasp.bench", "add_parser"),  # sern bench grasp
)
# Commands under `sern grasp ...`.
_GRASP = (
    ("sern_jax.grasp.show", "add_parser"),  # sern grasp show
)


def add_regret_parser(subparsers) -> None:
    """``sern regret``: this module is the one library module that imports the script folders
    (``experiments/``, ``figures/``); it hands their functions to :mod:`sern_jax.regret_cli`."""
    from experiments import regret
    from figures import make_regret_figs
    from sern_jax import regret_cli

    regret_cli.add_parser(subparsers, defaults=regret.RegretExperiment(),
                          run_experiment=regret.run_experiment,
                          make_figures=make_regret_figs.make_figures)


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
    parser = argparse.ArgumentParser(
        prog="sern",
        description=(
            "sern_jax: SERN (Shannon-entropy-regularised neural contextual bandits) in JAX. "
            "Regret experiments over thousands of seeds, numerical checks of the paper's "
            "Theorems 1-5, and an MJX grasp simulator."
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
        "grasp", help="grasp simulator tools",
        description="The MJX grasp simulator: objects, depth images, candidates, trials.",
    )
    grasp_sub = grasp.add_subparsers(dest="grasp_command", metavar="WHAT")
    _register(grasp_sub, _GRASP)
    grasp.set_defaults(func=lambda args: _missing(grasp))
    return parser


def _missing(parser: argparse.ArgumentParser) -> int:
    parser.print_help(sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "func"):
        parser.print_help(sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:
        print(f"sern: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sern: interrupted; completed chunks are saved, rerun the same command to resume",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
