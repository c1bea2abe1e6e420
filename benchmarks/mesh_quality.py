"""Capacitance at the default mesh where the optimiser puts plates: near the sheet edge,
near each other, L-shaped, in the sheet's corners; against converged references.

A scene without a ``[mesh]`` table is meshed for a 1 % capacitance tolerance
(``mscap.scene.sizing``). That tolerance was calibrated on plates 10 mm from everything
(``benchmarks/plate_size.py``); this script checks it where designs go, with the 2D mesh
quality of each mesh (``mscap.mesh.shape``):

- squares of 6, 10 and 20 mm centred on a sheet with margins of 3–8 mm to its edge
  (21 cases). Reference: the plate alone 10 mm from the edge (docs/plate_size.csv, P2
  Richardson): at 3 mm the fringe field has decayed like exp(−π · 3 / 0.56) ≈ 5e-8, and
  ``--check-margin`` computes the 6 mm square at 3 mm directly;
- two 10 mm squares 0.5, 1 and 2 mm apart, an L-shaped plate, and plates in the corners
  of the sheet, 3 mm from two edges. References: P2 with the outline edge and elements
  per layer refined together (0.4 / 0.2 / 0.1 mm with 1 / 2 / 4 per layer), Richardson.

Also run on the hand-set sizes of jobs/poking.toml (``--hand-set``). The same script run
from a checkout of an earlier commit measures that commit's meshes (the table's "before").

Run (about 25 minutes on one core with the references; ``--references CSV`` reuses an
earlier run's)::

    .venv/bin/python benchmarks/mesh_quality.py --out docs/mesh_quality.csv
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import table_head, write_csv  # noqa: E402
from benchmarks.scene_accuracy import richardson  # noqa: E402
from mscap.fem.electrostatic import build_problem, solve  # noqa: E402
from mscap.fem.petsc import petsc  # noqa: E402
from mscap.mesh.layered import mesh_sheet  # noqa: E402
from mscap.scene import load_scene  # noqa: E402
from mscap.scene.settings import MeshSettings  # noqa: E402

#: Each plate alone, 10 mm from the sheet edge (docs/plate_size.csv: P2 Richardson, observed
#: orders 1.61–1.81; NGSolve's hp reference 0.013–0.061 % lower, docs/performance.md §12).
ALONE_PF = {6.0: 6.90142, 10.0: 18.6852, 20.0: 73.2813}
MARGINS_MM = (3.0, 3.5, 4.0, 5.0, 6.0, 7.0, 8.0)
REFERENCE_LEVELS = [(0.4, 1), (0.2, 2), (0.1, 4)]
HAND_SET = "[mesh]\nedge_length_mm = 5.0\nedge_length_outline_mm = 0.075\ngrading_distance_mm = 2.5\n"
FIELDS = ["case", "mesh", "capacitor", "capacitance_pF", "reference_pF", "error", "min_angle_deg", "size_ratio",
          "triangles", "dofs", "seconds"]


def square(x0, y0, size):
    return [[x0, y0], [x0 + size, y0], [x0 + size, y0 + size], [x0, y0 + size]]


def cases():
    """``(name, sheet width, height, outlines, reference per plate or None)``."""
    out = []
    for size in (6.0, 10.0, 20.0):
        for margin in MARGINS_MM:
            w = size + 2 * margin
            out.append((f"square {size:g} margin {margin:g}", w, w, [square(margin, margin, size)], [ALONE_PF[size]]))
    for gap in (0.5, 1.0, 2.0):
        out.append((f"two 10 mm squares {gap:g} mm apart", 40.0 + gap, 30.0,
                    [square(10.0, 10.0, 10.0), square(20.0 + gap, 10.0, 10.0)], None))
    ell = [[4.0, 4.0], [16.0, 4.0], [16.0, 9.0], [9.0, 9.0], [9.0, 16.0], [4.0, 16.0]]
    out.append(("L-shaped plate (12 mm arms, 5 mm wide), margin 4", 20.0, 20.0, [ell], None))
    out.append(("6 mm squares in two corners, 3 mm from both edges", 30.0, 30.0,
                [square(3.0, 3.0, 6.0), square(21.0, 21.0, 6.0)], [ALONE_PF[6.0]] * 2))
    out.append(("20 mm square in a corner, 3 mm from both edges", 40.0, 40.0,
                [square(3.0, 3.0, 20.0)], [ALONE_PF[20.0]]))
    return out


def scene_text(width, height, outlines, mesh_table=""):
    stack = (ROOT / "jobs" / "quick.toml").read_text().split("[capacitors]")[0]
    stack = stack.replace("width_mm = 40.0", f"width_mm = {width!r}").replace("height_mm = 30.0",
                                                                               f"height_mm = {height!r}")
    return stack + (f"[capacitors]\nmin_gap_mm = 0.25\noutlines_mm = {outlines!r}\n\n{mesh_table}\n"
                    "[[poses]]\nname = \"rest\"\nkind = \"free\"\n")


def load(text):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "case.toml"
        path.write_text(text)
        return load_scene(str(path))


def capacitances(scene, settings=None):
    """``(C per plate, dofs, min angle, size ratio, triangles, seconds)`` on ``settings`` (the scene's)."""
    from mscap.mesh.quality import triangle_angles_deg

    if settings is not None:
        scene = dataclasses.replace(scene, mesh=settings)
    start = time.perf_counter()
    mesh = mesh_sheet(scene.sheet)
    problem = build_problem(mesh, scene.layers, scene.mesh.order, getattr(scene.mesh, "element", "tet"))
    c = np.asarray(solve(problem).capacitance_pF, dtype=float)
    seconds = time.perf_counter() - start
    m2 = mesh.mesh2d
    angle = float(triangle_angles_deg(m2.points, m2.triangles).min())
    try:
        from mscap.mesh.shape import neighbour_size_ratios
        ratio = float(neighbour_size_ratios(m2.points, m2.triangles)[0].max())
    except ImportError:  # a checkout from before mscap.mesh.shape
        ratio = float("nan")
    return c, problem.n_dofs, angle, ratio, len(m2.triangles), seconds


def reference(scene):
    levels = [capacitances(scene, MeshSettings(2.0, h, 3.0, n, 2))[0] for h, n in REFERENCE_LEVELS]
    c_ref, p, _ = richardson(*levels, ratio=2.0)
    return np.asarray(c_ref, dtype=float), p


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(ROOT / "docs" / "mesh_quality.csv"))
    parser.add_argument("--references", metavar="CSV", help="take the computed references from an earlier run")
    parser.add_argument("--check-margin", action="store_true",
                        help="also compute the 6 mm square at 3 mm's reference directly (4 min)")
    parser.add_argument("--only", help="only cases whose name contains this")
    args = parser.parse_args(argv)
    petsc()
    known = {}
    if args.references:
        with open(args.references) as f:
            for row in csv.DictReader(f):
                known.setdefault(row["case"], {})[int(row["capacitor"])] = float(row["reference_pF"])
    rows = []
    for name, width, height, outlines, ref in cases():
        if args.only and args.only not in name:
            continue
        default = load(scene_text(width, height, outlines))
        if ref is None or (args.check_margin and name == "square 6 margin 3"):
            if name in known:
                ref = [known[name][j] for j in range(len(outlines))]
            else:
                c_ref, p = reference(default)
                print(f"{name}: reference {np.round(c_ref, 5)} pF (observed orders {np.round(p, 2)})", flush=True)
                ref = list(c_ref)
        for label, scene in (("default", default), ("hand-set", load(scene_text(width, height, outlines, HAND_SET)))):
            c, dofs, angle, ratio, triangles, seconds = capacitances(scene)
            for j, (cj, rj) in enumerate(zip(c, ref)):
                rows.append(dict(case=name, mesh=label, capacitor=j, capacitance_pF=float(cj), reference_pF=float(rj),
                                 error=float(cj / rj - 1), min_angle_deg=angle, size_ratio=ratio, triangles=triangles,
                                 dofs=dofs, seconds=seconds))
            errors = ", ".join(f"{100 * (cj / rj - 1):+.2f} %" for cj, rj in zip(c, ref))
            print(f"{name:<52} {label:<9} {errors:<20} min angle {angle:5.2f} ratio {ratio:4.2f} "
                  f"{dofs:>7d} dofs {seconds:5.2f} s", flush=True)
    write_csv(rows, Path(args.out), FIELDS)
    print()
    print("\n".join(table_head("| case | mesh | error per plate | min angle | size ratio | unknowns |")))
    seen = []
    for r in rows:
        key = (r["case"], r["mesh"])
        if key in seen:
            continue
        seen.append(key)
        sel = [s for s in rows if (s["case"], s["mesh"]) == key]
        print(f"| {key[0]} | {key[1]} | " + ", ".join(f"{100 * s['error']:+.2f} %" for s in sel)
              + f" | {r['min_angle_deg']:.1f}° | {r['size_ratio']:.2f} | {r['dofs']:,} |")
    worst = max(abs(r["error"]) for r in rows if r["mesh"] == "default")
    print(f"\nlargest error at the defaults: {100 * worst:.2f} %; wrote {args.out}")


if __name__ == "__main__":
    main()
