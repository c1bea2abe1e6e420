"""Electrostatic FEM: exact answers, fringing, convergence, shape derivative, Maxwell matrix.

Meshes are built directly (a hand-made TriMesh or a coarse gmsh triangulation, then
extruded) so the whole file runs in a few seconds.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

from mscap.cli import main
from mscap.fem import electrostatic as es, elements as fem
from mscap.geometry import polygons as geometry
from mscap.geometry.layout import Layout
from mscap.mesh.layered import extrude
from mscap.mesh.triangulate import triangulate
from mscap.scene.settings import EPSILON0_PF_PER_MM, Layer, Material, MeshSettings
from mscap.testing import taylor_test
from tests.conftest import grid_trimesh

CLEAR = Material("clear", 0.57, 0.47, 2.84)
CARBON = Material("carbon", 1.1, 0.47, 7.0)
KINDS = ("dielectric", "conductive", "dielectric", "conductive", "dielectric")
STACK_MM = (0.14, 0.07, 0.14, 0.07, 0.14)  # jobs/grid3x3.toml: 0.14 mm dielectric gap
ORDERS = pytest.mark.parametrize("order", [1, 2])


def make_layers(thicknesses=STACK_MM, dielectrics=(CLEAR, CLEAR, CLEAR)):
    """Five layers; ``dielectrics`` are the materials of layers 0, 2, 4 (fill: clear)."""
    d = iter(dielectrics)
    return [Layer(f"layer{i}", kind, t, CARBON, CLEAR) if kind == "conductive" else
            Layer(f"layer{i}", kind, t, next(d)) for i, (kind, t) in enumerate(zip(KINDS, thicknesses))]


def plate_mesh(sheet_mm, centres, size_mm, edge_outline_mm, edge_mm=2.0, per_layer=1):
    """gmsh triangulation of square plates on a rectangular sheet, extruded."""
    sheet = np.array([[0, 0], [sheet_mm[0], 0], sheet_mm, [0, sheet_mm[1]]], dtype=float)
    layout = Layout(tuple(geometry.square(c, size_mm) for c in centres))
    mesh2d = triangulate(sheet, layout, MeshSettings(edge_mm, edge_outline_mm, edge_mm, per_layer, 1))
    return extrude(mesh2d, STACK_MM, per_layer)


@pytest.fixture(scope="module")
def two_plates():
    """Two 4 mm plates 1 mm apart on a 12 × 8 mm sheet (822 vertices)."""
    return plate_mesh((12.0, 8.0), [(3.5, 4.0), (8.5, 4.0)], 4.0, 0.8)


@pytest.fixture(scope="module")
def problems(two_plates):
    return {order: es.build_problem(two_plates, make_layers(), order) for order in (1, 2)}


def perturbed(mesh, scale=0.005, seed=1):
    """A generic (non-flat) configuration near rest."""
    return mesh.points + np.random.default_rng(seed).normal(scale=scale, size=mesh.points.shape)


# --- exact answers ---------------------------------------------------------------------

@ORDERS
def test_full_coverage_is_an_exact_parallel_plate(order):
    # One capacitor covering the whole sheet: between the plates the field is uniform,
    # which P1 and P2 represent exactly on any mesh, so C = ε A / d to round-off. The
    # protective layers see no field (one plate and a zero-flux surface each).
    thicknesses = (0.11, 0.05, 0.23, 0.06, 0.17)
    dielectrics = (Material("a", 1, 0.4, 5.0), Material("gap", 1, 0.4, 3.3), Material("b", 1, 0.4, 9.0))
    mesh2d = grid_trimesh(7, 5, 13.0, 9.0, lambda c: np.zeros(len(c)), jitter=0.3)
    mesh = extrude(mesh2d, thicknesses, elements_per_layer=3)
    assert np.ptp(mesh2d.areas()) > 0.3 * mesh2d.areas().mean()  # really irregular
    problem = es.build_problem(mesh, make_layers(thicknesses, dielectrics), order)
    expected = 3.3 * EPSILON0_PF_PER_MM * 13.0 * 9.0 / 0.23
    caps = es.solve(problem, maxwell=True)
    assert caps.capacitance_pF[0] == pytest.approx(expected, rel=1e-10)
    np.testing.assert_allclose(caps.maxwell_pF, expected * np.array([[1, -1], [-1, 1]]), rtol=1e-10)

    # An in-plane linear map (with shear) and a change of thickness keep the plates
    # parallel and the side walls vertical: C = ε det(A) area / (s d).
    in_plane, s = np.array([[1.3, 0.4], [-0.2, 0.9]]), 0.8
    x = mesh.points.copy()
    x[:, :2] = x[:, :2] @ in_plane.T
    x[:, 2] *= s
    deformed = es.solve(problem, x).capacitance_pF[0]
    assert deformed == pytest.approx(expected * np.linalg.det(in_plane) / s, rel=1e-10)


def test_p2_element_energy_of_a_quadratic_is_exact():
    # A quadratic is interpolated exactly by P2, so φᵀKφ = ∫ε|∇φ|²; the exact integral of
    # the quadratic |∇φ|² is computed here with the tet's 4 vertices and 6 edge midpoints
    # (Simpson-type rule for degree 2: (−Σ vertex + 4 Σ midpoint)/20 · vol).
    mesh = extrude(grid_trimesh(3, 2, 3.0, 2.0, lambda c: np.where(c[:, 0] < 1.5, 0, -1), jitter=0.2),
                   STACK_MM, 2)
    problem = es.build_problem(mesh, make_layers(), order=2)
    x = perturbed(mesh, 0.01)
    q = np.array([[0.3, 1.2, -0.7], [1.2, -2.0, 0.5], [-0.7, 0.5, 1.1]])  # φ = xᵀQx + bᵀx
    b = np.array([0.2, -0.4, 0.9])
    coords = np.zeros((problem.n_dofs, 3))
    coords[problem.dofs[:, :4]] = x[problem.cells]
    edges = x[problem.cells[:, fem.TET_EDGES]]
    coords[problem.dofs[:, 4:]] = edges.mean(axis=2)
    phi = np.einsum("ni,ij,nj->n", coords, q, coords) + coords @ b
    data = es.assemble(problem, x)
    stiffness = sp.csr_matrix((data, problem.indices, problem.indptr), shape=(problem.n_dofs,) * 2)
    grad2 = lambda p: np.sum((2 * p @ q + b) ** 2, axis=-1)  # noqa: E731
    vol = fem.jacobians(x, problem.cells)[1]
    exact = np.sum(problem.permittivity * vol * (4 * grad2(edges.mean(axis=2)).sum(axis=1)
                                                  - grad2(x[problem.cells]).sum(axis=1)) / 20)
    assert phi @ (stiffness @ phi) == pytest.approx(exact, rel=1e-12)
    assert np.abs(stiffness @ np.ones(problem.n_dofs)).max() < 1e-12 * np.abs(data).max()


# --- fringing and convergence ----------------------------------------------------------

def test_square_plate_fringing_decreases_under_refinement():
    # A 20 mm square plate with a 0.14 mm gap (paper §4.4) on a 30 mm sheet. Fringing
    # fields make C exceed ε A / d; the discrete C is the minimum of the Dirichlet energy
    # over a subspace, hence an upper bound that falls as the outline mesh is refined and
    # that P2 (a larger space on the same mesh) lowers further.
    plate = CLEAR.permittivity_pF_per_mm * 400.0 / 0.14  # 71.85 pF
    factors = {1: [], 2: []}
    for h in (1.0, 0.5, 0.25):
        mesh = plate_mesh((30.0, 30.0), [(15.0, 15.0)], 20.0, h, edge_mm=5.0)
        for order in (1, 2):
            c = es.solve(es.build_problem(mesh, make_layers(), order)).capacitance_pF[0]
            factors[order].append(c / plate)
    for order, f in factors.items():
        assert np.all(np.diff(f) < 0), (order, f)
        # Converged fringing factor 1.0202 (P2, outline mesh down to 0.0625 mm, 4 elements
        # per layer, Richardson-extrapolated); every discrete value is an upper bound.
        assert min(f) > 1.0195, (order, f)
    assert np.all(np.array(factors[2]) < np.array(factors[1]))
    assert factors[2][-1] < 1.025


def strip_capacitance(order, level, shape="tet"):
    """A plate edge in a strip (2D field in x–z): plate over x < 1 of a 2 mm × 0.25 mm
    sheet, layers 0.25 mm, refined uniformly in x and z (cell 0.25 / 2^level)."""
    per_layer = 2 ** level
    mesh2d = grid_trimesh(8 * per_layer, 1, 2.0, 0.25, lambda c: np.where(c[:, 0] < 1.0, 0, -1))
    mesh = extrude(mesh2d, (0.25,) * 5, per_layer)
    return es.solve(es.build_problem(mesh, make_layers((0.25,) * 5), order, shape)).capacitance_pF[0]


def strip_convergence(order, shape="tet"):
    """The strip's capacitances at four levels, their Richardson (Aitken) limit from the
    three finest, and the observed rate."""
    h = 0.25 / 2.0 ** np.arange(4)
    c = np.array([strip_capacitance(order, level, shape) for level in range(4)])
    d1, d2 = c[2] - c[1], c[3] - c[2]
    reference = c[3] + d2 * d2 / (d1 - d2)
    return c, reference, np.polyfit(np.log(h), np.log(c - reference), 1)[0]


@ORDERS
def test_convergence_rate(order):
    # The plate edge is a 270° corner of a Dirichlet conductor: φ ~ r^(2/3) there, so on
    # quasi-uniform meshes the energy (= C) error is O(h^(4/3)) for every element order
    # (measured: 1.39 for P1, 1.36 for P2). A rate above 1.1 leaves room for
    # pre-asymptotic effects; a wrong stiffness or a wrong Dirichlet set gives ~0.
    c, reference, rate = strip_convergence(order)
    assert np.all(np.diff(c) < 0)  # upper bounds decreasing
    assert 1.1 < rate < 2.0, (rate, c)
    if order == 2:  # same meshes, larger space: a smaller error
        p1 = np.array([strip_capacitance(1, level) for level in range(4)])
        assert np.all(c - reference < 0.25 * (p1 - reference))


# --- shape derivative ------------------------------------------------------------------

@ORDERS
def test_shape_derivative_matches_central_differences(problems, two_plates, order):
    problem = problems[order]
    x = perturbed(two_plates)
    caps = es.solve(problem, x, maxwell=True)
    jacobian = es.capacitance_jacobian(problem, caps, x)
    rng = np.random.default_rng(7)
    weights = rng.normal(size=(4, 4))
    maxwell_grad = es.maxwell_vjp(problem, caps, weights, x)
    step = 1e-4
    for _ in range(2):
        direction = rng.normal(scale=0.01, size=x.shape)  # mm; the mesh size is ~0.8 mm
        plus = es.solve(problem, x + step * direction, maxwell=True)
        minus = es.solve(problem, x - step * direction, maxwell=True)
        fd = (plus.capacitance_pF - minus.capacitance_pF) / (2 * step)
        np.testing.assert_allclose(np.einsum("kni,ni->k", jacobian, direction), fd, rtol=1e-6)
        fd_maxwell = np.sum(weights * (plus.maxwell_pF - minus.maxwell_pF)) / (2 * step)
        assert np.sum(maxwell_grad * direction) == pytest.approx(fd_maxwell, rel=1e-6)
    w = np.array([0.7, -1.9])
    np.testing.assert_allclose(es.capacitance_vjp(problem, caps, w, x),
                               np.einsum("k,kni->ni", w, jacobian), rtol=1e-12, atol=1e-15)


def test_p1_kernels_equal_the_general_ones(problems, two_plates):
    """The P1 fast paths (cofactors on component rows) against the reference-tensor and
    quadrature formulas they replace, on a generic configuration and a general W."""
    problem = problems[1]
    x = perturbed(two_plates, 0.02)
    tets, eps = problem.cells, problem.permittivity
    np.testing.assert_allclose(fem.stiffness(fem.P1, x, tets, eps), fem._tensor_stiffness(fem.P1, x, tets, eps),
                               rtol=1e-12, atol=1e-14 * np.abs(fem._tensor_stiffness(fem.P1, x, tets, eps)).max())
    rng = np.random.default_rng(5)
    fields, weights = rng.normal(size=(problem.n_dofs, 3)), rng.normal(size=(3, 3))
    general = fem._quadrature_energy_vjp(fem.P1, x, tets, problem.dofs, eps, fields, 0.5 * (weights + weights.T))
    np.testing.assert_allclose(fem.energy_vjp(fem.P1, x, tets, problem.dofs, eps, fields, weights), general,
                               rtol=1e-10, atol=1e-12 * np.abs(general).max())


@ORDERS
def test_upper_entries_are_the_element_matrices_upper_triangles(problems, two_plates, order):
    """What assembly scatters: the upper triangles (np.triu_indices order) of the full
    element matrices, from the P1 fast path or the general one."""
    problem = problems[order]
    x = perturbed(two_plates, 0.02)
    full = fem.stiffness(problem.element, x, problem.cells, problem.permittivity)
    upper = fem.upper_stiffness(problem.element, np.ascontiguousarray(x.T), problem.cells, problem.permittivity)
    a, b = np.triu_indices(problem.dofs.shape[1])
    np.testing.assert_allclose(upper, full[:, a, b].T, rtol=1e-12, atol=1e-14 * np.abs(full).max())


@ORDERS
def test_assembled_matrix_is_symmetric_bit_for_bit(problems, two_plates, order):
    problem = problems[order]
    data = es.assemble(problem, perturbed(two_plates))
    matrix = sp.csr_matrix((data, problem.indices, problem.indptr), shape=(problem.n_dofs,) * 2)
    assert (matrix != matrix.T).nnz == 0


@ORDERS
def test_blockwise_assembly_equals_one_shot_assembly(two_plates, order, monkeypatch):
    """The pattern and values built a few tets at a time (to bound memory) are those of
    scipy's COO → CSR sum over all element matrices at once, for any block size."""
    x = perturbed(two_plates)
    reference = None
    for block in (7, 64, 10 ** 6):
        monkeypatch.setattr(fem, "BLOCK", block)
        problem = es.build_problem(two_plates, make_layers(), order)
        nb = problem.dofs.shape[1]
        local = fem.stiffness(problem.element, x, problem.cells, problem.permittivity)
        rows, cols = np.repeat(problem.dofs, nb, axis=1).ravel(), np.tile(problem.dofs, (1, nb)).ravel()
        full = sp.coo_matrix((local.ravel(), (rows, cols)), shape=(problem.n_dofs,) * 2).tocsr()
        full.sort_indices()
        np.testing.assert_array_equal(problem.indptr, full.indptr)
        np.testing.assert_array_equal(problem.indices, full.indices)
        data = es.assemble(problem, x)
        np.testing.assert_allclose(data, full.data, rtol=1e-13, atol=1e-15 * np.abs(full.data).max())
        if reference is not None:
            np.testing.assert_allclose(data, reference, rtol=1e-13, atol=1e-15 * np.abs(reference).max())
        reference = data


