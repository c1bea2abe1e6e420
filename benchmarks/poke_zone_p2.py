"""Does a P2 elastic mesh refined only under the ball read a poke's gain cheaper than uniform P2?

A poke's signal, the gain C(poke) − C(rest) of a plate, is elastic-element limited: on
issue 44's poke (benchmarks/element_bias.py: a 40 mm sheet held at its x edges, a 16 mm
plate, a 5 mm ball 4 mm deep) uniform P2 reads 1.2257 / 1.1710 / 1.1339 / 1.1270 pF at a
5 / 2.5 / 1.25 / 0.8 mm elastic edge (ν = 0.47), limit ≈ 1.122 pF. The hypothesis tested:
the P2 error sits where the ball contacts and bends the sheet, so P2 at a 5 mm far edge
with one refinement zone under each ball, edge a·R within b·R of the ball's centre (R the
ball radius; the mscap rules kept: :mod:`mscap.mesh.triangulate` grades the edge at
ZONE_SLOPE = 0.5 mm per mm beyond the zone, and outline segments within the zone get its
size), beats refining everywhere per unit of wall time. The target: within 3 % of the
converged gain at ≤ 0.5× the wall of uniform P2 at 2.5 mm.

The study behind ``[elastic] refine_pokes`` (:func:`mscap.scene.sizing.p2_poke_refinement`
is its "ball a=0.35 b=1.5 + strips 2.5 mm" row, with gmsh Box fields for the strips; the
uniform rows here turn it off). :func:`mscap.mesh.layered.mesh_elastic` left the zones
out of a P2 elastic mesh; here a
local copy that puts ``(cx, cy, b R, a R)`` under every poke's ball is patched in for the
P2 runs that ask for a zone (and into :mod:`mscap.fem.simulate`, which imports it by
name); nothing in mscap/ is changed.

As a diagnostic of where else the error sits, the same copy can put strips along the held
edges instead or as well: discs of radius 1 mm, 1 mm apart, centred on each held edge, each
a zone of edge 1.25 or 2.5 mm (so graded out at ZONE_SLOPE too: a 1.25 mm strip refines
about 8.5 mm in from the edge).

Two scenes, each configuration one :func:`mscap.fem.simulate.simulate` of the whole
scene timed with ``time.perf_counter`` (meshing, both elastic and electrostatic phases),
one after the other in one process, after one untimed warm-up simulation; each timed
configuration ``--repeats`` times, the median wall reported (the gain is the same every
time):

- **issue44**: the scene of element_bias.py (its electrostatic mesh: the 1 % tolerance
  mesh with its zones under the ball) at ν = 0.47 (and ``--nus``). Reference: 1.122 pF at
  ν = 0.47 (the limit above; uniform P2 at 1.25 mm is run too and its gain is listed);
  at other ν, uniform P2 at 1.25 mm measured here (on ν = 0.47 it reads 1.0 % above the
  limit, so errors against it there read about a point low).
- **poking**: jobs/poking.toml with its ``[mesh]`` sizes replaced by ``tolerance = 0.01``
  (the electrostatic mesh of docs/electrostatics.md, "The pose-to-pose signal": zones R/8
  within 1.5 R under every ball), R = 10 mm, 13 mm deep, solved for the pose pair rest +
  poke_0 only (the four pokes are equal by symmetry); the elastic zones go under all four
  balls (the mesh the whole scene would use). Reference: the P2 Richardson reference of
  the pressed gains there, 4.871–4.877 pF (4.874 used; the P2 chain without elastic zones
  extrapolates 1.3 % higher, 4.930–4.936). Today's code reads uniform P2 at 5 and 2.5 mm
  0.47 % above the docs' rows for them (5.056 / 4.967 against 5.033 / 4.944 pF), so the
  reference may be as stale: rescaled, 4.897 pF, every error here is 0.45 points lower.
  The first configuration is timed alone; if it takes longer than ``--poking-budget``
  seconds the rest is skipped (a pose pair takes 15–55 s).

Run (about 9 minutes on one core of the 2-core machine, the other idle; 4 with ν = 0.47 only)::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/poke_zone_p2.py --nus 0.47 0.30 0.49

``--nus`` picks the Poisson ratios of the issue-44 scene (default 0.47 alone); ``--no-poking`` leaves out
jobs/poking.toml. Writes ``docs/poke_zone_p2.csv`` and prints a Markdown table.

**Sweep mode** (``--sweep`` and/or ``--extra``; the default run above is unchanged). The rows
become the baselines (uniform P2 at 5 and 2.5 mm, the default "ball a=0.35 b=1.5 + strips
2.5 mm" as discs, as Box strips and as mscap's own ``refine_pokes`` mesh), then the
configurations, then P2 2.5 mm and the default again (a drift check: the wall ratio is to
the median of both P2 2.5 mm runs' walls). ``--sweep`` adds the factorial grid ``--far`` ×
``--ball-a`` × ``--ball-b`` × ``--strip-size`` × ``--strip-width`` on the issue-44 scene
(strips as gmsh Box fields, mscap's form: edge ``size`` within ``width`` of each held edge);
``--extra SPEC ...`` adds named configurations on both scenes, SPEC ``far=5,a=0.3,b=1.25,s=2,w=2``
(``a``/``b``: the ball zone, ``s``/``w``: the strips; leave either pair out for none;
``strips=disc`` for the rows of discs above). The CSV gains the columns ``strip_width_mm``,
``strip_kind``, ``cpu_s`` (median process CPU seconds, less sensitive than the wall to other
jobs on the machine) and ``cpu_ratio`` (to P2 at 2.5 mm's). E.g. (write elsewhere than docs/)::

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/poke_zone_p2.py --sweep --no-poking --out /tmp/sweep.csv
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/poke_zone_p2.py --nus 0.30 0.49 \
        --extra far=6,a=0.3,b=1.25,s=2,w=2 --out /tmp/candidates.csv
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mscap.fem.simulate as simulate_module  # noqa: E402
import mscap.mesh.layered as layered  # noqa: E402
from benchmarks._common import table_head, tolerance_text, write_csv  # noqa: E402
from benchmarks.element_bias import scene_text  # noqa: E402
from mscap.fem.petsc import petsc  # noqa: E402
from mscap.profile import timed  # noqa: E402
from mscap.scene import load_scene  # noqa: E402
from mscap.scene.poses import PokePose  # noqa: E402

#: The converged gain of issue 44's poke at ν = 0.47 (uniform P2 at 5, 2.5, 1.25, 0.8 mm).
ISSUE44_LIMIT_047 = 1.122
#: poking.toml's pressed gain, P2 Richardson reference (docs/electrostatics.md): 4.871–4.877.
POKING_REFERENCE = 4.874

#: (label, elastic edge mm, zones: None or {"ball": (a, b), "edges": (size, width)}). a R: the
#: ball zone's edge, b R: its radius. The held-edge strips are a diagnostic of where else the
#: error sits (docs/elastic.md lists P2 5 mm with 1.25 mm strips 1 mm wide at +2.4 %).
ISSUE44_CONFIGS = [
    ("P2 5 mm", 5.0, None),
    ("P2 2.5 mm", 2.5, None),
] + [(f"P2 5 mm, ball a={a:g} b={b:g}", 5.0, {"ball": (a, b)}) for b in (1.5, 2.0) for a in (0.5, 0.35, 0.25)] + [
    ("P2 5 mm, held-edge strips 1.25 mm", 5.0, {"edges": (1.25, 1.0)}),
    ("P2 5 mm, held-edge strips 2.5 mm", 5.0, {"edges": (2.5, 1.0)}),
    ("P2 5 mm, ball a=0.5 b=1.5 + strips 1.25 mm", 5.0, {"ball": (0.5, 1.5), "edges": (1.25, 1.0)}),
    ("P2 5 mm, ball a=0.5 b=1.5 + strips 2.5 mm", 5.0, {"ball": (0.5, 1.5), "edges": (2.5, 1.0)}),
    ("P2 5 mm, ball a=0.35 b=1.5 + strips 2.5 mm", 5.0, {"ball": (0.35, 1.5), "edges": (2.5, 1.0)}),
]
ISSUE44_REFERENCE = ("P2 1.25 mm", 1.25, None)
#: R = 10 mm: a = 0.5 is the 5 mm far edge itself (no zone), so finer a.
POKING_CONFIGS = [
    ("P2 5 mm", 5.0, None),
    ("P2 2.5 mm", 2.5, None),
    ("P2 5 mm, ball a=0.25 b=1.5", 5.0, {"ball": (0.25, 1.5)}),
    ("P2 5 mm, ball a=0.35 b=1.5", 5.0, {"ball": (0.35, 1.5)}),
    ("P2 5 mm, held-edge strips 1.25 mm", 5.0, {"edges": (1.25, 1.0)}),
    ("P2 5 mm, held-edge strips 2.5 mm", 5.0, {"edges": (2.5, 1.0)}),
    ("P2 5 mm, ball a=0.35 b=1.5 + strips 2.5 mm", 5.0, {"ball": (0.35, 1.5), "edges": (2.5, 1.0)}),
]
#: The default refinement, (a, b) of the ball zone and (size, width) of the strips, at a 5 mm far edge.
DEFAULT_BALL, DEFAULT_STRIPS = (0.35, 1.5), (2.5, 1.0)


def sweep_label(far: float, spec: dict) -> str:
    parts = []
    if spec.get("ball"):
        parts.append("ball a={:g} b={:g}".format(*spec["ball"]))
    for kind in ("boxes", "edges"):
        if spec.get(kind):
            size, width = spec[kind]
            parts.append(f"strips {size:g} mm w={width:g}" + (" (discs)" if kind == "edges" else ""))
    return f"P2 {far:g} mm" + (", " + " + ".join(parts) if parts else "")


def parse_spec(text: str) -> tuple[str, float, dict | None]:
    """``far=5,a=0.3,b=1.25,s=2,w=2[,strips=disc]`` as a configuration (label, far edge, zones)."""
    values = dict(item.split("=", 1) for item in text.replace(" ", "").split(",") if item)
    unknown = set(values) - {"far", "a", "b", "s", "w", "strips"}
    if unknown:
        raise SystemExit(f"--extra {text!r}: unknown keys {sorted(unknown)} (far, a, b, s, w, strips)")
    far = float(values.get("far", 5.0))
    spec: dict = {}
    if "a" in values or "b" in values:
        spec["ball"] = (float(values.get("a", DEFAULT_BALL[0])), float(values.get("b", DEFAULT_BALL[1])))
    if "s" in values or "w" in values:
        kind = {"box": "boxes", "disc": "edges"}[values.get("strips", "box")]
        spec[kind] = (float(values.get("s", 0.5 * far)), float(values.get("w", DEFAULT_STRIPS[1])))
    return sweep_label(far, spec), far, spec or None


def sweep_configs(grid: bool, extras: list, args) -> tuple[list, list]:
    """Sweep mode's rows (issue 44, poking): baselines, the grid (issue 44 only), the extras, and
    P2 2.5 mm and the default again."""
    default = {"ball": DEFAULT_BALL, "boxes": DEFAULT_STRIPS}
    head = [("P2 5 mm", 5.0, None), ("P2 2.5 mm", 2.5, None),
            ("P2 5 mm, ball a=0.35 b=1.5 + strips 2.5 mm", 5.0, {"ball": DEFAULT_BALL, "edges": DEFAULT_STRIPS}),
            (sweep_label(5.0, default), 5.0, default),
            ("P2 5 mm, mscap refine_pokes", 5.0, {"mscap": True})]
    tail = [("P2 2.5 mm (again)", 2.5, None), (sweep_label(5.0, default) + " (again)", 5.0, default)]
    cells = []
    if grid:
        for far in args.far:
            for a in args.ball_a:
                for b in args.ball_b:
                    for size in args.strip_size:
                        for width in args.strip_width:
                            spec = {"ball": (a, b), "boxes": (size, width)}
                            cells.append((sweep_label(far, spec), far, spec))
    extra = [parse_spec(t) for t in extras]
    return head + cells + extra + tail, head + extra + tail[:1]


FIELDS = ["scene", "nu", "config", "edge_mm", "zone_a", "zone_b", "strip_edge_mm", "gain_pF", "reference_pF",
          "reference",
          "error", "error_vs_p2_1.25", "elastic_dofs", "wall_s", "walls_s", "elastic_s", "wall_ratio",
          "load_avg"]

#: What the patched mesh_elastic puts in a P2 mesh: ``{"ball": (a, b), "edges": (size, width)}``,
#: either optional (None: mscap's own rule, no zones).
_ZONE: dict | None = None
#: The poses whose balls and held edges get zones (default: the simulated scene's).
_ZONE_POSES: tuple = ()
_ORIGINAL = layered.mesh_elastic


def zones_of(spec: dict, poses, sheet_outline_mm) -> tuple[tuple[float, float, float, float], ...]:
    """The zones of ``spec``: ``(cx, cy, b R, a R)`` under every poke's ball; and, for
    ``edges = (size, width)``, discs of radius ``width`` ``width`` apart (at most ``size``)
    along every held edge, a strip of edge ``size`` about ``width`` wide (a diagnostic)."""
    pokes = [p for p in poses if isinstance(p, PokePose)]
    zones = []
    if spec.get("ball"):
        a, b = spec["ball"]
        zones += [(float(p.center_mm[0]), float(p.center_mm[1]), b * p.radius_mm, a * p.radius_mm) for p in pokes]
    if spec.get("edges"):
        size, width = spec["edges"]
        lo, hi = np.min(sheet_outline_mm, axis=0), np.max(sheet_outline_mm, axis=0)
        for edge in sorted({e for p in pokes for e in p.held_edges}):
            axis, at = (0, lo[0]) if edge == "x_min" else (0, hi[0]) if edge == "x_max" else \
                (1, lo[1]) if edge == "y_min" else (1, hi[1])
            other = 1 - axis
            n = int(np.ceil((hi[other] - lo[other]) / min(width, size))) + 1
            for t in np.linspace(lo[other], hi[other], n):
                xy = [0.0, 0.0]
                xy[axis], xy[other] = float(at), float(t)
                zones.append((xy[0], xy[1], float(width), float(size)))
    return tuple(zones)


def strips_of(spec: dict, poses, sheet_outline_mm) -> tuple[tuple[float, float, float, float, float], ...]:
    """For ``boxes = (size, width)``: gmsh Box strips ``(x0, y0, x1, y1, size)`` within
    ``width`` of every held edge, as :func:`mscap.scene.sizing.p2_poke_refinement` makes them."""
    if not spec.get("boxes"):
        return ()
    size, w = spec["boxes"]
    (x0, y0), (x1, y1) = np.min(sheet_outline_mm, axis=0), np.max(sheet_outline_mm, axis=0)
    boxes = {"x_min": (x0 - w, y0 - w, x0 + w, y1 + w), "x_max": (x1 - w, y0 - w, x1 + w, y1 + w),
             "y_min": (x0 - w, y0 - w, x1 + w, y0 + w), "y_max": (x0 - w, y1 - w, x1 + w, y1 + w)}
    held = sorted({e for p in poses if isinstance(p, PokePose) for e in p.held_edges})
    return tuple((*map(float, boxes[e]), float(size)) for e in held)


@timed("meshing")
def zoned_mesh_elastic(sheet, settings, mesh, poses):
    """:func:`mscap.mesh.layered.mesh_elastic` with, for P2 and a set :data:`_ZONE`, the
    zones of :func:`zones_of` instead of none (the rest is mesh_elastic's own code)."""
    from mscap.mesh.budget import check_fits, estimate_elastic
    from mscap.mesh.triangulate import triangulate

    if _ZONE is not None and _ZONE.get("mscap"):  # mscap's own refined mesh (refine_pokes on)
        return _ORIGINAL(sheet, replace(settings, refine_pokes=True), mesh, poses)
    if _ZONE is None or settings.order != 2 or settings.mesh == "shared":  # uniform: mscap's refinement off
        return _ORIGINAL(sheet, replace(settings, refine_pokes=False), mesh, poses)
    check_fits(estimate_elastic(sheet, settings, poses), sheet.path)
    h = settings.edge_length_mm
    outline = min(settings.edge_length_outline_mm or 0.5 * h, h)
    zones = zones_of(_ZONE, _ZONE_POSES or poses, sheet.outline_mm)
    strips = strips_of(_ZONE, _ZONE_POSES or poses, sheet.outline_mm)
    mesh2d = triangulate(sheet.outline_mm, layered.elastic_layout(sheet.layout, sheet.outline_mm, outline),
                         replace(sheet.mesh, edge_length_mm=h, edge_length_outline_mm=outline, fringe_distance_mm=0.0,
                                 zones=zones, strips=strips))
    return layered.extrude(mesh2d, sheet.thicknesses_mm, sheet.mesh.elements_per_layer,
                           slabs=settings.elements_through_thickness or None)


layered.mesh_elastic = zoned_mesh_elastic
simulate_module.mesh_elastic = zoned_mesh_elastic


def load_text(text: str):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "case.toml"
        path.write_text(text)
        return load_scene(str(path))


def poking_scene():
    """jobs/poking.toml at the 1 % electrostatic tolerance (zones under all four balls),
    poses rest and poke_0 only; and all its poses (for the elastic zones)."""
    scene = load_text(tolerance_text(ROOT / "jobs" / "poking.toml"))
    return replace(scene, poses=scene.poses[:2]), scene.poses


def measure(scene, edge: float, zone, repeats: int, zone_poses=()):
    """Gain of capacitor 0 between the scene's first two poses, elastic dofs, median wall,
    every wall and the median elastic seconds, for P2 at ``edge`` with the zones ``zone``
    (:func:`zones_of`; under ``zone_poses``' balls when given)."""
    global _ZONE, _ZONE_POSES
    from mscap.fem.simulate import simulate

    _ZONE, _ZONE_POSES = zone, tuple(zone_poses)
    scene = replace(scene, elastic=replace(scene.elastic, order=2, edge_length_mm=edge))
    gains, walls, elastic, cpus = [], [], [], []
    try:
        for _ in range(repeats):
            start, cpu = time.perf_counter(), time.process_time()
            sim = simulate(scene, keep_fields=False)
            walls.append(time.perf_counter() - start)
            cpus.append(time.process_time() - cpu)
            c = sim.capacitance_pF[:, 0]
            gains.append(float(c[1] - c[0]))
            elastic.append(sum(p.elastic_s for p in sim.poses))
            dofs = sim.elastic.n_dofs
            del sim
    finally:
        _ZONE, _ZONE_POSES = None, ()
    if max(gains) - min(gains) > 1e-9 * abs(gains[0]):
        print(f"  (gain differs between repeats: {gains})", flush=True)
    return gains[0], dofs, statistics.median(walls), walls, statistics.median(elastic), statistics.median(cpus)


def report(rows, row):
    rows.append(row)
    print(f"{row['scene']:<8} nu {row['nu']:.2f} {row['config']:<56} gain {row['gain_pF']:8.4f} pF "
          f"{100 * row['error']:+6.2f} %  {row['elastic_dofs']:>7d} dofs  wall {row['wall_s']:7.2f} s "
          f"(elastic {row['elastic_s']:6.2f} s, cpu {row['cpu_s']:6.2f} s)  ratio {row['wall_ratio']:.2f} "
          f"(cpu {row['cpu_ratio']:.2f})", flush=True)


def row_of(scene_name, nu, measured, reference, what, fine, base, load, base_cpu=None):
    label, edge, spec, g, dofs, wall, walls, elastic, cpu = measured
    spec = spec or {}
    return dict(scene=scene_name, nu=nu, config=label, edge_mm=edge, zone_a=spec.get("ball", ("", ""))[0],
                zone_b=spec.get("ball", ("", ""))[1],
                strip_edge_mm=spec.get("edges", spec.get("boxes", ("", "")))[0],
                strip_width_mm=spec.get("edges", spec.get("boxes", ("", "")))[1],
                strip_kind="disc" if spec.get("edges") else "box" if spec.get("boxes") else "", gain_pF=g,
                reference_pF=reference, reference=what, error=g / reference - 1,
                **{"error_vs_p2_1.25": g / fine - 1}, elastic_dofs=dofs, wall_s=wall,
                walls_s=" ".join(f"{w:.3f}" for w in walls), elastic_s=elastic, wall_ratio=wall / base,
                load_avg=load, cpu_s=cpu, cpu_ratio=cpu / base_cpu if base_cpu else float("nan"))


def baseline_wall(measured) -> float:
    """The wall of uniform P2 at 2.5 mm: the median of every wall of its rows (one, or two in a sweep)."""
    walls = [w for m in measured if m[0].startswith("P2 2.5 mm") for w in m[6]]
    return statistics.median(walls) if walls else float("nan")


def baseline_cpu(measured) -> float:
    """The CPU seconds of uniform P2 at 2.5 mm (the mean of its rows' medians)."""
    cpus = [m[8] for m in measured if m[0].startswith("P2 2.5 mm")]
    return statistics.mean(cpus) if cpus else float("nan")


def run_issue44(nu: float, repeats: int, rows: list, configs=None) -> None:
    scene = load_text(scene_text("poke", nu))
    measured = []
    for label, edge, spec in (configs or ISSUE44_CONFIGS) + [ISSUE44_REFERENCE]:
        n = 1 if label == ISSUE44_REFERENCE[0] else repeats
        measured.append((label, edge, spec, *measure(scene, edge, spec, n)))
        print(f"  issue44 nu {nu:.2f} {label}: {measured[-1][3]:.4f} pF, {measured[-1][4]} dofs, walls "
              f"{[round(w, 2) for w in measured[-1][6]]}, load {os.getloadavg()[0]:.2f}", flush=True)
    fine = measured[-1][3]
    reference, what = (ISSUE44_LIMIT_047, "limit of P2 5/2.5/1.25/0.8 mm (issue 44)") if abs(nu - 0.47) < 1e-9 \
        else (fine, "P2 1.25 mm, measured")
    base = baseline_wall(measured)
    for m in measured:
        report(rows, row_of("issue44", nu, m, reference, what, fine, base, os.getloadavg()[0],
                            baseline_cpu(measured)))


def run_poking(budget_s: float, configs: list, rows: list) -> None:
    scene, all_poses = poking_scene()
    measured = []
    for i, (label, edge, spec) in enumerate(configs):
        measured.append((label, edge, spec, *measure(scene, edge, spec, 1, all_poses)))
        print(f"  poking {label}: {measured[-1][3]:.4f} pF, {measured[-1][4]} dofs, {measured[-1][5]:.1f} s, "
              f"load {os.getloadavg()[0]:.2f}", flush=True)
        if i == 0 and measured[-1][5] > budget_s:
            print(f"  poking: {measured[-1][5]:.0f} s for one pose pair is over the {budget_s:.0f} s budget; "
                  "the rest skipped", flush=True)
            break
    base = baseline_wall(measured)
    what = "P2 Richardson (docs/electrostatics.md), pressed gains 4.871-4.877"
    for m in measured:
        report(rows, row_of("poking", 0.47, m, POKING_REFERENCE, what, float("nan"), base, os.getloadavg()[0],
                            baseline_cpu(measured)))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(ROOT / "docs" / "poke_zone_p2.csv"))
    parser.add_argument("--nus", nargs="*", type=float, default=[0.47])
    parser.add_argument("--repeats", type=int, default=3, help="timed simulations per issue44 configuration")
    parser.add_argument("--no-poking", action="store_true")
    parser.add_argument("--poking-budget", type=float, default=600.0, help="seconds for poking's first config")
    parser.add_argument("--poking-configs", type=int, default=len(POKING_CONFIGS),
                        help="run the first this many of POKING_CONFIGS")
    sweep = parser.add_argument_group("sweep mode (the default rows are replaced by baselines + these)")
    sweep.add_argument("--sweep", action="store_true", help="the factorial grid below on issue 44 (not on poking)")
    sweep.add_argument("--far", nargs="+", type=float, default=[5.0, 6.0, 7.5], help="far edges, mm")
    sweep.add_argument("--ball-a", nargs="+", type=float, default=[0.25, 0.3, 0.35], help="ball zone edge / R")
    sweep.add_argument("--ball-b", nargs="+", type=float, default=[1.0, 1.25, 1.5], help="ball zone radius / R")
    sweep.add_argument("--strip-size", nargs="+", type=float, default=[2.0, 2.5], help="held-edge strip edge, mm")
    sweep.add_argument("--strip-width", nargs="+", type=float, default=[1.0, 2.0],
                       help="held-edge strip half-width, mm")
    sweep.add_argument("--extra", nargs="+", default=[], metavar="SPEC",
                       help="extra configurations on both scenes: far=5,a=0.3,b=1.25,s=2,w=2[,strips=disc]")
    args = parser.parse_args(argv)
    issue44_configs, poking_configs = None, POKING_CONFIGS[:args.poking_configs]
    fields = FIELDS
    if args.sweep or args.extra:
        issue44_configs, poking_configs = sweep_configs(args.sweep, args.extra, args)
        fields = FIELDS + ["strip_width_mm", "strip_kind", "cpu_s", "cpu_ratio"]
        if Path(args.out).resolve() == (ROOT / "docs" / "poke_zone_p2.csv").resolve():
            raise SystemExit("sweep mode: give --out elsewhere than docs/poke_zone_p2.csv")
        print(f"sweep: {len(issue44_configs)} issue44 configurations x {len(args.nus)} nu, "
              f"{0 if args.no_poking else len(poking_configs)} on poking", flush=True)
    petsc()
    rows: list = []
    measure(load_text(scene_text("poke", 0.47)), 5.0, None, 1)  # warm-up: imports, gmsh, PETSc
    for nu in args.nus:
        run_issue44(nu, args.repeats, rows, issue44_configs)
    if not args.no_poking:
        run_poking(args.poking_budget, poking_configs, rows)
    write_csv([{k: r[k] for k in fields} for r in rows], Path(args.out), fields)
    print()
    print("\n".join(table_head("| scene | ν | configuration | gain | error | elastic dofs | wall | "
                                "wall / P2 2.5 mm |")))
    for r in rows:
        print(f"| {r['scene']} | {r['nu']:.2f} | {r['config']} | {r['gain_pF']:.4f} pF | {100 * r['error']:+.1f} % | "
              f"{r['elastic_dofs']:,} | {r['wall_s']:.2f} s | {r['wall_ratio']:.2f} |")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
