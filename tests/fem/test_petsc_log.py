"""PETSc's view of a run: mscap's phases in ``-log_view``, and a warning naming the
command-line options nothing read. Each case runs ``mscap`` in a fresh process (PETSc's
options database and log live as long as the process)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap

import pytest

from tests.conftest import SMALL_SCENE, to_toml

POSES = [{"name": "rest", "kind": "free"},
         {"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "clamp"}]
WARNING = "PETSc options never used"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """The small scene with a stretch pose on a coarse elastic mesh of its own."""
    path = tmp_path_factory.mktemp("scene") / "scene.toml"
    path.write_text(to_toml({**SMALL_SCENE, "poses": POSES, "elastic": {"edge_length_mm": 6.0}}))
    return path


def mscap(*args, env=None) -> subprocess.CompletedProcess:
    code = "import sys; from mscap.cli import main; sys.exit(main(sys.argv[1:]))"
    result = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True,
                            timeout=300, env={**os.environ, **(env or {})})
    assert result.returncode == 0, result.stderr
    return result


def test_log_view_shows_mscap_stages_and_events(scene, tmp_path):
    # One optimiser iteration: meshing, both assemblies, factorisations, Newton and the adjoints.
    result = mscap("optimize", scene, "-o", tmp_path, "--max-iterations", "1", "--cascade", "1", "--no-figure",
                   "-q", "-log_view")
    out = result.stdout
    stages = re.findall(r"^ *\d+: +([\w ]+): +\d", out, re.MULTILINE)
    assert stages[:1] == ["Main Stage"] and {"Newton", "adjoint"} <= set(stages)
    events = {}  # stage name -> event names with a count
    for stage, table in re.findall(r"^--- Event Stage \d+: ([\w ]+)\n(.*?)(?=^---)", out, re.MULTILINE | re.DOTALL):
        events.setdefault(stage, set()).update(re.findall(r"^(\w+) +[1-9]\d* 1\.0 ", table, re.MULTILINE))
    # The electrostatics' k potentials go to the factor in one MatMatSolve.
    assert {"meshing", "assembly", "factorisation", "solve", "MatMatSolve"} <= events["Main Stage"]
    assert {"Newton", "assembly", "factorisation", "solve"} <= events["Newton"]
    assert {"adjoint", "assembly", "solve"} <= events["adjoint"]
    assert WARNING not in result.stderr  # -log_view was read


def test_a_misspelt_option_is_named_on_stderr(scene):
    result = mscap("simulate", scene, "-q", "--json", "-ksp_tpye", "cg", "-elastic_ksp_type", "preonly",
                   env={"PETSC_OPTIONS": "-pc_tpye lu"})
    warning = [line for line in result.stderr.splitlines() if WARNING in line]
    assert len(warning) == 1 and warning[0].endswith(": -ksp_tpye -pc_tpye"), result.stderr
    json.loads(result.stdout)  # stdout stays one JSON object


@pytest.mark.parametrize("options", [["-elastic_ksp_type", "preonly", "-electro_pc_type", "cholesky", "-log_view",
                                      ":" + os.devnull],
                                     ["-options_left", "0", "-ksp_tpye", "cg"]], ids=["valid", "options_left 0"])
def test_no_warning_for_used_options_or_when_turned_off(scene, options):
    result = mscap("simulate", scene, "-q", *options)
    assert WARNING not in result.stderr + result.stdout and "WARNING!" not in result.stdout


def test_a_command_without_petsc_names_its_petsc_options(scene):
    stderr = mscap("mesh", scene, "-ksp_type", "cg", "-mat_mumps_icntl_14", "-1").stderr
    assert stderr.strip().endswith(f"{WARNING} (misspelt, or for a solver this command does not run): "
                                   "-ksp_type -mat_mumps_icntl_14")


def test_logging_never_initialises_petsc():
    code = """
        import sys
        from mscap import profile
        with profile.phase("Newton"), profile.section("assembly"):
            pass
        assert "petsc4py.PETSc" not in sys.modules and profile.totals()["assembly"] > 0
    """
    subprocess.run([sys.executable, "-c", textwrap.dedent(code)], check=True, timeout=60)
