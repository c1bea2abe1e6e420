"""``mscap COMMAND --help`` for every subcommand: no literal ``%%`` (argparse expands
``%%`` in ``help=`` texts but not in descriptions), and every option with a default
worth showing (not ``None``, not a flag's ``False``) shows it."""

from __future__ import annotations

import argparse
import re

import pytest

from mscap.cli import build_parser

#: ``(default: VALUE)`` as the formatter writes it, or ``(default VALUE)`` as a text may.
SHOWN_DEFAULT = re.compile(r"\(default:? ([^)]*)\)")


def subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def flat(text: str) -> str:
    return " ".join(text.split())


def shows(value, default) -> bool:
    if isinstance(default, float):
        return value in (str(default), f"{default:g}")
    return value == str(default)


@pytest.mark.parametrize("name", sorted(subparsers()))
def test_help_has_no_literal_percent_percent_and_shows_defaults(name):
    parser = subparsers()[name]
    text = parser.format_help()
    assert "%%" not in text
    formatter = parser._get_formatter()
    for action in parser._actions:
        if not action.option_strings or action.nargs == 0 or action.default in (None, argparse.SUPPRESS):
            continue
        option_help = formatter._expand_help(action)
        assert flat(option_help) in flat(text), f"mscap {name} {action.option_strings[-1]}: not rendered"
        found = SHOWN_DEFAULT.findall(option_help)
        assert len(found) == 1 and shows(found[0], action.default), \
            f"mscap {name} {action.option_strings[-1]}: default {action.default!r} not shown in {option_help!r}"


def test_the_subcommands_are_all_checked():
    assert {"mesh", "capacitance", "simulate", "optimize", "run", "inspect", "merge", "plot",
            "calibrate", "readout"} <= set(subparsers())


def test_defaults_are_shown_once_and_never_as_none_or_false():
    for name, parser in subparsers().items():
        formatter = parser._get_formatter()
        for action in parser._actions:
            option_help = formatter._expand_help(action) if action.help else ""
            assert option_help.count("(default") <= 1, f"mscap {name} {action.option_strings}: {option_help!r}"
        text = parser.format_help()
        assert "(default: None)" not in text and "(default: False)" not in text, f"mscap {name}"
