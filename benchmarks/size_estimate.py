"""The size estimate before meshing (:mod:`mscap.mesh.budget`) against the meshes gmsh makes.

For every shipped scene (the seven paper scenes, the ``*_quick`` ones and quick.toml):
the estimated vertices and tets of the electrostatic and the elastic mesh against the
real counts (both meshed here, in this process), and the estimated peak memory of a
simulation against the peak resident set that ``/usr/bin/time -v`` reads off

* ``mscap mesh SCENE`` (the mesh and its quality report),
* ``mscap capacitance SCENE`` (the electrostatic solve at rest, no elastic problem),
* with ``--elastic``: ``mscap simulate SCENE --poses POSE`` for the first pose that
  deforms (elastic phase, then one electrostatic solve), on the quick scenes only (the
  paper scenes' first poses take minutes);
* with ``--p2``: ``mscap capacitance SCENE --order 2`` on the quick scenes (no shipped
  scene is P2);
* with ``--finer``: the counts of the finer-mesh check's meshes (every edge halved,
  :func:`mscap.service.accuracy.finer`) of the paper scenes.

Writes docs/size_estimate.csv and prints the Markdown table of docs/performance.md
("Size estimate before meshing") and the fits of ``KAPPA`` and ``BYTES_PER_UNKNOWN``
(median of measured over estimated; least squares for the bytes per unknown)::

    .venv/bin/python benchmarks/size_estimate.py --elastic --p2 --finer   # all, ~6 min
    .venv/bin/python benchmarks/size_estimate.py quick poking_quick --elastic --p2
"""

from __future__ import annotations

import argparse
import csv
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PAPER = ("poking", "poking_cross", "biaxial", "pneumatic", "joystick", "wrist", "glove")
QUICK = ("quick",) + tuple(f"{s}_quick" for s in PAPER)
CSV = ROOT / "docs" / "size_estimate.csv"
FIELDS = ("scene", "problem", "order", "est_vertices", "vertices", "vertices_err", "est_tets", "tets", "tets_err",
          "est_unknowns", "est_peak_MB", "mesh_peak_MB", "simulate_peak_MB", "simulate", "peak_err", "estimate_us")


def peak_mb(args: list[str]) -> float:
    """Peak RSS (MB) of ``mscap ARGS`` (``nan`` when it fails)."""
    mscap = str(Path(sys.executable).with_name("mscap"))
    done = subprocess.run(["/usr/bin/time", "-v", mscap, *args], cwd=ROOT, capture_output=True, text=True)
    found = re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr)
    if done.returncode != 0 or found is None:
        print(f"  mscap {' '.join(args)} failed (exit {done.returncode}): {done.stderr.strip()[-300:]}",
              file=sys.stderr)
        return float("nan")
    return int(found.group(1)) * 1024 / 1e6


def relative(estimate: float, actual: float) -> float:
    return estimate / actual - 1 if actual else float("nan")


def measure(name: str, elastic: bool, p2: bool, finer: bool) -> list[dict]:
    from mscap.mesh.budget import estimate_elastic, estimate_electrostatic
    from mscap.mesh.layered import mesh_elastic, mesh_sheet
    from mscap.scene import load_scene

    path = f"jobs/{name}.toml"
    scene = load_scene(ROOT / path)
    start = time.perf_counter()
    electro, el = estimate_electrostatic(scene.sheet), estimate_elastic(scene.sheet, scene.elastic, scene.poses)
    micros = (time.perf_counter() - start) * 1e6 / 2
    mesh = mesh_sheet(scene.sheet)
    rows = [dict(scene=name, problem="electrostatic", order=scene.mesh.order, est_vertices=electro.vertices,
                 vertices=len(mesh.points), est_tets=electro.tets, tets=len(mesh.tets),
                 est_unknowns=electro.unknowns, est_peak_MB=electro.memory_bytes / 1e6, estimate_us=micros)]
    rows[0]["mesh_peak_MB"] = peak_mb(["mesh", path])
    rows[0].update(simulate_peak_MB=peak_mb(["capacitance", path]), simulate="capacitance")
    if el is not None:
        emesh = mesh_elastic(scene.sheet, scene.elastic, mesh, scene.poses)
        row = dict(scene=name, problem="elastic", order=scene.elastic.order, est_vertices=el.vertices,
                   vertices=len(emesh.points), est_tets=el.tets, tets=len(emesh.tets), est_unknowns=el.unknowns,
                   est_peak_MB=max(el.memory_bytes, electro.memory_bytes) / 1e6, estimate_us=micros)
        deforming = next((p.name for p in scene.poses if p.kind != "free"), None)
        if elastic and deforming and name in QUICK:
            row.update(simulate_peak_MB=peak_mb(["simulate", path, "--poses", deforming, "-q"]),
                       simulate=f"simulate {deforming}")
        rows.append(row)
    if p2 and name in QUICK:
        from dataclasses import replace

        from mscap.mesh.budget import estimate_electrostatic as estimate

        e2 = estimate(replace(scene.sheet, mesh=replace(scene.mesh, order=2)))
        rows.append(dict(scene=name, problem="electrostatic", order=2, est_vertices=e2.vertices,
                         vertices=len(mesh.points), est_tets=e2.tets, tets=len(mesh.tets), est_unknowns=e2.unknowns,
                         est_peak_MB=e2.memory_bytes / 1e6, estimate_us=micros,
                         simulate_peak_MB=peak_mb(["capacitance", path, "--order", "2"]),
                         simulate="capacitance --order 2"))
    if finer and name in PAPER:
        from mscap.service.accuracy import finer as one_level_finer

        fine, fine_elastic = one_level_finer(scene.sheet, scene.elastic)
        fe, fel = estimate_electrostatic(fine), estimate_elastic(fine, fine_elastic, scene.poses)
        fmesh = mesh_sheet(fine)
        femesh = mesh_elastic(fine, fine_elastic, fmesh, scene.poses)
        for problem, est, m, order in (("electrostatic", fe, fmesh, fine.mesh.order),
                                       ("elastic", fel, femesh, fine_elastic.order)):
            rows.append(dict(scene=f"{name} (finer check)", problem=problem, order=order, est_vertices=est.vertices,
                             vertices=len(m.points), est_tets=est.tets, tets=len(m.tets), est_unknowns=est.unknowns,
                             est_peak_MB=max(fe.memory_bytes, fel.memory_bytes) / 1e6, estimate_us=micros))
    for row in rows:
        row["vertices_err"] = relative(row["est_vertices"], row["vertices"])
        row["tets_err"] = relative(row["est_tets"], row["tets"])
        measured = [m for m in (row.get("simulate_peak_MB"), row.get("mesh_peak_MB")) if m is not None and m == m]
        row["peak_err"] = relative(row["est_peak_MB"], max(measured)) if measured else float("nan")
    return rows


