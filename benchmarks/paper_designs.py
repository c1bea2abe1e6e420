"""Do the poking scenes' chosen designs change when the sheet is held all around?

Takes the results files of ``mscap run`` on a poking scene held at the x ends (the shipped
scenes until 2026-12-06) and held at all four edges (since), and prints for each: the best
min L1 per k, the chosen run, its plates' areas and rest capacitances (the paper reports
the poking-cross design's rest values), and every chosen design's min L1 under *both*
holdings (the metric a design optimised for one holding keeps under the other: what a
wrong guess of the setup costs the sensor). Run after the two multi-starts (the scene
files are those the runs stored)::

    .venv/bin/python benchmarks/paper_designs.py x=cross_x.h5 all=cross_all.h5

Prints a Markdown table.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mscap.design.history import min_pairwise_l1  # noqa: E402
from mscap.fem.simulate import simulate  # noqa: E402
from mscap.geometry.layout import Layout  # noqa: E402
from mscap.geometry.polygons import signed_area  # noqa: E402
from mscap.scene import load_scene  # noqa: E402
from mscap.scene.poses import FreePose  # noqa: E402
from mscap.scene.sizing import sheet_for  # noqa: E402
from mscap.service.store import read_run, read_store, run_summaries, store_selection  # noqa: E402


def chosen(path: str):
    """(scene, chosen run record, best metric per k) of a results file."""
    with read_store(path) as store:
        scene = load_scene(path + ".scene.toml", source=str(store.attrs["scene_toml"]))
        selection = store_selection(store)
        best = {}
        for s in run_summaries(store):
            if s.ok and (s.k not in best or s.metric > best[s.k]):
                best[s.k] = s.metric
        return scene, read_run(store, selection.chosen_run), best


def readings(scene, outlines, rest: bool = False) -> np.ndarray:
    sheet = sheet_for(scene, Layout(tuple(outlines)))
    poses = (FreePose(name="rest"),) if rest else scene.poses
    return simulate(scene, sheet=sheet, poses=poses).capacitance_pF


def main(argv: list[str]) -> int:
    runs = dict(arg.split("=", 1) for arg in argv)
    loaded = {label: chosen(path) for label, path in runs.items()}
    print("| held | best min L1 per k (pF) | chosen run | plate areas (mm²) | rest C (pF) | "
          + " | ".join(f"min L1 held {other} (pF)" for other in loaded) + " |")
    print("|---|---|---|---|---|" + "---|" * len(loaded))
    for label, (scene, record, best) in loaded.items():
        outlines = record.final_outlines
        areas = [abs(signed_area(o)) for o in outlines]
        rest = readings(scene, outlines, rest=True)[0]
        under = [min_pairwise_l1(readings(other_scene, outlines)) for other_scene, _, _ in loaded.values()]
        print(f"| {label} | {', '.join(f'k={k}: {m:.2f}' for k, m in sorted(best.items()))} | {record.id} | "
              f"{', '.join(f'{a:.0f}' for a in areas)} | {', '.join(f'{c:.1f}' for c in rest)} | "
              + " | ".join(f"{m:.2f}" for m in under) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
