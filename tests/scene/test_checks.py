"""Physical ranges and budgets of a scene (issue 21): each bad value found in the wild
stops the load with one line naming the file, the key and the value (and the pose where
one is involved), instead of a traceback, a solver message naming nothing, or a silent
wrong answer."""

from __future__ import annotations

from pathlib import Path

import pytest

from mscap.cli import main
from mscap.errors import SceneError
from mscap.scene import load_scene
from mscap.scene.settings import PETSC_TYPES
from tests.conftest import to_toml
from tests.scenes import QUICK, poke_scene_dict

ROOT = Path(__file__).resolve().parents[2]


def quick_with(tmp_path, old: str, new: str) -> Path:
    """:data:`QUICK` with the first ``old`` replaced by ``new``."""
    assert old in QUICK
    path = tmp_path / "scene.toml"
    path.write_text(QUICK.replace(old, new, 1))
    return path


CASES = [
    # (id, old, new, key, words). Before issue 21 the first three were tracebacks, the
    # rest loaded (and simulated to nonsense, or failed in a solver naming no key).
    ("width 1e308 (OverflowError)", "width_mm = 40.0", "width_mm = 1e308", "sheet.width_mm", "must be <= 10000"),
    ("stretch 1e308 (OverflowError)", "stretch = 1.2", "stretch = 1e308", "poses[2].stretch",
     "must lie in [0.5, 10], got 1e+308"),
    ("elements_per_layer 2**63-1 (array too big)", "grading_distance_mm = 2.0",
     "grading_distance_mm = 2.0\nelements_per_layer = 9223372036854775807", "mesh.elements_per_layer",
     "must be <= 32"),
    ("stretch 1e-6 (arched 32 mm)", "stretch = 1.2", "stretch = 1e-6", "poses[2].stretch", "buckles"),
    ("grading 1e308 (12x the tets)", "grading_distance_mm = 2.0", "grading_distance_mm = 1e308",
     "mesh.grading_distance_mm", "must be <= 50"),  # the 40 x 30 mm sheet's diagonal
    ("E 1e308", "youngs_modulus_MPa = 0.57", "youngs_modulus_MPa = 1e308", "materials.clear.youngs_modulus_MPa",
     "must lie in [0.0001, 10000] MPa, got 1e+308"),
    ("thickness 1e308", "thickness_mm = 0.14", "thickness_mm = 1e308", "layers[0].thickness_mm",
     "must lie in [0.001, 10] mm, got 1e+308"),
    ("permittivity 1e308", "relative_permittivity = 2.84", "relative_permittivity = 1e308",
     "materials.clear.relative_permittivity", "must be <= 10000"),
    ("k_min 0 (crashed the MPI master)", "k_min = 2", "k_min = 0", "multistart.k_min", "must be >= 2, got 0"),
    ("k_min 1", "k_min = 2", "k_min = 1", "multistart.k_min", "must be >= 2, got 1"),
    ("starts_per_k 0", "starts_per_k = 4", "starts_per_k = 0", "multistart.starts_per_k", "must be in 1..999, got 0"),
    ("optimizer max_iterations 0", "max_iterations = 15", "max_iterations = 0", "optimizer.max_iterations",
     "must lie in [1, 100000], got 0"),
    ("optimizer stall_window -1", "max_iterations = 15", "max_iterations = 15\nstall_window = -1",
     "optimizer.stall_window", "must be >= 0"),
    ("optimizer stall_tolerance -1", "max_iterations = 15", "max_iterations = 15\nstall_tolerance = -1.0",
     "optimizer.stall_tolerance", "must be >= 0, got -1.0"),
    ("elastic max_iterations 0", "[elastic]", "[elastic]\nmax_iterations = 0", "elastic.max_iterations",
     "must lie in 1..100000, got 0"),
    ("elastic tolerance 1e308 (converged at once)", "[elastic]", "[elastic]\ntolerance = 1e308", "elastic.tolerance",
     "must lie in (0, 1), got 1e+308"),
    ("lloyd_fraction 2", "starts_per_k = 4", "starts_per_k = 4\nlloyd_fraction = 2.0", "multistart.lloyd_fraction",
     "must lie in [0, 1], got 2.0"),
    ("petsc type (a PETSc traceback)", "[[poses]]", '[petsc]\nelastic_pc_type = "nonexistent"\n\n[[poses]]',
     "petsc.elastic_pc_type", "unknown pc type 'nonexistent'"),
    ("petsc type misspelt", "[[poses]]", '[petsc]\nelectro_ksp_type = "gmress"\n\n[[poses]]',
     "petsc.electro_ksp_type", "did you mean 'gmres'?"),
    ("typo in a required key", "poisson_ratio = 0.47", "poisson_rato = 0.47", "materials.clear.poisson_ratio",
     "missing (required); is 'poisson_rato' a misspelling of it?"),
    ("pose name ../../", 'name = "poke_left"', 'name = "../../escaped_pose"', "poses[0].name", "cannot name a file"),
    ("pose name absolute", 'name = "poke_left"', 'name = "/tmp/anywhere"', "poses[0].name", "cannot name a file"),
    ("pose name 300 characters (OSError)", 'name = "poke_left"', f'name = "{"p" * 300}"', "poses[0].name",
     "at most 100 characters"),
    ("ball radius 1e-9", "radius_mm = 5.0", "radius_mm = 1e-9", "poses[0].radius_mm",
     "pose 'poke_left': a ball of radius 1e-09 mm passes between the elastic mesh's nodes, 5 mm apart"),
    ("ball radius 0.3", "radius_mm = 5.0", "radius_mm = 0.3", "poses[0].radius_mm", "pose 'poke_left'"),
    ("ball radius 1", "center_mm = [28.0, 15.0]\nradius_mm = 5.0", "center_mm = [28.0, 15.0]\nradius_mm = 1.0",
     "poses[1].radius_mm", "pose 'poke_right'"),
    ("ball depth beyond the sheet", "depth_mm = 3.0", "depth_mm = 1e9", "poses[0].depth_mm",
     "deeper than the sheet's diagonal"),
    ("load steps 1e6", "grips = \"roller\"", "grips = \"roller\"\nload_steps = 1000000", "poses[2].load_steps",
     "must be <= 1000"),
]


