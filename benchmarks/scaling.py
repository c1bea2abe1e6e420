"""Forward simulation time and peak memory against mesh size, with fitted exponents.

Refines a scene (default: jobs/poking.toml, the paper's 2 × 2 poking sensor: rest and
four 13 mm pokes) by multiplying every edge length by a factor: ``[mesh]
edge_length_mm`` and ``edge_length_outline_mm``, ``[elastic] edge_length_mm`` (and its
``edge_length_outline_mm`` if set); the grading distance and the layers through the
thickness stay as they are. Each level runs the cold forward simulation
(:func:`mscap.fem.simulate.simulate`, every pose, meshing included) on one core in a
process of its own, so the peak resident memory (``ru_maxrss``) is that level's alone.

Per level: electrostatic tets and vertices, elastic tets and nodes, wall time with the
split of :func:`~mscap.fem.simulate.simulate` (mesh, setup, elastic, electrostatic) and of
:mod:`mscap.profile` (meshing, assembly, factorisation, solve, other), the resident
memory after start-up (Python, numpy, PETSc) and the peak. The fits
log t = a + p log(tets) and log(peak MB) = a + p log(tets) run over the levels, tets
being the electrostatic mesh's (the elastic mesh is 60–100× smaller); the elastic time
is also fitted against the elastic tets. Python, numpy and PETSc take some 90 MB before
any mesh, which flattens the peak-memory fit on small meshes, so the memory above
start-up is fitted too, and that fit (plus the start-up) says at how many tets a worker
would reach 2 GB, the memory target per worker, marked on the plot.

Run (about 2–3 minutes on an idle machine: seven levels, 77k to 1.8M tets; ``--quick``
for a 10-second smoke run on jobs/poking_quick.toml, three levels, 31k to 78k tets,
that writes to a temporary directory)::

    .venv/bin/python benchmarks/scaling.py
    .venv/bin/python benchmarks/scaling.py --quick

Writes ``docs/scaling.csv`` and ``docs/scaling.png`` (``--csv``/``--png`` elsewhere)
and prints a Markdown table and the exponents.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"):  # one core per level
    os.environ.setdefault(_var, "1")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import table_head, write_csv  # noqa: E402

#: Edge-length factors: on poking.toml 76,740 to 1,821,750 electrostatic tets (24×).
FACTORS = (2.83, 2.0, 1.41, 1.0, 0.71, 0.5, 0.35)
QUICK_FACTORS = (2.0, 1.41, 1.0)
#: Memory target per worker (MB).
TARGET_MB = 2048.0
FIELDS = ["factor", "edge_length_outline_mm", "edge_length_mm", "elastic_edge_length_mm", "tets", "vertices",
          "elastic_tets", "elastic_nodes", "wall_s", "mesh_s", "setup_s", "elastic_s", "electrostatic_s",
          "meshing_s", "assembly_s", "factorisation_s", "solve_s", "other_s", "start_rss_MB", "peak_rss_MB"]


def refined(scene, factor: float):
    """``scene`` with every edge length multiplied by ``factor``."""
    mesh, elastic = scene.mesh, scene.elastic
    outline = elastic.edge_length_outline_mm
    return replace(scene,
                   mesh=replace(mesh, edge_length_mm=mesh.edge_length_mm * factor,
                                edge_length_outline_mm=mesh.edge_length_outline_mm * factor),
                   elastic=replace(elastic, edge_length_mm=elastic.edge_length_mm * factor,
                                   edge_length_outline_mm=None if outline is None else outline * factor))


def peak_rss_MB() -> float:
    """Peak resident memory of this process so far (``ru_maxrss`` is in kB on Linux)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure(scene_path: str, factor: float) -> dict:
    """One level, in this process: the cold forward simulation of the refined scene."""
    from mscap import profile
    from mscap.fem.petsc import petsc, set_scene_options
    from mscap.scene import load_scene
    from mscap.fem.simulate import simulate

    petsc()
    scene = refined(load_scene(scene_path), factor)
    set_scene_options(scene.petsc_options)
    start_rss = peak_rss_MB()
    profile.reset()
    t0 = time.perf_counter()
    sim = simulate(scene)
    wall = time.perf_counter() - t0
    split = profile.split(wall)
    elastic = sim.elastic
    return dict(factor=factor, edge_length_outline_mm=scene.mesh.edge_length_outline_mm,
                edge_length_mm=scene.mesh.edge_length_mm, elastic_edge_length_mm=scene.elastic.edge_length_mm,
                tets=len(sim.mesh.tets), vertices=len(sim.mesh.points),
                elastic_tets=0 if elastic is None else len(elastic.mesh.tets),
                elastic_nodes=0 if elastic is None else len(elastic.rest),
                wall_s=wall, **{f"{key}_s": sim.times[key] for key in ("mesh", "setup", "elastic", "electrostatic")},
                **{f"{key}_s": split[key] for key in ("meshing", "assembly", "factorisation", "solve", "other")},
                start_rss_MB=start_rss, peak_rss_MB=peak_rss_MB())


