"""Write docs/CLI.md, the command-line reference, from the argparse definitions.

``python -m figures.cli_reference`` rewrites ``docs/CLI.md`` from
``sern_jax.commands.main.build_parser()``, walking every subcommand; ``--check`` exits 1 when
the file differs from what the parsers say (``tests/test_cli_reference.py`` runs it).

The page is built from each action's option strings, metavar, default and help, not from
``format_help()``, whose line wrapping depends on the terminal width and whose layout
changes between Python versions: the same parsers give the same page everywhere.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

__all__ = ["render", "main"]

OUT = Path(__file__).resolve().parent.parent / "docs" / "CLI.md"

HEADER = """# Command-line reference

Every `sern` command, subcommand and flag, generated from the argparse definitions by
`python -m figures.cli_reference` (a test regenerates it and fails on any difference, so this
page is the parsers' own word). `sern COMMAND --help` prints the same in the terminal.
Bad input to any command is one line naming the flag, exit status 2, before anything is
computed or written ([Runs](RUNS.md)).
"""


def _cell(text: str) -> str:
    """One markdown table cell: one line, pipes escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _expand_help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    if not action.help or action.help == argparse.SUPPRESS:
        return ""
    formatter = parser._get_formatter()
    text = formatter._expand_help(action)  # with the parser's "(default: ...)" where it adds one
    return _NO_DEFAULT.sub("", text)


# the defaults formatter's note where there is nothing to say
_NO_DEFAULT = re.compile(r"\s*\(default: (None|False|\[\]|)\)$")


def _option(action: argparse.Action) -> str:
    if action.option_strings:
        names = ", ".join(action.option_strings)
        if action.nargs == 0:
            return f"`{names}`"
        metavar = action.metavar
        if metavar is None:
            metavar = (("{" + ",".join(map(str, action.choices)) + "}") if action.choices
                       else action.dest.upper())
        if isinstance(metavar, tuple):
            metavar = " ".join(metavar)
        if action.nargs == "?":
            metavar = f"[{metavar}]"
        elif action.nargs in ("*", "+", argparse.REMAINDER):
            metavar = f"{metavar} ..."
        return f"`{names} {metavar}`"
    metavar = action.metavar or action.dest
    if isinstance(metavar, tuple):
        metavar = " ".join(metavar)
    if action.nargs in ("*", "+", argparse.REMAINDER):
        metavar = f"{metavar} ..."
    elif action.nargs == "?":
        metavar = f"[{metavar}]"
    return f"`{metavar}`"


def _section(parser: argparse.ArgumentParser, prog: str, level: int,
             summary: str | None) -> list[str]:
    lines = [f"{'#' * level} `{prog}`", ""]
    text = parser.description or summary
    if text:
        lines += [" ".join(text.replace("%%", "%").split()), ""]
    rows = []
    children = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                children.append((name, sub, helps.get(name)))
            continue
        if action.help == argparse.SUPPRESS:
            continue
        rows.append(f"| {_cell(_option(action))} | {_cell(_expand_help(parser, action))} |")
    if children:
        lines += ["| command | what it does |", "|---|---|"]
        lines += [f"| [`{prog} {name}`](#{_anchor(f'{prog} {name}')}) | {_cell(help or '')} |"
                  for name, _, help in children]
        lines.append("")
    if rows:
        lines += ["| option | meaning |", "|---|---|", *rows, ""]
    for name, sub, help in children:
        lines += _section(sub, f"{prog} {name}", min(level + 1, 4), help)
    return lines


def _anchor(title: str) -> str:
    """The id MkDocs' toc extension gives the heading `` `title` `` (words joined by '-')."""
    return "-".join(title.lower().split())


def render() -> str:
    """The whole page, from ``build_parser()``."""
    from sern_jax.commands.main import build_parser

    parser = build_parser()
    return HEADER + "\n" + "\n".join(_section(parser, "sern", 2, None)).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m figures.cli_reference",
                                 description="Write docs/CLI.md from the sern parsers.")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 if docs/CLI.md differs from the parsers' page")
    ap.add_argument("--out", type=Path, default=OUT, help="the page to write or check")
    args = ap.parse_args(argv)
    text = render()
    if args.check:
        current = args.out.read_text() if args.out.exists() else ""
        if current != text:
            print(f"{args.out} is out of date: run python -m figures.cli_reference",
                  file=sys.stderr)
            return 1
        return 0
    args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