def fits(rows: list[dict]) -> list[str]:
    """The coefficients the measurements suggest (least squares over the scenes)."""
    from mscap.mesh.budget import BASE_BYTES, BYTES_PER_TET, BYTES_PER_UNKNOWN, KAPPA, MESH_BASE_BYTES

    lines = []
    tets = np.array([r["tets"] / r["est_tets"] for r in rows if "finer" not in r["scene"]])
    lines.append(f"KAPPA: {KAPPA:g} x median(actual/estimated tets) {np.median(tets):.3f} = "
                 f"{KAPPA * np.median(tets):.3f} (range {tets.min():.2f}-{tets.max():.2f})")
    meshed = [r for r in rows if np.isfinite(r.get("mesh_peak_MB", np.nan))]
    if len(meshed) > 1:
        slope, base = np.polyfit([r["tets"] for r in meshed], [r["mesh_peak_MB"] * 1e6 for r in meshed], 1)
        lines.append(f"mscap mesh: peak = {base / 1e6:.0f} MB + {slope:.0f} B x tets "
                     f"(now {MESH_BASE_BYTES / 1e6:.0f} MB "
                     f"+ {BYTES_PER_TET:.0f} B; {len(meshed)} scenes)")
    for order in (1, 2):
        chosen = [r for r in rows if (r["problem"], r["order"]) == ("electrostatic", order)
                  and np.isfinite(r.get("simulate_peak_MB", np.nan))]
        if len(chosen) < 2:
            continue
        u = np.array([r["est_unknowns"] * r["tets"] / r["est_tets"] for r in chosen])  # unknowns, count-corrected
        slope, base = np.polyfit(u, [r["simulate_peak_MB"] * 1e6 for r in chosen], 1)
        lines.append(f"mscap capacitance P{order}: peak = {base / 1e6:.0f} MB + {slope:.0f} B x unknowns (now "
                     f"{BASE_BYTES / 1e6:.0f} MB + {BYTES_PER_UNKNOWN[('electrostatic', order)]:.0f} B; "
                     f"{len(chosen)} scenes)")
    return lines


def markdown(rows: list[dict]) -> str:
    def pct(x):
        return "–" if not np.isfinite(x) else f"{100 * x:+.0f} %"

    def mb(x):
        return "–" if x is None or not np.isfinite(x) else f"{x:.0f}"
    lines = ["| scene | mesh | vertices est. / actual | tets est. / actual | error "
             "| peak MB est. / measured (run) | error |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['problem']} P{r['order']} | {r['est_vertices']:,.0f} / {r['vertices']:,} | "
                     f"{r['est_tets']:,.0f} / {r['tets']:,} | {pct(r['tets_err'])} | {mb(r['est_peak_MB'])} / "
                     f"{mb(r.get('simulate_peak_MB'))} ({r.get('simulate') or 'none'}; mesh alone "
                     f"{mb(r.get('mesh_peak_MB'))}) | {pct(r['peak_err'])} |")
    return "\n".join(lines)


def main() -> None:
    import os

    from mscap.mesh.budget import MEMORY_ENV

    os.environ.setdefault(MEMORY_ENV, "1000")  # measure, do not refuse (the finer meshes, a busy machine)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", default=PAPER + QUICK)
    parser.add_argument("--elastic", action="store_true", help="also one deforming pose of each quick scene")
    parser.add_argument("--p2", action="store_true", help="also the rest pose at --order 2 on the quick scenes")
    parser.add_argument("--finer", action="store_true", help="also the paper scenes' finer-mesh check meshes")
    parser.add_argument("--csv", default=str(CSV))
    args = parser.parse_args()
    rows = []
    for name in args.scenes:
        t0 = time.perf_counter()
        rows += measure(name, args.elastic, args.p2, args.finer)
        print(f"{name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    with open(args.csv, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in r.items()})
    print(markdown(rows))
    print()
    print("\n".join(fits(rows)))
    print(f"wrote {args.csv}")


if __name__ == "__main__":
    main()