def capacitance_taylor(problem, mesh):
    """Taylor test of ``w · C`` at a perturbed configuration of ``mesh`` along a random
    direction, with ``capacitance_vjp`` as the gradient."""
    x = perturbed(mesh)
    caps = es.solve(problem, x)
    w = np.array([1.0, 0.5])
    grad = es.capacitance_vjp(problem, caps, w, x)
    direction = np.random.default_rng(3).normal(scale=0.004, size=x.shape)
    return taylor_test(lambda y: w @ es.solve(problem, y).capacitance_pF, x, direction, grad,
                       value=w @ caps.capacitance_pF, h0=1.0, halvings=3)


def test_taylor_remainder_is_second_order(problems, two_plates):
    taylor = capacitance_taylor(problems[2], two_plates)
    assert np.all(taylor.rates > 1.8), taylor


@ORDERS
def test_rigid_motion_invariance(problems, two_plates, order):
    from scipy.spatial.transform import Rotation

    problem = problems[order]
    x = perturbed(two_plates)
    caps = es.solve(problem, x)
    jacobian = es.capacitance_jacobian(problem, caps, x)
    rotation = Rotation.from_rotvec([0.3, -0.5, 0.7]).as_matrix()
    moved_x = x @ rotation.T + np.array([10.0, -4.0, 2.5])
    moved = es.solve(problem, moved_x)
    np.testing.assert_allclose(moved.capacitance_pF, caps.capacitance_pF, rtol=1e-12)
    # The derivative rotates with the body ...
    np.testing.assert_allclose(es.capacitance_jacobian(problem, moved, moved_x), jacobian @ rotation.T,
                               atol=1e-10 * np.abs(jacobian).max())
    # ... and has no component along the six rigid motions.
    scale = np.abs(jacobian).sum(axis=(1, 2)) * np.abs(x).max()
    for axis in np.eye(3):
        assert np.all(np.abs(np.einsum("kni,i->k", jacobian, axis)) < 1e-12 * scale)
        assert np.all(np.abs(np.einsum("kni,ni->k", jacobian, np.cross(axis, x))) < 1e-12 * scale)


