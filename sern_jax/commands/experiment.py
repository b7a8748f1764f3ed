"""``sern experiment NAME [ARGS ...]``: run one of the paper's experiment scripts.

The same as ``python -m experiments.NAME ARGS ...`` from a clone's root, or
``python -m sern_jax.experiments.NAME ARGS ...`` wherever sern_jax is installed: the
experiments folder installs as ``sern_jax.experiments``. ``sern experiment --list`` lists them;
``sern experiment NAME --help`` shows an experiment's own flags.
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Registers ``sern experiment`` on an argparse subparsers object."""
    p = subparsers.add_parser(
        "experiment",
        help="run one of the paper's experiment scripts (experiments/NAME.py)",
        description=__doc__.split("\n\n")[1].replace("\n", " "),
    )
    p.add_argument("name", nargs="?", metavar="NAME",
                   help="the experiment (a module of experiments/, e.g. grasp_learning)")
    p.add_argument("args", nargs=argparse.REMAINDER, metavar="ARGS",
                   help="the experiment's own arguments (NAME --help lists them)")
    p.add_argument("--list", action="store_true", help="list the experiments and exit")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    """Runs ``experiments.<NAME>.main(ARGS)``; returns its exit status."""
    from sern_jax.commands.scripts import experiment_names, script_module

    names = experiment_names()
    if args.list or not args.name:
        if not args.list:
            print("sern experiment: error: NAME is required; choose from " + ", ".join(names),
                  file=sys.stderr)
            return 2
        print("\n".join(names))
        return 0
    if args.name not in names:
        raise ValueError(f"NAME: unknown experiment {args.name!r}; choose from "
                         + ", ".join(names))
    module = script_module("experiments", args.name)
    main = getattr(module, "main", None)
    if main is None:
        raise ValueError(f"NAME: experiments.{args.name} has no command line of its own")
    argv0, sys.argv[0] = sys.argv[0], f"sern experiment {args.name}"  # the usage line's name
    try:
        return int(main(list(args.args)) or 0)
    finally:
        sys.argv[0] = argv0
