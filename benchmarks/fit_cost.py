"""What ``mscap fit`` costs on the poking sensor: forwards, wall time, ranks.

Fits the gap (``thickness_scale``) and the poke depth (``poses.*.depth_mm``) of
``jobs/poking.toml`` — two parameters the readings separate (the gap sets the rest value,
the depth the gains; plate size and gap they do not, docs/validation.md) — to the paper's
measured means (``benchmarks/data/paper_poking_measured_mean.csv``: rest and poke_0, so each
forward is two poses) on one process and on ``mpirun -n 3`` (two workers: a Jacobian's two
columns at once), one after the other, and writes ``docs/fit_cost.csv``;
``FIT_COST_RANKS=1,3,4`` adds three workers (more than the parameters: each trial point with
its columns at once), which needs three free cores to mean anything. Run alone on the
machine (about 6 minutes on 2 cores)::

    .venv/bin/python benchmarks/fit_cost.py
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import write_csv  # noqa: E402

MSCAP = str(Path(sys.executable).with_name("mscap"))
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
ARGS = ["fit", str(ROOT / "jobs" / "poking.toml"), str(ROOT / "benchmarks" / "data" / "paper_poking_measured_mean.csv"),
        "--param", "thickness_scale=0.7:1.5", "--param", "poses.*.depth_mm=8:18", "--max-forwards", "10", "--json",
        "-q"]
#: One process, then two workers (``FIT_COST_RANKS``, comma-separated rank counts).
RANKS = tuple(int(r) for r in os.environ.get("FIT_COST_RANKS", "1,3").split(","))
FIELDS = ["ranks", "workers", "forwards", "trial_points", "wall_s", "wall_per_forward_s", "thickness_scale",
          "depth_mm", "rms_pF", "message"]


def main() -> int:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for ranks in RANKS:
            command = [MSCAP, *ARGS, "-o", str(Path(tmp) / f"fitted_{ranks}.toml")]
            if ranks > 1:
                command = ["mpirun", "-n", str(ranks), "--oversubscribe", *command]
            t0 = time.perf_counter()
            done = subprocess.run(command, env=ENV, capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if done.returncode != 0:
                print(done.stderr, file=sys.stderr)
                return 1
            record = json.loads(done.stdout)
            values = {p["name"]: p for p in record["parameters"]}
            rows.append(dict(ranks=ranks, workers=max(ranks - 1, 1), forwards=record["forwards"],
                             trial_points=record["trial_points"], wall_s=wall,
                             wall_per_forward_s=wall / record["forwards"],
                             thickness_scale=values["thickness_scale"]["fitted"],
                             depth_mm=values["poses.*.depth_mm"]["fitted"], rms_pF=record["rms_pF"],
                             message=record["message"]))
            print(rows[-1], flush=True)
    write_csv(rows, ROOT / "docs" / "fit_cost.csv", FIELDS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
