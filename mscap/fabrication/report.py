"""``mscap fabricate``'s output directory: the stencils, the preview, and
``fabrication.json`` with the array, the nets, the overlaps and the design-rule check of
the files as written. Written into a temporary sibling and renamed at the end, so a
failure leaves nothing behind and an existing ``-o`` (or a link there) is never touched.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import asdict
from pathlib import Path

import numpy as np

from mscap.errors import FabricationError
from mscap.fabrication.check import check_stencils
from mscap.fabrication.router import LAYERS, OVERLAP_WEIGHT_MM, Routing
from mscap.fabrication.stencil import layer_regions, write_dxf, write_svg

__all__ = ["FABRICATION_FILES", "fabrication_document", "write_fabrication", "check_target"]

#: What ``mscap fabricate -o DIR`` writes.
FABRICATION_FILES = ("bottom.dxf", "bottom.svg", "top.dxf", "top.svg", "preview.png", "fabrication.json")


def check_target(out) -> Path:
    """``out`` as a directory still to be made: nothing (not even a dangling link) may be
    there, and its parent must be a writable directory.

    Raises
    ------
    FabricationError
        ``out`` exists or its parent is not a writable directory.
    """
    out = Path(out)
    if os.path.lexists(out):
        kind = "a link" if out.is_symlink() else "a directory" if out.is_dir() else "a file"
        raise FabricationError(f"fabricate -o {out}: exists ({kind}); name a directory that does not exist yet")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise FabricationError(f"fabricate -o {out}: its parent {parent} is not a writable directory")
    return out


def fabrication_document(routing: Routing, check: dict, scene, design: str) -> dict:
    """``fabrication.json``: the array, pads in lead order, nets, overlaps with their
    parallel-plate rest capacitance across the middle dielectric (fringing left out), the
    rules and the design-rule check."""
    middle = scene.layers[2]
    per_mm2 = middle.material.permittivity_pF_per_mm / middle.thickness_mm
    array = routing.array
    overlaps = routing.overlaps()
    for o in overlaps:
        o["rest_capacitance_pF"] = o["area_mm2"] * per_mm2
    plates = []
    for c, (i, j) in enumerate(array.slots):
        area = routing.plates[c].area
        extra = sum(o["area_mm2"] for o in overlaps if (o["row"], o["column"]) == (i, j))
        plates.append({"capacitor": c, "row": i, "column": j, "plate_area_mm2": area,
                       "plate_capacitance_pF": area * per_mm2, "lead_overlap_mm2": extra,
                       "lead_share": extra / area,
                       "outline_mm": np.asarray(routing.plates[c].exterior.coords)[:-1].tolist()})
    return {
        "scene": scene.path, "design": design, "connector_edge": routing.edge,
        "array": {"rows": array.rows, "columns": array.columns, "slots": plates},
        "pads": [{"lead": n.lead, "net": n.name, "layer": n.layer,
                  "centre_mm": [round(n.pad.centroid.x, 4), round(n.pad.centroid.y, 4)]} for n in routing.nets],
        "nets": [{"name": n.name, "layer": n.layer, "lead": n.lead, "capacitors": list(n.capacitors),
                  "trace_width_mm": routing.rules.trace_width_mm, "length_mm": n.length_mm,
                  "centre_lines_mm": [np.round(p, 4).tolist() for p in n.paths]} for n in routing.nets],
        "overlaps": overlaps,
        "overlap_mm2": sum(o["area_mm2"] for o in overlaps),
        "overlap_capacitance_pF": sum(o["rest_capacitance_pF"] for o in overlaps),
        "dielectric": {"layer": middle.name, "thickness_mm": middle.thickness_mm,
                       "relative_permittivity": middle.material.relative_permittivity},
        "router": {"assignments_tried": routing.assignments_tried, "time_s": routing.time_s,
                   "cost_mm": routing.cost, "overlap_weight_mm_per_mm2": OVERLAP_WEIGHT_MM,
                   "lead_length_mm": routing.length_mm},
        "rules": asdict(routing.rules),
        "design_rule_check": check,
    }


def write_fabrication(routing: Routing, out, scene, design: str, preview=None) -> dict:
    """Write :data:`FABRICATION_FILES` of ``routing`` to the new directory ``out``; the
    design rules are checked on the written files before the directory appears.
    ``preview(routing, path, title)`` draws ``preview.png`` (``mscap fabricate`` gives
    :func:`mscap.viz.fabrication.plot_routing`; without it there is no preview: figures
    are the floor above, docs/architecture.md).

    Raises
    ------
    FabricationError
        ``out`` exists (:func:`check_target`), or the written files break a rule.
    """
    out = check_target(out)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent if str(out.parent) else "."))
    try:
        groups = {layer: layer_regions(routing, layer) for layer in LAYERS}
        bounds = np.array([g.bounds for layer in groups.values() for polys in layer.values() for g in polys])
        extent = (bounds[:, 0].min() - 1, bounds[:, 1].min() - 1, bounds[:, 2].max() + 1, bounds[:, 3].max() + 1)
        for layer, layer_groups in groups.items():
            write_dxf(tmp / f"{layer}.dxf", layer_groups)
            write_svg(tmp / f"{layer}.svg", layer_groups, extent)
        check = check_stencils(tmp, routing.rules, list(routing.plates))
        if check["violations"]:
            raise FabricationError(f"the written stencils break the design rules: {'; '.join(check['violations'][:3])}"
                                   + (f" (and {len(check['violations']) - 3} more)" if len(check["violations"]) > 3
                                      else ""))
        document = fabrication_document(routing, _finite(check), scene, design)
        if preview is not None:
            preview(routing, tmp / "preview.png", title=design)
        (tmp / "fabrication.json").write_text(json.dumps(document, indent=1))
        os.rename(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return document


def _finite(value):
    """JSON has no infinity: a layer with a single net has no clearance to report."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value
