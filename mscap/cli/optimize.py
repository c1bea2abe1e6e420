"""``mscap optimize SCENE --k K --seed S --init random|lloyd|scene -o DIR``: one start of
the layout optimisation (paper §5.1)."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from mscap.cli.common import load_scene_for, progress_printer


def add_parser(sub) -> None:
    p = sub.add_parser("optimize", help="optimise the capacitor layout of a scene (one start)",
                       description="Optimise the capacitor outlines so that the poses' capacitance "
                                   "vectors lie far apart (L-BFGS on the layout, remeshing, control "
                                   "cascade). Writes the outlines, the capacitance table, the history, "
                                   "summary.json and a before/after figure to DIR; progress per "
                                   "iteration on stderr.")
    p.add_argument("scene", help="scene file (jobs/*.toml)")
    p.add_argument("--k", type=int, help="number of capacitors (random and lloyd starts)")
    p.add_argument("--seed", type=int, default=0, help="seed of the initial layout (default 0)")
    p.add_argument("--init", choices=("random", "lloyd", "scene"), default="scene",
                   help="initial layout: seeded random squares, squares at Lloyd centroids, or "
                        "the scene's own layout (default)")
    p.add_argument("--max-iterations", type=int, help="per cascade level (default: the scene's)")
    p.add_argument("--cascade", type=int, help="control-doubling levels (default: the scene's)")
    p.add_argument("-o", "--output", metavar="DIR", required=True, help="output directory")
    p.add_argument("--no-figure", action="store_true", help="skip the before/after figure")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.design.pipeline import build_design
    from mscap.geometry.initial import initial_layout
    from mscap.design.optimizer import HISTORY_FIELDS, optimize

    from mscap.design.readback import ReconstructionBound, design_scene

    scene = design_scene(load_scene_for(args))  # the design poses: listed, or from the family
    say = progress_printer(args.quiet) or (lambda message: None)
    layout = initial_layout(scene, args.k, args.seed, args.init)
    say(f"{scene.name}: k = {layout.k}, seed {args.seed}, init {args.init}, {len(scene.poses)} design poses")
    design = build_design(replace(scene, layout=layout))
    result = optimize(design, progress=say, max_iterations=args.max_iterations, cascade_levels=args.cascade)

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    final = result.layout
    bound = None if scene.design_family is None else ReconstructionBound(scene.design_family, scene.optimizer.tau_mm)
    poses = [p.name for p in scene.poses]
    (out / "outlines.json").write_text(json.dumps(
        {"scene": scene.path, "min_gap_mm": scene.min_gap_mm,
         "outlines_mm": [np.round(o, 6).tolist() for o in final.outlines]}))
    with open(out / "capacitance.csv", "w", newline="") as f:
        writer = csv.writer(f)
        k = final.k
        writer.writerow(["pose", "stage"] + [f"C{j}_pF" for j in range(k)])
        for stage, e in (("initial", result.initial), ("final", result.evaluation)):
            for name, row in zip(poses, e.capacitance_pF):
                writer.writerow([name, stage] + [f"{c:.6f}" for c in row])
    with open(out / "history.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(HISTORY_FIELDS)
        writer.writerows(r.row() for r in result.history)
    summary = {"scene": scene.path, "k": layout.k, "seed": args.seed, "init": args.init,
               "iterations": result.iterations, "reason": result.reason, "time_s": result.time_s,
               "initial_min_l1_pF": result.initial.min_l1_pF, "final_min_l1_pF": result.evaluation.min_l1_pF,
               "initial_J": result.initial.J, "final_J": result.evaluation.J,
               "remeshes": sum(r.event == "remesh" for r in result.history),
               **({} if bound is None else {"initial_bound_mm": bound.value(result.initial.capacitance_pF),
                                            "final_bound_mm": bound.value(result.evaluation.capacitance_pF)}),
               "poses": poses,
               "capacitance_pF": {name: row.tolist()
                                  for name, row in zip(poses, result.evaluation.capacitance_pF)},
               "initial_capacitance_pF": {name: row.tolist()
                                          for name, row in zip(poses, result.initial.capacitance_pF)}}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    files = ["outlines.json", "capacitance.csv", "history.csv", "summary.json"]
    if not args.no_figure:
        figure(out / "layout.png", scene, layout, final, result.initial.capacitance_pF,
               result.evaluation.capacitance_pF, poses)
        files.append("layout.png")
    print(f"{scene.name}: {result.iterations} iterations ({result.reason}) in {result.time_s:.1f} s; "
          f"min pairwise L1 {result.initial.min_l1_pF:.4g} → {result.evaluation.min_l1_pF:.4g} pF"
          + (f"; read-back bound {summary['initial_bound_mm']:.4g} → {summary['final_bound_mm']:.4g} mm"
             if "final_bound_mm" in summary else ""))
    print("wrote " + ", ".join(str(out / f) for f in files))
    return 0


def figure(path: Path, scene, before, after, c_before: np.ndarray, c_after: np.ndarray, poses) -> None:
    """Layouts before and after (with the poke centres) and per-pose capacitance bars
    (change from the layout's mean over poses, pF), as the paper's Fig. 9."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mscap.design.pipeline import min_pairwise_l1
    from mscap.cli.plot import draw_layout

    fig, axes = plt.subplots(2, 2, figsize=(10, 8.5))
    colours = plt.get_cmap("tab10")
    for col, (title, layout, caps) in enumerate((("initial", before, c_before), ("optimised", after, c_after))):
        ax = axes[0, col]
        draw_layout(ax, scene.sheet_outline_mm, layout.outlines, colours, fontsize=10)
        for p in scene.poses:
            if p.kind == "poke":
                ax.add_patch(plt.Circle(p.center_mm, p.radius_mm, fill=False, ls="--", color="k", lw=0.8))
                ax.text(*p.center_mm, p.name, fontsize=7, ha="center", va="center")
        ax.set_title(f"{title} layout")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax = axes[1, col]
        n, k = caps.shape
        width = 0.8 / k
        delta = caps - caps.mean(axis=0)
        for j in range(k):
            ax.bar(np.arange(n) + (j - 0.5 * (k - 1)) * width, delta[:, j], width, color=colours(j % 10),
                   label=f"C{j}")
        if n > 10 or max(len(p) for p in poses) > 24:  # family grid poses: numbered, named in summary.json
            ax.set_xticks(np.arange(n), [str(i) for i in range(n)], fontsize=7)
            ax.set_xlabel("design pose (the order of summary.json \"poses\")", fontsize=8)
        else:
            ax.set_xticks(np.arange(n), poses, rotation=20, fontsize=8)
        ax.axhline(0, color="0.5", lw=0.5)
        l1 = min_pairwise_l1(caps)
        ax.set_title(f"{title}: C − mean over poses (min pairwise L1 {l1:.3g} pF)", fontsize=9)
        ax.set_ylabel("ΔC (pF)")
        ax.legend(fontsize=7)
    lo = min(a.get_ylim()[0] for a in axes[1])
    hi = max(a.get_ylim()[1] for a in axes[1])
    for a in axes[1]:
        a.set_ylim(lo, hi)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
