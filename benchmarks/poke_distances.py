"""A poked scene's pose-to-pose distances against a P2 Richardson reference of its own.

What the optimiser and the k choice read are the L1 distances between the poses'
capacitance vectors. benchmarks/poke_signal.py measures jobs/poking.toml's gains against
the P2 reference of docs/electrostatics.md; a scene without that reference (poking_cross:
four pokes between the plates, no rest pose) gets one here, the same way. On the scene's
own electrostatic mesh, uniform P2 elasticity at 5, 3.54 and 2.5 mm (no refinement)
gives three capacitance tables. Each entry is extrapolated (Richardson, ratio √2) at the
median observed order over the entries, clipped to [0.5, 4] (poking: 1.2). Then the
scene as shipped and its variants are compared with the reference, distance by distance:
the worst relative error and the error of the smallest distance (the min-L1 metric); and
with the finest level itself (P2 at 2.5 mm), which does not lean on the extrapolation.

Run (about 20 minutes on one core for poking_cross)::

    .venv/bin/python benchmarks/poke_distances.py jobs/poking_cross.toml

A variant is a JSON object of MeshSettings / ElasticSettings fields, as in poke_signal.py
(``{}``: the scene as it is; ``"hand_set": true``: poke_signal's hand-set P1 meshes).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import table_head  # noqa: E402
from benchmarks.poke_signal import hand_set_scene, run  # noqa: E402
from mscap.design.history import pairwise_l1  # noqa: E402
from mscap.fem.petsc import petsc  # noqa: E402
from mscap.scene import load_scene  # noqa: E402
from mscap.service.accuracy import relative_difference  # noqa: E402

#: The reference ladder: uniform P2 elastic edges (mm), refined by √2 each.
LADDER = (5.0, 5.0 / math.sqrt(2.0), 2.5)
#: The variants compared with the reference by default.
VARIANTS = [{"label": "as shipped"}, {"label": "hand-set P1 meshes", "hand_set": True}]


def richardson(tables: list[np.ndarray], ratio: float = math.sqrt(2.0)) -> tuple[np.ndarray, float]:
    """The entrywise extrapolation of three tables (coarse to fine) at the median observed
    order of the entries that change monotonically, and that order."""
    c1, c2, c3 = tables
    d1, d2 = c1 - c2, c2 - c3
    ok = (d1 * d2 > 0) & (np.abs(d2) > 1e-12 * np.abs(c3))
    orders = np.log(d1[ok] / d2[ok]) / math.log(ratio)
    p = float(np.clip(np.median(orders), 0.5, 4.0)) if orders.size else 1.0
    return c3 + (c3 - c2) / (ratio ** p - 1.0), p


def errors(c: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Worst relative error of a pose-to-pose L1 distance, and of the smallest one."""
    d, d_ref = pairwise_l1(c), pairwise_l1(reference)
    return relative_difference(d, d_ref), float(d.min() / d_ref.min() - 1)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene", nargs="?", default=str(ROOT / "jobs" / "poking_cross.toml"))
    parser.add_argument("variants", nargs="?", help="JSON list of variants (default: as shipped, hand-set P1)")
    args = parser.parse_args(argv)
    petsc()
    path = Path(args.scene)
    scene = load_scene(path)
    variants = json.loads(args.variants) if args.variants else VARIANTS
    rows, tables = [], []
    for edge in LADDER:
        variant = {"label": f"P2 {edge:.2f} mm uniform", "elastic": {"order": 2, "edge_length_mm": edge,
                                                                      "refine_pokes": False}}
        c, wall, _, nodes = run(scene, variant)
        tables.append(c)
        rows.append((variant["label"], c, wall, nodes))
        print(f"{variant['label']}: {nodes:,} elastic nodes, {wall:.1f} s", flush=True)
    reference, order = richardson(tables)
    print(f"reference: Richardson at observed order {order:.2f}; distances {np.round(pairwise_l1(reference), 4)} pF, "
          f"smallest {pairwise_l1(reference).min():.4f} pF", flush=True)
    for variant in variants:
        chosen = load_scene(hand_set_scene(path)) if variant.get("hand_set") else scene
        c, wall, _, nodes = run(chosen, variant)
        rows.append((variant.get("label", json.dumps(variant)), c, wall, nodes))
    print()
    print("\n".join(table_head("| elastic | elastic nodes | wall | worst distance error | smallest distance "
                                "(error) | against P2 2.5 mm: worst / smallest |")))
    for label, c, wall, nodes in rows:
        worst, metric = errors(c, reference)
        finest = errors(c, tables[-1])
        print(f"| {label} | {nodes:,} | {wall:.1f} s | {100 * worst:.2f} % | "
              f"{pairwise_l1(c).min():.4f} pF ({100 * metric:+.2f} %) | "
              f"{100 * finest[0]:.2f} % / {100 * finest[1]:+.2f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
