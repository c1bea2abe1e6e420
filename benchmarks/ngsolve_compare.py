"""Side by side with NGSolve: capacitance error against wall time (issue 19).

Solves the same capacitance problems with mscap and with NGSolve, an independent FEM
code, in one run of this script (the machine is shared and noisy: only ratios measured
in the same run mean anything), all on one thread:

1. ``plate20``: one 20 mm square plate pair centred on a 40 mm sheet (10 mm margin);
2. ``plate6``: one 6 mm square plate pair centred on a 26 mm sheet (10 mm margin);
3. ``poking``: ``jobs/poking.toml`` at rest (its ``free`` pose: the rest positions), all
   4 capacitors (18 mm squares, 40 mm pitch, 100 mm sheet).

Every problem is the one of docs/electrostatics.md: the 5-layer stack of the scene
(0.14/0.07/0.14/0.07/0.14 mm, εr 2.84), conductors equipotential, C_j = ∫ ε|∇φ_j|² with
top plate j at 1 V and every other conductor at 0 V, zero flux through the sheet
surface, no air.

Reference. NGSolve, hexahedra of degree 1, 2, 3 (static condensation, UMFPACK) on a
tensor grid of a quarter of a lone plate (the two symmetry planes through the plate
centre are zero-flux planes, so C = 4 × quarter), geometrically graded towards the plate
edges in x and y (5 layers, ratio 0.2, from 1.5 mm down to 2.4 µm) and towards the plate
faces in z (ratio 0.2): an hp mesh for the r^(2/3) edge singularity. C* is the degree-3
value; the script prints |C(P3) − C(P2)| (a bound on the P2 error) and, from the
shrinking P1 → P2 → P3 steps, an estimate of the P3 error (0.002-0.007 %). Finer grids
(ratio 0.15-0.3, 6-7 layers, 3 per face in z; not run here, 3 min each) moved the P3
value by 0.002 % (20 mm) and 0.011 % (6 mm).

The poking sensor's reference is that of a lone 18 mm plate plus an array term. The
plates of an array are not isolated however far apart: the sheet is a thin 2D conductor
(zero flux through its surfaces, no ground at infinity) whose z-independent mode does
not decay, so an in-plane field runs from the plate at 1 V to the grounded ones (the
potential is 0.13 V at the sheet centre, 0.45 V in the sheet corner beside the live
plate and 0.001 V in the far corner). The term C_j(array) − C_j(plate j alone, the other
plates' tets made dielectric) is computed on one mesh, where the edge discretisation
errors cancel: +0.0113 pF (+0.019 %), the same for the four capacitors and within 1 % of
itself on three meshes/orders; the last one (P2 prisms on the 0.4 mm gmsh mesh) is used.

Settings compared (per problem):

- ``mscap``: gmsh triangulation extruded into tets (3 per prism), P1/P2, CHOLMOD; the
  scene defaults (outline edge 0.075 mm, far edge 5 mm, grading 2.5 mm, P1, 1 element
  per layer) and coarser/finer/P2 variants;
- ``ng-tet@mscap``: NGSolve on mscap's own tet mesh, written to VTU by
  ``mscap.mesh.io.write_mesh`` and read with meshio: at P1/P2 it is the same discrete
  problem as mscap's (the capacitances agree to round-off), so it compares the solvers;
- ``ng-prism@gmsh``: NGSolve on mscap's 2D triangulation extruded into prisms (1 per
  layer) instead of tets: compares the element type;
- ``ng-prism@netgen``: NGSolve on its own mesh: a netgen 2D mesh of the sheet (plate
  outlines embedded, local mesh size at the outlines, netgen grading 0.6), extruded into
  prisms, 1 per layer;
- ``ng-tet@netgen3d`` (plate6 only): netgen's own 3D mesher on the OCC geometry of the
  layered box (plate boxes glued into the conductive layers, local mesh size on the
  plate edges). It works but is slow (about 20 s for the 26 mm sheet alone), hence the
  extruded 2D netgen meshes above.

NGSolve's conductors are holes in its mesh with Dirichlet boundaries on their surfaces
(mscap assembles only the dielectric tets and fixes the conductor nodes: the same
problem). Its linear solver is a sparse direct one (UMFPACK; one row per problem with
NGSolve's own ``sparsecholesky``); CG with NGSolve's BDDC preconditioner was tried and
needs 100-1100 iterations on these flat elements (slower than the direct solvers). The
times: mesh (gmsh or netgen; for NGSolve on mscap's meshes, mscap's meshing time plus
the extrusion), import (reading and converting the exchanged file, not counted in the
total), electrostatics (set-up + assembly + factorisation + solves), total = mesh +
electrostatics.

Set-up, once (NGSolve lives in its own venv and never in the project's)::

    /usr/bin/python3 -m venv /work/ngvenv && /work/ngvenv/bin/pip install ngsolve meshio numpy

Run (8-14 minutes on one core, depending on the machine's load; ``--quick``, 2-3
minutes, checks the script)::

    .venv/bin/python benchmarks/ngsolve_compare.py --ngsolve-python /work/ngvenv/bin/python

The script runs mscap's part itself and, per problem, runs itself again under the
NGSolve interpreter with ``--ngsolve-part JOBS.json RESULTS.json`` (meshes exchanged as
VTU/npz files in a temporary folder). Writes ``docs/ngsolve_compare.csv`` and prints the
tables and, per problem and error target, the fastest run of each code and their ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one core, both codes
    os.environ[_var] = "1"

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

FIELDS = ["problem", "code", "family", "setting", "order", "solver", "dofs", "free_dofs", "mesh_s", "import_s",
          "setup_s", "assembly_s", "factorisation_s", "solve_s", "electrostatics_s", "total_s", "capacitances_pF",
          "error"]

#: Error targets of the equal-error comparison.
TARGETS = (0.02, 0.01, 0.005)

#: The reference's tensor grid (see the module docstring): distance of the first graded
#: node from the plate edge (mm), grading ratio, graded layers on each side of the edge,
#: spacing beyond the graded zone (mm); z: ratio and layers per singular face.
REFERENCE_GRID = dict(D=1.5, sigma=0.2, n=5, far=3.0, zsigma=0.2, nz=2, margin=10.0)


# ------------------------------------------------------------------------------------
# NGSolve part (runs under the NGSolve venv: no mscap imports here)
# ------------------------------------------------------------------------------------

TET_FACES = [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]
PRISM_FACES = [[0, 2, 1], [3, 4, 5], [0, 1, 4, 3], [1, 2, 5, 4], [2, 0, 3, 5]]
HEX_FACES = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]


def _interface_faces(cells, plate, faces):
    """Faces shared by a conductor cell (``plate >= 0``) and a dielectric one, per face
    size: ``[(vertices, plate)]``."""
    near_conductor = np.zeros(cells.max() + 1, dtype=bool)
    near_conductor[cells[plate >= 0].ravel()] = True
    near = (plate >= 0) | near_conductor[cells].any(axis=1)
    c, p = cells[near], plate[near]
    local_id = np.full(cells.max() + 1, -1, dtype=np.int64)
    used = np.unique(c)
    local_id[used] = np.arange(len(used))
    m = np.int64(len(used))
    out = []
    for n in (3, 4):
        local = [f for f in faces if len(f) == n]
        if not local:
            continue
        fv = np.concatenate([c[:, f] for f in local])
        fp = np.concatenate([p] * len(local))
        # a face is known by its 3 smallest vertices (two faces of a conforming mesh
        # never share 3 vertices), as one int64: fast to sort
        s3 = np.sort(local_id[fv], axis=1)[:, :3]
        key = (s3[:, 0] * m + s3[:, 1]) * m + s3[:, 2]
        _, inverse = np.unique(key, return_inverse=True)
        lowest = np.full(inverse.max() + 1, 1 << 30)
        np.minimum.at(lowest, inverse, fp)
        chosen = (fp >= 0) & (lowest[inverse] < 0)
        out.append((fv[chosen], fp[chosen]))
    return out


def _ng_mesh(points, cells, plate, k):
    """An NGSolve mesh of the dielectric cells of ``cells`` (tets, prisms or hexes), with
    the conductor surfaces as boundaries ``cb{j}`` (bottom plate j) and ``ct{j}`` (top)."""
    import netgen.meshing as nm
    from ngsolve import Mesh

    faces = {4: TET_FACES, 6: PRISM_FACES, 8: HEX_FACES}[cells.shape[1]]
    interfaces = _interface_faces(cells, plate, faces)
    dielectric = plate < 0
    used = np.zeros(len(points), dtype=bool)
    used[cells[dielectric].ravel()] = True
    renumber = (np.cumsum(used) - 1).astype(np.int32)
    m = nm.Mesh(dim=3)
    m.AddPoints(np.ascontiguousarray(points[used], dtype=float))
    m.AddRegion("dielectric", dim=3)
    m.AddElements(dim=3, index=1, data=np.ascontiguousarray(renumber[cells[dielectric]]), base=0)
    for i in range(2 * k):
        m.Add(nm.FaceDescriptor(surfnr=i + 1, domin=1, domout=0, bc=i + 1))
        m.SetBCName(i, f"cb{i}" if i < k else f"ct{i - k}")
    for fv, fp in interfaces:
        for i in np.unique(fp):
            m.AddElements(dim=2, index=int(i) + 1, data=np.ascontiguousarray(renumber[fv[fp == i]]), base=0)
    return Mesh(m)


def _ng_solve(mesh, k, eps, order, inverse, condense):
    """Capacitances of the ``k`` top plates (``ct{j}`` at 1 V, every other conductor
    boundary at 0 V), one factorisation, with stage times."""
    from ngsolve import H1, BilinearForm, GridFunction, InnerProduct, grad, dx

    t0 = time.perf_counter()
    fes = H1(mesh, order=order, dirichlet="|".join(f"cb{j}|ct{j}" for j in range(k)))
    free = fes.FreeDofs(condense)
    u, v = fes.TnT()
    t1 = time.perf_counter()
    a = BilinearForm(eps * grad(u) * grad(v) * dx, condense=condense).Assemble()
    full = BilinearForm(eps * grad(u) * grad(v) * dx).Assemble() if condense else a
    t2 = time.perf_counter()
    inv = a.mat.Inverse(free, inverse=inverse)
    t3 = time.perf_counter()
    phi = GridFunction(fes)
    r, du, kphi = phi.vec.CreateVector(), phi.vec.CreateVector(), phi.vec.CreateVector()
    caps = []
    for j in range(k):
        phi.vec[:] = 0
        phi.Set(1, definedon=mesh.Boundaries(f"ct{j}"))  # a constant: exact at any order
        r.data = -full.mat * phi.vec
        if condense:
            r.data += a.harmonic_extension_trans * r
            du.data = inv * r
            du.data += a.harmonic_extension * du
            du.data += a.inner_solve * r
        else:
            du.data = inv * r
        phi.vec.data += du
        kphi.data = full.mat * phi.vec
        caps.append(float(InnerProduct(phi.vec, kphi)))
    t4 = time.perf_counter()
    return dict(dofs=fes.ndof, free_dofs=int(sum(fes.FreeDofs())), setup_s=t1 - t0, assembly_s=t2 - t1,
                factorisation_s=t3 - t2, solve_s=t4 - t3, capacitances_pF=caps)


def _extrude_prisms(points2, triangles, capacitor, thicknesses, k):
    """Prisms, one per layer, over a triangulation; plate of each prism (bottoms first)."""
    z = np.concatenate([[0.0], np.cumsum(thicknesses)])
    n2 = len(points2)
    points = np.zeros((len(z), n2, 3))
    points[:, :, :2] = points2[None]
    points[:, :, 2] = z[:, None]
    a, b, c = (points2[triangles[:, i]] for i in range(3))
    clockwise = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) < 0
    triangles = np.where(clockwise[:, None], triangles[:, [0, 2, 1]], triangles)
    cells, plate = [], []
    for layer in range(len(thicknesses)):
        cells.append(np.concatenate([triangles + layer * n2, triangles + (layer + 1) * n2], axis=1))
        if layer in (1, 3):
            plate.append(np.where(capacitor >= 0, capacitor + (k if layer == 3 else 0), -1))
        else:
            plate.append(np.full(len(triangles), -1))
    return points.reshape(-1, 3), np.concatenate(cells), np.concatenate(plate)


def _netgen_2d(width, squares, h_out, h_far, grading):
    """netgen's 2D mesh of the sheet with the square outlines embedded."""
    from netgen.geom2d import SplineGeometry

    g = SplineGeometry()
    g.AddRectangle((0.0, 0.0), (width, width), leftdomain=1, rightdomain=0)
    for j, (x0, y0, s) in enumerate(squares):
        g.AddRectangle((x0, y0), (x0 + s, y0 + s), leftdomain=2 + j, rightdomain=1, maxh=h_out)
    m = g.GenerateMesh(maxh=h_far, grading=grading)
    elements = m.Elements2D().NumPy()
    return (np.array(m.Coordinates())[:, :2], elements["nodes"][:, :3].astype(np.int64) - 1,
            elements["index"].astype(np.int64) - 2)


