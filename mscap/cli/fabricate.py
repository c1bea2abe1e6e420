"""``mscap fabricate RESULTS.h5 [--run NAME] -o DIR``: route a design's leads in the
multiplexed array and write its stencils (docs/fabrication.md)."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

__all__ = ["add_parser", "run"]

log = logging.getLogger(__name__)


def add_parser(sub) -> None:
    p = sub.add_parser("fabricate", help="route a design's leads and write one stencil per conductive layer",
                       description="Join the plates of a stored design row by row (bottom layer) and column by "
                                   "column (top layer) to connector pads on one sheet edge, under the scene's "
                                   "[fabrication] design rules, and write DIR/bottom.{dxf,svg}, "
                                   "DIR/top.{dxf,svg}, DIR/preview.png and DIR/fabrication.json (the array, "
                                   "the nets, every row/column overlap and its rest capacitance, the design-rule "
                                   "check of the written files). DIR must not exist yet.")
    p.add_argument("design", metavar="RESULTS.h5|OPTIMIZE_DIR",
                   help="a results file (its chosen design, or --run) or an `mscap optimize` output directory")
    p.add_argument("--run", dest="run_id", metavar="NAME", help="the run of the results file (default: the chosen design)")
    p.add_argument("--which", choices=("final", "initial"), default="final", help="which layout of the run")
    p.add_argument("--scene", metavar="SCENE.toml",
                   help="take the [fabrication] rules (and sheet) from this scene file instead of the scene "
                        "the design was made for (its name must match)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="the directory to create")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress line per slot assignment on stderr")
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.errors import FabricationError
    from mscap.fabrication.report import check_target, write_fabrication
    from mscap.fabrication.router import CROSSING_MM2, route
    from mscap.scene import load_scene
    from mscap.service.designs import check_scene, read_design, read_optimize_output
    from mscap.service.store import read_store
    from mscap.viz.fabrication import plot_routing

    check_target(args.output)  # before any work
    source = Path(args.design)
    if source.is_dir():
        if args.run_id:
            raise FabricationError(f"fabricate {source}: --run names a run of a results file, and this is an "
                                   f"`mscap optimize` directory")
        stored = read_optimize_output(source)
        scene_path = args.scene or stored.summary.get("scene")
        if not isinstance(scene_path, str) or not scene_path:
            raise FabricationError(f"fabricate {source}: summary.json names no scene file; give --scene")
        scene = load_scene(scene_path)
        outlines, label = stored.outlines, f"{source.name} (optimised)"
    else:
        with read_store(source) as store:
            if args.scene:
                scene = load_scene(args.scene)
                check_scene(store, scene)
            else:
                scene = load_scene(f"{source} (stored scene {store.attrs.get('scene_path', '')})",
                                   source=str(store.attrs["scene_toml"]))
            design = read_design(store, args.run_id, args.which)
        outlines, label = design.outlines, design.label
    routing = route(outlines, scene.sheet_outline_mm, scene.fabrication,
                    progress=None if args.quiet else lambda line: print(line, file=sys.stderr, flush=True))
    document = write_fabrication(routing, args.output, scene, label, preview=plot_routing)
    check = document["design_rule_check"]["layers"]
    print(f"{label}: {routing.array.rows} x {routing.array.columns} array, connector on the {routing.edge} edge, "
          f"{routing.length_mm:.1f} mm of leads, "
          f"{sum(o['area_mm2'] >= CROSSING_MM2 for o in document['overlaps'])} row/column crossings "
          f"({document['overlap_mm2']:.3g} mm2 of overlap, {document['overlap_capacitance_pF']:.3g} pF at rest); "
          f"routed in {routing.time_s:.1f} s over {routing.assignments_tried} slot assignments")
    for layer, report in check.items():
        clearance = report["min_clearance_mm"]
        print(f"  {layer}: nets {', '.join(report['nets'])}; clearance "
              f"{'-' if clearance is None else f'{clearance:.3g} mm'}, edge {report['min_edge_distance_mm']:.3g} mm: "
              f"rules met")
    print(f"wrote {args.output}/: bottom.dxf bottom.svg top.dxf top.svg preview.png fabrication.json")
    return 0
