"""The layered mesh: exact volumes, conformity, tags, sizes, and the VTU round trip."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mscap.cli import main
from mscap.geometry import polygons as geometry
from mscap.mesh.io import read_mesh, write_mesh
from mscap.mesh.layered import CONDUCTIVE_LAYERS, extrude, mesh_sheet
from mscap.mesh.quality import aspect_ratios, dihedral_angles_deg, triangle_angles_deg
from mscap.mesh.triangulate import TriMesh
from mscap.scene import load_scene

from tests.conftest import SMALL_SCENE, to_toml

_FACES = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


@pytest.fixture(scope="module", params=[1, 2], ids=["1 per layer", "2 per layer"])
def scene_and_mesh(request, tmp_path_factory):
    data = json.loads(json.dumps(SMALL_SCENE))
    data["mesh"]["elements_per_layer"] = request.param
    path = tmp_path_factory.mktemp("scene") / "small.toml"
    path.write_text(to_toml(data))
    scene = load_scene(path)
    return scene, mesh_sheet(scene.sheet)


def boundary_edges_2d(triangles: np.ndarray) -> np.ndarray:
    pairs = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, counts = np.unique(pairs, axis=0, return_counts=True)
    return edges[counts == 1]


def check_conforming(points, tets, mesh2d, n_slabs, z_top):
    """Every interior face in exactly two tets, every boundary face in one and on the surface."""
    faces = np.sort(tets[:, _FACES].reshape(-1, 3), axis=1)
    unique, counts = np.unique(faces, axis=0, return_counts=True)
    assert set(np.unique(counts)) <= {1, 2}
    boundary = unique[counts == 1]
    n2 = len(mesh2d.points)
    outer = boundary_edges_2d(mesh2d.triangles)
    assert len(boundary) == 2 * len(mesh2d.triangles) + 2 * len(outer) * n_slabs
    z = points[boundary, 2]
    caps = np.all(z == 0.0, axis=1) | np.all(z == z_top, axis=1)
    side = boundary[~caps] % n2  # 2D vertices of the side faces
    side_edges = np.array([np.unique(f) for f in side])
    assert side_edges.shape[1] == 2  # a side face stands on one 2D edge
    outer_set = {tuple(e) for e in outer}
    assert all(tuple(e) in outer_set for e in side_edges)


def test_positive_volumes(scene_and_mesh):
    _, mesh = scene_and_mesh
    assert mesh.volumes().min() > 0


def test_faces_conform(scene_and_mesh):
    scene, mesh = scene_and_mesh
    check_conforming(mesh.points, mesh.tets, mesh.mesh2d, 5 * scene.mesh.elements_per_layer,
                     scene.thickness_mm)


def test_layer_volumes_exact(scene_and_mesh):
    scene, mesh = scene_and_mesh
    area = geometry.signed_area(scene.sheet_outline_mm)
    volumes = np.bincount(mesh.layer_of_tet, weights=mesh.volumes())
    expected = [area * layer.thickness_mm for layer in scene.layers]
    np.testing.assert_allclose(volumes, expected, rtol=1e-12)


def test_conductor_volumes_exact(scene_and_mesh):
    """The mesh conforms to every outline, so each plate's volume is exact."""
    scene, mesh = scene_and_mesh
    v = mesh.volumes()
    for j, area in enumerate(scene.layout.areas_mm2()):
        for layer in CONDUCTIVE_LAYERS:
            got = v[(mesh.capacitor_of_tet == j) & (mesh.layer_of_tet == layer)].sum()
            assert got == pytest.approx(area * scene.layers[layer].thickness_mm, rel=1e-12)
    assert np.all(mesh.capacitor_of_tet[~np.isin(mesh.layer_of_tet, CONDUCTIVE_LAYERS)] == -1)


def test_vertex_map(scene_and_mesh):
    _, mesh = scene_and_mesh
    np.testing.assert_array_equal(mesh.points[:, :2], mesh.mesh2d.points[mesh.vertex_2d])
    np.testing.assert_array_equal(mesh.points[:, 2], mesh.level_z_mm[mesh.vertex_level])
    # every tet spans one slab: its levels differ by at most one, and the triangle matches
    levels = mesh.vertex_level[mesh.tets]
    assert np.all(levels.max(axis=1) - levels.min(axis=1) == 1)
    tri_of_tet = np.sort(mesh.mesh2d.triangles[mesh.triangle_of_tet], axis=1)
    assert all(np.array_equal(np.unique(v2), t) for v2, t in
               zip(mesh.vertex_2d[mesh.tets][:50], tri_of_tet[:50]))


def test_mesh_size_at_outlines(scene_and_mesh):
    scene, mesh = scene_and_mesh
    settings = scene.mesh
    points = mesh.mesh2d.points
    edges = mesh.mesh2d.edges()
    length = np.linalg.norm(points[edges[:, 1]] - points[edges[:, 0]], axis=1)
    outline_segments = np.concatenate([geometry.edges(o) for o in scene.layout.outlines])
    mid = 0.5 * (points[edges[:, 0]] + points[edges[:, 1]])
    distance = geometry.point_segment_distance(mid, outline_segments).min(axis=1)
    on_outline = distance < 1e-9
    # outline edges honour the requested length
    assert on_outline.sum() > 0
    assert length[on_outline].max() <= 1.05 * settings.edge_length_outline_mm
    # within the grading zone, edges follow the linear size ramp (50 % slack for 2D meshing)
    target = settings.edge_length_outline_mm + (settings.edge_length_mm - settings.edge_length_outline_mm) * \
        np.minimum(distance / settings.grading_distance_mm, 1.0)
    assert np.all(length <= 1.5 * target)
    assert triangle_angles_deg(points, mesh.mesh2d.triangles).min() > 15.0


