"""``mscap capacitance SCENE``: mesh a scene at rest and print its capacitances (pF)."""

from __future__ import annotations

import json
import sys

from mscap.cli.common import add_memory_option, load_scene_for

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
                   help="also solve with each bottom plate at 1 V and print the Maxwell capacitance "
                        "matrix of all 2k plates (2k solves instead of k, on the same factorisation)")
    p.add_argument("--export", metavar="DIR", help="write DIR/potential.vtu with φ per capacitor")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    add_memory_option(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.fem.report import rest_capacitance, rest_capacitance_record, rest_capacitance_text

    scene = load_scene_for(args)
    if args.export:
        from mscap.outputs import output_directory

        output_directory(args.export, "capacitance --export")  # before the work
    if args.maxwell:
        k = scene.layout.k
        print(f"mscap: warning: --maxwell solves {2 * k} systems (one per plate) instead of {k}: "
              f"about twice the solve time", file=sys.stderr, flush=True)
        if scene.mesh.tolerance is not None:
            print("mscap: --maxwell: the couplings get their own mesh (P2, outline edge = the dielectric gap, "
                  "two elements per layer; about 10x the unknowns): within 2 % for gaps down to 0.5 mm, where "
                  "the capacitance mesh errs 3-7 % (docs/electrostatics.md)", file=sys.stderr, flush=True)
        else:
            print("mscap: --maxwell on hand-set sizes: couplings between plates a few mm apart err 3-20 % where C "
                  "errs 1-3 % (docs/electrostatics.md); a scene without [mesh] sizes gets a mesh for them",
                  file=sys.stderr, flush=True)
    rest = rest_capacitance(scene.sheet, order=args.order, maxwell=args.maxwell)
    written = None
    if args.export:
        from mscap.viz.vtu import write_potentials

        written = write_potentials(args.export, rest.mesh, rest.problem, rest.capacitances)
    if args.json:
        print(json.dumps(rest_capacitance_record(scene, rest, written)))
        return 0
    print(rest_capacitance_text(scene, rest))
    if written:
        print(f"wrote {written}")
    return 0