# --- Maxwell matrix --------------------------------------------------------------------

@ORDERS
def test_maxwell_matrix(problems, order):
    problem = problems[order]
    caps = es.solve(problem)
    maxwell = es.solve(problem, maxwell=True).maxwell_pF
    scale = np.abs(maxwell).max()
    np.testing.assert_allclose(maxwell, maxwell.T, rtol=0, atol=1e-13 * scale)
    off = maxwell[~np.eye(4, dtype=bool)]
    assert np.all(-off > 1e-3 * scale)  # plates 1 mm apart couple visibly: all clearly < 0
    # Rows sum to ≥ 0 (diagonal dominance); here exactly 0: the zero-flux sheet surface
    # leaves no ground at infinity, so all plates at 1 V give φ ≡ 1 and no charge.
    row_sums = maxwell.sum(axis=1)
    assert np.all(row_sums > -1e-10 * scale)
    assert np.all(np.abs(row_sums) < 1e-10 * scale)
    np.testing.assert_allclose(caps.capacitance_pF, np.diag(maxwell)[2:], rtol=1e-12)
    np.testing.assert_allclose(caps.top_potentials, es.solve(problem, maxwell=True).top_potentials,
                               atol=1e-12)


# --- errors ----------------------------------------------------------------------------

def test_errors_name_the_problem(two_plates):
    mesh2d = grid_trimesh(4, 2, 4.0, 2.0, lambda c: np.where(c[:, 0] < 1.0, 0, np.where(c[:, 0] > 3, 2, -1)))
    with pytest.raises(es.ElectrostaticError, match="capacitor 1 has no conductor tets"):
        es.build_problem(extrude(mesh2d, STACK_MM), make_layers())
    touching = grid_trimesh(4, 2, 4.0, 2.0, lambda c: np.where(c[:, 0] < 2.0, 0, 1))
    with pytest.raises(es.ElectrostaticError, match="plate of capacitor 0 and the bottom plate of capacitor 1 touch"):
        es.build_problem(extrude(touching, STACK_MM), make_layers())
    problem = es.build_problem(two_plates, make_layers())
    flat = two_plates.points.copy()
    flat[:, 2] = 0.0
    with pytest.raises(es.InvertedMeshError, match="inverted or degenerate"):  # an ElectrostaticError
        es.solve(problem, flat)
    with pytest.raises(es.ElectrostaticError, match="shape"):
        es.solve(problem, two_plates.points[:-1])
    nan = two_plates.points.copy()
    nan[3, 1] = np.nan
    with pytest.raises(es.ElectrostaticError, match="not finite"):
        es.solve(problem, nan)


