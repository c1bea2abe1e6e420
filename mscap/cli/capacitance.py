"""``mscap capacitance SCENE``: mesh a scene at rest and print its capacitances (pF)."""

from __future__ import annotations

import json
import time

from mscap.cli.common import load_scene_for

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("capacitance", help="rest capacitances of a scene (pF)",
                       description="Mesh a scene, solve the electrostatic problem at rest and "
                                   "print each capacitor's capacitance (top plate at 1 V, all "
                                   "other plates grounded). PETSc options such as "
                                   "-electro_pc_factor_mat_solver_type mumps may follow.")
    p.add_argument("scene", help="scene file (jobs/*.toml)")
    p.add_argument("--order", type=int, choices=(1, 2), help="element order (default: the scene's)")
    p.add_argument("--maxwell", action="store_true",
                   help="also print the Maxwell capacitance matrix of all 2k plates")
    p.add_argument("--export", metavar="DIR", help="write DIR/potential.vtu with φ per capacitor")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(run=run)


def run(args) -> int:
    import numpy as np

    from mscap.fem.electrostatic import build_problem, solve
    from mscap.fem.petsc import LinearSolver
    from mscap.mesh.layered import mesh_scene

    scene = load_scene_for(args)
    order = args.order or scene.mesh.order
    start = time.perf_counter()
    mesh = mesh_scene(scene)
    meshed = time.perf_counter()
    problem = build_problem(mesh, scene.layers, order)
    prepared = time.perf_counter()
    solver = LinearSolver("electro_")
    caps = solve(problem, maxwell=args.maxwell, solver=solver)
    total = time.perf_counter() - start
    times = {"mesh": meshed - start, "setup": prepared - meshed,
             "assembly_factorisation": caps.assembly_s + caps.factorisation_s,
             "solves": caps.solve_s, "total": total}

    written = None
    if args.export:
        from mscap.viz.vtu import write_potentials

        written = write_potentials(args.export, mesh, problem, caps)

    if args.json:
        record = {"scene": scene.name, "order": order, "solver": solver.description,
                  "capacitance_pF": caps.capacitance_pF.tolist()}
        if args.maxwell:
            record["maxwell_pF"] = caps.maxwell_pF.tolist()
        record.update({"time_s": times, "mesh": {"vertices": len(mesh.points), "tets": len(mesh.tets),
                                                 "dofs": problem.n_dofs}})
        if written:
            record["file"] = str(written)
        print(json.dumps(record))
        return 0

    middle = scene.layers[2]
    areas = scene.layout.areas_mm2()
    print(f"scene {scene.name} ({scene.path}): {problem.k} capacitors, P{order}, "
          f"{len(mesh.points)} vertices, {len(mesh.tets)} tets, {problem.n_dofs} dofs, "
          f"solver {solver.description}")
    print(f"  {'capacitor':>9} {'area_mm2':>10} {'C_pF':>12} {'C/(eps A/d)':>12}")
    for j, c in enumerate(caps.capacitance_pF):
        plate = middle.material.permittivity_pF_per_mm * areas[j] / middle.thickness_mm
        print(f"  {j:>9d} {areas[j]:>10.3f} {c:>12.5f} {c / plate:>12.5f}")
    if args.maxwell:
        print("  Maxwell matrix (pF), plates: bottom 0..k-1, then top 0..k-1")
        with np.printoptions(precision=4, suppress=True, linewidth=200):
            for row in caps.maxwell_pF:
                print("   ", np.array2string(row))
    print(f"  time: mesh {times['mesh']:.2f} s, setup {times['setup']:.2f} s, assembly+factorisation "
          f"{times['assembly_factorisation']:.2f} s, solves {times['solves']:.2f} s, "
          f"total {total:.2f} s")
    if written:
        print(f"wrote {written}")
    return 0