def _netgen_3d(width, squares, thicknesses, maxh, edge_maxh):
    """netgen's own tet mesh of the OCC layered box; plate of each tet."""
    from netgen.occ import Box, Glue, OCCGeometry, Pnt

    solids, z, k = [], 0.0, len(squares)
    for layer, t in enumerate(thicknesses):
        box = Box(Pnt(0, 0, z), Pnt(width, width, z + t))
        if layer in (1, 3):
            for j, (x0, y0, s) in enumerate(squares):
                plate = Box(Pnt(x0, y0, z), Pnt(x0 + s, y0 + s, z + t))
                plate.mat(f"plate{j + (k if layer == 3 else 0)}")
                plate.edges.maxh = edge_maxh
                box = box - plate
                solids.append(plate)
        box.mat("dielectric")
        solids.append(box)
        z += t
    m = OCCGeometry(Glue(solids)).GenerateMesh(maxh=maxh)
    names = [m.GetMaterial(i + 1) for i in range(m.GetNDomains())]
    plate_of_domain = np.array([int(n[5:]) if n.startswith("plate") else -1 for n in names])
    elements = m.Elements3D().NumPy()
    return (np.array(m.Coordinates()), elements["nodes"][:, :4].astype(np.int64) - 1,
            plate_of_domain[elements["index"] - 1])


