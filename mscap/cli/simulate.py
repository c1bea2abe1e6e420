"""``mscap simulate SCENE``: every pose's equilibrium and capacitances."""

from __future__ import annotations

import json

from mscap.cli.common import add_memory_option, load_scene_for, progress_printer

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("simulate", help="simulate every pose: elastic equilibrium, then capacitances",
                       description="Mesh a scene, solve the neo-Hookean equilibrium of every pose "
                                   "and the capacitances in it; print a pose × capacitor table "
                                   "(pF) and the time per stage. PETSc options such as "
                                   "-elastic_pc_factor_mat_solver_type cholmod may follow.")
    p.add_argument("scene", help="scene file (jobs/*.toml)")
    p.add_argument("--order", type=int, choices=(1, 2), help="electrostatic element order (default: the scene's)")
    p.add_argument("--elastic-order", type=int, choices=(1, 2), help="elastic element order (default: the scene's)")
    p.add_argument("--poses", help="comma-separated pose names to run (default: all)")
    p.add_argument("--export", metavar="DIR", help="write DIR/<pose>.vtu: the rest mesh with point data "
                                                   "displacement (Warp By Vector, scale 1, draws the pose), φ; "
                                                   "J and stress (in DIR/<pose>_elastic.vtu when the elastic "
                                                   "problem has its own mesh); DIR/poses.pvd (and "
                                                   "poses_elastic.pvd) steps through the poses in ParaView")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    add_memory_option(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.fem.report import simulation_record, simulation_text
    from mscap.errors import SceneError
    from mscap.fem.simulate import simulate
    from mscap.outputs import output_directory
    from mscap.scene.loader import select_poses

    scene = load_scene_for(args)
    if args.poses:
        scene = select_poses(scene, args.poses.split(","))
    if not scene.poses:
        raise SceneError(scene.path, "poses", "no [[poses]]: nothing to simulate")
    if args.export:
        output_directory(args.export, "simulate --export")  # before the work
    sim = simulate(scene, order=args.order, elastic_order=args.elastic_order,
                   progress=progress_printer(args.quiet))
    files = []
    if args.export:
        from mscap.viz.vtu import write_poses

        files = write_poses(args.export, sim)
    if args.json:
        print(json.dumps(simulation_record(scene, sim, files)))
        return 0
    print(simulation_text(scene, sim))
    for f in files:
        print(f"wrote {f}")
    return 0
