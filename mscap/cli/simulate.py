"""``mscap simulate SCENE``: every pose's equilibrium and capacitances."""

from __future__ import annotations

import json

from mscap.cli.common import load_scene_for, progress_printer

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
    p.add_argument("--export", metavar="DIR", help="write DIR/<pose>.vtu: displacement, J, stress, φ "
                                                   "(J and stress in DIR/<pose>_elastic.vtu when the "
                                                   "elastic problem has its own mesh)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(run=run)


def run(args) -> int:
    import dataclasses

    from mscap.fem.simulate import simulate

    scene = load_scene_for(args)
    if args.poses:
        wanted = args.poses.split(",")
        known = {p.name for p in scene.poses}
        unknown = [name for name in wanted if name not in known]
        if unknown:
            from mscap.errors import SceneError

            raise SceneError(scene.path, "poses", f"no pose named {unknown[0]!r}; "
                             f"the scene has {', '.join(p.name for p in scene.poses)}")
        scene = dataclasses.replace(scene, poses=tuple(p for p in scene.poses if p.name in wanted))
    progress = progress_printer(args.quiet)
    sim = simulate(scene, order=args.order, elastic_order=args.elastic_order, progress=progress)

    files = []
    if args.export:
        from mscap.viz.vtu import write_poses

        files = write_poses(args.export, sim)

    iterations = [r.state.newton_iterations if r.state else 0 for r in sim.poses]
    if args.json:
        record = {"scene": scene.name, "poses": [r.name for r in sim.poses],
                  "capacitance_pF": sim.capacitance_pF.tolist(), "newton_iterations": iterations,
                  "load_steps": [r.state.load_steps if r.state else 0 for r in sim.poses],
                  "time_s": {key: sim.times[key] for key in ("mesh", "elastic", "electrostatic", "total")},
                  "elastic_split_s": sim.times["elastic_split"]}
        if files:
            record["files"] = [str(f) for f in files]
        print(json.dumps(record))
        return 0

    k = sim.electro.k
    print(f"scene {scene.name} ({scene.path}): {len(sim.poses)} poses, {k} capacitors, "
          f"{len(sim.mesh.points)} vertices, {len(sim.mesh.tets)} tets")
    if sim.elastic is not None:
        where = "the electrostatic mesh" if sim.transfer is None else (
            f"its own mesh of {len(sim.elastic.mesh.tets)} tets, {len(sim.elastic.mesh.level_z_mm) - 1} "
            f"through the stack")
        print(f"  elastic: P{sim.elastic.order}, {sim.elastic.n_dofs} dofs on {where}")
    header = "".join(f"{'C' + str(j) + '_pF':>10}" for j in range(k))
    print(f"  {'pose':<16}{header} {'newton':>7} {'steps':>6} {'elastic_s':>10} {'electro_s':>10}")
    for r in sim.poses:
        caps = "".join(f"{c:>10.3f}" for c in r.capacitance_pF)
        steps = r.state.load_steps if r.state else 0
        print(f"  {r.name:<16}{caps} {iterations[sim.poses.index(r)]:>7d} {steps:>6d} "
              f"{r.elastic_s:>10.2f} {r.electrostatic_s:>10.2f}")
    t = sim.times
    print(f"  time: mesh {t['mesh']:.2f} s, setup {t['setup']:.2f} s, elastic {t['elastic']:.2f} s, "
          f"electrostatic {t['electrostatic']:.2f} s, total {t['total']:.2f} s")
    if sim.elastic is not None:
        print("  elastic: " + ", ".join(f"{key.replace('_', ' ')} {value:.2f} s"
                                         for key, value in t["elastic_split"].items()))
    for f in files:
        print(f"wrote {f}")
    return 0

