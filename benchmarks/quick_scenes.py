"""The paper's scenes end to end at quick resolution: `mpirun -n 3 mscap run` on each
``jobs/<scene>_quick.toml`` with the scene's own ``[multistart]``, then, where the scene
has a ``[calibration]``, `mpirun -n 3 mscap calibrate` of the chosen design against its
initial layout and the scene's layout. Plain commands, no extra flags: what a user
types. Each stage is timed; the issue's budget is 15 minutes per scene on 2 cores.

Run (about an hour on 2 cores; nothing else should run beside it, the times are the
point)::

    .venv/bin/python benchmarks/quick_scenes.py [SCENE ...] [--out out/quick]

Writes ``<out>/<scene>.h5`` (results), ``<out>/<scene>_calibration/`` (errors.csv,
summary.json, errors.png), ``<out>/<scene>_layouts.png`` and ``docs/quick_scenes.csv``
(one row per scene: times, chosen k, metric, error estimate, calibration errors), and
prints the rows as a Markdown table. Rows of scenes not run this time are kept.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCENES = ["poking", "poking_cross", "biaxial", "pneumatic", "joystick", "wrist", "glove"]
FIELDS = ["scene", "poses", "starts", "run_s", "calibrate_s", "total_s", "chosen_k", "chosen_run",
          "initial_metric_pF", "metric_pF", "iterations", "error_estimate", "finer_metric_pF",
          "error_optimised_mm", "error_optimised_std_mm", "error_initial_mm", "error_scene_mm",
          "error_no_signal_mm"]
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", OMP_NUM_THREADS="1")


def mscap(*args: str, ranks: int = 3, log: Path) -> float:
    """Run one mscap command under mpirun; return its wall time (s); stop on failure."""
    exe = str(Path(sys.executable).with_name("mscap"))
    command = ["mpirun", "-n", str(ranks), "--oversubscribe", exe, *args]
    print("$", " ".join(command[4:]), flush=True)
    start = time.perf_counter()
    with open(log, "a") as out:
        done = subprocess.run(command, env=ENV, stdout=out, stderr=subprocess.STDOUT, cwd=ROOT)
    wall = time.perf_counter() - start
    if done.returncode:
        sys.exit(f"{' '.join(args)} failed (exit {done.returncode}); see {log}")
    return wall


def scene_row(name: str, out: Path) -> dict:
    from mscap.design.history import min_pairwise_l1
    from mscap.scene import load_scene
    from mscap.service.store import read_run, read_store, store_selection

    path = ROOT / "jobs" / f"{name}_quick.toml"
    scene = load_scene(path)
    results = out / f"{name}.h5"
    log = out / f"{name}.log"
    log.unlink(missing_ok=True)
    results.unlink(missing_ok=True)
    run_s = mscap("run", str(path), "-o", str(results), log=log)
    with read_store(results) as store:
        selection = store_selection(store)
        best = read_run(store, selection.chosen_run)
        starts = len(store["runs"])
    subprocess.run([str(Path(sys.executable).with_name("mscap")), "plot", str(results), "-o",
                    str(out / f"{name}_layouts.png")], cwd=ROOT, env=ENV, capture_output=True)
    row = {"scene": f"{name}_quick", "poses": len(scene.poses), "starts": starts, "run_s": round(run_s, 1),
           "chosen_k": selection.chosen_k, "chosen_run": selection.chosen_run,
           "initial_metric_pF": round(min_pairwise_l1(best.initial_capacitance_pF), 3),
           "metric_pF": round(best.metric, 3), "iterations": best.iterations,
           "error_estimate": round(best.error_estimate, 5), "finer_metric_pF": round(best.finer_metric_pF, 3)}
    calibrate_s = 0.0
    if scene.calibration is not None:
        cal = out / f"{name}_calibration"
        calibrate_s = mscap("calibrate", str(path), "--design", str(results), "--baseline", "initial", "scene",
                            "-o", str(cal), log=log)
        summary = json.loads((cal / "summary.json").read_text())
        designs = summary["designs"]
        row.update(error_optimised_mm=round(designs[0]["mean_error"], 4),
                   error_optimised_std_mm=round(designs[0]["mean_error_std"], 4),
                   error_initial_mm=round(designs[1]["mean_error"], 4),
                   error_scene_mm=round(designs[2]["mean_error"], 4),
                   error_no_signal_mm=round(designs[0]["no_signal_mean_error"], 4))
    row.update(calibrate_s=round(calibrate_s, 1), total_s=round(run_s + calibrate_s, 1))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", default=SCENES, help=f"scene names (default: {' '.join(SCENES)})")
    parser.add_argument("--out", default="out/quick", help="directory for results, logs, figures")
    parser.add_argument("--csv", default=str(ROOT / "docs" / "quick_scenes.csv"))
    args = parser.parse_args()
    out = (ROOT / args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    table = Path(args.csv)
    rows = {}
    if table.exists():
        with open(table) as f:
            rows = {r["scene"]: r for r in csv.DictReader(f)}
    for name in args.scenes:
        row = scene_row(name, out)
        rows[row["scene"]] = row
        print(json.dumps(row), flush=True)
        with open(table, "w", newline="") as f:  # after every scene: a killed run keeps the rest
            writer = csv.DictWriter(f, FIELDS)
            writer.writeheader()
            for key in sorted(rows, key=lambda s: SCENES.index(s.removesuffix("_quick"))):
                writer.writerow({k: rows[key].get(k, "") for k in FIELDS})
    print("| scene | poses | starts | run | calibrate | k | min L1 initial → final (pF) | error est. | "
          "calibration: optimised / initial / scene / no signal (mm) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows.values():
        def mm(key):
            return "–" if r.get(key) in ("", None) else f"{float(r[key]):.3g}"
        print(f"| {r['scene']} | {r['poses']} | {r['starts']} | {float(r['run_s']) / 60:.1f} min | "
              f"{float(r['calibrate_s']) / 60:.1f} min | {r['chosen_k']} | {r['initial_metric_pF']} → "
              f"{r['metric_pF']} | {100 * float(r['error_estimate']):.2f} % | {mm('error_optimised_mm')} / "
              f"{mm('error_initial_mm')} / {mm('error_scene_mm')} / {mm('error_no_signal_mm')} |")


if __name__ == "__main__":
    main()