def _graded(a, width, D, sigma, n, far):
    """1D nodes on [0, width], geometrically graded towards ``a`` from both sides."""
    d = D * sigma ** np.arange(n)
    nodes = [0.0, a, width, *(a - d), *(a + d)]
    x = a - D
    while x - far > 0:
        x -= far
        nodes.append(x)
    x = a + D
    while x + far < width:
        x += far
        nodes.append(x)
    return np.unique(np.clip(nodes, 0.0, width))


def _graded_levels(thicknesses, sigma, n):
    """z nodes graded towards the plate faces (the interfaces of the conductive layers)."""
    bounds = np.concatenate([[0.0], np.cumsum(thicknesses)])
    z, last = [0.0], len(thicknesses) - 1
    for layer, t in enumerate(thicknesses):
        lo, hi = bounds[layer], bounds[layer + 1]
        d = t * sigma ** np.arange(1, n + 1)
        d = d[d < t / 2]
        nodes = ([*(lo + d)] if layer > 0 else []) + ([*(hi - d)] if layer < last else [])
        if 0 < layer < last:
            nodes.append(0.5 * (lo + hi))
        z += sorted(set(nodes)) + [hi]
    return np.array(z)


def _quarter_hex(a, thicknesses, grid):
    """Hexahedra of a quarter of a lone square plate of half-side ``a`` (plate [0, a]²)."""
    xs = _graded(a, a + grid["margin"], grid["D"], grid["sigma"], grid["n"], grid["far"])
    zs = _graded_levels(thicknesses, grid["zsigma"], grid["nz"])
    interfaces = np.cumsum(thicknesses)
    nx = len(xs)
    X, Y, Z = np.meshgrid(xs, xs, zs, indexing="ij")
    points = np.stack([g.transpose(2, 1, 0).ravel() for g in (X, Y, Z)], axis=1)
    I, J, K = (g.ravel() for g in np.meshgrid(np.arange(nx - 1), np.arange(nx - 1), np.arange(len(zs) - 1),
                                              indexing="ij"))

    def node(i, j, kk):
        return (kk * nx + j) * nx + i

    cells = np.stack([node(I, J, K), node(I + 1, J, K), node(I + 1, J + 1, K), node(I, J + 1, K),
                      node(I, J, K + 1), node(I + 1, J, K + 1), node(I + 1, J + 1, K + 1), node(I, J + 1, K + 1)], 1)
    layer = np.searchsorted(interfaces, 0.5 * (zs[K] + zs[K + 1]))
    inside = (0.5 * (xs[I] + xs[I + 1]) < a) & (0.5 * (xs[J] + xs[J + 1]) < a)
    plate = np.where(inside & (layer == 1), 0, np.where(inside & (layer == 3), 1, -1))
    return points, cells, plate


