"""The pose-to-pose signal of jobs/poking.toml against its meshes.

The objective and the k choice read differences of capacitances between poses, not C.
On the poking sensor (a 2 × 2 array of 18 mm plates, a 10 mm ball pressed 13 mm deep at
each plate's centre in turn) the four pressed gains C_j(poke_j) − C_j(rest) are equal by
symmetry, and so are the neighbour gains of each kind; their spread is a mesh error the
symmetry makes visible. Each variant replaces some ``[mesh]``/``[elastic]`` settings of
the scene (JSON objects of MeshSettings / ElasticSettings fields), simulates every pose
and prints the rest capacitances, the pressed gains and their spread, the gain matrix
and the wall time.

Run (the variants of docs/electrostatics.md, "The pose-to-pose signal", about 30
minutes on one core)::

    .venv/bin/python benchmarks/poke_signal.py

or one's own: ``... benchmarks/poke_signal.py jobs/poking.toml '[{}, {"elastic": {"edge_length_mm": 2.5}}]'``
(``{}``: the scene as it is). On poking the 16 gains are also compared with the P2
Richardson reference (:data:`REFERENCE_PF`).
Writes ``docs/poke_signal.csv`` (one row per variant and capacitor) with ``--csv``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import tolerance_text, write_csv  # noqa: E402
from mscap.fem.petsc import petsc  # noqa: E402
from mscap.fem.simulate import simulate  # noqa: E402
from mscap.scene import load_scene  # noqa: E402

#: The hand-set meshes jobs/poking.toml had until 2026-12-05, the tolerance mesh with its
#: zones under the balls and the elastic edge refined everywhere (P1) or P2, and the scene
#: as shipped (the 1 % mesh, P2 refined under the balls and along the held edges, 10 mm).
VARIANTS = [
    {"label": "hand-set: P1 0.075 mm, 5 mm; elastic 5 mm", "tolerance": False},
    {"label": "hand-set, elastic 1.25 mm", "tolerance": False, "elastic": {"edge_length_mm": 1.25}},
    {"label": "hand-set, far edge 1.25 mm, elastic 1.25 mm", "tolerance": False,
     "mesh": {"edge_length_mm": 1.25, "grading_distance_mm": 0.6}, "elastic": {"edge_length_mm": 1.25}},
    {"label": "tolerance 1 % (zones R/8 under the balls); elastic 5 mm", "tolerance": True,
     "elastic": {"order": 1, "edge_length_mm": 5.0}},
    {"label": "tolerance 1 %; elastic 2.5 mm", "tolerance": True, "elastic": {"order": 1, "edge_length_mm": 2.5}},
    {"label": "tolerance 1 %; elastic 1.25 mm", "tolerance": True, "elastic": {"order": 1, "edge_length_mm": 1.25}},
    {"label": "tolerance 1 %; elastic P2 2.5 mm", "tolerance": True,
     "elastic": {"edge_length_mm": 2.5, "order": 2, "refine_pokes": False}},
    {"label": "the scene as shipped: 1 %, P2 refined for the pokes, 10 mm"},
]
FIELDS = ["variant", "capacitor", "rest_pF", "pressed_gain_pF", "row_neighbour_gain_pF", "wall_s", "tets",
          "elastic_nodes"]

#: The P2 Richardson reference of jobs/poking.toml's gains (docs/electrostatics.md, "The
#: pose-to-pose signal"), by the plate pair's index xor (poke i on plate j): the pressed
#: plate (0), its same-row neighbour (1), the other two (2: 0.338–0.340, 3: 0.513–0.514;
#: the docs' "diagonal" and "column" rows).
REFERENCE_PF = {0: 4.874, 1: 1.309, 2: 0.339, 3: 0.5135}


def reference_errors(gains: np.ndarray) -> dict[int, np.ndarray]:
    """Relative errors of the 4 × 4 gain matrix ``gains[i, j]`` (poke i, plate j) against
    :data:`REFERENCE_PF`, per index xor."""
    i, j = np.indices(gains.shape)
    return {x: gains[(i ^ j) == x] / ref - 1 for x, ref in REFERENCE_PF.items()}


def tolerance_scene(path: Path) -> Path:
    """The scene file with its three ``[mesh]`` sizes replaced by ``tolerance = 0.01``."""
    out = ROOT / "out" / f"{path.stem}_tolerance.toml"
    out.parent.mkdir(exist_ok=True)
    out.write_text(tolerance_text(path))
    return out


#: The sizes jobs/poking.toml set by hand until 2026-12-05 (P1 electrostatics, P1 elastic).
HAND_SET = {"mesh": {"edge_length_mm": 5.0, "edge_length_outline_mm": 0.075, "grading_distance_mm": 2.5,
                     "elements_per_layer": 1, "order": 1},
            "elastic": {"order": 1, "edge_length_mm": 5.0}}


def hand_set_scene(path: Path) -> Path:
    """The scene file with its ``[mesh]`` and ``[elastic]`` tables replaced by :data:`HAND_SET`."""
    lines, table = [], ""
    for line in path.read_text().splitlines():
        if line.startswith("["):
            table = line.strip()
            if table in ("[mesh]", "[elastic]"):
                continue
        if table not in ("[mesh]", "[elastic]"):
            lines.append(line)
    for name, values in HAND_SET.items():
        lines += ["", f"[{name}]"] + [f"{key} = {value!r}" for key, value in values.items()]
    out = ROOT / "out" / f"{path.stem}_hand_set.toml"
    out.parent.mkdir(exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    return out


def run(scene, variant):
    mesh = dataclasses.replace(scene.mesh, **variant.get("mesh", {}))
    elastic = dataclasses.replace(scene.elastic, **variant.get("elastic", {}))
    start = time.perf_counter()
    sim = simulate(dataclasses.replace(scene, mesh=mesh, elastic=elastic), keep_fields=False)
    wall = time.perf_counter() - start
    c = np.array([p.capacitance_pF for p in sim.poses])
    return c, wall, len(sim.mesh.tets), sim.elastic.rest.shape[0] if sim.elastic is not None else 0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene", nargs="?", default=str(ROOT / "jobs" / "poking.toml"))
    parser.add_argument("variants", nargs="?", help="JSON list of variants (default: the documented ones)")
    parser.add_argument("--csv", help="write the table here")
    args = parser.parse_args(argv)
    petsc()
    path = Path(args.scene)
    # "tolerance": false, the hand-set sizes; true, the 1 % tolerance mesh; left out, the scene as it is
    scenes = {False: load_scene(hand_set_scene(path)), True: load_scene(tolerance_scene(path)), None: load_scene(path)}
    variants = json.loads(args.variants) if args.variants else VARIANTS
    rows = []
    for i, variant in enumerate(variants):
        scene = scenes[variant.get("tolerance")]
        c, wall, tets, nodes = run(scene, variant)
        gains = c[1:] - c[0]
        pressed = np.diag(gains)
        # the same-row neighbour of plate j in the 2 × 2 array: 0 <-> 1, 2 <-> 3
        neighbour = np.array([gains[j ^ 1, j] for j in range(len(pressed))])
        label = variant.get("label", json.dumps(variant))
        print(f"{label}: {tets:,} tets, {nodes:,} elastic nodes, {wall:.1f} s\n"
              f"  rest {np.round(c[0], 4)}\n  pressed gains {np.round(pressed, 4)} (spread "
              f"{100 * np.ptp(pressed) / pressed.mean():.2f} %), mean {pressed.mean():.4f} pF\n"
              f"  row-neighbour gains {np.round(neighbour, 4)}, mean {neighbour.mean():.4f} pF", flush=True)
        if gains.shape == (4, 4) and path.stem.startswith("poking") and "cross" not in path.stem:
            errors = reference_errors(gains)
            worst = max(np.abs(e).max() for e in errors.values())
            print("  against the P2 reference (pressed / row / xor 2 / xor 3): "
                  + " / ".join(f"{100 * e.min():+.1f}..{100 * e.max():+.1f} %" for e in errors.values())
                  + f"; worst {100 * worst:.2f} %", flush=True)
        rows += [dict(variant=label, capacitor=j, rest_pF=c[0, j], pressed_gain_pF=pressed[j],
                      row_neighbour_gain_pF=neighbour[j], wall_s=wall, tets=tets, elastic_nodes=nodes)
                 for j in range(len(pressed))]
    if args.csv:
        write_csv(rows, Path(args.csv), FIELDS)


if __name__ == "__main__":
    main()