def run_level(scene_path: str, factor: float) -> dict:
    """One level in a fresh Python process (its own peak memory)."""
    out = subprocess.run([sys.executable, __file__, "--child", str(factor), "--scene", scene_path],
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"level {factor:g} failed:\n{out.stderr[-3000:]}")
    row = json.loads(out.stdout.strip().splitlines()[-1])
    print(f"factor {factor:<5g} {row['tets']:>9d} tets {row['elastic_tets']:>7d} elastic tets  "
          f"{row['wall_s']:7.2f} s  peak {row['peak_rss_MB']:7.0f} MB", flush=True)
    return row


def fit(x, y) -> tuple[float, float]:
    """Exponent p and intercept a of log y = a + p log x."""
    p, a = np.polyfit(np.log(x), np.log(y), 1)
    return float(p), float(a)


def fits(rows) -> dict[str, tuple[float, float]]:
    """The fitted (p, a) of the total time, the two physics stages and the peak memory."""
    col = {key: np.array([r[key] for r in rows], dtype=float) for key in rows[0]}
    out = {"time": fit(col["tets"], col["wall_s"]),
           "electrostatic": fit(col["tets"], col["electrostatic_s"]),
           "memory": fit(col["tets"], col["peak_rss_MB"]),
           "memory_above_start": fit(col["tets"], col["peak_rss_MB"] - col["start_rss_MB"])}
    if col["elastic_tets"].min() > 0:
        out["elastic_vs_elastic_tets"] = fit(col["elastic_tets"], col["elastic_s"])
    return out


def tets_at_target(rows, fitted) -> float:
    """Electrostatic tets at which start-up plus the fitted memory above it reaches the target."""
    start = float(np.mean([r["start_rss_MB"] for r in rows]))
    p, a = fitted["memory_above_start"]
    return float(np.exp((np.log(TARGET_MB - start) - a) / p))


def markdown(rows) -> str:
    """The levels as a Markdown table."""
    head = ("| factor | h_out mm | tets | vertices | elastic tets | mesh s | setup s | elastic s | electro s "
            "| total s | assembly s | factor. s | solve s | other s | peak MB |")
    lines = table_head(head)
    for r in rows:
        lines.append(f"| {r['factor']:g} | {r['edge_length_outline_mm']:.3g} | {r['tets']:,} | {r['vertices']:,} "
                     f"| {r['elastic_tets']:,} | {r['mesh_s']:.2f} | {r['setup_s']:.2f} | {r['elastic_s']:.2f} "
                     f"| {r['electrostatic_s']:.2f} | {r['wall_s']:.2f} | {r['assembly_s']:.2f} "
                     f"| {r['factorisation_s']:.2f} | {r['solve_s']:.2f} | {r['other_s']:.2f} "
                     f"| {r['peak_rss_MB']:.0f} |")
    return "\n".join(lines)


