"""``mscap COMMAND --help`` for every subcommand: no literal ``%%`` (argparse expands
``%%`` in ``help=`` texts but not in descriptions), and every option with a default
worth showing (not ``None``, not a flag's ``False``) shows it."""

from __future__ import annotations

import argparse
import re

import pytest

from mscap.cli import build_parser, parse

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
            "calibrate", "readout", "fit"} <= set(subparsers())


def test_defaults_are_shown_once_and_never_as_none_or_false():
    for name, parser in subparsers().items():
        formatter = parser._get_formatter()
        for action in parser._actions:
            option_help = formatter._expand_help(action) if action.help else ""
            assert option_help.count("(default") <= 1, f"mscap {name} {action.option_strings}: {option_help!r}"
        text = parser.format_help()
        assert "(default: None)" not in text and "(default: False)" not in text, f"mscap {name}"


def test_one_name_per_idea_across_the_commands():
    """``-o`` is DIR where a command writes a directory and names the file's kind where it
    writes one; the read-out noise is ``--relative-shift``/``--additive-pF`` (the scene's
    ``[calibration.noise]`` keys) wherever it is set."""
    for name, parser in subparsers().items():
        for action in parser._actions:
            if "-o" in action.option_strings:
                assert action.metavar == "DIR" or action.metavar.endswith((".h5", ".png", ".toml")), \
                    (name, action.metavar)
        visible = {o for a in parser._actions if a.help != argparse.SUPPRESS for o in a.option_strings}
        assert not visible & {"--noise-relative", "--noise-additive-pF"}, name
    for name in ("calibrate", "readout"):
        options = {o: a.dest for a in subparsers()[name]._actions for o in a.option_strings}
        assert options["--relative-shift"] == "relative_shift" and options["--additive-pF"] == "additive_pF", name


@pytest.mark.parametrize("argv, verbose", [
    (["plot", "r.h5", "-o", "f.png", "-v"], 1),
    (["plot", "r.h5", "-vv", "-o", "f.png"], 2),
    (["-v", "plot", "r.h5", "-o", "f.png"], 1),
    (["plot", "r.h5", "-o", "f.png"], 0),
])
def test_verbose_after_the_subcommand_is_not_a_petsc_option(argv, verbose):
    args, petsc_args = parse(argv)
    assert args.verbose == verbose and petsc_args == []


@pytest.mark.parametrize("argv, output, petsc_args", [
    # argparse alone read these as "-o ptions_left" (an output directory) and "-v ec_type"
    (["optimize", "s.toml", "-o", "d", "-options_left"], "d", ["-options_left"]),
    (["plot", "r.h5", "-o", "f.png", "-vec_type", "seq", "-vv"], "f.png", ["-vec_type", "seq"]),
    (["simulate", "s.toml", "-help", "-ksp_rtol", "1e-8", "-mat_shift", "-1", "--json"], None,
     ["-help", "-ksp_rtol", "1e-8", "-mat_shift", "-1"]),
    (["optimize", "s.toml", "-q", "-log_view", "-o", "d"], "d", ["-log_view"]),
])
def test_petsc_options_after_the_arguments_go_to_petsc_whole(argv, output, petsc_args):
    args, petsc = parse(argv)
    assert getattr(args, "output", None) == output and petsc == petsc_args


def test_an_unknown_mscap_option_is_an_error_not_a_petsc_option(capsys):
    for argv in (["simulate", "s.toml", "--jsn"], ["simulate", "s.toml", "-x"]):
        with pytest.raises(SystemExit):
            parse(argv)
        assert "unrecognized arguments" in capsys.readouterr().err


def test_the_old_readout_noise_names_still_set_the_same_values():
    parse = build_parser().parse_known_args
    old, _ = parse(["readout", "s.toml", "--design", "r.h5", "--noise-relative", "0.1", "--noise-additive-pF", "3"])
    new, _ = parse(["readout", "s.toml", "--design", "r.h5", "--relative-shift", "0.1", "--additive-pF", "3"])
    default, _ = parse(["readout", "s.toml", "--design", "r.h5"])
    assert (old.relative_shift, old.additive_pF) == (new.relative_shift, new.additive_pF) == (0.1, 3.0)
    assert (default.relative_shift, default.additive_pF) == (0.15, 2.0)
