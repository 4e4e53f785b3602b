"""Every option of every subcommand says what it does, and options are never abbreviated.

The parser is walked (:func:`ftc_verify.cli.main.build_parser`), so a subcommand or option
added later is checked too: it needs help text, and an option with a default value must
name it in its help (``%(default)s`` or written out). ``--path 10`` must be an error, not
silently ``--paths`` (issue 33).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator

import pytest

from ftc_verify.cli.common import EXIT_BAD_INPUT
from ftc_verify.cli.main import build_parser, main


def parsers(parser: argparse.ArgumentParser, name: str = "ftc-verify") -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """``parser`` and every subcommand's parser, with its command name."""
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub_name, sub in action.choices.items():
                yield from parsers(sub, sub_name)


def _options() -> list[tuple[str, argparse.Action]]:
    return [(name, action) for name, parser in parsers(build_parser()) for action in parser._actions
            if not isinstance(action, (argparse._HelpAction, argparse._VersionAction, argparse._SubParsersAction))]


def test_the_walk_sees_every_subcommand() -> None:
    names = {name for name, _ in parsers(build_parser())}
    assert names >= {"analyze", "simulate", "verify", "synthesize", "build-fmus", "build-fmu", "plant", "linearize"}
    assert len(_options()) > 60


def test_every_option_and_argument_has_help() -> None:
    missing = [f"{name} {action.option_strings or action.dest}" for name, action in _options()
               if not action.help or action.help == argparse.SUPPRESS or not action.help.strip()]
    assert missing == [], "options without help text"


def test_every_default_value_is_named_in_the_help() -> None:
    """A value the program picks when the user says nothing is written in ``--help``."""
    unnamed = []
    for name, action in _options():
        if not action.option_strings or action.default in (None, False, argparse.SUPPRESS):
            continue
        text = (action.help or "") % {"default": action.default, "prog": name}
        value = format(action.default, "g") if isinstance(action.default, float) else str(action.default)
        if "default" not in text or value not in text:
            unnamed.append(f"{name} {action.option_strings[0]} (default {action.default!r}): {action.help}")
    assert unnamed == [], "\n".join(unnamed)


def test_no_parser_accepts_abbreviations() -> None:
    assert [name for name, parser in parsers(build_parser()) if parser.allow_abbrev] == []


@pytest.mark.parametrize("argv", [
    ["simulate", "examples/paper.toml", "--controller", "examples/paper_gains.toml", "--path", "10"],
    ["verify", "examples/paper.toml", "--pat", "5"],
    ["analyze", "examples/paper.toml", "--gains", "examples/paper_gains.toml", "--no-l"],
])
def test_an_abbreviated_option_is_an_error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(argv)
    err = capsys.readouterr().err
    assert stop.value.code == EXIT_BAD_INPUT
    assert "unrecognized arguments" in err and argv[-2 if argv[-1].isdigit() else -1] in err
    assert len(err.strip().splitlines()) == 1


def test_full_option_names_still_parse() -> None:
    args = build_parser().parse_args(["simulate", "s.toml", "--controller", "k.toml", "--paths", "10"])
    assert args.paths == 10
