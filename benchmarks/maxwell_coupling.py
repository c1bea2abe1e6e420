"""Accuracy of the Maxwell coupling terms between neighbouring plates, per mesh setting.

``mscap capacitance --maxwell`` reports the full 2k × 2k Maxwell matrix of the plates
(bottom plates first, then top plates). Its diagonal entries of the top plates are the
capacitances C_j, which ``[mesh] tolerance`` controls (docs/electrostatics.md); its
off-diagonal entries between neighbouring plates come from the fringe fields that reach
across the gap, which the tolerance's calibration does not see. This script measures them.

Two 6 mm squares side by side, ``gap`` apart (2 mm and 0.5 mm), centred on a sheet with
a 10 mm margin, in the stack of ``jobs/poking.toml``. Coupling terms: top–top (the two
plates of the same layer), top–bottom across (top plate 0 and bottom plate 1) and the
diagonal C_top0 for comparison. Reference: P2, outline edge and elements per layer refined
together (0.3 / 0.15 / 0.075 mm with 1 / 2 / 4 per layer), Richardson per entry at the
observed order. Settings: the hand-set paper mesh, the default (the 1 % tolerance rung
for these plates), the rungs of the tolerance ladder (``mscap.scene.sizing.LADDER``) and
four finer ones for the couplings, the last ``mscap.scene.sizing.COUPLING_RUNG``.

Run (about 15 minutes on one core)::

    .venv/bin/python benchmarks/maxwell_coupling.py

Writes ``docs/maxwell_coupling.csv`` (``--out docs/maxwell_coupling_quality.csv``: the run of
docs/electrostatics.md's 2026-12-05 table).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
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
from mscap.geometry.polygons import square  # noqa: E402
from mscap.mesh.layered import mesh_sheet  # noqa: E402
from mscap.scene.sizing import COUPLING_RUNG, LADDER, Rung, rung_settings, settings_for_tolerance  # noqa: E402
from mscap.scene import load_scene  # noqa: E402
from mscap.scene.settings import MeshSettings  # noqa: E402

SIDE_MM, MARGIN_MM = 6.0, 10.0
REFERENCE_LEVELS = [(0.3, 1), (0.15, 2), (0.075, 4)]
#: (label, row, column) of the Maxwell matrix, plates ordered bottom 0, bottom 1, top 0, top 1
ENTRIES = [("top-top", 2, 3), ("top-bottom across", 2, 1), ("C_top0", 2, 2)]
FIELDS = ["gap_mm", "setting", "dofs", "entry", "value_pF", "reference_pF", "error"]


def maxwell(scene, gap, settings):
    half = 0.5 * (SIDE_MM + gap)
    layout = Layout((square((-half, 0.0), SIDE_MM), square((half, 0.0), SIDE_MM)))
    width = 2 * SIDE_MM + gap + 2 * MARGIN_MM
    variant = dataclasses.replace(scene, mesh=settings, layout=layout,
                                  sheet_outline_mm=np.array([[-width / 2, -width / 2], [width / 2, -width / 2],
                                                             [width / 2, width / 2], [-width / 2, width / 2]]),
                                  )
    problem = build_problem(mesh_sheet(variant.sheet), scene.layers, settings.order, settings.element)
    return solve(problem, maxwell=True).maxwell_pF, problem.n_dofs


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--gaps", type=float, nargs="*", default=[2.0, 0.5])
    parser.add_argument("--out", default=str(ROOT / "docs" / "maxwell_coupling.csv"))
    args = parser.parse_args(argv)
    petsc()
    scene = load_scene(ROOT / "jobs" / "poking.toml")
    gap_mm = scene.layers[2].thickness_mm
    stack = sum(layer.thickness_mm for layer in scene.layers)
    settings = [("hand-set (0.075 mm, 5 mm at 2.5 mm)", MeshSettings(5.0, 0.075, 2.5, 1, 1))]
    default = settings_for_tolerance(0.01, [square((0.0, 0.0), SIDE_MM)], gap_mm, stack)[0]
    settings += [("default (no [mesh]: 1 % tolerance)", default)]
    settings += [(rung.label, rung_settings(rung, gap_mm, stack)) for rung in LADDER]
    # finer than the C ladder, for the couplings (mscap.scene.sizing.COUPLING_RUNG is the last)
    couplings = [Rung(1, 0.5, 2, 0.5, float("nan"), "prism"), Rung(1, 0.25, 2, 0.5, float("nan"), "prism"),
                 Rung(2, 0.5, 1, 0.5, float("nan")), COUPLING_RUNG]
    settings += [(rung.label, rung_settings(rung, gap_mm, stack)) for rung in couplings]
    rows = []
    for gap in args.gaps:
        levels = [maxwell(scene, gap, MeshSettings(2.0, h, 3.0, n, 2))[0] for h, n in REFERENCE_LEVELS]
        reference, order, _ = richardson(*levels, ratio=2.0)
        print(f"gap {gap} mm: reference " + ", ".join(f"{name} {reference[i, j]:.5f} pF (order {order[i, j]:.2f})"
                                                   for name, i, j in ENTRIES), flush=True)
        for label, mesh in settings:
            values, dofs = maxwell(scene, gap, mesh)
            for name, i, j in ENTRIES:
                rows.append(dict(gap_mm=gap, setting=label, dofs=dofs, entry=name, value_pF=float(values[i, j]),
                                 reference_pF=float(reference[i, j]),
                                 error=float(values[i, j] / reference[i, j] - 1)))
            print(f"  {label:<38} {dofs:>8d} dofs  " + "  ".join(
                f"{r['entry']} {100 * r['error']:+.2f} %" for r in rows[-len(ENTRIES):]), flush=True)
    write_csv(rows, Path(args.out), FIELDS)
    print()
    head = "| gap | setting | unknowns | " + " | ".join(name for name, _, _ in ENTRIES) + " |"
    print("\n".join(table_head(head)))
    for gap in args.gaps:
        for label, _ in settings:
            sel = [r for r in rows if r["gap_mm"] == gap and r["setting"] == label]
            print(f"| {gap:g} mm | {label} | {sel[0]['dofs']:,} | "
                  + " | ".join(f"{100 * r['error']:+.2f} %" for r in sel) + " |")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