@pytest.mark.parametrize("old, new, key, words", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_out_of_range_is_named(tmp_path, old, new, key, words):
    path = quick_with(tmp_path, old, new)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    message = str(info.value)
    assert message.startswith(f"{path}: {key}: "), message
    assert words in message, message
    assert "\n" not in message


def test_binary_file_is_named(tmp_path):
    path = tmp_path / "binary.toml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")  # was a UnicodeDecodeError traceback
    with pytest.raises(SceneError, match=r"binary\.toml: not a text file: byte 0x89 at offset 0 is not UTF-8"):
        load_scene(path)


def test_the_ball_check_follows_the_elastic_mesh(tmp_path):
    # A 1 mm ball pushed 3 mm into quick.toml's 5 mm elastic mesh passed between the nodes
    # (0 Newton iterations, exactly the rest capacitances). The check compares the radius
    # with the elastic node spacing, not with a fixed size: 1 mm edges take that ball.
    path = quick_with(tmp_path, "radius_mm = 5.0", "radius_mm = 1.0")
    with pytest.raises(SceneError, match=r"refine the elastic mesh to a spacing of at most 2 mm there"):
        load_scene(path)
    path.write_text(path.read_text().replace("[elastic]\nedge_length_mm = 5.0", "[elastic]\nedge_length_mm = 1.0"))
    assert load_scene(path).poses[0].radius_mm == 1.0


def test_calibration_family_size_is_bounded(tmp_path):
    data = poke_scene_dict()
    data["calibration"] = {"pose": "press", "training": {"depth_mm": [1.0, 3.0, 200_000]},
                           "sequence": {"depth_mm": [1.0, 2.0]}}
    path = tmp_path / "family.toml"
    path.write_text(to_toml(data))
    with pytest.raises(SceneError, match=r"calibration\.training\.depth_mm: count 200000 exceeds 10000"):
        load_scene(path)


def test_calibration_family_stays_physical(tmp_path):
    # A family that shrinks the ball to nothing: refused like a listed pose.
    data = poke_scene_dict()
    data["calibration"] = {"pose": "press", "training": {"radius_mm": [0.1, 5.0, 3]},
                           "sequence": {"radius_mm": [5.0, 2.0]}}
    path = tmp_path / "family.toml"
    path.write_text(to_toml(data))
    with pytest.raises(SceneError, match=r"calibration\.training\.radius_mm: pose 'press \(family\)': a ball of "
                                         r"radius 0\.1 mm"):
        load_scene(path)


def test_petsc_type_names_are_the_installed_petscs():
    from mscap.fem.petsc import petsc

    PETSc = petsc([])
    for kind, table in (("ksp_type", PETSc.KSP.Type), ("pc_type", PETSc.PC.Type),
                        ("mat_solver_type", PETSc.Mat.SolverType)):
        installed = {v for k, v in vars(table).items() if not k.startswith("_") and isinstance(v, str)}
        assert installed == set(PETSC_TYPES[kind]), kind


def test_simulate_without_poses_says_nothing_to_simulate(tmp_path, capsys):
    # Was exit 0 with an empty table.
    path = tmp_path / "scene.toml"
    path.write_text(QUICK[:QUICK.index("[[poses]]")])
    assert main(["simulate", str(path), "-q"]) == 2
    assert capsys.readouterr().err.strip() == f"mscap: error: {path}: poses: no [[poses]]: nothing to simulate"


def test_inverted_tets_name_the_pose(tmp_path, capsys):
    # glue_narrow's 10 mm strip on a cylinder of radius 2 mm, its deformation from 20 mm
    # P1 elastic elements (h/R = 10) folds a dielectric tet: the electrostatic error says which
    # pose. (The default 5 mm elements folded one too until the 2D meshes kept a quality
    # bound, mscap/mesh/shape.py; they now read C(R2)/C(rest) = 1.19 where 0.4 mm reads 1.26.)
    scene = tmp_path / "glue_narrow.toml"
    scene.write_text((ROOT / "benchmarks" / "scenes" / "glue_narrow.toml").read_text().replace(
        "[objects.strip]", "[elastic]\nedge_length_mm = 20.0\norder = 1\n\n[objects.strip]"))
    assert main(["simulate", str(scene), "--poses", "cylinder_R2", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mscap: error: pose 'cylinder_R2': ") and "inverted or degenerate" in err, err
