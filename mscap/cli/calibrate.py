"""``mscap calibrate SCENE --design results.h5[:RUN] [--baseline ...]``: virtual
calibration of a design against baselines (pose reconstruction under noise)."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

__all__ = ["add_parser", "run", "designs_from", "write_outputs"]


def add_parser(sub) -> None:
    p = sub.add_parser("calibrate", help="pose reconstruction under noise: a design against baselines",
                       description="Simulate the scene's [calibration] pose family (training grid and "
                                   "evaluation sequence) for the design and each baseline (once; cached "
                                   "beside the results file), fit an RBF map from capacitances to the "
                                   "posed object's vertices (or the pose parameters), and score the "
                                   "sequence over noisy runs (±15 %% per capacitor and run, ±2 pF per "
                                   "pose: the scene's [calibration.noise]). Under mpirun the ranks "
                                   "share the simulations.")
    p.add_argument("scene", help="scene file with a [calibration] section")
    p.add_argument("--design", required=True, metavar="FILE.h5[:RUN]|DIR",
                   help="results file of `mscap run` (default run: the chosen one), or an output "
                        "directory of `mscap optimize`")
    p.add_argument("--baseline", nargs="*", default=None, metavar="B",
                   help="baselines: 'initial' (the design's initial layout), 'scene' (the scene's "
                        "own layout), a run id of the results file, or RUN:initial (default: initial)")
    p.add_argument("-o", "--output", help="output directory (default: <results>_calibration/, or "
                                          "DIR/calibration/ for an optimize directory)")
    p.add_argument("--cache", help="simulation cache (default: <results>_calibration.h5, or "
                                   "DIR/calibration.h5)")
    p.add_argument("--runs", type=int, help="noisy runs (default: the scene's, 100)")
    p.add_argument("--seed", type=int, help="noise seed (default: the scene's)")
    p.add_argument("--relative-shift", type=float, help="per-run multiplicative shift, ± fraction (0.15)")
    p.add_argument("--additive-pF", type=float, help="per-pose additive noise, ± pF (2)")
    p.add_argument("--reference", metavar="POSE",
                   help="divide every read-out by this pose's, read once per run ('none': raw "
                        "read-outs; default: the scene's calibration.reference)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.set_defaults(run=run)


def _designs_from_optimize(scene, directory: Path, baselines: list[str] | None) -> list:
    """The final layout of an ``mscap optimize`` output directory and its baselines:
    ``initial`` (rebuilt from the run's k, seed and init: initial layouts are functions
    of those alone) and ``scene``."""
    from mscap.calibration.service import CalibrationError, Design
    from mscap.geometry.initial import initial_layout
    from mscap.geometry.layout import Layout

    try:
        outlines = json.loads((directory / "outlines.json").read_text())["outlines_mm"]
        summary = json.loads((directory / "summary.json").read_text())
    except (OSError, KeyError, ValueError) as exc:
        raise CalibrationError(f"{directory}: not an `mscap optimize` output directory "
                               f"(outlines.json, summary.json): {exc}") from None
    designs = [Design(f"{directory.name} (optimised)", tuple(np.array(o, dtype=float) for o in outlines))]
    for b in ["initial"] if baselines is None else baselines:
        if b == "scene":
            designs.append(Design("scene layout", scene.layout.outlines))
        elif b == "initial":
            init = summary["init"]
            layout = scene.layout if init == "scene" else initial_layout(scene, int(summary["k"]),
                                                                          int(summary["seed"]), init)
            label = "scene layout" if init == "scene" else f"{directory.name}:initial"
            designs.append(Design(label, Layout(layout.outlines).outlines))
        else:
            raise CalibrationError(f"--baseline {b!r}: an `mscap optimize` directory has only the "
                                   "baselines 'initial' and 'scene'; run ids need a results file")
    return designs


def designs_from(scene, spec: str, baselines: list[str] | None) -> list:
    """The design named by ``spec`` (a results file, optionally ``:RUN``, or an ``mscap
    optimize`` output directory) and its baselines, as :class:`~mscap.calibration.service.Design`."""
    from mscap.calibration.service import Design
    from mscap.service.store import check_scene, read_design, read_store, split_design_spec

    if Path(spec).is_dir():
        return _designs_from_optimize(scene, Path(spec), baselines)
    path, rid = split_design_spec(spec)
    with read_store(path) as store:
        check_scene(store, scene)
        main = read_design(store, rid, "final")
        designs = [Design(f"{main.label} (optimised)", main.outlines)]
        for b in ["initial"] if baselines is None else baselines:
            if b == "scene":
                designs.append(Design("scene layout", scene.layout.outlines))
                continue
            run_id, _, which = b.partition(":")
            if run_id == "initial":
                run_id, which = main.run_id, "initial"
            d = read_design(store, run_id, which or "final")
            designs.append(Design(d.label, d.outlines))
    return designs


def run(args) -> int:
    from mpi4py import MPI

    from mscap.calibration.service import evaluate, settings, simulate_family
    from mscap.service.store import split_design_spec
    from mscap.cli.common import load_scene_for, progress_printer

    comm = MPI.COMM_WORLD
    rank = comm.Get_rank()
    scene = load_scene_for(args)
    cal = settings(scene)
    if args.reference is not None:
        reference = None if args.reference == "none" else args.reference
        if reference is not None and reference not in {p.name for p in scene.poses}:
            from mscap.calibration.service import CalibrationError

            raise CalibrationError(f"--reference {reference!r}: no such pose in {scene.path} "
                                   f"({', '.join(p.name for p in scene.poses)})")
        cal = replace(cal, reference=reference)
        scene = replace(scene, calibration=cal)
    results_path = Path(split_design_spec(args.design)[0])
    if results_path.is_dir():       # an `mscap optimize` directory: write inside it
        default_cache, default_out = results_path / "calibration.h5", results_path / "calibration"
    else:
        stem = results_path.with_suffix("")
        default_cache, default_out = Path(f"{stem}_calibration.h5"), Path(f"{stem}_calibration")
    cache = Path(args.cache or default_cache)
    outdir = Path(args.output or default_out)
    designs = designs_from(scene, args.design, args.baseline)
    say = progress_printer(args.quiet or rank > 0)
    simulate_family(scene, designs, cache, comm, progress=say)
    if rank != 0:
        return 0
    noise = cal.noise
    overrides = {"runs": args.runs, "seed": args.seed, "relative_shift": args.relative_shift,
                 "additive_pF": args.additive_pF}
    noise = replace(noise, **{k: v for k, v in overrides.items() if v is not None})
    scores = evaluate(scene, designs, cache, noise)
    write_outputs(outdir, scene, scores, noise)
    unit = "mm" if cal.target == "vertices" else "(parameter units)"
    print(f"{'design':<34} {'k':>2} {'mean error':>16} {'max error':>16}  {unit}, mean ± std over "
          f"{noise.runs} runs, averaged over {len(cal.sequence)} sequence poses")
    for s in scores:
        m = s.errors.summary()
        print(f"{s.design.label:<34} {s.design.k:>2} {np.nanmean(m['mean_error']):>8.3f} ± "
              f"{np.nanmean(m['mean_error_std']):<6.3f} {np.nanmean(m['max_error']):>8.3f} ± "
              f"{np.nanmean(m['max_error_std']):<6.3f}")
    print(f"{'no signal (mean training pose)':<34} {'':>2} {np.mean(scores[0].no_signal):>8.3f}")
    print(f"wrote {outdir}/errors.csv, summary.json, errors.png")
    return 0


def write_outputs(outdir: Path, scene, scores, noise) -> None:
    """``errors.csv`` (one row per design and sequence pose), ``summary.json`` and the
    ``errors.png`` figure (the paper's Fig. 15)."""
    cal = scene.calibration
    outdir.mkdir(parents=True, exist_ok=True)
    with open(outdir / "errors.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["design", "k", "pose", *cal.parameters, "in_training_range", "mean_error",
                    "mean_error_std", "max_error", "max_error_std", "no_signal_mean_error"])
        for s in scores:
            m = s.errors.summary()
            for i, row in enumerate(cal.sequence):
                w.writerow([s.design.label, s.design.k, i, *[f"{x:.6g}" for x in row], int(cal.in_range[i]),
                            *[f"{m[c][i]:.6g}" for c in ("mean_error", "mean_error_std", "max_error",
                                                           "max_error_std")], f"{s.no_signal[i]:.6g}"])
    summary = {"scene": scene.name, "target": cal.target, "reference_pose": cal.reference,
               "kernel": cal.kernel, "smoothing": cal.smoothing,
               "noise": {"relative_shift": noise.relative_shift, "additive_pF": noise.additive_pF,
                         "runs": noise.runs, "seed": noise.seed},
               "training_poses": len(cal.training), "sequence_poses": len(cal.sequence),
               "out_of_range_poses": int((~cal.in_range).sum()), "designs": []}
    for s in scores:
        m = s.errors.summary()
        summary["designs"].append({
            "label": s.design.label, "k": s.design.k, "training_used": s.training_used,
            "training_failed": s.training_failed, "rbf_samples": s.samples,
            "sequence_failed": s.sequence_failed, "simulation_s": s.simulation_s,
            "mean_error": float(np.nanmean(m["mean_error"])), "mean_error_std": float(np.nanmean(m["mean_error_std"])),
            "max_error": float(np.nanmean(m["max_error"])), "max_error_std": float(np.nanmean(m["max_error_std"])),
            "no_signal_mean_error": float(np.nanmean(s.no_signal)),
            "mean_error_in_range": float(np.nanmean(m["mean_error"][cal.in_range])),
            "mean_error_out_of_range": (float(np.nanmean(m["mean_error"][~cal.in_range]))
                                        if (~cal.in_range).any() else None)})
    (outdir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    figure(outdir / "errors.png", scene, scores)


def figure(path: Path, scene, scores) -> None:
    """Mean and max error per sequence pose, mean ± std over runs, one line per design;
    out-of-distribution poses shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cal = scene.calibration
    unit = "mm" if cal.target == "vertices" else "parameter units"
    x = np.arange(len(cal.sequence))
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharex=True)
    for ax, key, title in ((axes[0], "mean_error", "mean per-vertex error"),
                           (axes[1], "max_error", "max per-vertex error")):
        for i in np.flatnonzero(~cal.in_range):
            ax.axvspan(i - 0.5, i + 0.5, color="0.9", lw=0)
        for s in scores:
            m = s.errors.summary()
            line, = ax.plot(x, m[key], lw=1.5, label=f"{s.design.label} (k={s.design.k})")
            low = np.maximum(m[key] - m[key + "_std"], 0.1 * m[key])  # log axis: keep the band > 0
            ax.fill_between(x, low, m[key] + m[key + "_std"], color=line.get_color(), alpha=0.2, lw=0)
        if key == "mean_error" and scores:
            ax.plot(x, scores[0].no_signal, "k:", lw=1, label="no signal (mean training pose)")
        ax.set_title(title if cal.target == "vertices" else title.replace("vertex", "parameter"))
        ax.set_xlabel("sequence pose (grey: outside the training ranges)")
        ax.set_ylabel(f"{unit}, log scale")
        ax.set_yscale("log")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{scene.name}: reconstruction error, mean ± std over {scores[0].errors.mean.shape[0]} "
                 "noisy runs" if scores else scene.name)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