def _read_tets(path):
    """mscap's tet mesh from its VTU (``mscap.mesh.io.write_mesh``): points, tets, plate."""
    import meshio

    data = meshio.read(path)
    tets = np.concatenate([b.data for b in data.cells if b.type == "tetra"]).astype(np.int64)
    layer = np.concatenate(data.cell_data["layer"]).astype(np.int64)
    capacitor = np.concatenate(data.cell_data["capacitor"]).astype(np.int64)
    k = int(capacitor.max()) + 1
    plate = np.where(capacitor >= 0, capacitor + k * (layer == 3), -1)
    return np.asarray(data.points, dtype=float), tets, plate


def _array_correction(job, thicknesses, eps):
    """C_j(array) − C_j(plate j alone) on one mesh (the other plates' tets made dielectric).

    Off the plates the potential is not a constant: the sheet between the plates is a
    thin 2D conductor (zero flux through its surfaces, no ground at infinity) whose
    z-independent mode does not decay, so it carries an in-plane field from the plate
    at 1 V to the grounded ones, and the plates of an array are not isolated however far
    apart. The difference is a smooth, large-scale field, so it is well resolved on a
    mesh whose discretisation errors at the plate edges cancel in it."""
    with np.load(job["path"]) as f:
        points2, tri, cap = f["points"], f["triangles"].astype(np.int64), f["capacitor"].astype(np.int64)
    k, order = job["k"], job["orders"][0]
    array = _ng_solve(_ng_mesh(*_extrude_prisms(points2, tri, cap, thicknesses, k), k), k, eps, order,
                      "umfpack", order >= 3)["capacitances_pF"]
    alone = [_ng_solve(_ng_mesh(*_extrude_prisms(points2, tri, np.where(cap == j, 0, -1), thicknesses, 1), 1),
                       1, eps, order, "umfpack", order >= 3)["capacitances_pF"][0] for j in range(k)]
    delta = [c - c1 for c, c1 in zip(array, alone)]
    print(f"  ngsolve array correction, {job['setting']} P{order}: array {np.round(array, 5)}, alone "
          f"{np.round(alone, 5)}: C(array) - C(alone) = {np.round(delta, 5)} pF", flush=True)
    return dict(problem=job["problem"], family="array-correction", setting=job["setting"], order=order,
                array_pF=array, alone_pF=alone, delta_pF=delta)


