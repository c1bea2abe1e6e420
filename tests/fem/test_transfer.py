"""The elastic problem on its own, coarser mesh: exact layer fractions and material mix,
exact interpolation to the electrostatic vertices, and closed-form stretches through the
transfer.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mscap.errors import MeshError, SceneError
from mscap.fem import electrostatic as es
from mscap.fem.elastic.loading import loading_for
from mscap.fem.elastic.newton import NewtonSettings, solve_pose
from mscap.fem.elastic.problem import build_problem, total_energy
from mscap.fem.simulate import simulate
from mscap.errors import GeometryError
from mscap.geometry.layout import Layout, check_layout
from mscap.geometry.polygons import coarsened, square
from mscap.mesh.layered import elastic_layout, extrude, layer_fractions, mesh_elastic, mesh_sheet
from mscap.fem import transfer
from mscap.fem.transfer import interpolation_matrix, locate
from mscap.scene import load_scene
from mscap.scene.poses import StretchPose
from mscap.scene.settings import ElasticSettings
from tests.conftest import grid_trimesh, to_toml
from tests.scenes import CLEAR, STACK_MM, free_thickness_stretch, poke_scene_dict, scene_dict, stack

FULL = lambda centroids: np.zeros(len(centroids))  # noqa: E731 — one plate over the sheet


def coarse(nx=3, ny=2, slabs=1, width=6.0, height=4.0, seed=3):
    """A jittered ``nx × ny`` grid of the 6 × 4 mm sheet, ``slabs`` through the stack."""
    return extrude(grid_trimesh(nx, ny, width, height, FULL, 0.25, seed), STACK_MM, 1, slabs=slabs)


def test_layer_fractions_of_each_tet_match_sampling():
    # One slab through the whole stack: every tet spans all five layers. The fraction of
    # a tet below a plane is s³, 3s² − 2s³ or 1 − (1 − s)³ by how many of its vertices sit
    # on the lower level; sampling each tet uniformly (Dirichlet barycentrics) checks each
    # formula on its own, which a sum over a prism would not (its tets' errors could cancel).
    mesh = coarse(slabs=1)
    fractions = layer_fractions(mesh, STACK_MM)
    rng = np.random.default_rng(0)
    lam = rng.dirichlet(np.ones(4), size=200_000)
    interfaces = np.cumsum(STACK_MM)[:-1]
    for tet in range(3):  # the three tets of the first prism: k = 3, 2, 1
        z = lam @ mesh.points[mesh.tets[tet], 2]
        sampled = np.bincount(np.searchsorted(interfaces, z), minlength=5) / len(z)
        np.testing.assert_allclose(fractions[tet], sampled, atol=4e-3)  # ~4σ of 200k samples
    assert sorted(np.sum(np.isclose(mesh.points[mesh.tets[:3], 2], 0.0), axis=1)) == [1, 2, 3]


@pytest.mark.parametrize("slabs", [1, 2, 3, None])
def test_layer_fractions_integrate_to_the_layer_volumes(slabs):
    mesh = coarse(slabs=slabs)
    fractions = layer_fractions(mesh, STACK_MM)
    np.testing.assert_allclose(fractions.sum(axis=1), 1.0, rtol=0, atol=1e-14)
    volumes = fractions.T @ mesh.volumes()
    np.testing.assert_allclose(volumes, 6.0 * 4.0 * np.array(STACK_MM), rtol=1e-13)
    if slabs is None:  # one slab per layer: each tet in exactly one layer
        np.testing.assert_array_equal(fractions, np.eye(5)[mesh.layer_of_tet])


@pytest.mark.parametrize("order", [1, 2])
def test_mixed_tets_carry_the_exact_energy_of_a_homogeneous_strain(order):
    # Under a constant F the energy of a tet spanning several layers is Σ vol_l ψ_l(F):
    # linear in (μ, λ), so the volume-weighted mean material gives it exactly. The
    # one-layer-per-slab mesh holds the same energy layer by layer.
    F = np.array([[1.3, 0.2, 0.05], [-0.1, 0.9, 0.1], [0.02, -0.03, 0.8]])
    energies = []
    for slabs in (1, 2, None):
        problem = build_problem(coarse(slabs=slabs), stack(), order)
        energies.append(total_energy(problem, problem.rest @ F.T)[0])
    # Measured 3e-16 relative.
    np.testing.assert_allclose(energies[:2], energies[2], rtol=1e-13)


@pytest.mark.parametrize("order", [1, 2])
def test_interpolation_reproduces_the_element_polynomials(order, monkeypatch):
    # T evaluates the elastic shape functions: it must reproduce affine fields (P1) and
    # quadratics (P2) exactly, at interior points, on layer interfaces inside the slabs,
    # on shared faces and edges, and on the sheet's boundary and corners.
    problem = build_problem(coarse(slabs=2), stack(), order)
    rng = np.random.default_rng(1)
    corners = np.array([[0, 0, 0], [6, 0, 0], [6, 4, 0.56], [0, 4, 0.56], [3, 0, 0.28], [0, 2, 0.21]])
    inside = rng.uniform([0, 0, 0], [6, 4, 0.56], size=(500, 3))
    on_levels = np.column_stack([rng.uniform([0, 0], [6, 4], size=(100, 2)),
                                 rng.choice(np.cumsum((0,) + STACK_MM), 100)])
    points = np.concatenate([corners, inside, on_levels])
    T = interpolation_matrix(problem, points)
    np.testing.assert_allclose(np.asarray(T.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-13)

    def field(p):
        x, y, z = p.T
        linear = np.column_stack([1 + 2 * x - y + 3 * z, -x + 0.5 * y, 4 * z - 0.2 * x])
        return linear if order == 1 else linear + np.column_stack([x * y, z * z - x * z, y * y])
    # Measured 4e-15 (P1) and 2e-14 (P2).
    np.testing.assert_allclose(T @ field(problem.rest), field(points), rtol=0, atol=1e-12)
    # Located a few points at a time (the memory bound), the matrix is the same.
    monkeypatch.setattr(transfer, "POINT_BLOCK", 37)
    blocked = interpolation_matrix(problem, points)
    assert (blocked != T).nnz == 0


def test_points_outside_the_sheet_are_reported():
    mesh = coarse()
    with pytest.raises(MeshError, match="1 points lie outside the triangulation"):
        locate(mesh.mesh2d, np.array([[1.0, 1.0], [6.5, 2.0]]))
    tri, bary = locate(mesh.mesh2d, np.array([[6.0, 4.0], [1.0, 1.0]]))  # a corner is inside
    assert (bary >= 0).all() and np.allclose(bary.sum(axis=1), 1.0)


@pytest.fixture(scope="module")
def electro_plate():
    """The fine electrostatic mesh of a full-plate 6 × 4 mm capacitor and its C0."""
    mesh = extrude(grid_trimesh(7, 5, 6.0, 4.0, FULL, 0.25, 0), STACK_MM, 1)
    problem = es.build_problem(mesh, stack(), 1)
    return mesh, problem, es.solve(problem).capacitance_pF[0]


@pytest.mark.parametrize("mode, stretch, slabs, order", [
    ("uniaxial", (2.0, 1.0), 1, 1),
    ("biaxial", (1.25, 1.25), 2, 1),
    ("plane_strain", (2.0, 1.0), 3, 1),
    ("plane_strain", (2.0, 1.0), None, 2),
])
def test_roller_stretch_on_a_coarse_elastic_mesh_keeps_the_closed_form(electro_plate, mode, stretch, slabs, order):
    # The homogeneous stretch (see test_elastic) is exact on any mesh with one layer per
    # slab, and for P1 also with layers mixed inside a tet (equal λ/μ in both silicones):
    # interpolated onto the unrelated fine electrostatic mesh it must give the same
    # closed-form C/C0. (P2 with mixed tets is not exact: its quadratic field can bend
    # between the stiffer and softer mixes; measured 2e-5 to 1e-3 off on these meshes,
    # docs/elastic.md.)
    mesh, electro, c0 = electro_plate
    problem = build_problem(coarse(slabs=slabs), stack(), order)
    pose = StretchPose("s", mode, stretch, "roller", 0, load_steps=4)
    state = solve_pose(problem, loading_for(problem, pose), NewtonSettings(tolerance=1e-10))
    T = interpolation_matrix(problem, mesh.points)
    ratio = es.solve(electro, mesh.points + T @ (state.nodes - problem.rest)).capacitance_pF[0] / c0
    l1, l2 = stretch
    if mode == "uniaxial":
        from scipy.optimize import brentq

        l2 = brentq(lambda s: free_thickness_stretch(l1, s, CLEAR) - s, 0.1, 1.0, xtol=1e-15)
    expected = l1 * l2 / free_thickness_stretch(l1, l2, CLEAR)
    # 2 (uniaxial), 2.3556736823992 (equibiaxial 1.25), 3.8189330329193 (plane strain 2);
    # measured ≤ 3e-14.
    assert ratio == pytest.approx(expected, rel=1e-9)


def layered_stretch(scene, l1, l2):
    """The exact homogeneous stretch of a stack of unequal ν: every layer takes the
    in-plane stretches (l1, l2) and its own free thickness stretch (P33 = 0), bottom at
    z = 0. ``l2=None``: uniaxial, the lateral stretch with no net lateral force
    Σ t_i P22_i = 0, P22 = μ (λ2 − 1/λ2) + λ ln J / λ2."""
    from scipy.optimize import brentq

    def thickness(m, a, b):
        return free_thickness_stretch(a, b, m)

    def lateral_force(b):
        total = 0.0
        for layer in scene.layers:
            mu, lam = layer.material.lame_MPa
            j = l1 * b * thickness(layer.material, l1, b)
            total += layer.thickness_mm * (mu * (b - 1 / b) + lam * np.log(j) / b)
        return total

    l2 = brentq(lateral_force, 0.3, 1.0, xtol=1e-15) if l2 is None else l2
    t = np.array([layer.thickness_mm for layer in scene.layers])
    s = np.array([thickness(layer.material, l1, l2) for layer in scene.layers])
    levels, stretched = np.concatenate([[0.0], np.cumsum(t)]), np.concatenate([[0.0], np.cumsum(t * s)])

    def move(points):
        return np.column_stack([l1 * points[:, 0], l2 * points[:, 1], np.interp(points[:, 2], levels, stretched)])
    return move


@pytest.mark.parametrize("mode, stretch", [("biaxial", [1.25, 1.25]), ("uniaxial", 1.25)])
def test_unequal_poisson_ratios_get_a_layer_aligned_elastic_mesh_by_default(tmp_path, mode, stretch):
    # Plates and their layers of ν = 0.30 between dielectrics of 0.47: each layer takes its
    # own thickness stretch, which one slab through the stack cannot (measured C/C0
    # 2.06 % low biaxial, 2.56 % uniaxial, at λ = 1.25). Without `elements_through_thickness`
    # the scene gets one slab per layer (auto_slabs), and C equals the electrostatic solve
    # on the closed-form map of the same mesh: measured 3e-14 biaxial (rollers all round);
    # 5e-7 uniaxial, whose free edges cannot carry each layer's own lateral stress.
    data = scene_dict()
    data["materials"]["carbon"]["poisson_ratio"] = 0.30
    for layer in data["layers"]:
        if layer["kind"] == "conductive":
            layer["fill"] = "carbon"
    data["poses"] = [{"name": "s", "kind": "stretch", "mode": mode, "stretch": stretch, "grips": "roller",
                      "load_steps": 4}]
    path = tmp_path / "nu.toml"
    path.write_text(to_toml(data))
    scene = load_scene(path)
    assert scene.elastic.elements_through_thickness == 0
    sim = simulate(scene)
    move = layered_stretch(scene, 1.25, 1.25 if mode == "biaxial" else None)
    exact = es.solve(sim.electro, move(sim.mesh.points)).capacitance_pF
    np.testing.assert_allclose(sim.poses[0].capacitance_pF, exact, rtol=1e-6)
    one_slab = dataclasses.replace(scene, elastic=dataclasses.replace(scene.elastic, elements_through_thickness=1))
    low = simulate(one_slab).poses[0].capacitance_pF / exact - 1
    assert np.all(low < -0.015)
    data["materials"]["carbon"]["poisson_ratio"] = 0.47  # equal ν: one slab is exact
    path.write_text(to_toml(data))
    assert load_scene(path).elastic.elements_through_thickness == 1


def test_scene_with_its_own_elastic_mesh_pokes_like_the_shared_one(tmp_path):
    # The 30 mm poke of test_elastic on a 2 mm elastic mesh with one element through the
    # whole stack: about a quarter of the nodes, the same physics. Measured: shared
    # +3.3 %, own mesh within 0.2 % of it.
    # P1 both (as measured; a poke without an order gets P2, 13x the time here, the same comparison).
    data = poke_scene_dict()
    data["elastic"] = {"mesh": "shared", "order": 1}
    path = tmp_path / "shared.toml"
    path.write_text(to_toml(data))
    shared = simulate(load_scene(path))
    data["elastic"] = {"edge_length_mm": 2.0, "edge_length_outline_mm": 1.0, "elements_through_thickness": 1,
                       "order": 1}
    path = tmp_path / "own.toml"
    path.write_text(to_toml(data))
    scene = load_scene(path)
    own = simulate(scene)
    assert own.transfer is not None and shared.transfer is None
    assert own.elastic.n_nodes < 0.5 * shared.elastic.n_nodes
    assert len(own.elastic.mesh.level_z_mm) == 2
    state = own.poses[1].state
    assert state.residual <= scene.elastic.tolerance and 0 < state.min_gap_mm
    # The electrostatic vertices follow the elastic field: the bottom stays at the
    # clamped edges, the sheet goes down under the ball.
    vertices = own.poses[1].vertices
    assert vertices[:, 2].min() < -0.9 * scene.poses[1].depth_mm + 0.56
    rise = own.capacitance_pF[1, 0] / own.capacitance_pF[0, 0]
    assert rise > 1.01
    np.testing.assert_allclose(own.capacitance_pF, shared.capacitance_pF, rtol=5e-3)


@pytest.mark.parametrize("key, value, message", [
    ("edge_length_mm", 0.0, "must be > 0, got 0.0"),
    ("elements_through_thickness", -1, "must be >= 0, got -1"),
    ("edge_length_mm", "fine", "expected a number"),
    ("mesh", "fine", "unknown value 'fine'; expected one of own, shared"),
])
def test_bad_elastic_mesh_settings_name_the_key(write_scene, small_scene_dict, key, value, message):
    small_scene_dict["elastic"] = {key: value}
    with pytest.raises(SceneError, match=rf"elastic\.{key}.*{message}"):
        load_scene(write_scene(small_scene_dict))


def test_mesh_elastic_builds_what_the_scene_asks_for(small_scene_dict, write_scene):
    small_scene_dict["elastic"] = {"mesh": "shared"}
    scene = load_scene(write_scene(small_scene_dict))
    mesh = mesh_sheet(scene.sheet)
    assert mesh_elastic(scene.sheet, scene.elastic, mesh, scene.poses) is mesh
    # The defaults: its own mesh, one element through the whole stack.
    default = dataclasses.replace(scene, elastic=ElasticSettings())
    own = mesh_elastic(default.sheet, default.elastic, mesh, default.poses)
    np.testing.assert_array_equal(own.level_z_mm, [0.0, mesh.level_z_mm[-1]])
    assert len(own.mesh2d.points) < 0.5 * len(mesh.mesh2d.points)
    # 0 through the thickness: the electrostatic levels.
    levels = dataclasses.replace(scene, elastic=ElasticSettings(edge_length_mm=6.0, elements_through_thickness=0))
    on_levels = mesh_elastic(levels.sheet, levels.elastic, mesh, levels.poses)
    np.testing.assert_array_equal(on_levels.level_z_mm, mesh.level_z_mm)
    # The outlines are embedded: the plate areas are the same on both meshes.
    for m in (mesh, own):
        areas = m.mesh2d.areas()
        plates = [areas[m.mesh2d.capacitor_of_triangle == j].sum() for j in range(2)]
        np.testing.assert_allclose(plates, [120.0, 84.0], rtol=1e-12)  # shoelace areas


@pytest.mark.parametrize("elastic", [{"mesh": "shared"}, {"edge_length_mm": 6.0}], ids=["shared", "own"])
def test_simulate_export_writes_the_fields_on_their_meshes(write_scene, small_scene_dict, tmp_path, capsys, elastic):
    import meshio

    from mscap.cli import main

    small_scene_dict["poses"] = [{"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2,
                                  "grips": "clamp"}]
    small_scene_dict["elastic"] = elastic
    out = tmp_path / "vtu"
    assert main(["simulate", str(write_scene(small_scene_dict)), "--export", str(out), "-q"]) == 0
    pose = meshio.read(out / "pull.vtu")
    assert {"displacement", "phi_0", "phi_1"} <= set(pose.point_data)
    # Grips at x = 0 and 30 mm move by ∓3 mm (λ = 1.2 about the centre), on either mesh.
    x, u = pose.points[:, 0], pose.point_data["displacement"][:, 0]  # the rest mesh
    np.testing.assert_allclose(u[np.isclose(x, 0.0)], -3.0, rtol=1e-12)
    np.testing.assert_allclose(u[np.isclose(x, 30.0)], 3.0, rtol=1e-12)
    own = "mesh" not in elastic
    assert (out / "pull_elastic.vtu").exists() == own
    fields = meshio.read(out / "pull_elastic.vtu") if own else pose
    j = fields.cell_data["J"][0]
    assert len(j) == len(fields.cells[0].data) and 0.8 < j.min() and j.max() < 1.2
    assert fields.cell_data["von_mises"][0].max() > 0


@pytest.mark.parametrize("order, stretch, warned", [(1, 1.5, True), (2, 1.5, False), (1, 1.1, False)])
def test_p1_clamped_large_stretch_warns(small_scene_dict, write_scene, caplog, order, stretch, warned):
    # P1 on a clamped 100 % stretch is 8 % high at the default elastic mesh
    # (docs/elastic.md): a warning, not a silent answer.
    from mscap.fem.simulate import _warn_p1_clamped_stretch

    small_scene_dict["poses"] = [{"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": stretch,
                                  "grips": "clamp"}]
    scene = load_scene(write_scene(small_scene_dict))
    with caplog.at_level("WARNING", logger="mscap.fem.simulate"):
        _warn_p1_clamped_stretch(scene.path, order, scene.poses)
        _warn_p1_clamped_stretch(scene.path, order, scene.poses)      # once per scene and pose: optimisers rebuild
    assert caplog.text.count("pose pull: P1 elements overestimate") == int(warned)


def test_elastic_mesh_does_not_embed_every_vertex_of_an_optimised_outline(small_scene_dict, write_scene):
    # An optimised outline passes through every electrostatic outline vertex (0.5 mm apart
    # here); the elastic mesh (6 mm, outlines 3 mm) is built on the outlines coarsened to
    # its own spacing, so it has about the nodes of the scene's 4-vertex outlines.
    small_scene_dict["elastic"] = {"edge_length_mm": 6.0}
    scene = load_scene(write_scene(small_scene_dict))
    dense = Layout(tuple(np.vstack([a + np.linspace(0, 1, int(np.ceil(np.linalg.norm(b - a) / 0.05)),
                                                    endpoint=False)[:, None] * (b - a)
                                    for a, b in zip(o, np.roll(o, -1, axis=0))]) for o in scene.layout.outlines))
    assert min(len(o) for o in dense.outlines) > 600
    mesh = mesh_sheet(scene.sheet)
    plain = mesh_elastic(scene.sheet, scene.elastic, mesh, scene.poses)
    optimised = mesh_elastic(dataclasses.replace(scene.sheet, layout=dense), scene.elastic, mesh, scene.poses)
    assert len(optimised.mesh2d.points) < 1.3 * len(plain.mesh2d.points)
    for m in (plain, optimised):  # both still embed the plates exactly (straight edges)
        areas = m.mesh2d.areas()
        np.testing.assert_allclose([areas[m.mesh2d.capacitor_of_triangle == j].sum() for j in range(2)],
                                   [120.0, 84.0], rtol=1e-12)


def test_elastic_layout_keeps_outlines_that_coarsening_would_make_cross():
    # A plate with a concave bite (an arc of radius 8 mm, sampled 0.05 mm apart) around an
    # octagon 0.05 mm from the arc at its corners: the chords of the coarsened arc sag
    # 0.39 mm into the bite and would cut the octagon, so the outlines stay as they are.
    t = np.linspace(1.5 * np.pi, 0.5 * np.pi, 503)  # (25, 2) round by (17, 10) to (25, 18)
    bite = np.column_stack([25.0 + 8.0 * np.cos(t), 10.0 + 8.0 * np.sin(t)])
    plate = np.vstack([[[0.0, 0.0], [25.0, 0.0]], bite, [[25.0, 20.0], [0.0, 20.0]]])
    a = 2 * np.pi * np.arange(8) / 8 + np.pi / 8
    octagon = np.column_stack([25.0 + 7.95 * np.cos(a), 10.0 + 7.95 * np.sin(a)])
    sheet = square((20.0, 10.0), 60.0)
    layout = Layout((plate, octagon))
    check_layout(layout, sheet, 0.0)
    coarse = Layout(tuple(coarsened(o, 5.0) for o in layout.outlines))
    with pytest.raises(GeometryError):
        check_layout(coarse, sheet, 0.0)
    assert elastic_layout(layout, sheet, 5.0) is layout
    assert len(plate) == 507 and len(elastic_layout(Layout((plate,)), sheet, 5.0).outlines[0]) < 30
