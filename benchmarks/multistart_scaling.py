"""Multi-start speed-up and worker busy fraction against the number of MPI workers.

Runs the same multi-start (default: jobs/quick.toml, 12 starts: k = 2..4, 4 each) as
``mpirun -n R --oversubscribe mscap run SCENE -o rR.h5 -q`` for R = 2, 3, 5 ranks:
rank 0 is the master, so 1, 2 and 4 workers. From each results file:

- job wall: measured around ``mpirun`` (so it includes Python, MPI and PETSc start-up
  and the tail where the last runs finish while other workers wait);
- Σ run wall: every run's ``wall_s`` plus its ``error_estimate_wall_s`` when it was
  checked (a worker spends both);
- busy fraction = Σ run wall / (workers × job wall);
- speed-up = job wall of the 1-worker job / job wall (with no 1-worker job: relative to
  the fewest workers, times their number);
- idle per run = (workers × job wall − Σ run wall) / runs: with 1 worker the master's
  overhead per run (start-up, scheduling, writing the HDF5 file);
- max |ΔC|: the largest difference of a run's stored final capacitances from the same
  run's in the first job (0 when the results do not depend on the number of workers).

A job with more workers than cores (``os.cpu_count()``) is oversubscribed: its workers
share cores, so its speed-up measures the machine, not the service; the table and the
plot mark it. The master costs no core while it waits (``Iprobe`` and 10 ms sleeps).

Run (about 4 minutes on an idle 2-core machine: roughly 95, 60 and 60 s for the three
jobs; ``--quick`` for a 20-second smoke run: R = 2, 3 on two starts of two L-BFGS
iterations, output to a temporary directory)::

    .venv/bin/python benchmarks/multistart_scaling.py
    .venv/bin/python benchmarks/multistart_scaling.py --quick

Writes ``docs/multistart_scaling.csv`` and ``.png`` (``--csv``/``--png`` elsewhere) and
prints a Markdown table. The HDF5 files go to a temporary directory (printed).
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import table_head, write_csv  # noqa: E402

from mscap.service.store import finished_ids, read_run, read_store  # noqa: E402

FIELDS = ["ranks", "workers", "cores", "oversubscribed", "runs", "failed", "runs_per_rank", "job_wall_s",
          "run_wall_sum_s", "busy_fraction", "speedup", "idle_per_run_s", "max_dC_pF"]
QUICK_RUN_ARGS = ["--k-max", "2", "--seeds", "0:2", "--max-iterations", "2"]


def mpi_env() -> dict[str, str]:
    """The environment for ``mpirun``: one thread per rank; root allowed (containers)."""
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    if os.geteuid() == 0:
        env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    return env


def run_job(ranks: int, scene: str, output: Path, run_args: list[str], mscap: str) -> float:
    """Run the multi-start on ``ranks`` MPI ranks into a fresh ``output``; its wall time (s)."""
    output.unlink(missing_ok=True)
    command = [shutil.which("mpirun") or "mpirun", "-n", str(ranks), "--oversubscribe",
               mscap, "run", scene, "-o", str(output), "-q", *run_args]
    start = time.perf_counter()
    out = subprocess.run(command, env=mpi_env(), capture_output=True, text=True)
    wall = time.perf_counter() - start
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({out.returncode}):\n{out.stderr[-3000:]}")
    return wall


def read_records(path: Path) -> dict:
    """Every finished run of a results file, by id."""
    store = read_store(path)
    try:
        return {rid: read_run(store, rid) for rid in sorted(finished_ids(store))}
    finally:
        store.close()


def worker_time_s(record) -> float:
    """What a worker spent on a run: the optimisation and, if done, the error estimate."""
    extra = record.error_estimate_wall_s
    return record.wall_s + (extra if math.isfinite(extra) else 0.0)


def max_difference_pF(records: dict, reference: dict) -> float:
    """Largest |ΔC| of the final capacitances over the runs both jobs finished ok (inf if
    they did not finish the same runs or the shapes differ)."""
    if records.keys() != reference.keys():
        return math.inf
    worst = 0.0
    for rid, record in records.items():
        a, b = record.final_capacitance_pF, reference[rid].final_capacitance_pF
        if a.shape != b.shape:
            return math.inf
        if a.size:
            worst = max(worst, float(np.max(np.abs(a - b))))
    return worst


def summarise(ranks: int, wall: float, records: dict, cores: int) -> dict:
    """One row of the table (speed-up and max |ΔC| are filled in later)."""
    workers = ranks - 1
    busy = sum(worker_time_s(r) for r in records.values())
    per_rank = [sum(r.rank == rank for r in records.values()) for rank in range(1, ranks)]
    return dict(ranks=ranks, workers=workers, cores=cores, oversubscribed=workers > cores, runs=len(records),
                failed=sum(not r.ok for r in records.values()), runs_per_rank="/".join(map(str, per_rank)),
                job_wall_s=wall, run_wall_sum_s=busy, busy_fraction=busy / (workers * wall),
                idle_per_run_s=(workers * wall - busy) / max(len(records), 1))


def add_speedup(rows) -> None:
    """Speed-up against the job with the fewest workers (normally one)."""
    ref = min(rows, key=lambda r: r["workers"])
    for row in rows:
        row["speedup"] = ref["workers"] * ref["job_wall_s"] / row["job_wall_s"]


def markdown(rows) -> str:
    """The jobs as a Markdown table."""
    head = ("| ranks (workers) | runs (per worker) | job wall s | Σ run wall s | busy fraction | speed-up "
            "| idle per run s | max abs ΔC pF |")
    lines = table_head(head)
    for r in rows:
        mark = f", oversubscribed on {r['cores']} cores" if r["oversubscribed"] else ""
        failed = f", {r['failed']} failed" if r["failed"] else ""
        lines.append(f"| {r['ranks']} ({r['workers']}{mark}) | {r['runs']} ({r['runs_per_rank']}{failed}) "
                     f"| {r['job_wall_s']:.1f} | {r['run_wall_sum_s']:.1f} | {r['busy_fraction']:.2f} "
                     f"| {r['speedup']:.2f} | {r['idle_per_run_s']:.2f} | {r['max_dC_pF']:.3g} |")
    return "\n".join(lines)


def plot(rows, path: Path, name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    workers = np.array([r["workers"] for r in rows])
    over = np.array([r["oversubscribed"] for r in rows])
    cores = rows[0]["cores"]
    fig, (ax_s, ax_b) = plt.subplots(1, 2, figsize=(10, 4.2))
    for ax, key, ideal in [(ax_s, "speedup", workers), (ax_b, "busy_fraction", np.ones(len(rows)))]:
        values = np.array([r[key] for r in rows])
        ax.plot(workers, ideal, "--", color="gray", label="ideal")
        ax.plot(workers, values, "-", color="tab:blue", alpha=0.5)
        ax.plot(workers[~over], values[~over], "o", color="tab:blue", label="measured")
        if over.any():
            ax.plot(workers[over], values[over], "o", mfc="none", mec="tab:red", ms=9,
                    label=f"oversubscribed (> {cores} cores)")
        ax.axvline(cores, color="tab:red", ls=":", lw=1)
        ax.set_xlabel("workers (MPI ranks − 1)")
        ax.set_xticks(workers)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    ax_s.set_ylabel("speed-up (job wall of 1 worker / job wall)")
    ax_b.set_ylabel("busy fraction: Σ run wall / (workers × job wall)")
    ax_b.set_ylim(0, 1.05)
    fig.suptitle(f"{name}: {rows[0]['runs']} multi-start runs, this machine ({cores} cores)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default=str(ROOT / "jobs" / "quick.toml"))
    parser.add_argument("--ranks", type=lambda s: [int(r) for r in s.split(",")],
                        help="comma-separated MPI rank counts, each >= 2 (default 2,3,5; --quick: 2,3)")
    parser.add_argument("--quick", action="store_true",
                        help=f"R = 2, 3 and `mscap run {' '.join(QUICK_RUN_ARGS)}`; output to a temporary directory")
    parser.add_argument("--mscap", default=str(Path(sys.executable).with_name("mscap")), help="the mscap script")
    parser.add_argument("--csv", help="CSV path (default docs/multistart_scaling.csv; --quick: temporary)")
    parser.add_argument("--png", help="PNG path (default docs/multistart_scaling.png; --quick: temporary)")
    args = parser.parse_args(argv)
    ranks = args.ranks or ([2, 3] if args.quick else [2, 3, 5])
    if min(ranks) < 2:
        parser.error("every job needs a master and at least one worker: --ranks >= 2")
    run_args = QUICK_RUN_ARGS if args.quick else []
    work = Path(tempfile.mkdtemp(prefix="mscap_multistart_scaling_"))
    out_dir = work if args.quick else ROOT / "docs"
    cores = os.cpu_count() or 1

    rows, first = [], None
    for r in ranks:
        wall = run_job(r, args.scene, work / f"r{r}.h5", run_args, args.mscap)
        records = read_records(work / f"r{r}.h5")
        first = records if first is None else first
        row = summarise(r, wall, records, cores)
        row["max_dC_pF"] = max_difference_pF(records, first)
        rows.append(row)
        print(f"{r} ranks: {row['runs']} runs in {wall:.1f} s, busy {row['busy_fraction']:.2f}", flush=True)
    add_speedup(rows)

    csv_path = Path(args.csv or out_dir / "multistart_scaling.csv")
    png_path = Path(args.png or out_dir / "multistart_scaling.png")
    write_csv(rows, csv_path, FIELDS)
    plot(rows, png_path, Path(args.scene).stem)
    print("\n" + markdown(rows) + "\n")
    single = [r for r in rows if r["workers"] == 1]
    if single:
        print(f"master overhead per run (1 worker, start-up included): {single[0]['idle_per_run_s']:.3f} s")
    print(f"results files in {work}\nwrote {csv_path} and {png_path}")


if __name__ == "__main__":
    main()
