"""Route designs and write their stencils (``mscap fabricate``), and how the router's cost
grows with k (docs/fabrication.md).

    .venv/bin/python benchmarks/fabrication.py --design jobs/wrist_quick.toml=out/wrist.h5 \
        --design jobs/grid3x3.toml=layout --figures docs/fabrication
    .venv/bin/python benchmarks/fabrication.py --scaling 2 3 4 5
    .venv/bin/python benchmarks/fabrication.py --design jobs/glove_quick.toml=out/glove.h5 --stiffness

``--design SCENE=RESULTS.h5`` routes the results file's chosen design under the scene's
``[fabrication]`` rules (``SCENE=layout``: the scene's own layout); one markdown row each:
the array, the connector edge, lead length, row/column crossings, the overlap area and its parallel-plate
rest capacitance against the plates', route and write times. ``--scaling N ...``: N × N
grids of 12 mm plates at a 20 mm pitch, k = N², the same 24 slot assignments each.
``--stiffness``: each routed design's readings over the scene's poses with the leads as
stiff as the plates (the default) and as soft as the silicone around them, on the same
meshes, and the plates alone on those meshes: how much the leads' stiffness, and the
leads, move a reading and a pose-to-pose signal.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mscap.errors import FabricationError
from mscap.fabrication.report import write_fabrication
from mscap.fabrication.router import CROSSING_MM2, route
from mscap.viz.fabrication import plot_routing
from mscap.geometry.layout import grid_layout
from mscap.scene import load_scene
from mscap.scene.settings import FabricationSettings
from mscap.service.designs import read_design
from mscap.service.store import read_store


def fabricate(spec: str, figures: Path | None, stiffness: list | None = None) -> str:
    scene_path, source = spec.split("=", 1)
    scene = load_scene(scene_path)
    if source == "layout":
        outlines, label = scene.layout.outlines, "scene layout"
    else:
        with read_store(source) as store:
            design = read_design(store)
        outlines, label = design.outlines, design.label
    started = time.perf_counter()
    routing = route(outlines, scene.sheet_outline_mm, scene.fabrication)
    routed = time.perf_counter() - started
    tmp = Path(tempfile.mkdtemp())
    try:
        started = time.perf_counter()
        document = write_fabrication(routing, tmp / "out", scene, label, preview=plot_routing)
        written = time.perf_counter() - started
        if figures is not None:
            figures.mkdir(parents=True, exist_ok=True)
            shutil.copy(tmp / "out" / "preview.png", figures / f"fabrication_{scene.name}.png")
    finally:
        shutil.rmtree(tmp)
    if stiffness is not None:
        stiffness.append(lead_stiffness(scene, outlines, routing, label))
    plates = [s["plate_capacitance_pF"] for s in document["array"]["slots"]]
    share = max(s["lead_share"] for s in document["array"]["slots"])
    checks = document["design_rule_check"]["layers"]
    clearance = min(v["min_clearance_mm"] for v in checks.values() if v["min_clearance_mm"] is not None)
    return (f"| {scene.name} | {label} | {len(outlines)} | {routing.array.rows} x {routing.array.columns} | "
            f"{routing.edge} | {routing.length_mm:.0f} | "
            f"{sum(o['area_mm2'] >= CROSSING_MM2 for o in document['overlaps'])} / "
            f"{document['overlap_mm2']:.2f} | {document['overlap_capacitance_pF']:.3f} | "
            f"{min(plates):.0f}-{max(plates):.0f} | {100 * share:.2f} % | {clearance:.2f} | "
            f"{routing.assignments_tried} | {routed:.1f} | {written:.1f} |")


def lead_stiffness(scene, outlines, routing, label: str) -> str:
    """One markdown row: the readings as wired with and without the leads' stiffness."""
    from mscap.fabrication.wired import plates_only, readings, wiring_of
    from mscap.geometry.layout import Layout
    from mscap.scene.sizing import sheet_for

    sheet = sheet_for(scene, Layout(outlines))
    wiring = wiring_of(routing)
    started = time.perf_counter()
    stiff, _ = readings(scene, sheet, wiring)
    stiff_s = time.perf_counter() - started
    started = time.perf_counter()
    alone = plates_only(outlines, meshed_like=wiring)
    soft, _ = readings(scene, sheet, wiring, stiffness=alone)  # the same meshes, the leads of the silicone around them
    soft_s = time.perf_counter() - started
    plates, _ = readings(scene, sheet, alone)

    def signal_change(a, b):  # largest change of a pose-to-pose signal, % of that capacitor's range
        da, db = a - a[0], b - b[0]
        return 100 * np.max(np.abs(da - db) / np.ptp(a, axis=0))

    reading = 100 * (stiff - soft) / soft
    leads = 100 * (stiff - plates) / plates
    return (f"| {scene.name} | {label} | {len(scene.poses)} | {reading.min():+.3f} … {reading.max():+.3f} % | "
            f"{signal_change(stiff, soft):.2f} | {leads.min():+.3f} … {leads.max():+.3f} % | "
            f"{signal_change(stiff, plates):.2f} | {soft_s:.1f} / {stiff_s:.1f} |")


def scaling(sizes: list[int]) -> None:
    print("| k | sheet (mm) | array | routed / tried assignments | lead length (mm) | overlap (mm2) | "
          "route (s) | per assignment (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for n in sizes:
        side = 20.0 * n + 30.0
        layout = grid_layout("square", n, n, 12.0, (20.0, 20.0), (side / 2, side / 2 + 5.0), 1.0)
        sheet = np.array([[0, 0], [side, 0], [side, side], [0, side]])
        started = time.perf_counter()
        try:
            routing = route(layout.outlines, sheet, FabricationSettings(connector_edge="bottom"))
        except FabricationError as exc:
            print(f"| {n * n} | {side:.0f} | {n} x {n} | 0 / 24 | no route: {str(exc)[:120]}… | | "
                  f"{time.perf_counter() - started:.1f} | |", flush=True)
            continue
        elapsed = time.perf_counter() - started
        print(f"| {n * n} | {side:.0f} | {routing.array.rows} x {routing.array.columns} | "
              f"{routing.assignments_tried - len(routing.rejected)} / {routing.assignments_tried} | "
              f"{routing.length_mm:.0f} | {routing.overlap_mm2:.2f} | {elapsed:.1f} | "
              f"{elapsed / routing.assignments_tried:.2f} |", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--design", action="append", default=[], metavar="SCENE=RESULTS.h5|layout")
    parser.add_argument("--figures", type=Path, help="copy each preview to DIR/fabrication_<scene>.png")
    parser.add_argument("--scaling", type=int, nargs="*", metavar="N")
    parser.add_argument("--stiffness", action="store_true",
                        help="also each design's readings with and without the leads' stiffness")
    args = parser.parse_args(argv)
    stiffness = [] if args.stiffness else None
    if args.design:
        print("| scene | design | k | array | connector | leads (mm) | crossings / overlap mm² | overlap pF | plates pF "
              "(parallel plate) | largest lead share | clearance (mm) | assignments | route (s) | write + check (s) |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for spec in args.design:
            print(fabricate(spec, args.figures, stiffness), flush=True)
    if stiffness:
        print("\n| scene | design | poses | readings, leads as stiff as plates against as soft as silicone | "
              "largest signal change, % of its range | readings as wired against plates alone | largest signal "
              "change, % of its range | simulate (s), soft / stiff leads |")
        print("|---|---|---|---|---|---|---|---|")
        print("\n".join(stiffness))
    if args.scaling:
        scaling(args.scaling)
    return 0


if __name__ == "__main__":
    sys.exit(main())
