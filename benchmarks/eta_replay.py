"""How good the multi-start's ETA is: both forecasts replayed on a stored run's costs.

The stored runs of a results file keep their wall time but not when they finished, so the
farm is replayed: the file's runs in the master's order (largest k first, index order
within a k), each handed to the first free worker and costing its stored wall time (a
start's cost includes its finer-mesh check). At every completion the true time left (the
replay's last finish minus now) is compared with ``elapsed / done × left`` (the ETA before
2026-12-04) and with :class:`mscap.service.forecast.Forecast` (each task left at the
expected cost of its kind, a start running to its end or pruned; the tasks in flight at
what they have left). Prints the ETA at a few fractions of the tasks done and the median
and worst error over the run, relative to the time left and to the whole run's time. Example::

    .venv/bin/python benchmarks/eta_replay.py out/eta/poking_quick.h5 --workers 2 --prune 3:4
"""

from __future__ import annotations

import argparse
import heapq
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def replay(tasks, cost: dict[str, float], workers: int):
    """``[(id, start time, finish time)]`` in the order the tasks finish on ``workers`` workers."""
    free = [(0.0, w) for w in range(workers)]
    runs = []
    for task in tasks:
        now, w = heapq.heappop(free)
        heapq.heappush(free, (now + cost[task.id], w))
        runs.append((task.id, now, now + cost[task.id]))
    return sorted(runs, key=lambda item: item[2])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", help="a multi-start results file (every start of the scene stored)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--prune", default="3:4", help="the run's rung rule STEP:ETA (default 3:4; 0: none)")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from mscap.service.forecast import Forecast, duration
    from mscap.service.pruning import PruneRule
    from mscap.service.selection import StartConfig
    from mscap.service.store import finished_ids, read_run, read_store

    from mscap.errors import MscapError

    step, _, eta = args.prune.partition(":")
    if not (step.isdigit() and (eta.isdigit() or not eta)):
        parser.error(f"--prune expects STEP or STEP:ETA (whole numbers), got {args.prune!r}")
    try:
        store = read_store(args.file)
    except MscapError as exc:
        sys.exit(str(exc))
    records = {rid: read_run(store, rid) for rid in finished_ids(store)}
    store.close()
    tasks = sorted((StartConfig(r.k, r.seed, r.init) for r in records.values()), key=lambda c: (-c.k, c.seed))
    cost = {rid: float(r.wall_s) for rid, r in records.items()}
    finishes = replay(tasks, cost, args.workers)
    end = finishes[-1][2]
    forecast = Forecast(tasks, args.workers, PruneRule(int(step), int(eta or 3)))
    rows, errors, of_run = [], {"old": [], "new": []}, {"old": [], "new": []}
    for done, (rid, _, now) in enumerate(finishes, start=1):
        forecast.finished(rid, cost[rid], pruned=records[rid].status == "pruned", history=records[rid].history)
        left = len(finishes) - done
        if not left:
            break
        truth = end - now
        old = now / done * left
        running = {other: now - began for other, began, ended in finishes if began <= now < ended}
        new = forecast.seconds_left(running)
        errors["old"].append(abs(old - truth) / truth)
        of_run["old"].append(abs(old - truth) / end)
        if new is not None:
            errors["new"].append(abs(new - truth) / truth)
            of_run["new"].append(abs(new - truth) / end)
        rows.append((done, now, truth, old, new))
    statuses = [records[t.id].status for t in tasks]
    print(f"{args.file}: {len(tasks)} tasks ({statuses.count('pruned')} pruned), {args.workers} workers, "
          f"replayed end {duration(end)}")
    print("\n| done | elapsed | true time left | elapsed / done × left | forecast |")
    print("|---|---|---|---|---|")
    marks = {max(1, round(f * len(finishes))) for f in (0.1, 0.25, 0.5, 0.75, 0.9)}
    for done, now, truth, old, new in rows:
        if done in marks:
            print(f"| {done}/{len(finishes)} | {duration(now)} | {duration(truth)} | {duration(old)} "
                  f"({100 * (old / truth - 1):+.0f} %) | {duration(new)}"
                  + (f" ({100 * (new / truth - 1):+.0f} %) |" if new is not None else " |"))
    for name, values in errors.items():
        values, whole = sorted(values), sorted(of_run[name])
        print(f"{name}: median error {100 * values[len(values) // 2]:.0f} %, worst {100 * values[-1]:.0f} % "
              f"over {len(values)} completions; in shares of the whole run's time: median "
              f"{100 * whole[len(whole) // 2]:.0f} %, worst {100 * whole[-1]:.0f} %")


if __name__ == "__main__":
    main()
