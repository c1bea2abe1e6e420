"""``mscap calibrate SCENE --design results.h5[:RUN] [--baseline ...]``: virtual
calibration of a design against baselines (pose reconstruction under noise)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from mscap.cli.common import add_memory_option, add_noise_options

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("calibrate", help="pose reconstruction under noise: a design against baselines",
                       description="Simulate the scene's [calibration] pose family (training grid and "
                                   "evaluation sequence) for the design and each baseline (once; cached "
                                   "beside the results file), fit an RBF map from capacitances to the "
                                   "posed object's vertices (or the pose parameters), and score the "
                                   "sequence over noisy runs (±15 % per capacitor and run, ±2 pF per "
                                   "pose: the scene's [calibration.noise]). Under mpirun the ranks "
                                   "share the simulations.")
    p.add_argument("scene", help="scene file with a [calibration] section")
    p.add_argument("--design", required=True, metavar="FILE.h5[:RUN]|DIR",
                   help="results file of `mscap run` (default run: the chosen one), or an output "
                        "directory of `mscap optimize`")
    p.add_argument("--baseline", nargs="*", default=None, metavar="B",
                   help="baselines: 'initial' (the design's initial layout), 'scene' (the scene's "
                        "own layout), a run id of the results file, or RUN:initial (default: initial)")
    p.add_argument("--wiring", metavar="FABRICATE_DIR",
                   help="also calibrate the design as wired: the nets of an `mscap fabricate` output directory "
                        "(read from its stencils) and, for comparison, its plates alone on the same mesh")
    p.add_argument("-o", "--output", metavar="DIR", help="output directory (default: <results>_calibration/, or "
                                                         "OPTIMIZE_DIR/calibration/ for an optimize directory)")
    p.add_argument("--cache", metavar="FILE.h5", help="simulation cache (default: <results>_calibration.h5, or "
                                                      "OPTIMIZE_DIR/calibration.h5)")
    p.add_argument("--runs", type=int, metavar="N", help="noisy runs (default: the scene's, 100)")
    p.add_argument("--seed", type=int, metavar="N", help="noise seed (default: the scene's)")
    add_noise_options(p)
    p.add_argument("--reference", metavar="POSE",
                   help="divide every read-out by this pose's, read once per run ('none': raw "
                        "read-outs; default: the scene's calibration.reference)")
    p.add_argument("--features", choices=("whitened", "raw"),
                   help="read-out features of the map: 'whitened' (noise units, the directions the family "
                        "resolves above the noise) or 'raw' (the paper's map); default: the scene's, whitened. "
                        "A scene's smoothing is in its features' units: with --features the smoothing is "
                        "that map's default (1 whitened, 0 raw) unless --smoothing is given")
    p.add_argument("--smoothing", type=float, help="RBF smoothing (whitened: in noise units); default: the scene's")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    add_memory_option(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.calibration.report import default_paths, text_report, write_outputs
    from mscap.calibration.service import CalibrationError, Candidate, evaluate, settings, simulate_family
    from mscap.cli.common import load_scene_for, progress_printer, rank_logging, start_mpi
    from mscap.outputs import output_directory
    from mscap.service.designs import design_layouts
    from mscap.viz.calibration import error_figure

    comm = start_mpi().COMM_WORLD
    rank_logging(comm)  # before the scene is loaded: its warnings once, from rank 0
    rank = comm.Get_rank()
    scene = load_scene_for(args)
    cal = settings(scene)
    # Every argument before the family is simulated (minutes): a bad one costs nothing.
    overrides = {"runs": args.runs, "seed": args.seed, "relative_shift": args.relative_shift,
                 "additive_pF": args.additive_pF}
    noise = replace(cal.noise, **{k: v for k, v in overrides.items() if v is not None})
    if args.reference is not None:
        reference = None if args.reference == "none" else args.reference
        if reference is not None and reference not in {p.name for p in scene.poses}:
            raise CalibrationError(f"--reference {reference!r}: no such pose in {scene.path} "
                                   f"({', '.join(p.name for p in scene.poses)})")
        cal = replace(cal, reference=reference)
    if args.features is not None and args.features != cal.features:
        cal = replace(cal, features=args.features, smoothing=1.0 if args.features == "whitened" else 0.0)
    if args.smoothing is not None:
        if not args.smoothing >= 0:
            raise CalibrationError(f"--smoothing must be >= 0, got {args.smoothing}")
        cal = replace(cal, smoothing=args.smoothing)
    scene = replace(scene, calibration=cal)
    default_cache, default_out = default_paths(args.design)
    cache, outdir = Path(args.cache or default_cache), Path(args.output or default_out)
    if rank == 0:
        output_directory(outdir, "calibrate -o")
    designs = [Candidate(label, outlines) for label, outlines in design_layouts(scene, args.design, args.baseline)]
    if args.wiring:  # the design as wired, and its plates on the same mesh, before the baselines
        from mscap.fabrication.wired import plates_only, read_wiring_dir

        main = designs[0]
        wiring = read_wiring_dir(args.wiring, main.outlines)
        designs[1:1] = [Candidate(f"{main.label.split(' (')[0]} (as wired)", main.outlines, wiring),
                        Candidate(f"{main.label.split(' (')[0]} (plates, wired mesh)", main.outlines,
                                  plates_only(main.outlines, meshed_like=wiring))]
    simulate_family(scene, designs, cache, comm, progress=progress_printer(args.quiet or rank > 0))
    if rank != 0:
        return 0
    scores = evaluate(scene, designs, cache, noise)
    write_outputs(outdir, scene, scores, noise, figure=error_figure)
    print(text_report(scene, scores, noise))
    print(f"wrote {outdir}/errors.csv, summary.json, errors.png")
    return 0
