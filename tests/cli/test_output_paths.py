"""Where the commands write (issue 21): a link planted in an output directory is replaced,
never followed; an existing file named as an output directory, or a directory that
cannot be made, is one line before any work; missing directories are created; names
from a scene cannot leave the directory."""

from __future__ import annotations

import os
from dataclasses import replace

import pytest

from mscap.cli import main
from mscap.outputs import MAX_STEM, file_stem, file_stems


@pytest.fixture
def scene(small_scene_dict, write_scene):
    """The small scene (one free pose: no elastic solve)."""
    return write_scene(small_scene_dict)


@pytest.fixture
def victim(tmp_path):
    """An unrelated file that must survive every command."""
    path = tmp_path / "victim.txt"
    path.write_text("precious\n")
    return path


def test_mesh_replaces_a_link_in_the_output_directory(scene, victim, tmp_path):
    # DIR/mesh.vtu linked to an unrelated file: `mesh -o DIR` overwrote that file.
    out = tmp_path / "out"
    out.mkdir()
    (out / "mesh.vtu").symlink_to(victim)
    assert main(["mesh", str(scene), "-o", str(out)]) == 0
    assert victim.read_text() == "precious\n"
    assert not (out / "mesh.vtu").is_symlink() and (out / "mesh.vtu").stat().st_size > 1000
    assert sorted(p.name for p in out.iterdir()) == ["mesh.vtu"]  # no temporary left


def test_simulate_export_replaces_links_too(scene, victim, tmp_path):
    out = tmp_path / "export"
    out.mkdir()
    (out / "rest.vtu").symlink_to(victim)
    (out / "poses.pvd").symlink_to(victim)
    assert main(["simulate", str(scene), "-q", "--export", str(out)]) == 0
    assert victim.read_text() == "precious\n"
    assert sorted(p.name for p in out.iterdir()) == ["poses.pvd", "rest.vtu"]
    assert not any(p.is_symlink() for p in out.iterdir())


def test_optimize_replaces_links_to_its_files(small_scene_dict, write_scene, victim, tmp_path):
    # Every file `mscap optimize -o DIR` writes, linked to an unrelated file beforehand.
    stretched = {"name": "stretch", "kind": "stretch", "mode": "uniaxial", "stretch": 1.1, "grips": "roller"}
    scene = write_scene({**small_scene_dict, "poses": [*small_scene_dict["poses"], stretched]}, "two.toml")
    out = tmp_path / "opt"
    out.mkdir()
    names = ["outlines.json", "capacitance.csv", "history.csv", "summary.json"]
    for name in names:
        (out / name).symlink_to(victim)
    assert main(["optimize", str(scene), "--max-iterations", "1", "--no-figure", "-q", "-o", str(out)]) == 0
    assert victim.read_text() == "precious\n"
    assert not any((out / name).is_symlink() for name in names)
    assert all((out / name).stat().st_size > 0 for name in names)


@pytest.mark.parametrize("command", [["mesh", "{scene}", "-o", "{file}"],
                                     ["simulate", "{scene}", "-q", "--export", "{file}"],
                                     ["capacitance", "{scene}", "--export", "{file}"],
                                     ["readout", "{scene}", "--design", "{missing}", "-o", "{file}"]],
                         ids=["mesh -o", "simulate --export", "capacitance --export", "readout -o"])
def test_an_existing_file_as_output_directory_is_one_line(scene, victim, tmp_path, capsys, command):
    # Was a FileExistsError traceback, after the work (readout: after reading the design).
    argv = [a.format(scene=scene, file=victim, missing=tmp_path / "missing.h5") for a in command]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("mscap: error: "), err
    assert f"{victim}: exists and is not a directory" in err, err
    assert victim.read_text() == "precious\n"


def test_missing_directories_are_made_or_named_in_one_line(scene, victim, tmp_path, capsys):
    out = tmp_path / "a" / "b" / "c"
    assert main(["mesh", str(scene), "-o", str(out)]) == 0
    assert (out / "mesh.vtu").is_file()
    capsys.readouterr()
    assert main(["mesh", str(scene), "-o", str(victim / "below_a_file")]) == 2  # was a NotADirectoryError
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot create the directory (Not a directory)" in err, err


@pytest.mark.parametrize("name", ["../../escaped_pose", "/tmp/absolute_pose", "p" * 300, "..", "a/../../b"])
def test_a_name_cannot_leave_the_directory(name):
    stem = file_stem(name)
    assert "/" not in stem and not stem.startswith(".") and 0 < len(stem) <= MAX_STEM


def test_long_names_stay_apart():
    stems = file_stems(["p" * 300, "p" * 299 + "q", "a/b", "a_b", "A_B"])
    assert len({s.lower() for s in stems}) == 5 and all(len(s) <= MAX_STEM for s in stems)


def test_write_poses_keeps_every_file_in_the_directory(scene, tmp_path):
    # A pose named in code (the loader refuses such names in a file) cannot escape either:
    # `simulate --export` wrote ../../escaped_pose.vtu outside, and a 300-character name
    # was an OSError traceback.
    from mscap.fem.simulate import simulate
    from mscap.scene import load_scene
    from mscap.viz.vtu import write_poses

    sim = simulate(load_scene(scene))
    out = tmp_path / "deep" / "export"
    result = sim.poses[0]
    sim = replace(sim, poses=(replace(result, name="../../escaped_pose"), replace(result, name="p" * 300)))
    files = write_poses(out, sim)
    assert all(f.parent == out for f in files) and len(files) == 3
    assert not (tmp_path / "escaped_pose.vtu").exists()
    assert {os.path.basename(f) for f in files} == {"_.._escaped_pose.vtu", file_stem("p" * 300) + ".vtu", "poses.pvd"}