def test_tags(scene_and_mesh):
    scene, mesh = scene_and_mesh
    tri_owner = mesh.mesh2d.capacitor_of_triangle
    assert set(np.unique(tri_owner)) == {-1, 0, 1}
    # triangle centroids lie inside the outline of the capacitor they are tagged with
    centroids = mesh.mesh2d.points[mesh.mesh2d.triangles].mean(axis=1)
    for j, outline in enumerate(scene.layout.outlines):
        inside = geometry.points_in_polygon(centroids, outline)
        np.testing.assert_array_equal(inside, tri_owner == j)


def test_extrusion_conforms_for_any_numbering():
    """The index rule must conform whatever order the 2D vertices come in."""
    rng = np.random.default_rng(7)
    n = 6
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    points = np.column_stack([x.ravel(), y.ravel()]) + rng.uniform(-0.05, 0.05, (n * n, 2)) * \
        np.array([[1, 1]]) * (np.arange(n * n) % n > 0)[:, None] * (np.arange(n * n) % n < n - 1)[:, None]
    quads = np.array([[i * n + j, i * n + j + 1, (i + 1) * n + j + 1, (i + 1) * n + j]
                      for i in range(n - 1) for j in range(n - 1)])
    flip = rng.random(len(quads)) < 0.5  # random diagonal per quad
    tris = np.concatenate([np.where(flip[:, None], quads[:, [0, 1, 2]], quads[:, [0, 1, 3]]),
                           np.where(flip[:, None], quads[:, [0, 2, 3]], quads[:, [1, 2, 3]])])
    perm = rng.permutation(n * n)  # random global numbering
    inverse = np.argsort(perm)
    mesh2d = TriMesh(points[perm], inverse[tris], np.full(len(tris), -1))
    thick = [0.1, 0.05, 0.2, 0.05, 0.1]
    mesh = extrude(mesh2d, thick, 3)
    assert mesh.volumes().min() > 0
    check_conforming(mesh.points, mesh.tets, mesh2d, 15, sum(thick))
    area = np.abs(mesh2d.areas()).sum()
    assert mesh.volumes().sum() == pytest.approx(area * sum(thick), rel=1e-12)


def test_quality_measures_on_known_tets():
    regular = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
    tet = np.array([[0, 1, 2, 3]])
    if np.linalg.det(regular[1:] - regular[0]) < 0:
        tet = tet[:, [0, 2, 1, 3]]
    assert aspect_ratios(regular, tet)[0] == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(dihedral_angles_deg(regular, tet), np.degrees(np.arccos(1 / 3)), rtol=1e-12)
    corner = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    angles = np.sort(dihedral_angles_deg(corner, np.array([[0, 1, 2, 3]]))[0])
    np.testing.assert_allclose(angles, [np.degrees(np.arccos(1 / np.sqrt(3)))] * 3 + [90.0] * 3, rtol=1e-12)
    tri = np.array([[0, 0], [1, 0], [0, 1]], dtype=float)
    np.testing.assert_allclose(np.sort(triangle_angles_deg(tri, np.array([[0, 1, 2]]))[0]), [45, 45, 90])


def test_vtu_round_trip(scene_and_mesh, tmp_path):
    _, mesh = scene_and_mesh
    path = tmp_path / "mesh.vtu"
    write_mesh(path, mesh)
    back = read_mesh(path)
    np.testing.assert_array_equal(back.points, mesh.points)
    np.testing.assert_array_equal(back.tets, mesh.tets)
    np.testing.assert_array_equal(back.layer, mesh.layer_of_tet)
    np.testing.assert_array_equal(back.capacitor, mesh.capacitor_of_tet)


def test_mesh_command(small_scene_dict, write_scene, tmp_path, capsys):
    path = write_scene(small_scene_dict)
    out = tmp_path / "out"
    assert main(["mesh", str(path), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    for words in ("2D mesh", "3D mesh", "min 2D angle", "min dihedral", "max aspect", "time", "mesh.vtu"):
        assert words in text
    data = read_mesh(out / "mesh.vtu")
    assert data.layer.max() == 4 and data.capacitor.max() == 1
    assert main(["mesh", str(path), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["tets"] == len(data.tets) and report["capacitors"] == 2


def test_mesh_command_reports_bad_scene(small_scene_dict, write_scene, capsys):
    small_scene_dict["layers"][2]["thickness_mm"] = -1.0
    path = write_scene(small_scene_dict)
    assert main(["mesh", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"mscap: error: {path}: layers[2].thickness_mm: must be > 0, got -1.0"


def test_meshing_keeps_the_processs_signal_handling(tmp_path):
    """gmsh.initialize/finalize reset SIGTERM to the default; an MPI worker that ignores it
    (mscap/farm.py: SLURM signals every task of a step) must survive a mesh and
    then a SIGTERM. Run in a child process: its dispositions are its own."""
    import os
    import subprocess
    import sys

    path = tmp_path / "small.toml"
    path.write_text(to_toml(SMALL_SCENE))
    child = (
        "import os, signal, sys\n"
        "from mscap.mesh.layered import mesh_sheet\n"
        "from mscap.scene import load_scene\n"
        "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "seen = []\n"
        "signal.signal(signal.SIGUSR1, lambda *a: seen.append(1))\n"
        f"mesh_sheet(load_scene({str(path)!r}).sheet)\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "os.kill(os.getpid(), signal.SIGUSR1)\n"
        "print('alive', len(seen))\n"
    )
    proc = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, timeout=120,
                          env=dict(os.environ))
    assert proc.returncode == 0, proc.stderr[-500:]
    assert proc.stdout.split() == ["alive", "1"]
