"""The README's command blocks run as written on a 2-core machine after ``make install``.

Every ``mscap`` command in a ```sh/```bash/```console block parses with mscap's own
parser, names only inputs that are in the repository or that an earlier command writes,
and reads a results file with the scene that wrote it; ``mpirun`` on more ranks than 2
cores carries ``--oversubscribe``; ``make`` names a target of the Makefile. The Python
blocks run, and so do two cheap commands, as written (outputs moved to a temporary
directory). Nothing here needs mpirun, make or the console script to be installed.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from mscap.cli import parse as mscap_parse

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CORES = 2
SHELL_LANGUAGES = {"sh", "bash", "shell", "console"}
#: ``mscap`` through the console script in the venv or on the PATH.
MSCAP = re.compile(r"^(\S*/)?mscap$")
#: What each command's parsed arguments name as inputs and as outputs (attribute names).
INPUTS, OUTPUTS = ("scene", "results", "inputs", "design"), ("output", "export", "cache")
#: A fresh interpreter running the ``mscap`` entry point, as the console script does.
ENTRY = [sys.executable, "-c", "import sys; from mscap.cli import main; sys.exit(main(sys.argv[1:]))"]


@dataclass(frozen=True)
class Command:
    """One command line of a README block; ``line`` is its line number in the README."""

    words: tuple[str, ...]
    line: int

    def __str__(self) -> str:
        return f"README.md:{self.line}: {shlex.join(self.words)}"


def fenced_blocks(text: str) -> list[tuple[str, str, int]]:
    """``(language, body, line of the body's first line)`` of every fenced block."""
    return [(m["language"], m["body"], text.count("\n", 0, m.start("body")) + 1)
            for m in re.finditer(r"^```(?P<language>\w*)\n(?P<body>.*?)^```", text, flags=re.M | re.S)]


def shell_commands(body: str, first_line: int, console: bool) -> list[Command]:
    """The commands of a shell block: comments dropped, ``\\`` continuations joined; in a
    console block only the ``$ `` lines (the rest is output)."""
    commands, pending, start = [], "", first_line
    for number, line in enumerate(body.splitlines(), first_line):
        if console and not pending:
            if not line.startswith("$ "):
                continue
            line = line[2:]
        if not pending:
            start = number
        if line.rstrip().endswith("\\"):
            pending += line.rstrip()[:-1] + " "
            continue
        words = shlex.split(pending + line, comments=True)
        pending = ""
        if words:
            commands.append(Command(tuple(words), start))
    return commands


def readme_commands() -> list[Command]:
    text = README.read_text()
    return [command for language, body, line in fenced_blocks(text) if language in SHELL_LANGUAGES
            for command in shell_commands(body, line, console=language == "console")]


def python_blocks() -> list[tuple[str, int]]:
    return [(body, line) for language, body, line in fenced_blocks(README.read_text()) if language == "python"]


def mscap_argv(command: Command) -> list[str] | None:
    """The arguments after ``mscap`` (also under ``mpirun``), or ``None`` for another
    program; checks the rank count against the cores on the way."""
    words = list(command.words)
    if MSCAP.match(words[0]):
        return words[1:]
    if words[0] != "mpirun":
        return None
    ranks, position = None, next((i for i, w in enumerate(words) if MSCAP.match(w)), None)
    assert position is not None, f"{command}: mpirun runs no mscap"
    options = words[1:position]
    for flag, value in zip(options, options[1:] + [""]):
        if flag in ("-n", "-np", "--np", "-c"):
            ranks = int(value)
    assert ranks is not None, f"{command}: mpirun without -n"
    assert ranks <= CORES or "--oversubscribe" in options, \
        f"{command}: {ranks} ranks on {CORES} cores need --oversubscribe"
    return words[position + 1:]


def parse(argv: list[str], command: Command):
    """mscap's own parser on ``argv``, as ``mscap.cli.main`` runs it: options it does not
    know must be PETSc's (``-name``), never ``--name`` nor stray words."""
    errors = io.StringIO()
    try:
        with contextlib.redirect_stderr(errors), contextlib.redirect_stdout(io.StringIO()):
            args, rest = mscap_parse(argv)
    except SystemExit:
        raise AssertionError(f"{command}: mscap's parser refuses it: {errors.getvalue().strip()}") from None
    assert not rest or re.match(r"-[A-Za-z]", rest[0]), f"{command}: not PETSc options: {rest}"
    assert not [word for word in rest if word.startswith("--")], f"{command}: unknown options {rest}"
    return args


def named(args, names) -> list[str]:
    """The paths ``args`` holds under ``names`` (design specs without their ``:RUN``)."""
    from mscap.service.designs import split_design_spec

    paths = []
    for name in names:
        value = getattr(args, name, None)
        values = value if isinstance(value, list) else [value]
        paths += [os.path.normpath(split_design_spec(v)[0] if name == "design" else v)
                  for v in values if isinstance(v, str)]
    return paths


def run_ids(scene_path: str) -> set[str]:
    from mscap.scene import load_scene
    from mscap.service.selection import configurations

    return {config.id for config in configurations(load_scene(ROOT / scene_path))}


def in_fresh_clone(path: str) -> bool:
    """``path`` exists here and is not under a directory ``.gitignore`` keeps out of a
    clone (``out/``: what a developer ran before does not count)."""
    ignored = {line.strip().rstrip("/") for line in (ROOT / ".gitignore").read_text().splitlines()
               if line.strip().endswith("/")}
    return (ROOT / path).exists() and Path(path).parts[0] not in ignored


def make_targets() -> set[str]:
    return set(re.findall(r"^([\w.-]+):", (ROOT / "Makefile").read_text(), flags=re.M))


def test_readme_has_command_and_python_blocks():
    commands = readme_commands()
    assert sum(mscap_argv(c) is not None for c in commands) >= 10
    assert any(c.words[0] == "mpirun" for c in commands)
    assert python_blocks()


def test_every_command_parses_and_names_inputs_that_exist_or_were_made():
    made: dict[str, str | None] = {}  # output path -> the scene whose results it holds
    for command in readme_commands():
        argv = mscap_argv(command)
        if argv is None:
            program, *rest = command.words
            if program == "make":
                targets = [w for w in rest if "=" not in w and not w.startswith("-")]
                assert set(targets) <= make_targets(), f"{command}: no such make target"
                for word in rest:
                    value = word.partition("=")[2]
                    assert "/" not in value or in_fresh_clone(value), f"{command}: {value} does not exist"
            else:
                assert program == "export" and all("=" in w for w in rest), f"{command}: not checked here"
            continue
        args = parse(argv, command)
        inputs = named(args, INPUTS)
        for path in inputs:
            assert path in made or in_fresh_clone(path), \
                f"{command}: {path} is neither in the repository nor written by an earlier command"
        scene = os.path.normpath(args.scene) if getattr(args, "scene", None) else None
        for path in named(args, ("results", "design")):
            if made.get(path) and scene:
                assert made[path] == scene, f"{command}: {path} holds results of {made[path]}"
        if getattr(args, "run_id", None) and made.get(inputs[0]):
            assert args.run_id in run_ids(made[inputs[0]]), f"{command}: no run {args.run_id}"
        source = scene or next((made[p] for p in inputs if made.get(p)), None)
        made.update({path: source for path in named(args, OUTPUTS)})


def test_the_checks_catch_the_old_defects():
    stale = Command(("mpirun", "-n", "3", ".venv/bin/mscap", "run", "jobs/quick.toml"), 1)
    with pytest.raises(AssertionError, match="--oversubscribe"):
        mscap_argv(stale)
    with pytest.raises(AssertionError, match="parser refuses"):
        parse(shlex.split("inspect out/quick.h5 [--json | --runs | --run k2_s2001_random]"), stale)
    with pytest.raises(AssertionError, match="not PETSc options"):
        parse(["plot", "out/quick.h5", "-o", "out/quick.png", "[-q]"], stale)
    with pytest.raises(AssertionError, match="(?s)parser refuses it: .*unrecognized arguments: --jsn"):
        parse(["simulate", "jobs/poking.toml", "-log_view", "--jsn"], stale)
    console = shell_commands("$ .venv/bin/mscap mesh \\\n  jobs/quick.toml\noutput line\n", 10, console=True)
    assert [c.words for c in console] == [(".venv/bin/mscap", "mesh", "jobs/quick.toml")]


@pytest.mark.parametrize("body, line", python_blocks())
def test_python_block_runs(body, line):
    done = subprocess.run([sys.executable, "-c", body], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, f"README.md:{line}: {done.stderr[-2000:]}"
    assert done.stdout.strip(), f"README.md:{line}: printed nothing"


def as_written(words: tuple[str, ...], tmp_path: Path) -> list[str]:
    """A README command's mscap arguments with its output paths moved under ``tmp_path``."""
    argv = list(words[1:])
    for i, word in enumerate(argv[:-1]):
        if word in ("-o", "--output", "--export"):
            argv[i + 1] = str(tmp_path / argv[i + 1])
    return argv


def readme_command(*words: str) -> Command:
    """The README's command that starts with ``words`` (after the program)."""
    found = [c for c in readme_commands() if c.words[1:1 + len(words)] == words]
    assert found, f"the README no longer has `mscap {' '.join(words)} ...`"
    return found[0]


def run_as_written(command: Command, tmp_path: Path) -> str:
    """Run a README ``mscap`` command in a fresh interpreter; its stdout."""
    done = subprocess.run(ENTRY + as_written(command.words, tmp_path), cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, f"{command}: {done.stderr[-2000:]}"
    return done.stdout


def test_the_cheap_commands_run_end_to_end(tmp_path):
    # Two of the README's commands of a few seconds each: the simulation writer with
    # its JSON, and a rest capacitance table.
    record = json.loads(run_as_written(readme_command("simulate", "jobs/poking.toml", "--poses"), tmp_path))
    assert record["poses"] == ["rest", "poke_0"] and len(record["capacitance_pF"]) == 2
    assert all(Path(f).exists() for f in record["files"])

    command = readme_command("capacitance", "jobs/grid3x3.toml")
    assert command.words[1:] == ("capacitance", "jobs/grid3x3.toml")
    text = run_as_written(command, tmp_path)
    assert "C_pF" in text and max(map(len, text.splitlines())) <= 100
