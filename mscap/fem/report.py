"""Reports of a forward simulation: the pose × capacitor table of ``mscap simulate``, the
rest capacitances of ``mscap capacitance``, and their JSON records."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mscap.fem import electrostatic
from mscap.fem.petsc import LinearSolver
from mscap.fem.simulate import Simulation, element_of
from mscap.mesh.layered import LayeredMesh, mesh_sheet

if TYPE_CHECKING:
    from mscap.scene.settings import Scene, Sheet

__all__ = ["simulation_record", "simulation_text", "RestCapacitance", "rest_capacitance",
           "rest_capacitance_record", "rest_capacitance_text", "maxwell_lines"]


def _iterations(sim: Simulation) -> list[int]:
    return [r.state.newton_iterations if r.state else 0 for r in sim.poses]


def simulation_record(scene: Scene, sim: Simulation, files=()) -> dict:
    """One JSON-ready record: capacitances (pF), Newton iterations, load steps, times (s)."""
    record = {"scene": scene.name, "poses": [r.name for r in sim.poses],
              "capacitance_pF": sim.capacitance_pF.tolist(), "newton_iterations": _iterations(sim),
              "load_steps": [r.state.load_steps if r.state else 0 for r in sim.poses],
              "time_s": {key: sim.times[key] for key in ("mesh", "elastic", "electrostatic", "total")},
              "elastic_split_s": sim.times["elastic_split"]}
    if files:
        record["files"] = [str(f) for f in files]
    return record


def simulation_text(scene: Scene, sim: Simulation) -> str:
    """The mesh, a pose × capacitor table (pF) with Newton iterations, load steps and
    times per pose, and the time per stage."""
    k = sim.electro.k
    lines = [f"scene {scene.name} ({scene.path}): {len(sim.poses)} poses, {k} capacitors, "
             f"{len(sim.mesh.points)} vertices, {len(sim.mesh.tets)} tets"]
    if sim.elastic is not None:
        where = "the electrostatic mesh" if sim.transfer is None else (
            f"its own mesh of {len(sim.elastic.mesh.tets)} tets, {len(sim.elastic.mesh.level_z_mm) - 1} "
            f"through the stack")
        lines.append(f"  elastic: P{sim.elastic.order}, {sim.elastic.n_dofs} dofs on {where}")
    header = "".join(f"{'C' + str(j) + '_pF':>10}" for j in range(k))
    lines.append(f"  {'pose':<16}{header} {'newton':>7} {'steps':>6} {'elastic_s':>10} {'electro_s':>10}")
    for r, iterations in zip(sim.poses, _iterations(sim)):
        caps = "".join(f"{c:>10.3f}" for c in r.capacitance_pF)
        steps = r.state.load_steps if r.state else 0
        lines.append(f"  {r.name:<16}{caps} {iterations:>7d} {steps:>6d} "
                     f"{r.elastic_s:>10.2f} {r.electrostatic_s:>10.2f}")
    t = sim.times
    lines.append(f"  time: mesh {t['mesh']:.2f} s, setup {t['setup']:.2f} s, elastic {t['elastic']:.2f} s, "
                 f"electrostatic {t['electrostatic']:.2f} s, total {t['total']:.2f} s")
    if sim.elastic is not None:
        lines.append("  elastic: " + ", ".join(f"{key.replace('_', ' ')} {value:.2f} s"
                                               for key, value in t["elastic_split"].items()))
    return "\n".join(lines)


@dataclass(frozen=True)
class RestCapacitance:
    """The scene at rest: its mesh, electrostatic problem, capacitances, the solver's
    description and the time per stage (s)."""

    mesh: LayeredMesh
    problem: electrostatic.ElectrostaticProblem
    capacitances: electrostatic.Capacitances
    order: int
    solver: str
    times: dict


def rest_capacitance(sheet: Sheet, order: int | None = None, maxwell: bool = False) -> RestCapacitance:
    """Mesh ``sheet`` (a scene's, :attr:`~mscap.scene.settings.Scene.sheet`) and solve its
    electrostatics at rest (top plate at 1 V, all other plates grounded; with ``maxwell``
    also the Maxwell matrix of all 2k plates, on the mesh
    :func:`mscap.scene.sizing.for_couplings` makes of a tolerance-sized one)."""
    if maxwell:
        from dataclasses import replace

        from mscap.scene.sizing import for_couplings

        coupled = for_couplings(sheet.mesh, sheet.layers[2].thickness_mm, sum(sheet.thicknesses_mm))
        if coupled is not sheet.mesh:
            sheet = replace(sheet, mesh=coupled)
    order = order or sheet.mesh.order
    start = time.perf_counter()
    mesh = mesh_sheet(sheet)
    meshed = time.perf_counter()
    problem = electrostatic.build_problem(mesh, sheet.layers, *element_of(sheet.mesh, order))
    prepared = time.perf_counter()
    solver = LinearSolver("electro_")
    try:
        caps = electrostatic.solve(problem, maxwell=maxwell, solver=solver)
        description = solver.description
    finally:
        solver.destroy()
    times = {"mesh": meshed - start, "setup": prepared - meshed,
             "assembly_factorisation": caps.assembly_s + caps.factorisation_s,
             "solves": caps.solve_s, "total": time.perf_counter() - start}
    return RestCapacitance(mesh, problem, caps, order, description, times)


def rest_capacitance_record(scene: Scene, rest: RestCapacitance, written=None) -> dict:
    """One JSON-ready record of :func:`rest_capacitance`."""
    caps, mesh = rest.capacitances, rest.mesh
    record = {"scene": scene.name, "order": rest.order, "element": rest.problem.shape, "solver": rest.solver,
              "capacitance_pF": caps.capacitance_pF.tolist()}
    if caps.maxwell_pF is not None:
        record["maxwell_pF"] = caps.maxwell_pF.tolist()
    record.update({"time_s": rest.times, "mesh": {"vertices": len(mesh.points), "tets": len(mesh.tets),
                                                  "dofs": rest.problem.n_dofs}})
    if written:
        record["file"] = str(written)
    return record


def rest_capacitance_text(scene: Scene, rest: RestCapacitance) -> str:
    """Each capacitor's area, capacitance and ratio to the parallel-plate ε A / d, the
    Maxwell matrix when solved, and the time per stage."""
    caps, mesh, problem, times = rest.capacitances, rest.mesh, rest.problem, rest.times
    middle = scene.layers[2]
    areas = scene.layout.areas_mm2()
    cells = f"{len(mesh.tets)} tets" if problem.shape == "tet" else f"{len(mesh.tets) // 3} prisms"
    lines = [f"scene {scene.name} ({scene.path}): {problem.k} capacitors, P{rest.order} {problem.shape}s",
             f"  {len(mesh.points)} vertices, {cells}, {problem.n_dofs} dofs; solver {rest.solver}",
             f"  {'capacitor':>9} {'area_mm2':>10} {'C_pF':>12} {'C/(eps A/d)':>12}"]
    for j, c in enumerate(caps.capacitance_pF):
        plate = middle.material.permittivity_pF_per_mm * areas[j] / middle.thickness_mm
        lines.append(f"  {j:>9d} {areas[j]:>10.3f} {c:>12.5f} {c / plate:>12.5f}")
    if caps.maxwell_pF is not None:
        lines += maxwell_lines(caps.maxwell_pF)
    lines.append(f"  time: mesh {times['mesh']:.2f} s, setup {times['setup']:.2f} s, assembly+factorisation "
                 f"{times['assembly_factorisation']:.2f} s, solves {times['solves']:.2f} s, "
                 f"total {times['total']:.2f} s")
    return "\n".join(lines)


def maxwell_lines(maxwell_pF: np.ndarray, width: int = 100) -> list[str]:
    """The ``(2k, 2k)`` Maxwell matrix (pF) as text lines of at most ``width``
    characters: plates labelled ``b0..`` (bottom) and ``t0..`` (top), the columns split
    into as many blocks as the width needs, each block with every row."""
    n = len(maxwell_pF)
    k = n // 2
    labels = [f"b{j}" for j in range(k)] + [f"t{j}" for j in range(k)]
    cells = [[f"{value:.4f}" for value in row] for row in np.round(maxwell_pF, 4) + 0.0]  # + 0.0: no "-0.0000"
    label_width = max(map(len, labels))
    cell_width = max(len(text) for row in cells for text in row) + 2
    indent = 4 + label_width
    per_block = max(1, (width - indent) // cell_width)
    lines = [f"  Maxwell matrix (pF), {n} x {n}: bottom plates b0..b{k - 1}, then top plates t0..t{k - 1}"]
    for first in range(0, n, per_block):
        columns = range(first, min(first + per_block, n))
        if per_block < n:
            lines.append(f"  columns {labels[columns[0]]}..{labels[columns[-1]]}")
        lines.append(" " * indent + "".join(f"{labels[j]:>{cell_width}}" for j in columns))
        lines += [f"    {labels[i]:<{label_width}}" + "".join(f"{cells[i][j]:>{cell_width}}" for j in columns)
                  for i in range(n)]
    return lines