def ngsolve_part(jobs_path, results_path):
    """Run the NGSolve jobs of ``jobs_path`` (JSON), one after the other; write the results."""
    import ngsolve

    ngsolve.SetNumThreads(1)  # and no TaskManager: one thread
    spec = json.loads(Path(jobs_path).read_text())
    thicknesses, eps = spec["thicknesses_mm"], spec["eps_pF_per_mm"]
    results = []
    for job in spec["jobs"]:
        family, k = job["family"], job["k"]
        t0 = time.perf_counter()
        mesh_s = import_s = 0.0
        solve_k = k
        if family == "reference":
            points, cells, plate = _quarter_hex(job["half_side_mm"], thicknesses, REFERENCE_GRID)
            mesh = _ng_mesh(points, cells, plate, 1)
            mesh_s, solve_k = time.perf_counter() - t0, 1
        elif family == "ng-prism@netgen":
            points2, tri, cap = _netgen_2d(job["width_mm"], job["squares"], job["h_out"], job["h_far"], job["grading"])
            mesh = _ng_mesh(*_extrude_prisms(points2, tri, cap, thicknesses, k), k)
            mesh_s = time.perf_counter() - t0
        elif family == "ng-tet@netgen3d":
            mesh = _ng_mesh(*_netgen_3d(job["width_mm"], job["squares"], thicknesses, job["maxh"], job["edge_maxh"]),
                            k)
            mesh_s = time.perf_counter() - t0
        elif family == "array-correction":
            results.append(_array_correction(job, thicknesses, eps))
            continue
        elif family == "ng-prism@gmsh":
            with np.load(job["path"]) as f:
                points2, tri, cap = f["points"], f["triangles"].astype(np.int64), f["capacitor"].astype(np.int64)
            t1 = time.perf_counter()
            mesh = _ng_mesh(*_extrude_prisms(points2, tri, cap, thicknesses, k), k)
            import_s = t1 - t0
            mesh_s = job["mscap_2d_mesh_s"] + time.perf_counter() - t1  # gmsh 2D + extrusion into prisms
        elif family == "ng-tet@mscap":
            mesh = _ng_mesh(*_read_tets(job["path"]), k)
            import_s = time.perf_counter() - t0  # VTU read + conversion: the file exchange, not counted
            mesh_s = job["mscap_mesh_s"]
        else:
            raise ValueError(family)
        for order in job["orders"]:
            condense = family == "reference" or order >= 3
            r = _ng_solve(mesh, solve_k, eps, order, job["solver"], condense)
            if family == "reference":
                r["capacitances_pF"] = [4.0 * r["capacitances_pF"][0]]
            r.update(problem=job["problem"], code="ngsolve", family=family, setting=job["setting"], order=order,
                     solver=job["solver"], mesh_s=mesh_s, import_s=import_s)
            r["electrostatics_s"] = r["setup_s"] + r["assembly_s"] + r["factorisation_s"] + r["solve_s"]
            r["total_s"] = r["mesh_s"] + r["electrostatics_s"]
            print(f"  ngsolve {family:16s} {job['setting']:36s} P{order} {job['solver']:14s} {r['dofs']:>8d} dofs  "
                  f"mesh {mesh_s:6.2f} s  import {import_s:5.2f} s  setup {r['setup_s']:5.2f} s  "
                  f"asm {r['assembly_s']:6.2f} s  factor {r['factorisation_s']:6.2f} s  solve {r['solve_s']:5.2f} s  "
                  f"C = {np.round(r['capacitances_pF'], 4)}", flush=True)
            results.append(r)
    Path(results_path).write_text(json.dumps(results))


# ------------------------------------------------------------------------------------
# mscap part (project venv)
# ------------------------------------------------------------------------------------

def _mscap_settings(name, quick):
    """(order, outline edge, far edge, grading, elements per layer)."""
    if quick:
        return [(1, 0.15, 5.0, 2.5, 1), (1, 0.075, 5.0, 2.5, 1), (2, 0.4, 5.0, 2.5, 1)]
    settings = [(1, 0.2, 5.0, 2.5, 1), (1, 0.15, 5.0, 2.5, 1), (1, 0.1, 5.0, 2.5, 1), (1, 0.075, 5.0, 2.5, 1),
                (1, 0.05, 5.0, 2.5, 1), (1, 0.075, 5.0, 2.5, 2), (2, 0.4, 5.0, 2.5, 1), (2, 0.3, 5.0, 2.5, 1),
                (2, 0.2, 5.0, 2.5, 1)]
    if name != "poking":  # (poking: 25-40 s each)
        settings += [(2, 0.15, 5.0, 2.5, 1), (2, 0.1, 5.0, 2.5, 1)]
    return settings


#: mscap meshes NGSolve also solves on: (outline edge, order) of the tet meshes and of the
#: 2D triangulations (extruded into prisms by the NGSolve part).
TET_EXPORTS = ((0.075, 1), (0.4, 2), (0.3, 2))
TRI_EXPORTS = ((0.15, 1), (0.075, 1), (0.05, 1), (0.4, 2), (0.3, 2), (0.2, 2))
#: Meshes and orders of the array term of an array's reference (the last one is used).
ARRAY_CORRECTION = (("h_out 0.15", 1), ("h_out 0.075", 1), ("h_out 0.4", 2))