def plot(rows, fitted, path: Path, name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tets = np.array([r["tets"] for r in rows], dtype=float)
    line = np.geomspace(tets.min(), tets.max(), 50)
    fig, (ax_t, ax_m) = plt.subplots(1, 2, figsize=(11, 4.5))
    for key, label, style in [("wall_s", "total", "ko"), ("electrostatic_s", "electrostatics", "s"),
                              ("elastic_s", "elastic", "^"), ("mesh_s", "meshing", "v")]:
        ax_t.loglog(tets, [r[key] for r in rows], style, label=label, alpha=0.8)
    for key, label in [("time", "total"), ("electrostatic", "electrostatics")]:
        p, a = fitted[key]
        ax_t.loglog(line, np.exp(a) * line ** p, "--", lw=1, label=f"fit {label}: t ∝ tets^{p:.2f}")
    ax_t.set_ylabel("wall time on one core (s)")
    ax_t.set_title(f"{name}: cold forward simulation, all poses")

    p, a = fitted["memory"]
    ax_m.loglog(tets, [r["peak_rss_MB"] for r in rows], "ko", label="peak resident memory")
    ax_m.loglog(tets, [r["start_rss_MB"] for r in rows], "x", color="gray", label="after start-up")
    ax_m.loglog(line, np.exp(a) * line ** p, "--", lw=1, label=f"fit: peak MB ∝ tets^{p:.2f}")
    start = np.mean([r["start_rss_MB"] for r in rows])
    p, a = fitted["memory_above_start"]
    ax_m.loglog(line, start + np.exp(a) * line ** p, ":", lw=1,
                label=f"start-up + fit ∝ tets^{p:.2f}: 2 GB at {tets_at_target(rows, fitted):.2g} tets")
    ax_m.axhline(TARGET_MB, color="tab:red", ls=":", label="target: 2 GB per worker")
    ax_m.set_ylabel("memory (MB)")
    ax_m.set_title("peak memory per level (own process)")
    for ax in (ax_t, ax_m):
        ax.set_xlabel("electrostatic tets")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", help="scene file (default jobs/poking.toml; --quick: jobs/poking_quick.toml)")
    parser.add_argument("--factors", type=lambda s: tuple(map(float, s.split(","))),
                        help=f"comma-separated edge-length factors (default {','.join(map(str, FACTORS))})")
    parser.add_argument("--quick", action="store_true", help="three coarse levels, output to a temporary directory")
    parser.add_argument("--csv", help="CSV path (default docs/scaling.csv; --quick: a temporary directory)")
    parser.add_argument("--png", help="PNG path (default docs/scaling.png; --quick: a temporary directory)")
    parser.add_argument("--child", type=float, help=argparse.SUPPRESS)  # run one level, print JSON
    args = parser.parse_args(argv)
    scene_path = args.scene or str(ROOT / "jobs" / ("poking_quick.toml" if args.quick else "poking.toml"))
    if args.child is not None:
        print(json.dumps(measure(scene_path, args.child)))
        return

    out_dir = Path(tempfile.mkdtemp(prefix="mscap_scaling_")) if args.quick else ROOT / "docs"
    csv_path = Path(args.csv or out_dir / "scaling.csv")
    png_path = Path(args.png or out_dir / "scaling.png")
    factors = args.factors or (QUICK_FACTORS if args.quick else FACTORS)
    rows = [run_level(scene_path, factor) for factor in factors]
    fitted = fits(rows)
    write_csv(rows, csv_path, FIELDS)
    plot(rows, fitted, png_path, Path(scene_path).stem)
    print("\n" + markdown(rows) + "\n")
    for key, (p, _) in fitted.items():
        print(f"exponent {key}: {p:.2f}")
    print(f"2 GB per worker reached at about {tets_at_target(rows, fitted):.3g} electrostatic tets "
          f"(start-up + memory above it, extrapolated)")
    print(f"wrote {csv_path} and {png_path}")


if __name__ == "__main__":
    main()
