"""Capacitance error against wall time for the electrostatic solver.

Sweeps the edge length at the outlines, the edge length away from them and the element
order on a scene (default: the paper's 3 × 3 array of 2 cm squares), times each stage
on one core, and measures the error of every run against a Richardson-extrapolated
reference built from the finest P2 runs.

Reference. The plates of the 3 × 3 array stand 10 mm apart and 10 mm from the sheet edge,
some 70 dielectric gaps: the field of a plate in a thin layered sheet decays like
exp(−π r / t), so each plate's capacitance is that of one 20 mm plate alone on a
40 mm sheet, to far below the errors measured here (the script checks it at one mesh).
The reference refines that single-plate model, P2, halving the outline edge and
doubling the elements per layer together (level i: h/2ⁱ at the outline, 2ⁱ elements
per layer; far edge 2 mm and grading 3 mm fixed, since the field away from the plate
edges is uniform or zero and P2 is exact there). With C₁, C₂, C₃ the three finest
values, the observed order is p = log₂((C₁ − C₂) / (C₂ − C₃)) and the reference is
C* = C₃ + (C₃ − C₂)/(2ᵖ − 1). The error of a run is max over capacitors |C_j − C*| / C*.

Run (about 15 minutes on one core; ``--quick`` for a 1-minute smoke run)::

    .venv/bin/python benchmarks/electrostatic_error_vs_time.py

Writes ``docs/electrostatic_error_vs_time.csv`` and ``.png`` and prints the table and
the fastest settings that reach 1 % error.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import os
import sys
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):  # one core, as the target says
    os.environ.setdefault(_var, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mscap.fem.electrostatic import build_problem, solve  # noqa: E402
from mscap.geometry.polygons import square  # noqa: E402
from mscap.geometry.layout import Layout  # noqa: E402
from mscap.mesh.layered import mesh_sheet  # noqa: E402
from mscap.fem.petsc import petsc  # noqa: E402
from mscap.scene import load_scene  # noqa: E402

FIELDS = ["order", "edge_length_outline_mm", "edge_length_mm", "grading_distance_mm",
          "elements_per_layer", "vertices", "tets", "dofs", "mesh_s", "setup_s", "assembly_s",
          "factorisation_s", "solve_s", "electrostatics_s", "mean_capacitance_pF", "error"]


def run(scene, order, h_out, h_far, grading, per_layer, sheet=None, layout=None, label=""):
    settings = dataclasses.replace(scene.mesh, edge_length_outline_mm=h_out, edge_length_mm=h_far,
                                   grading_distance_mm=grading, elements_per_layer=per_layer, order=order)
    variant = dataclasses.replace(scene, mesh=settings,
                                  sheet_outline_mm=scene.sheet_outline_mm if sheet is None else sheet,
                                  layout=scene.layout if layout is None else layout)
    t0 = time.perf_counter()
    mesh = mesh_sheet(variant.sheet)
    t1 = time.perf_counter()
    problem = build_problem(mesh, scene.layers, order)
    t2 = time.perf_counter()
    caps = solve(problem)
    t3 = time.perf_counter()
    row = dict(order=order, edge_length_outline_mm=h_out, edge_length_mm=h_far, grading_distance_mm=grading,
               elements_per_layer=per_layer, vertices=len(mesh.points), tets=len(mesh.tets),
               dofs=problem.n_dofs, mesh_s=t1 - t0, setup_s=t2 - t1, assembly_s=caps.assembly_s,
               factorisation_s=caps.factorisation_s, solve_s=caps.solve_s, electrostatics_s=t3 - t1,
               mean_capacitance_pF=float(caps.capacitance_pF.mean()))
    print(f"{label}P{order} h_out {h_out:<6g} h_far {h_far:<5g} grading {grading:<5g} x{per_layer}: "
          f"{problem.n_dofs:>8d} dofs  mesh {row['mesh_s']:6.2f} s  electrostatics "
          f"{row['electrostatics_s']:6.2f} s  C = {caps.capacitance_pF.round(3)}", flush=True)
    return row, caps.capacitance_pF


def single_plate(scene, order, h_out, h_far, grading, per_layer):
    """Capacitance of one 20 mm square plate centred on a 40 mm sheet."""
    _, c = run(scene, order, h_out, h_far, grading, per_layer, square((20.0, 20.0), 40.0),
               Layout((square((20.0, 20.0), 20.0),)), label="single plate ")
    return float(c[0])


def richardson(c1, c2, c3):
    """Extrapolate from three values on meshes refined by 2 each (coarse to fine)."""
    p = float(np.log2(abs((c1 - c2) / (c2 - c3))))
    return c3 + (c3 - c2) / (2.0 ** p - 1.0), p


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=str(ROOT / "jobs" / "grid3x3.toml"),
                        help="a scene of 20 mm square plates >= 10 mm apart (the reference assumes it)")
    parser.add_argument("--quick", action="store_true", help="a small sweep, for checking the script")
    parser.add_argument("--out", default=str(ROOT / "docs" / "electrostatic_error_vs_time"))
    parser.add_argument("--target", type=float, default=0.01, help="relative error to reach")
    args = parser.parse_args(argv)
    petsc()
    scene = load_scene(args.scene)

    if args.quick:
        reference_levels = [(0.8, 1), (0.4, 2), (0.2, 4)]
        sweep = list(itertools.product([1, 2], [0.6, 0.3], [8.0], [4.0], [1]))
    else:
        # the finest level has ~750k P2 dofs and takes ~3 min; a 4th (~3M dofs) would take hours
        reference_levels = [(0.4, 1), (0.2, 2), (0.1, 4)]
        sweep = list(itertools.product([1], [0.3, 0.2, 0.15, 0.1, 0.075], [5.0, 10.0], [2.5, 5.0], [1, 2])) + \
            list(itertools.product([2], [0.8, 0.6, 0.4, 0.3], [5.0, 10.0], [2.5, 5.0], [1]))

    levels = [single_plate(scene, 2, h_out, 2.0, 3.0, per_layer) for h_out, per_layer in reference_levels]
    reference, p = richardson(*levels[-3:])
    gap = scene.layers[2]
    parallel_plate = gap.material.permittivity_pF_per_mm * 400.0 / gap.thickness_mm
    print(f"reference: single-plate P2 levels {np.round(levels, 4)} pF; observed order {p:.2f}; "
          f"Richardson C* = {reference:.4f} pF = {reference / parallel_plate:.4f} x eps A / d")
    check_settings = (2, 0.3, 5.0, 5.0, 1)
    _, c_full = run(scene, *check_settings)
    c_single = single_plate(scene, *check_settings)
    print(f"isolation check at P2 h_out 0.3: array plates {c_full.min():.4f}..{c_full.max():.4f} pF, "
          f"single plate {c_single:.4f} pF")

    rows, values = [], []
    for order, h_out, h_far, grading, per_layer in sweep:
        row, c = run(scene, order, h_out, h_far, grading, per_layer)
        rows.append(row)
        values.append(c)
    for row, c in zip(rows, values):
        row["error"] = float(np.max(np.abs(c - reference) / reference))
    summary = dict(reference_pF=reference, observed_order=p, fringing_factor=reference / parallel_plate,
                   reference_levels_pF=levels)

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})

    ok = [r for r in rows if r["error"] <= args.target]
    best = min(ok, key=lambda r: r["electrostatics_s"]) if ok else None
    print(f"\n{'order':>5} {'h_out':>6} {'h_far':>6} {'grad':>5} {'x':>2} {'dofs':>9} {'mesh s':>7} "
          f"{'elec s':>7} {'error %':>8}")
    for r in sorted(rows, key=lambda r: r["electrostatics_s"]):
        mark = "  <- fastest to 1 %" if r is best else ""
        print(f"{r['order']:>5} {r['edge_length_outline_mm']:>6g} {r['edge_length_mm']:>6g} "
              f"{r['grading_distance_mm']:>5g} {r['elements_per_layer']:>2} {r['dofs']:>9d} "
              f"{r['mesh_s']:>7.2f} {r['electrostatics_s']:>7.2f} {100 * r['error']:>8.3f}{mark}")
    plot(rows, best, reference, out.with_suffix(".png"), args.target, scene.name)
    print(f"summary: {summary}")
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.png')}")


def plot(rows, best, reference, path, target, name):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for (order, per_layer), marker in [((1, 1), "o"), ((2, 1), "s"), ((1, 2), "^")]:
        sel = [r for r in rows if r["order"] == order and r["elements_per_layer"] == per_layer]
        if sel:
            ax.loglog([r["electrostatics_s"] for r in sel], [max(r["error"], 1e-6) for r in sel], marker,
                      label=f"P{order}, {per_layer} element{'s' if per_layer > 1 else ''} per layer", alpha=0.8)
    if best:
        ax.loglog([best["electrostatics_s"]], [best["error"]], "k*", ms=16, mfc="none",
                  label=f"chosen: P{best['order']}, h_out {best['edge_length_outline_mm']:g}, "
                        f"h_far {best['edge_length_mm']:g} mm")
    ax.axhline(target, color="gray", ls="--", lw=1)
    ax.set_xlabel("electrostatics wall time on one core (s): set-up + assembly + factorisation + solves")
    ax.set_ylabel("max relative capacitance error")
    ax.set_title(f"{name}: error against run time (reference {reference:.3f} pF, Richardson)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