def _ngsolve_jobs(name, squares, width, k, exports, quick):
    """The NGSolve runs of one problem (``exports``: the mscap meshes written for it)."""
    jobs = [dict(family="reference", setting="quarter hex, graded", orders=[1, 2] if quick else [1, 2, 3],
                 solver="umfpack", half_side_mm=0.5 * squares[0][2])]
    for tag, path, mesh_s in exports["tets"]:
        order = int(tag[1])
        orders = [2, 3] if tag == "P2 h_out 0.4" and name != "poking" and not quick else [order]
        for solver in (["umfpack", "sparsecholesky"] if tag == "P1 h_out 0.075" and not quick else ["umfpack"]):
            jobs.append(dict(family="ng-tet@mscap", setting=f"mscap mesh {tag[3:]}", orders=orders, solver=solver,
                             path=path, mscap_mesh_s=mesh_s))
    corrections = []
    for tag, path, mesh_s, order in exports["tri"]:
        jobs.append(dict(family="ng-prism@gmsh", setting=f"gmsh 2D {tag}", orders=[order], solver="umfpack",
                         path=path, mscap_2d_mesh_s=mesh_s))
        if k > 1 and (tag, order) in ARRAY_CORRECTION:  # the reference's array term, run first
            corrections.append(dict(family="array-correction", setting=f"P{order} prisms on gmsh 2D {tag}",
                                    orders=[order], path=path))
    if quick:
        netgen = [(0.15, 1), (0.075, 1), (0.4, 2)]
    else:
        netgen = [(0.3, 1), (0.15, 1), (0.075, 1), (0.6, 2), (0.4, 2)]
        if name != "poking":  # (poking: 30-80 s each)
            netgen += [(0.2, 2), (0.6, 3)]
    for h_out, order in netgen:
        jobs.append(dict(family="ng-prism@netgen", setting=f"netgen 2D h_out {h_out:g} grading 0.6", orders=[order],
                         solver="umfpack", h_out=h_out, h_far=5.0, grading=0.6, width_mm=width, squares=squares))
    if name == "plate6" and not quick:  # netgen's 3D mesher: 20-30 s here, minutes on the larger sheets
        jobs.append(dict(family="ng-tet@netgen3d", setting="netgen 3D maxh 1, plate edges 0.15", orders=[1, 2],
                         solver="umfpack", maxh=1.0, edge_maxh=0.15, width_mm=width, squares=squares))
    jobs = jobs[:1] + corrections + jobs[1:]
    for job in jobs:
        job.update(problem=name, k=k)
    return jobs


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ngsolve-part", nargs=2, metavar=("JOBS", "RESULTS"), help=argparse.SUPPRESS)
    parser.add_argument("--ngsolve-python", default=os.environ.get("NGSOLVE_PYTHON", "/work/ngvenv/bin/python"),
                        help="python of a venv with ngsolve, meshio and numpy (default /work/ngvenv/bin/python)")
    parser.add_argument("--quick", action="store_true", help="a few coarse runs, for checking the script")
    parser.add_argument("--problems", default="plate20,plate6,poking")
    parser.add_argument("--out", default=str(ROOT / "docs" / "ngsolve_compare.csv"))
    args = parser.parse_args(argv)
    if args.ngsolve_part:
        ngsolve_part(*args.ngsolve_part)
        return
    if not Path(args.ngsolve_python).exists():
        parser.error(f"{args.ngsolve_python} not found: create the NGSolve venv (see the docstring)")

    sys.path.insert(0, str(ROOT))
    import dataclasses

    from mscap.fem.electrostatic import build_problem, solve
    from mscap.fem.petsc import petsc
    from mscap.geometry.layout import Layout
    from mscap.geometry.polygons import square
    from mscap.mesh.io import write_mesh
    from mscap.mesh.layered import extrude
    from mscap.mesh.triangulate import triangulate
    from mscap.scene import load_scene

    petsc()
    poking = load_scene(ROOT / "jobs" / "poking.toml")
    eps = {layer.material.permittivity_pF_per_mm for layer in poking.layers} | \
        {layer.fill.permittivity_pF_per_mm for layer in poking.layers if layer.fill}
    if len(eps) != 1:
        raise SystemExit("the NGSolve part assumes one permittivity throughout the dielectric")
    eps = eps.pop()
    thicknesses = [layer.thickness_mm for layer in poking.layers]

    def lone(plate, width):
        c = 0.5 * width
        return dataclasses.replace(poking, sheet_outline_mm=square((c, c), width),
                                   layout=Layout((square((c, c), plate),)))

    problems = {"plate20": lone(20.0, 40.0), "plate6": lone(6.0, 26.0), "poking": poking}

    def run_mscap(scene, order, h_out, h_far, grading, per_layer):
        settings = dataclasses.replace(scene.mesh, edge_length_outline_mm=h_out, edge_length_mm=h_far,
                                       grading_distance_mm=grading, elements_per_layer=per_layer, order=order)
        variant = dataclasses.replace(scene, mesh=settings)
        t0 = time.perf_counter()
        mesh2d = triangulate(variant.sheet_outline_mm, variant.layout, settings)
        t1 = time.perf_counter()
        mesh = extrude(mesh2d, thicknesses, per_layer)  # = mesh_sheet(variant.sheet)
        t2 = time.perf_counter()
        problem = build_problem(mesh, scene.layers, order)
        t3 = time.perf_counter()
        caps = solve(problem)
        t4 = time.perf_counter()
        return mesh, problem, caps, t1 - t0, t2 - t0, t3 - t2, t4 - t2

    rows = []
    checks = {}
    workdir = Path(tempfile.mkdtemp(prefix="ngsolve_compare_"))
    for name in args.problems.split(","):
        scene = problems[name]
        k = len(scene.layout.outlines)
        squares = [[float(o[:, 0].min()), float(o[:, 1].min()), float(np.ptp(o[:, 0]))] for o in scene.layout.outlines]
        width = float(np.ptp(scene.sheet_outline_mm[:, 0]))
        print(f"\n== {name}: {k} plate(s) of {squares[0][2]:g} mm on a {width:g} mm sheet ==", flush=True)
        exports = dict(tets=[], tri=[])
        for order, h_out, h_far, grading, per_layer in _mscap_settings(name, args.quick):
            mesh, problem, caps, mesh2d_s, mesh_s, setup_s, elec_s = run_mscap(scene, order, h_out, h_far, grading,
                                                                                per_layer)
            setting = f"h_out {h_out:g} h_far {h_far:g} grading {grading:g} x{per_layer}"
            rows.append(dict(problem=name, code="mscap", family="mscap", setting=setting, order=order,
                             solver="cholmod", dofs=problem.n_dofs, free_dofs=len(problem.free), mesh_s=mesh_s,
                             import_s=0.0, setup_s=setup_s, assembly_s=caps.assembly_s,
                             factorisation_s=caps.factorisation_s, solve_s=caps.solve_s, electrostatics_s=elec_s,
                             total_s=mesh_s + elec_s,
                             capacitances_pF=[float(c) for c in caps.capacitance_pF]))
            print(f"  mscap   P{order} {setting:34s} {problem.n_dofs:>8d} dofs  mesh {mesh_s:6.2f} s  "
                  f"electrostatics {elec_s:6.2f} s  C = {np.round(caps.capacitance_pF, 4)}", flush=True)
            tag = f"P{order} h_out {h_out:g}"
            if per_layer == 1 and (h_out, order) in TET_EXPORTS:  # NGSolve on this very mesh
                path = workdir / f"{name}_{order}_{h_out:g}.vtu"
                write_mesh(path, mesh)
                exports["tets"].append((tag, str(path), mesh_s))
            if per_layer == 1 and (h_out, order) in TRI_EXPORTS:
                path = workdir / f"{name}_{order}_{h_out:g}_2d.npz"
                np.savez(path, points=mesh.mesh2d.points, triangles=mesh.mesh2d.triangles,
                         capacitor=mesh.mesh2d.capacitor_of_triangle)
                exports["tri"].append((f"h_out {h_out:g}", str(path), mesh2d_s, order))
        if name == "poking":  # isolation: each plate of the array against a lone 18 mm plate, same settings
            lone18 = lone(18.0, 38.0)
            defaults = (1, 0.075, 5.0, 2.5, 1)
            _, _, c_lone, *_ = run_mscap(lone18, *defaults)
            c_array = next(r["capacitances_pF"] for r in rows if r["problem"] == "poking"
                           and r["setting"].startswith("h_out 0.075 ") and r["setting"].endswith("x1")
                           and r["order"] == 1)
            checks["isolation"] = (min(c_array), max(c_array), float(c_lone.capacitance_pF[0]))
            print(f"  isolation check (mscap defaults): array plates {min(c_array):.4f}..{max(c_array):.4f} pF, "
                  f"lone 18 mm plate {c_lone.capacitance_pF[0]:.4f} pF", flush=True)

        jobs = _ngsolve_jobs(name, squares, width, k, exports, args.quick)
        jobs_path, results_path = workdir / f"{name}_jobs.json", workdir / f"{name}_results.json"
        jobs_path.write_text(json.dumps(dict(thicknesses_mm=thicknesses, eps_pF_per_mm=eps, jobs=jobs)))
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        env.pop("PYTHONPATH", None)
        subprocess.run([args.ngsolve_python, str(Path(__file__).resolve()), "--ngsolve-part", str(jobs_path),
                        str(results_path)], check=True, env=env)
        rows += json.loads(results_path.read_text())

    shutil.rmtree(workdir, ignore_errors=True)
    report(rows, checks, Path(args.out))


