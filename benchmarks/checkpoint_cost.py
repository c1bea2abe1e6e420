"""What an in-start checkpoint costs (issue 49 item 1): one start of a scene optimised for a
few steps, the optimiser's state made at the top of every iteration (what the worker does)
and written to an HDF5 file (what the master does every ``checkpoint_minutes`` and at a
stop); prints, per iteration, the step's wall time, the state's making and writing times
and the file's size, then the means.

::

    .venv/bin/python benchmarks/checkpoint_cost.py jobs/poking_cross.toml --k 3 --max-iterations 3
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene")
    parser.add_argument("--k", type=int, default=3)
    parser.add_argument("--seed", type=int, default=3000)
    parser.add_argument("--init", default="lloyd")
    parser.add_argument("--max-iterations", type=int, default=3)
    args = parser.parse_args()
    from mscap.design.optimizer import optimize
    from mscap.design.starts import start_design
    from mscap.scene import load_scene
    from mscap.service import checkpoints

    scene = load_scene(args.scene)
    started = time.perf_counter()
    _, design = start_design(scene, args.k, args.seed, args.init)
    rows, last = [], [time.perf_counter()]
    with tempfile.TemporaryDirectory() as tmp:
        results = Path(tmp) / "r.h5"

        def keep(state):
            now = time.perf_counter()
            t0 = time.perf_counter()
            made = state()
            t1 = time.perf_counter()
            path = checkpoints.save(results, "start", made)
            t2 = time.perf_counter()
            rows.append({"iteration": made.iteration, "since_last_s": round(now - last[0], 2),
                         "make_s": round(t1 - t0, 4), "write_s": round(t2 - t1, 4),
                         "bytes": path.stat().st_size,
                         "displacement_bytes": sum(u.nbytes for u in made.displacements if u is not None)})
            print(json.dumps(rows[-1]), flush=True)
            last[0] = time.perf_counter()

        result = optimize(design, max_iterations=args.max_iterations, cascade_levels=0, keep=keep)
    steps = [r for r in rows[1:]]
    summary = {"scene": args.scene, "k": args.k, "iterations": result.iterations,
               "start_s": round(time.perf_counter() - started, 1),
               "mean_step_s": round(sum(r["since_last_s"] for r in steps) / max(len(steps), 1), 2),
               "mean_make_s": round(sum(r["make_s"] for r in rows) / len(rows), 4),
               "mean_write_s": round(sum(r["write_s"] for r in rows) / len(rows), 4),
               "mean_mb": round(sum(r["bytes"] for r in rows) / len(rows) / 2**20, 2)}
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
