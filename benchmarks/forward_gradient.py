"""Forward, gradient and optimisation-iteration cost per scene, split by kind of work.

For each scene, in a process of its own (one core, ``OMP_NUM_THREADS=1``; peak memory
per scene):

1. **cold forward**: ``mscap.fem.simulate.simulate`` — meshing, every pose along its full
   load path, the electrostatics; what ``mscap simulate`` costs;
2. **design set-up**: ``build_design`` (meshes, skinning weights of the controls);
3. **evaluation** at the initial layout: every pose from rest (full load path) on the
   design's mesh, J and C;
4. **gradient** at that evaluation: the adjoints (one back-substitution per pose with
   the kept factorisation) and the vector-Jacobian products;
5. **warm evaluation + gradient** at a design moved 0.1 mm along −∇J, each pose
   warm-started from the previous equilibrium (since 2026-12-05 first as modified Newton
   on its kept factorised Hessian, as the optimiser does): what one optimiser step costs
   when its first trial is accepted;
6. **optimisation**: ``--iterations`` accepted L-BFGS steps from the scene's layout,
   time per accepted step (line-search trials included), in a process of its own: its
   peak memory is what a multi-start worker needs (the finer-mesh check at the end of a
   run excepted: benchmarks/scaling.py has memory against mesh size).

Each stage's wall time is split with :mod:`mscap.profile` into meshing, assembly,
factorisation, solve and other (Python and numpy outside the kernels). The issue's
targets: gradient ≤ 1.5× the evaluation; a warm iteration ≥ 5× cheaper than a cold
forward; ≤ 2 GB per process. The time inside the elastic Newton solves (PETSc's
``Newton`` event) is recorded per stage as well: the cold forward over the warm step
*without* it is the ratio that no warm start of the elastics could exceed, since the
electrostatics and the gradient of every design pose are the same work warm or cold.

Run (paper-resolution scenes, about 20 minutes on one core; ``--quick`` uses the
``*_quick`` scenes and takes about 3 minutes)::

    .venv/bin/python benchmarks/forward_gradient.py [--quick] [SCENE ...] [--iterations 5]

Writes ``docs/forward_gradient.csv`` and ``.png`` (``docs/forward_gradient_quick.*``)
and prints the tables; ``--replot`` redraws the PNG from the CSV.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):  # one core per process
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENES = ["poking", "poking_cross", "biaxial", "pneumatic", "joystick", "wrist", "glove"]
STAGES = ["cold_forward", "setup", "evaluation", "gradient", "warm_evaluation", "warm_gradient"]
KINDS = ["meshing", "assembly", "factorisation", "solve", "other", "total"]


def _newton_s() -> float:
    """Seconds spent so far in the elastic load paths and Newton solves (the PETSc event
    ``Newton`` of :func:`mscap.fem.elastic.newton.solve_pose`, in its own stage)."""
    from mscap.fem.petsc import petsc

    PETSc = petsc()
    stage = PETSc.Log.Stage("Newton")  # the stage mscap.profile.phase registers
    event = PETSc.Log.Event("Newton", PETSc.Log.Class("mscap"))
    return float(event.getPerfInfo(stage.id)["time"])


def _timed(stage: str, out: dict, function, *args, **kwargs):
    """Run ``function``, store its split under ``stage`` in ``out``, return its value;
    ``newton`` is the part of it spent in the elastic Newton solves."""
    from mscap import profile

    profile.reset()
    newton = _newton_s()
    start = time.perf_counter()
    value = function(*args, **kwargs)
    out[stage] = {k: round(v, 4) for k, v in profile.split(time.perf_counter() - start).items()}
    out[stage]["newton"] = round(_newton_s() - newton, 4)
    return value


def measure(path: Path) -> dict:
    """Every stage of the module docstring for the scene file ``path``."""
    import numpy as np

    from mscap.design.pipeline import build_design
    from mscap.scene import load_scene
    from mscap.fem.petsc import petsc
    from mscap.fem.simulate import simulate

    petsc().Log.begin()  # PETSc's event times (the Newton share of each stage)
    scene = load_scene(path)
    out: dict = {"scene": scene.name, "poses": len(scene.poses)}
    sim = _timed("cold_forward", out, simulate, scene)
    out["tets"] = int(len(sim.mesh.tets))
    out["elastic_tets"] = 0 if sim.elastic is None else int(len(sim.elastic.mesh.tets))
    design = _timed("setup", out, build_design, scene)
    q0 = design.deformer.zeros()
    e0 = _timed("evaluation", out, design.evaluate, q0)
    g0 = _timed("gradient", out, design.gradient, e0)
    step = -0.1 * g0 / np.max(np.linalg.norm(g0, axis=1))  # the largest control moves 0.1 mm
    e0.release(keep_elastic=True)  # as the optimiser keeps it: the trial starts on its Hessians
    e1 = _timed("warm_evaluation", out, design.evaluate, q0 + step, warm=e0)
    e0.release()
    _timed("warm_gradient", out, design.gradient, e1)
    e1.release()
    out["newton_cold"] = int(sum(e0.newton_iterations))
    out["newton_warm"] = int(sum(e1.newton_iterations))
    out["peak_rss_MB"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    return out


def measure_optimisation(path: Path, iterations: int) -> dict:
    """``iterations`` accepted steps from the scene's layout, in a process of its own so
    that its peak memory is what one multi-start worker needs for this scene."""
    from mscap.design.pipeline import build_design
    from mscap.design.optimizer import optimize
    from mscap.scene import load_scene

    scene = load_scene(path)
    start = time.perf_counter()
    result = optimize(build_design(scene), max_iterations=iterations, cascade_levels=0)
    wall = time.perf_counter() - start
    return {"iterations": result.iterations, "wall_s": round(wall, 2),
            "evaluations": int(sum(r.evaluations for r in result.history)),
            "per_iteration_s": round(wall / max(result.iterations, 1), 3),
            "min_l1_initial_pF": round(result.initial.min_l1_pF, 4),
            "min_l1_final_pF": round(result.evaluation.min_l1_pF, 4),
            "peak_rss_MB": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)}


def run_child(path: Path, iterations: int, part: str) -> dict:
    command = [sys.executable, __file__, f"--child-{part}", str(path), "--iterations", str(iterations)]
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
    if done.returncode:
        sys.exit(f"{path.name}: failed\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def rows_of(result: dict) -> dict:
    """The flat CSV row of one scene."""
    row = {key: result[key] for key in ("scene", "poses", "tets", "elastic_tets", "newton_cold", "newton_warm",
                                        "peak_rss_MB")}
    for stage in STAGES:
        for kind in KINDS:
            row[f"{stage}_{kind}_s"] = result[stage][kind]
    ev, gr = result["evaluation"]["total"], result["gradient"]["total"]
    warm = result["warm_evaluation"]["total"] + result["warm_gradient"]["total"]
    row["gradient_over_evaluation"] = round(gr / ev, 3)
    row["cold_forward_over_warm_iteration"] = round(result["cold_forward"]["total"] / warm, 2)
    # What no warm start of the elastics can beat: the warm step with its Newton solves
    # taken as free (the electrostatics and the gradient of every design pose remain).
    newton = result["warm_evaluation"]["newton"] + result["warm_gradient"]["newton"]
    row["warm_newton_s"] = round(newton, 4)
    row["cold_forward_newton_s"] = result["cold_forward"]["newton"]
    row["ceiling_without_newton"] = round(result["cold_forward"]["total"] / (warm - newton), 2)
    for key, value in result.get("optimisation", {}).items():
        row[f"opt_{key}"] = value
    return row


def print_tables(rows: list[dict]) -> None:
    print("\n| scene | poses | tets (electro / elastic) | cold forward | evaluation | gradient | grad / eval | "
          "warm eval + grad (Newton) | cold / warm | the same, Newton free | peak memory (stages) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        warm = r["warm_evaluation_total_s"] + r["warm_gradient_total_s"]
        print(f"| {r['scene']} | {r['poses']} | {r['tets']:,} / {r['elastic_tets']:,} | "
              f"{r['cold_forward_total_s']:.2f} s | {r['evaluation_total_s']:.2f} s | {r['gradient_total_s']:.2f} s | "
              f"{r['gradient_over_evaluation']:.2f} | {warm:.2f} s ({float(r['warm_newton_s']):.2f} s) | "
              f"{r['cold_forward_over_warm_iteration']:.1f} | {float(r['ceiling_without_newton']):.1f} | "
              f"{r['peak_rss_MB']:.0f} MB |")
    print("\nShares of each stage (meshing / assembly / factorisation / solve / other):\n")
    print("| scene | " + " | ".join(STAGES) + " |")
    print("|---|" + "---|" * len(STAGES))
    for r in rows:
        cells = []
        for stage in STAGES:
            total = r[f"{stage}_total_s"]
            cells.append(" / ".join(f"{100 * r[f'{stage}_{k}_s'] / total:.0f}" for k in KINDS[:-1]))
        print(f"| {r['scene']} | " + " | ".join(cells) + " |")
    if any("opt_iterations" in r for r in rows):
        print("\n| scene | accepted steps | evaluations | wall | per step | min L1 initial → final (pF) | peak memory |")
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            if "opt_iterations" in r:
                print(f"| {r['scene']} | {r['opt_iterations']} | {r['opt_evaluations']} | {r['opt_wall_s']:.1f} s | "
                      f"{r['opt_per_iteration_s']:.2f} s | {r['opt_min_l1_initial_pF']} → {r['opt_min_l1_final_pF']} | "
                      f"{r['opt_peak_rss_MB']:.0f} MB |")


def plot(rows: list[dict], path: Path) -> None:
    """Stacked bars per scene: each stage's time split by kind of work."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    stages = ["cold_forward", "evaluation", "gradient", "warm_evaluation", "warm_gradient"]
    labels = ["cold forward", "evaluation", "gradient", "warm evaluation", "warm gradient"]
    colours = ["#4daf4a", "#377eb8", "#e41a1c", "#984ea3", "#999999"]
    fig, axes = plt.subplots(1, len(rows), figsize=(2.6 * len(rows), 3.6), sharey=False)
    for ax, row in zip(np.atleast_1d(axes), rows):
        bottom = np.zeros(len(stages))
        for kind, colour in zip(KINDS[:-1], colours):
            values = np.array([float(row[f"{stage}_{kind}_s"]) for stage in stages])
            ax.bar(range(len(stages)), values, bottom=bottom, color=colour, label=kind)
            bottom += values
        ax.set_title(f"{row['scene']}\ngrad/eval {float(row['gradient_over_evaluation']):.2f}, "
                     f"cold/warm {float(row['cold_forward_over_warm_iteration']):.1f}", fontsize=8)
        ax.set_xticks(range(len(stages)), labels, rotation=60, ha="right", fontsize=7)
        ax.tick_params(axis="y", labelsize=7)
        ax.grid(axis="y", alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("wall time on one core (s)")
    handles, names = np.atleast_1d(axes)[0].get_legend_handles_labels()
    fig.legend(handles, names, loc="lower center", ncol=len(names), fontsize=8, frameon=False)  # below the bars
    fig.suptitle("forward, gradient and a warm optimiser step per scene, split by kind of work", fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", default=SCENES, help=f"scene names or scene files (default: {' '.join(SCENES)})")
    parser.add_argument("--quick", action="store_true", help="the *_quick scenes")
    parser.add_argument("--iterations", type=int, default=5, help="accepted optimiser steps to time (0: none)")
    parser.add_argument("--csv", help="output CSV (default docs/forward_gradient[_quick].csv)")
    parser.add_argument("--replot", action="store_true", help="only redraw the PNG from the CSV")
    parser.add_argument("--child-stages", help=argparse.SUPPRESS)
    parser.add_argument("--child-optimisation", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child_stages:
        print(json.dumps(measure(Path(args.child_stages))))
        return
    if args.child_optimisation:
        print(json.dumps(measure_optimisation(Path(args.child_optimisation), args.iterations)))
        return
    table = Path(args.csv or ROOT / "docs" / f"forward_gradient{'_quick' if args.quick else ''}.csv")
    if args.replot:
        with open(table) as f:
            plot(list(csv.DictReader(f)), table.with_suffix(".png"))
        return
    rows = []
    for name in args.scenes:
        path = Path(name) if name.endswith(".toml") else ROOT / "jobs" / f"{name}{'_quick' if args.quick else ''}.toml"
        print(f"{path.name} ...", flush=True)
        result = run_child(path, args.iterations, "stages")
        if args.iterations:
            result["optimisation"] = run_child(path, args.iterations, "optimisation")
        rows.append(rows_of(result))
        print(json.dumps(rows[-1]), flush=True)
    fields = list(dict.fromkeys(key for row in rows for key in row))
    with open(table, "w", newline="") as f:
        writer = csv.DictWriter(f, fields)
        writer.writeheader()
        writer.writerows(rows)
    print_tables(rows)
    plot(rows, table.with_suffix(".png"))
    print(f"\nwrote {table} and {table.with_suffix('.png')}")


if __name__ == "__main__":
    main()
