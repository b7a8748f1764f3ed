"""docs/CLI.md is what the parsers say: regenerated from build_parser() and compared."""

from __future__ import annotations

import argparse

from figures import cli_reference


def test_cli_page_matches_the_parsers():
    page = cli_reference.OUT.read_text()
    assert page == cli_reference.render(), (
        "docs/CLI.md is out of date: run python -m figures.cli_reference")


def test_every_subcommand_and_flag_is_on_the_page():
    from sern_jax.commands.main import build_parser

    page = cli_reference.render()
    todo = [("sern", build_parser())]
    seen = 0
    while todo:
        prog, parser = todo.pop()
        assert f"`{prog}`" in page
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                todo += [(f"{prog} {name}", sub) for name, sub in action.choices.items()]
            elif action.option_strings and action.help != argparse.SUPPRESS:
                if not isinstance(action, argparse._HelpAction):
                    assert action.option_strings[0] in page, (prog, action.option_strings)
                    seen += 1
    assert seen > 100  # every command's flags, not a page of headings


def test_check_flags_a_stale_page(tmp_path):
    stale = tmp_path / "CLI.md"
    stale.write_text(cli_reference.render().replace("`--seeds", "`--seedz", 1))
    assert cli_reference.main(["--check", "--out", str(stale)]) == 1
    fresh = tmp_path / "fresh.md"
    assert cli_reference.main(["--out", str(fresh)]) == 0
    assert cli_reference.main(["--check", "--out", str(fresh)]) == 0