def _reference(rows, problem):
    """C* of ``problem``, printing how it was obtained: the lone plate's highest-order
    value, plus for an array the array term of the finest array-correction run."""
    ref = {r["order"]: r["capacitances_pF"][0] for r in rows if r["problem"] == problem and r["family"] == "reference"}
    dofs = {r["order"]: (r["dofs"], r["electrostatics_s"]) for r in rows
            if r["problem"] == problem and r["family"] == "reference"}
    print(f"{problem}: lone plate " + ", ".join(f"P{o} {c:.5f} pF ({dofs[o][0]:,} dofs, {dofs[o][1]:.0f} s)"
                                              for o, c in sorted(ref.items())))
    if len(ref) >= 3:
        c1, c2, c3 = (ref[o] for o in sorted(ref)[-3:])
        d12, d23 = abs(c1 - c2), abs(c2 - c3)
        estimate = d23 * d23 / (d12 - d23) if d23 < d12 else float("nan")
        print(f"  |P3 - P2| / C = {100 * d23 / c3:.4f} % (bounds the P2 error); the P1 -> P2 -> P3 steps shrink "
              f"{d12 / d23:.1f}x, so the P3 error is about {100 * estimate / c3:.4f} %")
    best = ref[max(ref)]
    corrections = [r for r in rows if r["problem"] == problem and r["family"] == "array-correction"]
    for r in corrections:
        d = np.array(r["delta_pF"])
        print(f"  array term C(array) - C(alone), {r['setting']}: {d.mean():+.5f} pF (capacitors "
              f"{d.min():+.5f}..{d.max():+.5f}) = {100 * d.mean() / best:+.4f} %")
    if corrections:
        best += float(np.mean(corrections[-1]["delta_pF"]))
    print(f"  C* = {best:.5f} pF")
    return best


