"""Numerical stability of the elastic solver: hard materials, thin layers, large strains.

Runs every pose of the scenes in ``benchmarks/scenes/`` through the forward pipeline
(:func:`mscap.fem.simulate.simulate`, one pose at a time on one electrostatic mesh per
scene) and records, for each pose, either the converged equilibrium (Newton iterations, of them projected,
load steps, step cuts, final residual, min J, wall time, capacitances) or the
:class:`~mscap.errors.MscapError` it stopped with. Every converged pose is checked:

* no NaN: finite node positions and capacitances, C > 0;
* min J > 0 and the residual at most the scene's ``[elastic] tolerance``;
* pokes: the ball-node gap in (0, d̂] and the top surface at the full depth;
* a physical sanity check per pose kind (see :func:`physical_check` and
  docs/stability.md): roller stretches against the homogeneous neo-Hookean uniaxial
  solution, clamped stretches between the uniaxial and plane-strain limits, rigid plates
  barely stretch, glued cylinders between two kinematic bounds, pokes and domes raise C;
* C/C0 within 5 % of the same pose with P2 elements (:data:`REFERENCE_P2`), and across
  case 1 (ν = 0.47, 0.49, 0.499) within 2 %: more flags volumetric locking.

A failing pose must fail with an error naming the pose, the load step and the residual;
case 7 is meant to fail. Prints the table and writes ``docs/stability.csv``
(docs/stability.md explains it)::

The elastic problem lives where ``mscap simulate`` puts it (each scene's ``[elastic]
mesh``: its own coarser mesh, 5 mm edges by default) unless ``--elastic-mesh shared``
puts it on the electrostatic mesh, which resolves every layer; ``both`` runs each case
both ways (the rows carry an ``elastic_mesh`` column)::

    .venv/bin/python benchmarks/stability.py                    # all cases, as mscap simulate
    .venv/bin/python benchmarks/stability.py --elastic-mesh both   # and shared: docs/stability.csv
    .venv/bin/python benchmarks/stability.py --cases 1a,1b -v   # some, with progress
    .venv/bin/python benchmarks/stability.py --cases 1r,1a,1b --elastic-order 2   # P2
    .venv/bin/python benchmarks/stability.py --hessian projected   # every case, one mode
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime
import logging
import math
import os
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "benchmarks" / "scenes"
CSV = ROOT / "docs" / "stability.csv"


@dataclass(frozen=True)
class Case:
    id: str
    scene: str
    what: str
    expect_error: bool = False


CASES = (
    Case("1r", "nu_0.47.toml", "reference: the paper's nu = 0.47, stretch 1.5 and a poke"),
    Case("1a", "nu_0.49.toml", "nu = 0.49 (both materials), stretch 1.5 and a poke"),
    Case("1b", "nu_0.499.toml", "nu = 0.499 (both materials), stretch 1.5 and a poke"),
    Case("1c", "nu_0.499_fine.toml", "nu = 0.499, clamped stretch 1.5 on a finer mesh (edge 2 mm)"),
    Case("2", "stiff_1e3.toml", "stiffness ratio 1e3 (carbon 570 MPa, clear 0.57 MPa)"),
    Case("3", "thin_10um.toml", "five 10 um layers on a 100 mm sheet, stretch 1.5 and a 13 mm poke"),
    Case("4", "stretch_200.toml", "200 % uniaxial stretch (lambda = 3), clamp and roller"),
    Case("5", "ball_poke.toml", "2 cm ball 13 mm into the 10 cm poking sensor (coarse mesh)"),
    Case("6a", "glue_bend.toml", "glued: cylinder R = 5 mm on 30 mm (wraps 6 rad), dome R = 25 mm"),
    Case("6b", "glue_narrow.toml", "glued: 10 mm strip on cylinders R = 5 mm and R = 2 mm"),
    Case("7", "impossible.toml", "max_iterations = 2, max_cuts = 0 on one-step pokes: must fail",
         expect_error=True),
)

#: C/C0 of the same poses on the same meshes with P2 elements (quadratic tets lock far
#: less), measured by ``benchmarks/stability.py --cases 1r,1a,1b,2,4,6a,6b
#: --elastic-order 2`` (docs/stability.md; about 40 min). A P1 result further than
#: :data:`REFERENCE_TOLERANCE` from it fails the check: locking or discretisation error.
REFERENCE_P2 = {
    ("1r", "stretch_clamp"): 1.4508, ("1r", "stretch_roller"): 1.4219, ("1r", "poke"): 1.0418,
    ("1a", "stretch_clamp"): 1.4536, ("1a", "stretch_roller"): 1.4208, ("1a", "poke"): 1.0429,
    ("1b", "stretch_clamp"): 1.4555, ("1b", "stretch_roller"): 1.4202, ("1b", "poke"): 1.0448,
    ("2", "stretch_clamp"): 1.0592, ("2", "stretch_roller"): 1.0535, ("2", "poke"): 1.0053,
    ("4", "stretch_clamp"): 2.8082, ("4", "stretch_roller"): 2.6907,
    ("6a", "cylinder_R5"): 1.1049, ("6a", "dome_R25"): 1.0720,
    ("6b", "cylinder_R5"): 1.1011, ("6b", "cylinder_R2"): 1.2622,
}
REFERENCE_TOLERANCE = 0.05

FIELDS = ("case", "scene", "elastic_mesh", "pose", "kind", "outcome", "newton_iterations", "projected", "load_steps",
          "step_cuts", "residual", "tolerance", "min_J", "elastic_s", "wall_s", "C_pF", "C_over_C0",
          "P2_C_over_C0", "check", "note", "message")


# -- physical sanity checks -------------------------------------------------------------

def uniaxial_lateral_stretch(stretch: float, material) -> float:
    """Lateral (and thickness) stretch a of compressible neo-Hookean uniaxial tension:
    F = diag(λ, a, a) with zero lateral stress, μ (a² − 1) + λ_L ln(λ a²) = 0."""
    mu, lam = material.lame_MPa
    return brentq(lambda a: mu * (a * a - 1) + lam * math.log(stretch * a * a), 1e-6, 10.0, xtol=1e-14)


def cylinder_bounds(layers, radius: float) -> tuple[float, float]:
    """Bounds on C/C0 of a plate pair glued on a cylinder of radius R (sheet outside).

    Lower: the sheet keeps its thickness and straight normals (a cylindrical capacitor,
    C/C0 = d / (R ln((R + z2)/(R + z1)))). Upper: nearly incompressible plane strain
    along the axis, the gap's mid-line stretched by (R + z̄)/R and the gap thinned by as
    much: ((R + z̄)/R)². z1, z2 bound the dielectric gap (rest heights above the bottom)."""
    z1 = layers[0].thickness_mm + layers[1].thickness_mm
    z2 = z1 + layers[2].thickness_mm
    lower = (z2 - z1) / (radius * math.log((radius + z2) / (radius + z1)))
    upper = ((radius + 0.5 * (z1 + z2)) / radius) ** 2
    return lower, upper


def physical_check(scene, problem, pose, state, ratio: np.ndarray) -> tuple[list[str], str]:
    """``(failures, note)`` of one converged pose (see the module docstring)."""
    fails, notes = [], []
    rest = problem.rest
    x = state.nodes
    if pose.kind == "stretch":
        lam = max(pose.stretch)
        uz = float(np.abs(x[:, 2] - rest[:, 2]).max())
        mesh = problem.mesh
        # Plate 0's nodes by its 2D footprint: an own elastic mesh of one slab through the
        # stack has no tet in a conductive layer (capacitor_of_tet is -1 everywhere).
        plate = np.unique(mesh.tets[mesh.mesh2d.capacitor_of_triangle[mesh.triangle_of_tet] == 0])
        sx, sy = (np.ptp(x[plate, :2], axis=0) / np.ptp(rest[plate, :2], axis=0))
        notes.append(f"plate stretch {sx:.3f} x {sy:.3f}; max |u_z| {uz:.3g} mm")
        c = float(ratio.max())
        conductive = scene.layers[1]
        stiff = conductive.material.youngs_modulus_MPa / conductive.fill.youngs_modulus_MPa
        if stiff > 2:
            # Rigid-plate limit: the plates barely stretch, so C barely changes.
            if not (sx - 1 <= 0.1 * (lam - 1) and 1 <= c <= 1 + 0.2 * (lam - 1)):
                fails.append(f"plates {stiff:.0f}x stiffer than the fill stretch {sx:.3f} (C/C0 {c:.4f}); "
                             f"expected <= {1 + 0.1 * (lam - 1):.3g} (C/C0 in [1, {1 + 0.2 * (lam - 1):.3g}])")
        elif pose.grips == "roller":
            # The plates are stiffer than the fill, so the fill near the edge stretches a
            # little more than lambda: compare with the homogeneous solution at the local
            # axial stretch (slope of x against X within 5 mm of the edge).
            band = np.flatnonzero(rest[:, 0] <= rest[:, 0].min() + 5.0)
            local = float(np.polyfit(rest[band, 0], x[band, 0], 1)[0])
            a = uniaxial_lateral_stretch(local, scene.layers[0].material)
            # Columns of vertices on the roller edge x_min: thickness = top − bottom of each
            # column, width = y extent of each level (immune to a tilt of the edge).
            levels = len(mesh.level_z_mm)
            columns = x[:problem.n_vertices].reshape(levels, -1, 3)
            rest_columns = rest[:problem.n_vertices].reshape(levels, -1, 3)
            edge = np.flatnonzero(np.abs(rest_columns[0, :, 0] - rest[:, 0].min()) < 1e-9)
            thick = float(np.mean(columns[-1, edge, 2] - columns[0, edge, 2])) / float(mesh.level_z_mm[-1])
            width = float(np.mean(np.ptp(columns[:, edge, 1], axis=1))) / float(np.ptp(rest_columns[0, edge, 1]))
            notes.append(f"edge width x{width:.4f}, thickness x{thick:.4f}; homogeneous {a:.4f} at the "
                         f"edge's stretch {local:.4f}")
            if abs(width / a - 1) > 0.005 or abs(thick / a - 1) > 0.005:
                fails.append(f"edge contraction {width:.4f}/{thick:.4f} differs from {a:.4f} by > 0.5 %")
            if not 0.85 * lam <= c <= 1.01 * lam:
                fails.append(f"C/C0 = {c:.4f} outside [0.85, 1.01] x lambda = {lam:g}")
        elif not 0.85 * lam <= c <= lam ** 2:
            fails.append(f"C/C0 = {c:.4f} outside [0.85 lambda, lambda^2] = [{0.85 * lam:.3g}, {lam ** 2:.3g}]")
    elif pose.kind == "poke":
        dhat = pose.barrier_distance_mm
        gap = state.min_gap_mm
        top = np.flatnonzero(rest[:, 2] >= rest[:, 2].max() - 1e-12)
        z_top = float(rest[:, 2].max())
        bottom = z_top - pose.depth_mm                       # lowest point of the ball
        low = float(x[top, 2].min()) - bottom
        mesh = problem.mesh
        far = scene.elastic.edge_length_mm if scene.elastic.mesh == "own" else scene.mesh.edge_length_mm
        h = min(far, pose.radius_mm)  # the far edge of the mesh the elastic problem is on
        rise = pose.radius_mm - math.sqrt(pose.radius_mm ** 2 - h ** 2)
        # The barrier acts on nodes only: between them the flat top facets cut into the
        # ball by up to their sagitta. Informational (the tets stay valid).
        n2 = len(mesh.mesh2d.points)
        facets = mesh.mesh2d.triangles + (len(mesh.level_z_mm) - 1) * n2
        centre = np.array([*pose.center_mm, z_top + pose.radius_mm - pose.depth_mm])
        inside = pose.radius_mm - np.linalg.norm(x[facets].mean(axis=1) - centre, axis=1)
        notes.append(f"gap {gap:.3g} mm (d^ {dhat:g}); lowest top node {low:+.3g} mm from the ball's bottom; "
                     f"top facets up to {max(float(inside.max()), 0.0):.3g} mm inside the ball "
                     f"(sheet {z_top:g} mm thick)")
        if not (gap is not None and 0 < gap <= dhat * (1 + 1e-9)):
            fails.append(f"ball gap {gap} outside (0, {dhat:g}]")
        if not -dhat * (1 + 1e-9) <= low <= rise:
            fails.append(f"top surface {low:+.3g} mm from the ball's bottom, outside [-d^, {rise:.3g}]")
        if not ratio.max() >= 1.0:
            fails.append(f"poking lowers every capacitance (max C/C0 {ratio.max():.4f})")
    elif pose.kind == "glue":
        generator = pose.object.generator
        radius = dict(pose.generator_parameters).get("radius_mm") if pose.generator_parameters else None
        if generator == "cylinder":
            lower, upper = cylinder_bounds(scene.layers, radius)
            notes.append(f"cylinder bounds [{lower:.4f}, {upper:.4f}]")
            if not 0.99 * lower <= ratio.max() <= 1.01 * upper:
                fails.append(f"C/C0 = {ratio.max():.4f} outside the cylinder bounds [{lower:.4f}, {upper:.4f}]")
        elif not ratio.min() >= 1.0:
            fails.append(f"a glued {generator} lowers a capacitance (C/C0 {ratio.min():.4f})")
    return fails, "; ".join(notes)


# -- running ----------------------------------------------------------------------------

def run_case(case: Case, elastic_order: int | None = None, verbose: bool = False,
             hessian: str | None = None, elastic_mesh: str | None = None) -> list[dict]:
    """Every non-free pose of ``case``, each in its own :func:`simulate` on one
    electrostatic mesh. ``elastic_mesh``: ``None`` keeps the scene's ``[elastic] mesh``
    (``"own"`` unless the scene says otherwise: what ``mscap simulate`` runs); ``"shared"``
    or ``"own"`` override it."""
    from mscap.errors import MscapError
    from mscap.mesh.layered import mesh_sheet
    from mscap.fem.petsc import set_scene_options
    from mscap.scene import load_scene
    from mscap.fem.simulate import simulate

    scene = load_scene(SCENES / case.scene)
    if elastic_mesh is not None:
        scene = dataclasses.replace(scene, elastic=dataclasses.replace(scene.elastic, mesh=elastic_mesh))
    if hessian:
        scene = dataclasses.replace(scene, elastic=dataclasses.replace(scene.elastic, hessian=hessian))
    set_scene_options(scene.petsc_options)
    mesh = mesh_sheet(scene.sheet)
    progress = (lambda m: print("    " + m, file=sys.stderr, flush=True)) if verbose else None
    rest_scene = dataclasses.replace(scene, poses=tuple(p for p in scene.poses if p.kind == "free")[:1])
    c0 = simulate(rest_scene, mesh=mesh).capacitance_pF[0] if rest_scene.poses else None
    tol = scene.elastic.tolerance
    rows = []
    for pose in scene.poses:
        if pose.kind == "free":
            continue
        row = dict.fromkeys(FIELDS, "")
        row.update(case=case.id, scene=case.scene, elastic_mesh=scene.elastic.mesh, pose=pose.name, kind=pose.kind,
                   tolerance=tol)
        start = time.perf_counter()
        try:
            sim = simulate(dataclasses.replace(scene, poses=(pose,)), mesh=mesh,
                           elastic_order=elastic_order, progress=progress)
        except MscapError as exc:
            message = str(exc)
            row.update(wall_s=time.perf_counter() - start, message=message)
            missing = [w for w, ok in ((f"pose name {pose.name!r}", repr(pose.name) in message),
                                       ("'load step'", "load step" in message),
                                       ("'residual'", "residual" in message)) if not ok]
            if "nan" in message.lower().split("residual")[-1]:
                missing.append("a finite residual (message says nan)")
            kind = type(exc).__name__
            if missing:
                row.update(outcome=f"{kind}, MESSAGE INCOMPLETE", check="message lacks " + ", ".join(missing))
            else:
                row.update(outcome=f"{kind} (expected)" if case.expect_error else kind,
                           check="message names pose, load step, residual")
            rows.append(row)
            continue
        except Exception as exc:  # a crash is a bug: record it, keep going
            row.update(wall_s=time.perf_counter() - start, outcome=f"CRASH {type(exc).__name__}",
                       message=f"{type(exc).__name__}: {exc}")
            rows.append(row)
            continue
        wall = time.perf_counter() - start
        result = sim.poses[0]
        state = result.state
        caps = np.asarray(result.capacitance_pF, dtype=float)
        ratio = caps / c0 if c0 is not None else np.full_like(caps, np.nan)
        fails = []
        if not np.isfinite(state.nodes).all():
            fails.append("non-finite node positions")
        if not (np.isfinite(caps).all() and (caps > 0).all()):
            fails.append(f"capacitances not finite and positive: {caps}")
        if not (np.isfinite(state.min_j) and state.min_j > 0):
            fails.append(f"min J = {state.min_j}")
        if not (np.isfinite(state.residual) and state.residual <= tol):
            fails.append(f"residual {state.residual:.3g} > tolerance {tol:g}")
        note = ""
        if not fails:
            physical, note = physical_check(scene, sim.elastic, pose, state, ratio)
            fails += physical
        reference = REFERENCE_P2.get((case.id, pose.name))
        if reference is not None and (elastic_order or scene.elastic.order) == 1:
            off = float(ratio.max()) / reference - 1
            row["P2_C_over_C0"] = reference
            note = f"P2 reference {reference:.4f} ({off:+.1%}); " + note
            if abs(off) > REFERENCE_TOLERANCE:
                fails.append(f"C/C0 {off:+.1%} off the P2 reference {reference:.4f} "
                             f"(> {REFERENCE_TOLERANCE:.0%}: P1 locking or discretisation error)")
        if case.expect_error:
            fails.insert(0, "converged where an error was expected")
        row.update(outcome="converged" if not fails else "converged, CHECK FAILED",
                   newton_iterations=state.newton_iterations, projected=state.projected,
                   load_steps=state.load_steps, step_cuts=state.step_cuts, residual=state.residual,
                   min_J=state.min_j, elastic_s=result.elastic_s, wall_s=wall,
                   C_pF=" ".join(f"{c:.4f}" for c in caps), C_over_C0=" ".join(f"{r:.4f}" for r in ratio),
                   check="ok" if not fails else "; ".join(fails), note=note)
        rows.append(row)
    return rows


def _fmt(value, spec: str) -> str:
    return "" if value == "" else format(value, spec)


def table(rows: list[dict]) -> str:
    head = (f"{'case':<5}{'mesh':<7}{'pose':<16}{'outcome':<26}{'newton':>7}{'proj':>5}{'steps':>6}{'cuts':>5}"
            f"{'residual':>10}{'min J':>8}{'wall s':>8}  {'C/C0':<14}check")
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(f"{r['case']:<5}{r['elastic_mesh']:<7}{r['pose']:<16}{r['outcome']:<26}"
                     f"{_fmt(r['newton_iterations'], 'd'):>7}"
                     f"{_fmt(r['projected'], 'd'):>5}{_fmt(r['load_steps'], 'd'):>6}{_fmt(r['step_cuts'], 'd'):>5}"
                     f"{_fmt(r['residual'], '.2e'):>10}{_fmt(r['min_J'], '.3f'):>8}{_fmt(r['wall_s'], '.1f'):>8}  "
                     f"{r['C_over_C0']:<14}{r['check']}")
        for extra in (r["note"], r["message"]):
            if extra:
                lines.append(f"{'':28}{extra}")
    return "\n".join(lines)


DRIFT = 0.02


def nu_trend(rows: list[dict]) -> tuple[str, list[str]]:
    """C/C0 of the case-1 poses against ν, and the poses whose C/C0 drifts by more than
    :data:`DRIFT` between ν = 0.47 and 0.499. The physical answer barely depends on ν
    there (P2: < 0.4 %), so a drift flags volumetric locking of the elements."""
    by = {(r["case"], r["pose"], r["elastic_mesh"]): r for r in rows if r["case"] in ("1r", "1a", "1b")}
    poses = sorted({(p, m) for _, p, m in by}, key=lambda pm: [(r["pose"], r["elastic_mesh"]) for r in rows].index(pm))
    if not poses:
        return "", []
    lines = ["C/C0 against nu (case 1):         nu=0.47   nu=0.49  nu=0.499   drift"]
    drifting = []
    for pose, mesh in poses:
        values = [by.get((c, pose, mesh), {}).get("C_over_C0", "") for c in ("1r", "1a", "1b")]
        numbers = [float(v.split()[0]) for v in values if v]
        drift = max(numbers) / min(numbers) - 1 if len(numbers) > 1 else 0.0
        flag = f"  > {DRIFT:.0%}: LOCKING" if drift > DRIFT else ""
        if flag:
            drifting.append(f"{pose} ({mesh})")
        lines.append(f"  {pose + ' (' + mesh + ')':<31}" + "".join(f"{v or '-':>9}" for v in values)
                     + f"{drift:>8.1%}{flag}")
    return "\n".join(lines), drifting


def machine() -> str:
    cpu = ""
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    debian = Path("/etc/debian_version").read_text().strip() if Path("/etc/debian_version").exists() else "?"
    return f"{os.cpu_count()} cores ({cpu or platform.processor()}), Debian {debian}, Python {platform.python_version()}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", help="comma-separated case ids (default: all): "
                        + ", ".join(c.id for c in CASES))
    parser.add_argument("--elastic-order", type=int, choices=(1, 2), help="elastic element order (default: the scenes')")
    parser.add_argument("--hessian", choices=("auto", "exact", "projected"),
                        help="Hessian mode for every case (default: the scenes', auto)")
    parser.add_argument("--elastic-mesh", choices=("shared", "own", "both"),
                        help="where the elastic problem lives; default: each scene's [elastic] mesh, what "
                             "`mscap simulate` runs (own, at its [elastic] edge_length_mm, for every scene "
                             "here); shared: on the electrostatic mesh (resolves every layer); both: every "
                             "case in the default configuration, then shared")
    parser.add_argument("--csv", help=f"CSV to write (default: {CSV.relative_to(ROOT)} for a full default run, "
                        "else none)")
    parser.add_argument("-v", "--verbose", action="store_true", help="progress of every load step")
    args = parser.parse_args(argv)
    from mscap.fem.petsc import petsc

    petsc([])
    logging.basicConfig(level=logging.WARNING)
    cases = CASES
    if args.cases:
        wanted = args.cases.split(",")
        unknown = set(wanted) - {c.id for c in CASES}
        if unknown:
            parser.error(f"unknown case(s) {', '.join(sorted(unknown))}")
        cases = tuple(c for c in CASES if c.id in wanted)
    out = Path(args.csv) if args.csv else (CSV if not (args.cases or args.elastic_order or args.hessian
                                                       or args.elastic_mesh in ("shared", "own")) else None)

    stamp = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
    print(f"mscap stability benchmark, {stamp}, {machine()}")
    rows, start = [], time.perf_counter()
    for case in cases:
        t0 = time.perf_counter()
        print(f"case {case.id}: {case.what} ({case.scene})", flush=True)
        case_rows = []
        for mesh_choice in ((None, "shared") if args.elastic_mesh == "both" else (args.elastic_mesh,)):
            case_rows += run_case(case, args.elastic_order, args.verbose, args.hessian, mesh_choice)
        rows += case_rows
        print(f"  {len(case_rows)} poses in {time.perf_counter() - t0:.1f} s", flush=True)
    total = time.perf_counter() - start
    print()
    print(table(rows))
    trend, drifting = nu_trend(rows)
    if trend:
        print()
        print(trend)
    expected = {c.id for c in CASES if c.expect_error}
    bad = [r for r in rows if any(w in r["outcome"] for w in ("FAILED", "CRASH", "INCOMPLETE"))
           or (r["case"] in expected and "expected" not in r["outcome"])]
    failed = [r for r in rows if r["case"] not in expected and r["message"]]
    print(f"\n{len(rows)} poses: {len(bad)} wrong (check failed, crash, incomplete message), "
          f"{len(failed)} clean solver failures outside case 7, {len(drifting)} drifting with nu; "
          f"{total:.0f} s in all "
          f"(elastic order {args.elastic_order or 'of the scenes'}, Hessian {args.hessian or 'of the scenes'})")
    if out:
        with open(out, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=FIELDS)
            writer.writeheader()
            for r in rows:
                writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
        print(f"wrote {out}")
    return 1 if bad or drifting else 0


if __name__ == "__main__":
    sys.exit(main())
