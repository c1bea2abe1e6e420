"""Pruned against unpruned multi-start on one scene: chosen k, best metric per k, cost.

Runs (or reads, with ``--read``) two results files of the same scene and starts: the
baseline, every start to its end including the Lloyd starts that repeat an earlier
layout (``--keep-repeated-starts``, what ``mscap run`` did before they were skipped), and
the default service with ``--prune STEP:ETA`` (repeats skipped, dominated starts
pruned). A third row, repeats skipped without pruning, is the baseline less its repeated
starts: without pruning every start runs alone, so that subset is exactly the run that
would have been made. It compares what a designer reads off them: the chosen k, the best
metric per k (and whether it lies within the baseline's best run's finer-mesh error),
and the cost: core-seconds (every run's wall time plus its finer-mesh check) and
accepted optimiser steps (the same on a busy machine). Example (about 50 minutes on 2
cores)::

    .venv/bin/python benchmarks/pruning.py jobs/poking_cross_quick.toml --starts-per-k 8 --prune 3:4

Prints a Markdown table for docs/performance.md and appends its rows to ``--csv``.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")


def run(scene: str, out: Path, ranks: int, *extra: str) -> None:
    mscap = str(Path(sys.executable).with_name("mscap"))
    command = ["mpirun", "-n", str(ranks), mscap, "run", scene, "-o", str(out), *extra]
    subprocess.run(command, env=ENV, check=True)


def summary(path: Path, leave_out: frozenset = frozenset()) -> dict:
    """Chosen k, best metric and its finer-mesh error per k, core-seconds, run counts,
    over the file's finished runs less ``leave_out`` (run ids)."""
    from mscap.service.selection import select
    from mscap.service.store import finished_ids, read_run, read_store, run_summaries, scene_settings

    store = read_store(path)
    records = [read_run(store, rid) for rid in sorted(finished_ids(store)) if rid not in leave_out]
    ms = scene_settings(store)
    selection = select([r for r in run_summaries(store) if r.id not in leave_out], ms.plateau_tol,
                       range(ms.k_min, ms.k_max + 1))
    store.close()
    # Per run: C's finer-mesh error, the metric's (min L1; the bound has no finer-mesh value)
    # and the metric on the finer mesh. A min L1 distance is a difference of capacitances, so
    # its relative error is larger than C's (poking_quick's best k = 2 run: 3.5 % against 1.2 %).
    error = {r.id: (r.error_estimate, r.metric_error, r.finer_metric_pF) for r in records}
    core_s = sum(r.wall_s + (r.error_estimate_wall_s if math.isfinite(r.error_estimate_wall_s) else 0.0)
                 for r in records)
    by_bound = selection.by_bound
    return {"chosen_k": selection.chosen_k, "core_s": core_s, "runs": len(records), "by_bound": by_bound,
            "pruned": sum(r.pruned for r in records), "steps": sum(r.iterations for r in records),
            "per_k": {s.k: (s.best_bound_mm if by_bound else s.best_metric,
                            *error.get(s.best_run, (math.nan,) * 3), s.best_run) for s in selection.per_k}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene")
    parser.add_argument("--starts-per-k", default="8")
    parser.add_argument("--prune", default="3:4")
    parser.add_argument("--ranks", type=int, default=3)
    parser.add_argument("--outdir", default="out/prune")
    parser.add_argument("--pruned-file", default="pruned.h5", help="name of the pruned run's file in OUTDIR")
    parser.add_argument("--read", action="store_true", help="only compare existing files")
    parser.add_argument("--csv", default="", help="append a summary row to this CSV file")
    args = parser.parse_args()
    outdir = Path(args.outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    full, pruned = outdir / "full.h5", outdir / args.pruned_file
    if not args.read:
        run(args.scene, full, args.ranks, "--starts-per-k", args.starts_per_k, "--keep-repeated-starts")
        run(args.scene, pruned, args.ranks, "--starts-per-k", args.starts_per_k, "--prune", args.prune)
    from mscap.scene import load_scene
    from mscap.scene.loader import with_overrides
    from mscap.service.selection import repeated_starts

    scene = with_overrides(load_scene(args.scene), int(args.starts_per_k))
    repeats = frozenset(repeated_starts(scene))
    a, c, b = summary(full), summary(full, repeats), summary(pruned)
    unit = "mm, read-back bound" if a["by_bound"] else "pF, min L1"
    ks = sorted(a["per_k"])
    print(f"| {Path(args.scene).stem} | runs (pruned) | accepted steps | core-seconds | chosen k | "
          + " | ".join(f"best k = {k} ({unit})" for k in ks) + " |")
    print("|---|---|---|---|---|" + "---|" * len(ks))
    rows = (("every start, unpruned", a), ("repeats skipped", c), (f"repeats skipped, --prune {args.prune}", b))
    for name, s in rows:
        cells = []
        for k in ks:
            metric, err, *_ = s["per_k"].get(k, (None, math.nan))
            error = f" (±{100 * err:.1f} %)" if math.isfinite(err) else ""
            cells.append("-" if metric is None else f"{metric:.4g}{error}")
        ratio = "" if s is a else f" ({s['core_s'] / a['core_s']:.2f})"
        steps = "" if s is a else f" ({s['steps'] / a['steps']:.2f})"
        print(f"| {name} | {s['runs']} ({s['pruned']}) | {s['steps']}{steps} | {s['core_s']:.0f}{ratio} | "
              f"{s['chosen_k']} | " + " | ".join(cells) + " |")
    worst = 0.0
    for k in ks:
        (ma, ea, ma_error, fa, _), (mb, _, _, fb, _) = a["per_k"][k], b["per_k"].get(k, (None,) + (math.nan,) * 4)
        if ma is not None and mb is not None:
            loss = (ma - mb) / ma if not a["by_bound"] else (mb - ma) / ma  # > 0: the pruned best is worse
            worst = max(worst, loss)
            finer = "" if a["by_bound"] or not math.isfinite(fa * fb) else (
                f"; metric {100 * ma_error:.1f} %; on the finer mesh {fb:.4g} vs {fa:.4g}, "
                f"worse by {100 * (fa - fb) / fa:.1f} %")
            print(f"k = {k}: best {mb:.4g} vs {ma:.4g}, worse by {100 * loss:.1f} % (baseline best run's "
                  f"finer-mesh error: C {100 * ea:.1f} %{finer})")
    if args.csv:
        new_file = not Path(args.csv).exists()
        with open(args.csv, "a", newline="") as f:
            writer = csv.writer(f)
            if new_file:
                writer.writerow(["scene", "starts_per_k", "prune", "chosen_k_baseline", "chosen_k_pruned",
                                 "core_s_baseline", "core_s_skip", "core_s_pruned", "steps_baseline", "steps_pruned",
                                 "worst_loss"])
            writer.writerow([Path(args.scene).stem, args.starts_per_k, args.prune, a["chosen_k"], b["chosen_k"],
                             round(a["core_s"]), round(c["core_s"]), round(b["core_s"]), a["steps"], b["steps"],
                             round(worst, 4)])


if __name__ == "__main__":
    main()
