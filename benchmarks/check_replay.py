"""Replay which finer-mesh checks a multi-start skips, on files whose every run was checked.

Since 2026-12-04 a finished run asks the master whether a finished run of its k already
beats it (:func:`mscap.service.multistart.beaten_by`); if so it can never be the best of
its k, the only runs whose check the selection reads, and it skips its check. A file
written before (or with ``--check-all-runs``) stores every run's check and its wall time,
so the saving can be replayed without running anything: runs finish in the service's own
order on one worker (largest k first, then by start index), and in random orders within
each k (the mean over ``--orders`` shuffles; with several workers the order is between
the two). Per file this prints the checks run and the core-seconds saved, as a fraction of
all core-seconds (runs plus checks)::

    .venv/bin/python benchmarks/check_replay.py out/prune_quick/*/full.h5
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def checks_run(order, runs) -> set[str]:
    """The ids whose check runs when ``runs`` finish in ``order`` (their ids)."""
    from mscap.service.multistart import Finished, beaten_by

    by_id, finished, checked = {r.id: r for r in runs}, [], set()
    for rid in order:
        r = by_id[rid]
        if r.ok and not r.pruned and beaten_by(Finished(r.id, r.k, r.metric, r.bound_mm), finished) is None:
            checked.add(rid)
        finished.append(r)
    return checked


def main(argv=None) -> int:
    sys.path.insert(0, str(ROOT))
    from mscap.service.store import finished_ids, read_store, run_summaries

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", help="results files whose every run was checked")
    parser.add_argument("--orders", type=int, default=2000, help="random finishing orders to average (default 2000)")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    print("| file | runs (per k) | checks: all / service order / random orders | check share of core-s | "
          "core-s saved: service order / random orders |")
    print("|---|---|---|---|---|")
    for path in args.files:
        with read_store(path) as store:
            runs = [r for r in run_summaries(store) if r.ok and not r.pruned]
            check_s = {rid: float(store["runs"][rid].attrs.get("error_estimate_wall_s", math.nan))
                       for rid in finished_ids(store)}
        if not all(math.isfinite(check_s[r.id]) for r in runs):
            print(f"| {path} | a run has no check: not a file of every run checked |")
            continue
        total = sum(r.wall_s + check_s[r.id] for r in runs)
        ks = sorted({r.k for r in runs}, reverse=True)
        per_k = {k: [r.id for r in sorted(runs, key=lambda r: r.id) if r.k == k] for k in ks}

        def saved(order) -> tuple[int, float]:
            done = checks_run(order, runs)
            return len(done), sum(check_s[r.id] for r in runs if r.id not in done) / total
        service = saved([rid for k in ks for rid in sorted(per_k[k], key=lambda i: int(i.split("_s")[1].split("_")[0]))])
        shuffled = [saved([rid for k in ks for rid in rng.permutation(per_k[k])]) for _ in range(args.orders)]
        share = sum(check_s.get(r.id, 0.0) for r in runs) / total
        counts = ", ".join(str(len(per_k[k])) for k in sorted(ks))
        print(f"| {path} | {len(runs)} ({counts}) | {len(runs)} / {service[0]} / {np.mean([s[0] for s in shuffled]):.1f} | "
              f"{share:.2f} | {service[1]:.2f} / {np.mean([s[1] for s in shuffled]):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
