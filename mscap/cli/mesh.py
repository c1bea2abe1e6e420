"""``mscap mesh SCENE -o DIR``: build the layered mesh, write ``DIR/mesh.vtu``, report."""

from __future__ import annotations

import dataclasses
import json
import time

from mscap.cli.common import add_memory_option

__all__ = ["add_parser", "run"]


def add_parser(sub) -> None:
    p = sub.add_parser("mesh", help="mesh a scene and report mesh quality",
                       description="Mesh a scene's sheet and capacitor layout into layered "
                                   "tets; write DIR/mesh.vtu and print a report.")
    p.add_argument("scene", help="scene file (jobs/*.toml)")
    p.add_argument("-o", "--output", metavar="DIR", help="directory for mesh.vtu")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    add_memory_option(p)
    p.set_defaults(run=run)


def run(args) -> int:
    from mscap.mesh.io import write_mesh
    from mscap.mesh.layered import mesh_sheet
    from mscap.mesh.quality import mesh_report
    from mscap.mesh.triangulate import quality_grading_mm
    from mscap.outputs import output_directory, replace_file
    from mscap.scene import load_scene

    scene = load_scene(args.scene)
    out = output_directory(args.output, "mesh -o") if args.output else None  # before the work
    start = time.perf_counter()
    mesh = mesh_sheet(scene.sheet)
    report = mesh_report(mesh, time.perf_counter() - start)
    written = None
    if out is not None:
        written = replace_file(out / "mesh.vtu", lambda path: write_mesh(path, mesh))
    if args.json:
        print(json.dumps({"scene": scene.name, "settings": dataclasses.asdict(scene.mesh), **report.as_dict(),
                          "file": str(written) if written else None}))
        return 0
    print(f"scene {scene.name} ({scene.path}): {scene.layout.k} capacitors, "
          f"{scene.thickness_mm:.3f} mm thick")
    m = scene.mesh
    why = f"for a {100 * m.tolerance:g} % capacitance tolerance" if m.tolerance else "set by hand"
    grading = quality_grading_mm(m)
    print(f"  sizes ({why}): P{m.order} {m.element}s, edge {m.edge_length_outline_mm:.3g} mm at the outlines growing to "
          f"{m.edge_length_mm:g} mm over {grading:.3g} mm, {m.elements_per_layer} per layer")
    if grading > m.grading_distance_mm * (1 + 1e-9):
        print(f"  (grading_distance_mm = {m.grading_distance_mm:g} lengthened to {grading:.3g} mm: the edge length "
              f"grows at most 1 mm per mm, the 2D mesh quality's condition)")
    for line in report.lines():
        print("  " + line)
    if written:
        print(f"wrote {written}")
    return 0