# --- command line ----------------------------------------------------------------------

SCENE = """
name = "two"
[sheet]
width_mm = 14.0
height_mm = 8.0
[materials.clear]
youngs_modulus_MPa = 0.57
poisson_ratio = 0.47
relative_permittivity = 2.84
[[layers]]
name = "a"
kind = "dielectric"
thickness_mm = 0.14
material = "clear"
[[layers]]
name = "b"
kind = "conductive"
thickness_mm = 0.07
material = "clear"
fill = "clear"
[[layers]]
name = "c"
kind = "dielectric"
thickness_mm = 0.14
material = "clear"
[[layers]]
name = "d"
kind = "conductive"
thickness_mm = 0.07
material = "clear"
fill = "clear"
[[layers]]
name = "e"
kind = "dielectric"
thickness_mm = 0.14
material = "clear"
[capacitors]
min_gap_mm = 1.0
outlines_mm = [[[2, 2], [6, 2], [6, 6], [2, 6]], [[8, 2], [12, 2], [12, 6], [8, 6]]]
[mesh]
edge_length_mm = 2.0
edge_length_outline_mm = 1.0
grading_distance_mm = 2.0
"""


def test_cli_capacitance(tmp_path, capsys):
    import meshio

    scene = tmp_path / "two.toml"
    scene.write_text(SCENE)
    out = tmp_path / "out"
    assert main(["capacitance", str(scene), "--json", "--maxwell", "--order", "2", "--export", str(out)]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["scene"] == "two" and record["order"] == 2
    c, maxwell = np.array(record["capacitance_pF"]), np.array(record["maxwell_pF"])
    assert c.shape == (2,) and maxwell.shape == (4, 4)
    np.testing.assert_allclose(c, np.diag(maxwell)[2:], rtol=1e-12)
    plate = CLEAR.permittivity_pF_per_mm * 16.0 / 0.14
    assert np.all((c > plate) & (c < 1.3 * plate))
    assert record["mesh"]["vertices"] > 0 and record["mesh"]["tets"] > 0
    assert set(record["time_s"]) >= {"mesh", "assembly_factorisation", "solves"}
    data = meshio.read(out / "potential.vtu")
    for name in ("phi_0", "phi_1", "phi_bottom_0"):  # P2 has no discrete maximum principle
        phi = data.point_data[name]
        assert phi.shape == (len(data.points),) and np.any(phi == 1.0) and np.any(phi == 0.0)
        assert -1e-2 < phi.min() and phi.max() < 1 + 1e-2

    assert main(["capacitance", str(scene)]) == 0
    text = capsys.readouterr().out
    assert "C_pF" in text and "assembly+factorisation" in text and "Maxwell" not in text
    assert main(["capacitance", str(tmp_path / "missing.toml")]) == 2


def test_cli_passes_petsc_options(tmp_path):
    # A fresh process: PETSc reads the command line only when first initialised.
    scene = tmp_path / "two.toml"
    scene.write_text(SCENE)
    entry = "import sys; from mscap.cli import main; sys.exit(main(sys.argv[1:]))"
    run = subprocess.run([sys.executable, "-c", entry, "capacitance", str(scene), "--json",
                          "-electro_pc_factor_mat_solver_type", "mumps"],
                         capture_output=True, text=True, check=True)
    assert json.loads(run.stdout)["solver"] == "preonly/cholesky/mumps"


# --- memory: int32 index arrays ----------------------------------------------------------

def test_index_type_switches_to_int64_at_2_to_the_31():
    assert fem.index_type(2 ** 31 - 1) is np.int32
    assert fem.index_type(2 ** 31) is np.int64


@ORDERS
def test_index_arrays_are_int32_and_give_the_int64_capacitances(problems, two_plates, order):
    # Index arrays are most of a problem's memory: on poking's 1.46 M tet finer-mesh check
    # (k = 6) the electrostatic problem held 401 MB with int64 and 348 MB with int32
    # indices (docs/performance.md §9). The narrower type must not change a bit.
    problem = problems[order]
    names = ("cells", "dofs", "indices", "upper_to_csr", "above", "below", "ff_entries",
             "ff_indices", "fd_entries", "fd_target", "free")
    assert {name: getattr(problem, name).dtype for name in names} == {name: np.dtype(np.int32) for name in names}
    wide = replace(problem, **{name: getattr(problem, name).astype(np.int64)
                               for name in ("cells", "dofs", "indices", "ff_indices", "fd_target")})
    x = perturbed(two_plates)
    np.testing.assert_array_equal(es.solve(wide, x).capacitance_pF, es.solve(problem, x).capacitance_pF)
