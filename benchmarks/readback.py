"""Does the chosen design read poses back better than every baseline? (docs/results.md,
"Designing for read-back".)

For each calibrated quick scene: `mpirun -n 3 mscap run jobs/<scene>_quick.toml` (the
scene's own objective and `[multistart]`, optionally restricted to start indices with
``--seeds``, for replicas with disjoint seeds), then `mpirun -n 3 mscap calibrate` of the
chosen design against its own initial layout, the scene's layout and the initial layout
of every other start of the run. Plain commands, timed; nothing else should run beside it.

    .venv/bin/python benchmarks/readback.py wrist pneumatic [--multistart-seed 1] [--tag r2] [--out out/readback]
    .venv/bin/python benchmarks/readback.py wrist --scene-file jobs/wrist_quick.toml  # another objective

Appends one row per scene to ``docs/readback.csv`` (tag, times, chosen run, its bound,
the calibration error of the chosen design and of every baseline, and whether it beats
them all) and prints it.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from quick_scenes import mscap  # noqa: E402  (the timed mpirun wrapper)

FIELDS = ["scene", "tag", "objective", "seeds", "run_s", "calibrate_s", "chosen_k", "chosen_run",
          "initial_bound_mm", "bound_mm", "error_chosen_mm", "error_chosen_std_mm", "error_own_initial_mm",
          "error_scene_mm", "best_other_baseline", "error_best_other_mm", "error_no_signal_mm", "beats_all"]


def scene_row(name: str, scene_file: Path, out: Path, seeds: str | None, tag: str) -> dict:
    from mscap.service.store import read_run, read_store, store_selection

    results = out / f"{name}_{tag}.h5"
    log = out / f"{name}_{tag}.log"
    for stale in (results, log, out / f"{name}_{tag}_calibration.h5"):
        stale.unlink(missing_ok=True)
    run_s = mscap("run", str(scene_file), "-o", str(results), *(["--seeds", seeds] if seeds else []), log=log)
    with read_store(results) as store:
        selection = store_selection(store)
        best = read_run(store, selection.chosen_run)
        others = sorted(rid for rid in store["runs"] if rid != selection.chosen_run and not rid.startswith("."))
    cal = out / f"{name}_{tag}_calibration"
    baselines = ["initial", "scene"] + [f"{rid}:initial" for rid in others]
    calibrate_s = mscap("calibrate", str(scene_file), "--design", str(results), "--baseline", *baselines,
                        "-o", str(cal), log=log)
    designs = json.loads((cal / "summary.json").read_text())["designs"]
    chosen, rest = designs[0], designs[1:]
    best_other = min(rest[2:], key=lambda d: d["mean_error"]) if len(rest) > 2 else None
    return {"scene": f"{name}_quick", "tag": tag, "objective": scene_file.name, "seeds": seeds or "scene",
            "run_s": round(run_s, 1), "calibrate_s": round(calibrate_s, 1), "chosen_k": selection.chosen_k,
            "chosen_run": selection.chosen_run, "initial_bound_mm": round(best.initial_bound_mm, 4),
            "bound_mm": round(best.bound_mm, 4), "error_chosen_mm": round(chosen["mean_error"], 4),
            "error_chosen_std_mm": round(chosen["mean_error_std"], 4),
            "error_own_initial_mm": round(rest[0]["mean_error"], 4),
            "error_scene_mm": round(rest[1]["mean_error"], 4),
            "best_other_baseline": "" if best_other is None else best_other["label"],
            "error_best_other_mm": "" if best_other is None else round(best_other["mean_error"], 4),
            "error_no_signal_mm": round(chosen["no_signal_mean_error"], 4),
            "beats_all": all(chosen["mean_error"] < d["mean_error"] for d in rest)}


def markdown(table: Path) -> str:
    """docs/readback.csv as the Markdown table of docs/results.md."""
    lines = ["| scene | replica (seeds) | run + calibrate | chosen | bound, initial → final (mm) | "
             "chosen | its initial | scene layout | best other start | no signal | beats all |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    with open(table) as f:
        for r in csv.DictReader(f):
            seeds = r["seeds"]
            if seeds == "scene":  # the scene's own seeds, or a copy's (wrist_quick_seed1.toml)
                stem = Path(r["objective"]).stem
                seeds = f"multistart seed {stem.rsplit('_seed', 1)[1]}" if "_seed" in stem else "multistart seed 0"
            lines.append(f"| {r['scene']} | {r['tag']} ({seeds}) | {float(r['run_s']) / 60:.1f} + "
                         f"{float(r['calibrate_s']) / 60:.1f} min | {r['chosen_run']} | {r['initial_bound_mm']} → "
                         f"{r['bound_mm']} | **{float(r['error_chosen_mm']):.3g}** ± {float(r['error_chosen_std_mm']):.2g} | "
                         f"{float(r['error_own_initial_mm']):.3g} | {float(r['error_scene_mm']):.3g} | "
                         f"{float(r['error_best_other_mm']):.3g} | {float(r['error_no_signal_mm']):.3g} | "
                         f"{'yes' if r['beats_all'] == 'True' else '**no**'} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="*", help="scene names (wrist, pneumatic, joystick, glove)")
    parser.add_argument("--table", action="store_true", help="print docs/readback.csv as Markdown and stop")
    parser.add_argument("--seeds", help="start indices A:B within each k (replicas: disjoint ranges)")
    parser.add_argument("--tag", default="r1", help="names this replica in the files and the table")
    parser.add_argument("--scene-file", help="scene file to run instead of jobs/<scene>_quick.toml")
    parser.add_argument("--multistart-seed", type=int,
                        help="run a copy of the scene with this [multistart] seed (a replica: seeds "
                             "N·10⁶ + k·10³ + index, disjoint from the scene's own)")
    parser.add_argument("--out", default="out/readback")
    parser.add_argument("--csv", default=str(ROOT / "docs" / "readback.csv"))
    args = parser.parse_args()
    if args.table or not args.scenes:
        print(markdown(Path(args.csv)))
        return
    out = (ROOT / args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    for name in args.scenes:
        scene_file = Path(args.scene_file) if args.scene_file else ROOT / "jobs" / f"{name}_quick.toml"
        if args.multistart_seed is not None:
            text = scene_file.read_text()
            if "\n[multistart]\n" not in text:
                sys.exit(f"{scene_file}: no [multistart] table to seed")
            scene_file = out / f"{scene_file.stem}_seed{args.multistart_seed}.toml"
            scene_file.write_text(text.replace("\n[multistart]\n", f"\n[multistart]\nseed = {args.multistart_seed}\n"))
        row = scene_row(name, scene_file.resolve(), out, args.seeds, args.tag)
        if args.multistart_seed is not None:
            row["seeds"] = f"multistart seed {args.multistart_seed}"
        table = Path(args.csv)
        new = not table.exists()
        with open(table, "a", newline="") as f:  # one row per scene as it finishes
            writer = csv.DictWriter(f, FIELDS)
            if new:
                writer.writeheader()
            writer.writerow(row)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
