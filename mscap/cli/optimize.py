"""``mscap optimize SCENE --k K --seed S --init random|lloyd|scene -o DIR``: one start of
the layout optimisation (paper §5.1)."""

from __future__ import annotations

from mscap.cli.common import add_memory_option, load_scene_for, progress_printer

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("optimize", help="optimise the capacitor layout of a scene (one start)",
                       description="Optimise the capacitor outlines so that the poses' capacitance "
                                   "vectors lie far apart (L-BFGS on the layout, remeshing, control "
                                   "cascade). Writes the outlines, the capacitance table, the history, "
                                   "summary.json and a before/after figure to DIR; progress per "
                                   "iteration on stderr.")
    p.add_argument("scene", help="scene file (jobs/*.toml)")
    p.add_argument("--k", type=int, help="number of capacitors (random and lloyd starts)")
    p.add_argument("--seed", type=int, default=0, help="seed of the initial layout")
    p.add_argument("--init", choices=("random", "lloyd", "scene", "sensitivity"), default="scene",
                   help="initial layout: seeded random squares (random), squares at Lloyd centroids "
                        "(lloyd), the scene's own layout (scene), or squares where the design poses strain "
                        "the sheet differently (sensitivity: one elastic solve per design pose first)")
    p.add_argument("--max-iterations", type=int, help="per cascade level (default: the scene's)")
    p.add_argument("--cascade", type=int, help="control-doubling levels (default: the scene's)")
    p.add_argument("-o", "--output", metavar="DIR", required=True, help="output directory")
    p.add_argument("--no-figure", action="store_true", help="skip the before/after figure")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    add_memory_option(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.design.optimizer import optimize
    from mscap.design.starts import start_design
    from mscap.outputs import output_directory, replace_file
    from mscap.service.designs import OPTIMIZE_FILES, write_optimize_output

    from mscap.errors import DesignError
    from mscap.scene.settings import MAX_CASCADE_LEVELS, MAX_ITERATIONS

    if args.max_iterations is not None and not 0 <= args.max_iterations <= MAX_ITERATIONS:
        raise DesignError(f"--max-iterations: must lie in 0..{MAX_ITERATIONS}, got {args.max_iterations}")
    if args.cascade is not None and not 0 <= args.cascade <= MAX_CASCADE_LEVELS:
        raise DesignError(f"--cascade: must lie in 0..{MAX_CASCADE_LEVELS} (each level doubles the control "
                          f"points), got {args.cascade}")
    scene = load_scene_for(args)
    out = output_directory(args.output, "optimize -o")  # before the work
    say = progress_printer(args.quiet) or (lambda message: None)
    layout, design = start_design(scene, args.k, args.seed, args.init)
    say(f"{scene.name}: k = {layout.k}, seed {args.seed}, init {args.init}, {len(design.poses)} design poses")
    result = optimize(design, progress=say, max_iterations=args.max_iterations, cascade_levels=args.cascade)

    summary = write_optimize_output(out, scene, layout, result, args.seed, args.init, result.design.designed)
    files = list(OPTIMIZE_FILES)
    if not args.no_figure:
        from mscap.viz.optimize import optimize_figure

        replace_file(out / "layout.png", lambda path: optimize_figure(
            path, scene, layout, result.layout, result.initial.capacitance_pF, result.evaluation.capacitance_pF,
            summary["poses"]))
        files.append("layout.png")
    print(f"{scene.name}: {result.iterations} iterations ({result.reason}) in {result.time_s:.1f} s; "
          f"min pairwise L1 {result.initial.min_l1_pF:.4g} → {result.evaluation.min_l1_pF:.4g} pF"
          + (f"; read-back bound {summary['initial_bound_mm']:.4g} → {summary['final_bound_mm']:.4g} mm"
             if "final_bound_mm" in summary else ""))
    print("wrote " + ", ".join(str(out / f) for f in files))
    return 0
