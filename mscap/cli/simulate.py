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
    p.add_argument("--wiring", metavar="FABRICATE_DIR",
                   help="simulate the design of an `mscap fabricate` output directory as wired (its nets, read "
                        "from its stencils, in place of the scene's layout): each capacitor's reading is the mutual "
                        "capacitance of its row and column nets, beside its plates alone on the same mesh")
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
    if args.wiring:
        if args.export or args.order or args.elastic_order:
            raise SceneError(scene.path, "", "--wiring simulates with the scene's orders and exports nothing: "
                                             "leave out --export, --order and --elastic-order")
        return _wired(args, scene)
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


def _wired(args, scene) -> int:
    """``--wiring``: the design as wired and its plates alone, pose by pose."""
    import numpy as np

    from mscap.fabrication.wired import plates_only, read_wiring_dir, readings
    from mscap.geometry.layout import Layout
    from mscap.scene.sizing import sheet_for

    wiring = read_wiring_dir(args.wiring)
    outlines = [np.asarray(p.exterior.coords)[:-1] for p in wiring.plates]
    sheet = sheet_for(scene, Layout(tuple(outlines)))
    printer = progress_printer(args.quiet)
    say = printer or (lambda line: None)
    say("simulating the design as wired")
    wired, _ = readings(scene, sheet, wiring, progress=printer)
    say("simulating its plates alone on the same mesh")
    plates, _ = readings(scene, sheet, plates_only(outlines, meshed_like=wiring), progress=printer)
    names = [p.name for p in scene.poses]
    if args.json:
        print(json.dumps({"scene": scene.name, "wiring": str(args.wiring), "poses": names,
                          "slots": [list(s) for s in wiring.slots], "wired_pF": wired.tolist(),
                          "plates_pF": plates.tolist()}))
        return 0
    k = wired.shape[1]
    print(f"{scene.name} as wired ({args.wiring}): capacitor c reads its row and column nets (pF); "
          f"beside it, its plates alone")
    print(f"{'pose':<20}" + "".join(f"{f'C{c} wired':>12}{'plates':>10}{'+%':>8}" for c in range(k)))
    for name, w, p in zip(names, wired, plates):
        print(f"{name:<20}" + "".join(f"{w[c]:12.3f}{p[c]:10.3f}{100 * (w[c] / p[c] - 1):8.2f}" for c in range(k)))
    signal_w, signal_p = wired - wired[0], plates - plates[0]
    span = np.abs(signal_p).max(axis=0)
    change = np.abs(signal_w - signal_p).max(axis=0) / np.where(span > 0, span, np.nan)
    print("pose-to-pose signal (from the first pose), largest change by the wiring, % of its range: "
          + ", ".join(f"C{c} {100 * change[c]:.2f}" for c in range(k)))
    return 0
