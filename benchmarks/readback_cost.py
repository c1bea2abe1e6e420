"""Cost of an optimiser step designing for read-back against the paper's objective, in one
process, on the same layout (the scene's), so that the ratio is free of machine noise.

For each calibrated quick scene: the design built from its scene file as it is (the
read-back bound on the family's design poses) and with ``distance = "pF"`` on the listed
poses (the paper's objective); per variant a cold evaluation, then ``--reps`` warm
evaluations + gradients (what an accepted L-BFGS step costs at least), median wall time.

    .venv/bin/python benchmarks/readback_cost.py [SCENE ...] [--reps 3]

Writes ``docs/readback_cost.csv`` and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENES = ["pneumatic", "joystick", "wrist", "glove"]
FIELDS = ["scene", "listed_poses", "design_poses", "pF_step_s", "readback_step_s", "ratio"]


def step_time(scene, reps: int) -> tuple[int, float]:
    """Design poses and the median wall time (s) of a warm evaluation + gradient."""
    import numpy as np

    from mscap.design.pipeline import build_design

    design = build_design(scene)
    rng = np.random.default_rng(0)
    q = design.deformer.zeros()
    previous = design.evaluate(q)
    times = []
    for _ in range(reps):
        q = q + 0.02 * rng.uniform(-1, 1, q.shape)  # a small step, as an accepted one
        start = time.perf_counter()
        e = design.evaluate(q, warm=previous)
        design.gradient(e)
        times.append(time.perf_counter() - start)
        previous.release()
        previous = e
    previous.release()
    return len(design.scene.poses), statistics.median(times)


def main() -> None:
    from mscap.scene import load_scene

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", default=SCENES)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--csv", default=str(ROOT / "docs" / "readback_cost.csv"))
    args = parser.parse_args()
    rows = []
    for name in args.scenes:
        scene = load_scene(ROOT / "jobs" / f"{name}_quick.toml")
        paper = replace(scene, optimizer=replace(scene.optimizer, distance="pF", design_poses="listed"))
        n_listed, t_paper = step_time(paper, args.reps)
        n_design, t_readback = step_time(scene, args.reps)
        rows.append({"scene": f"{name}_quick", "listed_poses": n_listed, "design_poses": n_design,
                     "pF_step_s": round(t_paper, 2), "readback_step_s": round(t_readback, 2),
                     "ratio": round(t_readback / t_paper, 2)})
        print(rows[-1], flush=True)
    with open(args.csv, "w", newline="") as f:
        writer = csv.DictWriter(f, FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    print("| scene | listed poses | design poses | warm step, pF (s) | warm step, read-back (s) | ratio |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['listed_poses']} | {r['design_poses']} | {r['pF_step_s']} | "
              f"{r['readback_step_s']} | {r['ratio']} |")


if __name__ == "__main__":
    main()