def report(rows, checks, out):
    """Errors against the reference, the CSV, the tables and the equal-error ratios."""
    sys.path.insert(0, str(ROOT))
    from benchmarks._common import table_head, write_csv

    print("\n### References (NGSolve, quarter of a lone plate, graded hexahedra)\n")
    references = {problem: _reference(rows, problem) for problem in dict.fromkeys(r["problem"] for r in rows)}
    rows = [r for r in rows if r["family"] != "array-correction"]
    for r in rows:
        r["error"] = float(np.max(np.abs(np.array(r["capacitances_pF"]) - references[r["problem"]]))
                           / references[r["problem"]])
    if "isolation" in checks:
        lo, hi, single = checks["isolation"]
        print(f"poking, mscap defaults, each on its own mesh: array plates {lo:.4f}..{hi:.4f} pF, lone 18 mm plate "
              f"{single:.4f} pF")
    for a in rows:
        for b in rows:
            if (a["family"] == "mscap" and b["family"] == "ng-tet@mscap" and a["problem"] == b["problem"]
                    and a["order"] == b["order"] and a["setting"].endswith("x1")
                    and b["setting"] == f"mscap mesh h_out {a['setting'].split()[1]}"):
                d = np.max(np.abs(np.array(a["capacitances_pF"]) - b["capacitances_pF"]) / a["capacitances_pF"])
                print(f"same mesh and order ({a['problem']}, P{a['order']}, {a['setting']}): mscap and NGSolve "
                      f"({b['solver']}) differ by {d:.1e}")

    write_csv([{f: (";".join(f"{c:.6f}" for c in r[f]) if f == "capacitances_pF" else r.get(f, ""))
                for f in FIELDS} for r in rows], out, FIELDS)

    for problem in references:
        print(f"\n### {problem} (C* = {references[problem]:.4f} pF)\n")
        for line in table_head("| code | mesh | order | solver | dofs | mesh s | import s | setup s | "
                               "electrostatics s | total s | max error |"):
            print(line)
        for r in sorted((r for r in rows if r["problem"] == problem and r["family"] != "reference"),
                        key=lambda r: r["total_s"]):
            print(f"| {r['family']} | {r['setting']} | P{r['order']} | {r['solver']} | {r['dofs']:,} | "
                  f"{r['mesh_s']:.2f} | {r['import_s']:.2f} | {r['setup_s']:.2f} | {r['electrostatics_s']:.2f} | "
                  f"{r['total_s']:.2f} | {100 * r['error']:.2f} % |")

    equal_error(rows, list(references))
    print(f"\nwrote {out}")


GROUPS = {"mscap": ("mscap",), "NGSolve, own mesh": ("ng-prism@netgen", "ng-tet@netgen3d"),
          "NGSolve, mscap's tets": ("ng-tet@mscap",), "NGSolve, prisms on gmsh 2D": ("ng-prism@gmsh",)}


def _time_to(rows, target, key):
    """Time ``key`` to reach ``target`` along the Pareto front of ``rows`` (each run faster
    than every more accurate one), interpolated log-log between the two runs around it;
    None when no run reaches it."""
    front, best = [], float("inf")
    for r in sorted(rows, key=lambda r: r[key]):
        if r["error"] < best:
            front.append(r)
            best = r["error"]
    for i, r in enumerate(front):
        if r["error"] <= target:
            if i == 0:
                return r[key]
            q = front[i - 1]
            w = np.log(q["error"] / target) / np.log(q["error"] / r["error"])
            return float(np.exp((1 - w) * np.log(q[key]) + w * np.log(r[key])))
    return None


def _runs(rows, problem, families):
    """The rows of ``problem`` run by one of ``families``."""
    return [r for r in rows if r["problem"] == problem and r["family"] in families]


def equal_error(rows, problems):
    """Per problem and error target: each group's fastest run at or under it, and the
    time interpolated along each group's Pareto front; both as ratios to mscap's."""
    from benchmarks._common import table_head  # report() put the project on sys.path

    print("\n### Equal error: the fastest run at or under each error, total s (= mesh + electrostatics; "
          "in brackets electrostatics alone), and its time / mscap's\n")
    for line in table_head("| problem | error ≤ | " + " | ".join(GROUPS) + " |"):
        print(line)
    for problem in problems:
        for target in TARGETS:
            best = {}
            for group, families in GROUPS.items():
                ok = [r for r in _runs(rows, problem, families) if r["error"] <= target]
                best[group] = min(ok, key=lambda r: r["total_s"]) if ok else None
            m = best["mscap"]
            cells = []
            for group, b in best.items():
                if b is None:
                    cells.append("—")
                    continue
                text = f"{b['total_s']:.2f} ({b['electrostatics_s']:.2f}) P{b['order']} {b['setting']}"
                if group != "mscap" and m:
                    text += (f" → **{b['total_s'] / m['total_s']:.2f}×** "
                             f"({b['electrostatics_s'] / m['electrostatics_s']:.2f}×)")
                cells.append(text)
            print(f"| {problem} | {100 * target:g} % | " + " | ".join(cells) + " |")
    print("\n### Equal error, interpolated log-log along each code's Pareto front: total s (electrostatics s "
          "on its own front), and time / mscap's\n")
    for line in table_head("| problem | error | " + " | ".join(GROUPS) + " |"):
        print(line)
    for problem in problems:
        for target in TARGETS:
            cells, m = [], None
            for group, families in GROUPS.items():
                sel = _runs(rows, problem, families)
                t, e = _time_to(sel, target, "total_s"), _time_to(sel, target, "electrostatics_s")
                if group == "mscap":
                    m = (t, e)
                if t is None:
                    cells.append("—")
                    continue
                text = f"{t:.2f} ({e:.2f})"
                if group != "mscap" and m[0]:
                    text += f" → **{t / m[0]:.2f}×** ({e / m[1]:.2f}×)"
                cells.append(text)
            print(f"| {problem} | {100 * target:g} % | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
