"""What P1 elasticity costs the glued paper scenes' signal: P1 against P2 on the same meshes.

A thin stack bent over a body is where linear tets lock (docs/elastic.md, "Pokes and bends":
benchmarks/scenes/glue_bend.toml's cylinder, −6.9 % at ν = 0.47 on a 5 mm P1 mesh). The
glued paper scenes (pneumatic, joystick, wrist, glove) set P1 with their own, finer elastic
meshes. This reads the levels benchmarks/scene_accuracy.py stored with their capacitance
tables (``docs/scene_accuracy_levels.json``: every edge scaled by a factor, at both elastic
orders for the factors 1 and 1.41) and compares, at each factor, P1 elasticity with P2
elasticity on the same electrostatic and elastic meshes: the worst and the median relative
difference of a pose-to-pose L1 distance (what the optimiser and the k choice read), the
difference of the smallest one (the min-L1 metric) and the walls. Seconds, no simulation::

    .venv/bin/python benchmarks/glued_element.py

Prints the table of docs/elastic.md ("The glued paper scenes stay P1").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import table_head  # noqa: E402
from benchmarks.scene_accuracy import VARIANT_FACTORS, Level, _key, load_levels  # noqa: E402
from mscap.design.history import pairwise_l1  # noqa: E402

SCENES = ("pneumatic", "joystick", "wrist", "glove")


def compare(levels: dict, scene: str, factor: float) -> dict | None:
    """P1 against P2 elasticity (P1 electrostatics) at one edge factor, or ``None`` if
    either level is missing."""
    p1, p2 = (levels.get(_key(scene, Level(factor, 1, order))) for order in (1, 2))
    if p1 is None or p2 is None:
        return None
    d1, d2 = (pairwise_l1(np.array(level["capacitance_pF"])) for level in (p1, p2))
    signal = np.abs(d1 - d2) / d2
    return {"scene": scene, "factor": factor, "signal_max": float(signal.max()),
            "signal_median": float(np.median(signal)), "metric": float(d1.min() / d2.min() - 1),
            "elastic_tets": p1["elastic_tets"], "wall_p1_s": p1["wall_s"], "wall_p2_s": p2["wall_s"]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--levels", default=str(ROOT / "docs" / "scene_accuracy_levels.json"),
                        help="levels stored by benchmarks/scene_accuracy.py")
    args = parser.parse_args(argv)
    levels = load_levels(Path(args.levels))
    rows = [row for scene in SCENES for factor in sorted(VARIANT_FACTORS)
            if (row := compare(levels, scene, factor))]
    if not rows:
        print(f"{args.levels}: no level has both elastic orders; run benchmarks/scene_accuracy.py", file=sys.stderr)
        return 1
    print("\n".join(table_head("| scene | edges | elastic tets | signal P1 vs P2: worst / median | metric | "
                                "wall P1 / P2 |")))
    for r in rows:
        edges = "★" if r["factor"] == 1 else f"×{r['factor']:.2f}"
        print(f"| {r['scene']} | {edges} | {r['elastic_tets']:,} | {100 * r['signal_max']:.2f} % / "
              f"{100 * r['signal_median']:.2f} % | {100 * r['metric']:+.2f} % | "
              f"{r['wall_p1_s']:.1f} / {r['wall_p2_s']:.1f} s ({r['wall_p2_s'] / r['wall_p1_s']:.1f}×) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
