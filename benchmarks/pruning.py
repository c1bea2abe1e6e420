"""Pruned against unpruned multi-start on one scene: chosen k, best metric per k, cost.

Runs (or reads, with ``--read``) two results files of the same scene and starts, one
without pruning and one with ``--prune STEP:ETA``, and compares what a designer reads
off them: the chosen k, the best metric per k (and whether the pruned one lies within
the unpruned best run's finer-mesh error), and the core-seconds spent (every run's wall
time plus its finer-mesh check). Example (about 50 minutes on 2 cores)::

    .venv/bin/python benchmarks/pruning.py jobs/poking_cross_quick.toml --starts-per-k 8 --prune 5:3

Prints a Markdown table for docs/performance.md.
"""

from __future__ import annotations

import argparse
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


def summary(path: Path) -> dict:
    """Chosen k, best metric and its finer-mesh error per k, core-seconds, run counts."""
    from mscap.service.store import read_run, read_store, finished_ids, store_selection

    store = read_store(path)
    records = [read_run(store, rid) for rid in sorted(finished_ids(store))]
    selection = store_selection(store)
    store.close()
    error = {r.id: r.error_estimate for r in records}
    core_s = sum(r.wall_s + (r.error_estimate_wall_s if math.isfinite(r.error_estimate_wall_s) else 0.0)
                 for r in records)
    return {"chosen_k": selection.chosen_k, "core_s": core_s, "runs": len(records),
            "pruned": sum(r.pruned for r in records), "steps": sum(r.iterations for r in records),
            "per_k": {s.k: (s.best_metric, error.get(s.best_run, math.nan), s.best_run) for s in selection.per_k}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene")
    parser.add_argument("--starts-per-k", default="8")
    parser.add_argument("--prune", default="5:3")
    parser.add_argument("--ranks", type=int, default=3)
    parser.add_argument("--outdir", default="out/prune")
    parser.add_argument("--pruned-file", default="pruned.h5", help="name of the pruned run's file in OUTDIR")
    parser.add_argument("--read", action="store_true", help="only compare existing files")
    args = parser.parse_args()
    outdir = Path(args.outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    full, pruned = outdir / "full.h5", outdir / args.pruned_file
    if not args.read:
        run(args.scene, full, args.ranks, "--starts-per-k", args.starts_per_k)
        run(args.scene, pruned, args.ranks, "--starts-per-k", args.starts_per_k, "--prune", args.prune)
    a, b = summary(full), summary(pruned)
    print("| | runs (pruned) | accepted steps | core-seconds | chosen k | " +
          " | ".join(f"best k = {k} (pF)" for k in sorted(a["per_k"])) + " |")
    print("|---|---|---|---|---|" + "---|" * len(a["per_k"]))
    for name, s in (("unpruned", a), (f"pruned ({pruned.name})", b)):
        cells = []
        for k in sorted(a["per_k"]):
            metric, err, _ = s["per_k"][k]
            cells.append("-" if metric is None else f"{metric:.4g}" + (f" (±{100 * err:.1f} %)" if math.isfinite(err) else ""))
        print(f"| {name} | {s['runs']} ({s['pruned']}) | {s['steps']} | {s['core_s']:.0f} | {s['chosen_k']} | "
              + " | ".join(cells) + " |")
    print(f"\ncost ratio pruned / unpruned: {b['core_s'] / a['core_s']:.2f}")
    for k in sorted(a["per_k"]):
        (ma, ea, _), (mb, _, _) = a["per_k"][k], b["per_k"][k]
        if ma is not None and mb is not None:
            print(f"k = {k}: best metric {mb:.4g} vs {ma:.4g} pF, relative difference {abs(mb - ma) / ma:.3f} "
                  f"(unpruned best run's finer-mesh error {ea:.3f})")


if __name__ == "__main__":
    main()
