"""Replay the optimiser's plateau rule on stored histories (issue 18: paper-resolution cost).

Every accepted step of a start is a row of its history (J, min L1, wall time), so the
plateau rule (``[optimizer] stall_window`` W, ``stall_tolerance`` τ: a level ends when J
gained less than τ · |J| over its last W steps on one mesh) can be replayed on a
run made without it. Per run and rule this prints where the rule would first end a level,
the share of the run's wall time spent up to there, and how much of the J and min L1 the
run gained after it. A stop in the first of two levels is followed by the cascade level in
a real run, which this replay does not know: there its cost share is a lower bound and its
lost gain an upper bound; a real run with the rule (``mscap run``) is the check. Example::

    .venv/bin/python benchmarks/stall_replay.py out/paper_start/poking.h5 out/paper_start/wrist.h5
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RULES = ((5, 1e-2), (10, 1e-2), (10, 5e-3), (10, 2e-2), (20, 1e-2), (20, 2e-2))


def first_stop(history, window: int, tolerance: float, across_remesh: bool = False) -> int | None:
    """Row of ``history`` where the plateau rule would first end a level (``None``: never);
    ``across_remesh``: the window runs on through remeshes (J before and after one is the
    same design read on two meshes)."""
    from mscap.design.optimizer import _plateau  # the optimiser's own rule

    events = np.asarray(history["event"]).astype(str)
    J = np.asarray(history["J"], dtype=float)
    since: list[float] = []
    for row, event in enumerate(events):
        if event in ("start", "cascade") or (event == "remesh" and not across_remesh):
            since = [J[row]]
        elif event == "step":
            since.append(J[row])
            if _plateau(since, J[row], window, tolerance):
                return row
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", help="results files of runs made without the rule")
    parser.add_argument("--across-remesh", action="store_true", help="do not restart the window at a remesh")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    from mscap.service.store import finished_ids, read_run, read_store

    print("| run | steps, wall | rule W, τ | stops at step (level) | wall share | J gained after / J gained | min L1 then → final |")
    print("|---|---|---|---|---|---|---|")
    for path in args.files:
        store = read_store(path)
        runs = [read_run(store, rid) for rid in sorted(finished_ids(store))]
        store.close()
        for r in runs:
            h = r.history
            J, l1, t = (np.asarray(h[c], dtype=float) for c in ("J", "min_l1_pF", "time_s"))
            steps = int(np.asarray(h["iteration"])[-1])
            for window, tolerance in RULES:
                row = first_stop(h, window, tolerance, args.across_remesh)
                label = f"{Path(path).stem} {r.id}"
                if row is None:
                    print(f"| {label} | {steps}, {t[-1]:.0f} s | {window}, {tolerance:g} | never | 1 | 0 | {l1[-1]:.3f} |")
                    continue
                lost = (J[row] - J[-1]) / (J[0] - J[-1])
                print(f"| {label} | {steps}, {t[-1]:.0f} s | {window}, {tolerance:g} | "
                      f"{int(h['iteration'][row])} ({int(h['level'][row])}) | {t[row] / t[-1]:.2f} | {lost:.3f} | "
                      f"{l1[row]:.3f} → {l1[-1]:.3f} |")


if __name__ == "__main__":
    main()
