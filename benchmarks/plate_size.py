"""Capacitance error against plate size and mesh settings: the calibration of ``[mesh] tolerance``.

The default mesh overestimates each plate's fringe by an amount per millimetre of plate
edge, so its relative error grows as plates shrink. This script measures that error per
unit of edge for a ladder of mesh settings ("rungs") on single plates of several sizes and
shapes, against converged references, and prints the constants that
``mscap.scene.sizing.LADDER`` and ``TET_LADDER`` pin.

Plates: squares of 6, 10 and 20 mm and a 10 mm disk (a fixed 128-gon, so every mesh sees
the same polygon), each centred on a sheet with a 10 mm margin, in the stack of
``jobs/poking.toml`` (0.14 / 0.07 / 0.14 / 0.07 / 0.14 mm, εr 2.84). A plate 10 mm from the
sheet edge is alone: its field decays like exp(−π r / t) (docs/electrostatics.md).

Reference per plate: P2, the outline edge and the elements per layer refined together
(outline 0.4, 0.2, 0.1 mm with 1, 2, 4 elements per layer; far edge 2 mm, grading 3 mm)
and Richardson-extrapolated from the three levels with the observed order.

Rungs (``mscap.scene.sizing.LADDER``, ``TET_LADDER``): order, element, outline edge as a multiple of the dielectric
gap d, elements per layer, and the slope (mm per mm) at which the edge length grows within
4 stack thicknesses of the outlines (the fringe zone); beyond it, at 2 up to 5 mm.
Error per unit edge: e = (C − C*) / P, reported as e / ε (dimensionless: the fringe
overestimate per unit edge in units of the permittivity), which does not depend on the
plate when the mesh resolves the fringe consistently. A plate of area A and perimeter
P then has a relative error of about (e / ε) · P d / A.

Run (about 15 minutes on one core; ``--references docs/plate_size.csv`` reuses the
references of an earlier run, about 6 minutes)::

    .venv/bin/python benchmarks/plate_size.py

Writes ``docs/plate_size.csv``.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import os
import sys
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
from mscap.geometry.layout import Layout  # noqa: E402
from mscap.geometry.polygons import disk, square  # noqa: E402
from mscap.mesh.layered import mesh_sheet  # noqa: E402
from mscap.scene.sizing import FRINGE_STACKS, LADDER, STEEP, TET_LADDER, Rung, rung_settings  # noqa: E402
from mscap.scene import load_scene  # noqa: E402
from mscap.scene.settings import MeshSettings  # noqa: E402

PLATES = {"square 6": square((0.0, 0.0), 6.0), "square 10": square((0.0, 0.0), 10.0),
          "square 20": square((0.0, 0.0), 20.0), "disk 10": disk((0.0, 0.0), 10.0, 10.0 * np.pi / 128)}
MARGIN_MM = 10.0
REFERENCE_LEVELS = [(0.4, 1), (0.2, 2), (0.1, 4)]
#: Settings measured besides the ladder: P1 with two elements per layer (the ladder leaves
#: it out: P2 is as accurate for fewer unknowns) and the hand-set paper default.
EXTRA = [(Rung(1, 0.5, 2, 0.5, float("nan")), None), ("hand default", MeshSettings(5.0, 0.075, 2.5, 1, 1))]
#: P1 prisms (``[mesh] element = "prism"``, mscap.fem.wedge) on the tets' rungs and coarser.
PRISMS = [Rung(1, h, 1, slope, float("nan"), "prism") for h in (3.0, 2.0, 1.5, 1.0, 0.5) for slope in (1.0, 0.5)]
FIELDS = ["plate", "rung", "order", "element", "edge_length_outline_mm", "edge_length_mm", "grading_distance_mm",
          "elements_per_layer", "dofs", "electrostatics_s", "capacitance_pF", "reference_pF", "error",
          "e_over_eps"]


def capacitance(scene, plate, settings):
    extent = np.ptp(plate, axis=0).max()
    variant = dataclasses.replace(scene, mesh=settings, layout=Layout((plate,)),
                                  sheet_outline_mm=square(plate.mean(axis=0), extent + 2 * MARGIN_MM))
    mesh = mesh_sheet(variant.sheet)
    start = time.perf_counter()
    problem = build_problem(mesh, scene.layers, settings.order, settings.element)
    c = float(solve(problem).capacitance_pF[0])
    return c, problem.n_dofs, time.perf_counter() - start


def reference(scene, plate):
    levels = [capacitance(scene, plate, MeshSettings(2.0, h, 3.0, n, 2))[0] for h, n in REFERENCE_LEVELS]
    c_ref, p, _ = richardson(*levels, ratio=2.0)
    return float(c_ref), float(p), levels


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=str(ROOT / "jobs" / "poking.toml"), help="the stack to use")
    parser.add_argument("--plates", nargs="*", default=list(PLATES), help=f"some of {list(PLATES)}")
    parser.add_argument("--out", default=str(ROOT / "docs" / "plate_size.csv"))
    parser.add_argument("--only-prisms", action="store_true", help="only the prism rungs (PRISMS)")
    parser.add_argument("--references", metavar="CSV",
                        help="take each plate's reference from an earlier run's CSV instead of recomputing it")
    args = parser.parse_args(argv)
    petsc()
    scene = load_scene(args.scene)
    gap = scene.layers[2]
    eps = gap.material.permittivity_pF_per_mm
    stack = sum(layer.thickness_mm for layer in scene.layers)
    pinned_rungs = TET_LADDER + LADDER
    rungs = [(r.label, rung_settings(r, gap.thickness_mm, stack)) for r in pinned_rungs]
    rungs += [(r.label, rung_settings(r, gap.thickness_mm, stack)) if isinstance(r, Rung) else (r, settings)
              for r, settings in EXTRA]
    rungs += [(r.label, rung_settings(r, gap.thickness_mm, stack)) for r in PRISMS
              if r.label not in {p.label for p in pinned_rungs}]
    if args.only_prisms:
        rungs = [(label, settings) for label, settings in rungs if settings.element == "prism"]
    known = {}
    if args.references:
        with open(args.references) as f:
            known = {row["plate"]: (float(row["reference_pF"]), float("nan"), [])
                     for row in csv.DictReader(f)}
    rows = []
    for name in args.plates:
        plate = PLATES[name]
        perimeter = float(np.sum(np.linalg.norm(np.roll(plate, -1, axis=0) - plate, axis=1)))
        c_ref, p, levels = known.get(name) or reference(scene, plate)
        print(f"{name}: reference levels {np.round(levels, 5)} pF, observed order {p:.2f}, "
              f"C* = {c_ref:.5f} pF", flush=True)
        for label, settings in rungs:
            c, dofs, seconds = capacitance(scene, plate, settings)
            error = (c - c_ref) / c_ref
            rows.append(dict(plate=name, rung=label, order=settings.order, element=settings.element,
                             edge_length_outline_mm=settings.edge_length_outline_mm,
                             edge_length_mm=settings.edge_length_mm,
                             grading_distance_mm=settings.grading_distance_mm,
                             elements_per_layer=settings.elements_per_layer, dofs=dofs, electrostatics_s=seconds,
                             capacitance_pF=c, reference_pF=c_ref, error=error,
                             e_over_eps=(c - c_ref) / perimeter / eps))
            print(f"  {label:<22} {dofs:>8d} dofs {seconds:6.2f} s  error {100 * error:+.3f} %  "
                  f"e/eps {rows[-1]['e_over_eps']:.4f}", flush=True)
    write_csv(rows, Path(args.out), FIELDS)
    print()
    print("\n".join(table_head("| rung | " + " | ".join(args.plates) + " | max e/ε | ladder's e/ε |")))
    for label, _ in rungs:
        sel = [r for r in rows if r["rung"] == label]
        pinned = next((f"{r.e_over_eps:g}" for r in TET_LADDER + LADDER if label == r.label), "")
        cells = [f"{100 * r['error']:+.2f} % ({r['dofs']:,})" for r in sel]
        print(f"| {label} | " + " | ".join(cells) + f" | {max(r['e_over_eps'] for r in sel):.3f} | {pinned} |")
    print(f"\nfringe zone {FRINGE_STACKS:g} stack thicknesses, then slope {STEEP:g}; wrote {args.out}")


if __name__ == "__main__":
    main()
