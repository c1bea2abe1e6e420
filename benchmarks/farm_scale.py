"""The farm at scale: mscap's multi-start master with many workers, on synthetic starts.

The real service (``mscap.service.multistart.run_multistart``: the master's scheduling,
heartbeat, pruning table, forecast, ``/selection`` and the HDF5 writer that stores and
``fsync``-s every run) with its start replaced by a synthetic one: a worker sleeps
``--length`` seconds in ``--steps`` steps, asks the master its question after each step
(the heartbeat's :class:`~mscap.service.heartbeat.Progress`, as a real start does after every
accepted step) and returns a stored run of the scene as its record (a real k = 2 or 3 run of
``jobs/quick.toml``, made once by the first call, with its capacitances perturbed). Sleeping
workers need no core, so 8–64 workers oversubscribed on 2 cores measure the master, not the
machine.

Two measurements, written to ``docs/farm_scale.csv`` and ``.png``:

1. **The master per result, against the runs stored** (one rank, zero-length starts, 1,998
   runs by default): the master's own work for each finished run (``write_run`` with its
   ``fsync``, ``select`` over every stored run, ``write_selection``) and its heartbeat
   update per question.
2. **Workers** (``mpirun -n W+1 --oversubscribe``, W = 8, 16, 32, 64 by default): the job's
   wall, tasks per second handed out, results per second stored, the workers' busy fraction
   (Σ start wall ÷ (W × job wall)).

From 1 the model: the master saturates when W × (t_result(N) + q × t_question) reaches the
length L of a start; printed for the measured costs and for starts of 1 min (quick scenes)
to 1 h (paper resolution)::

    .venv/bin/python benchmarks/farm_scale.py                      # about 10 minutes
    .venv/bin/python benchmarks/farm_scale.py --quick              # W = 4, 8; 200 runs (1 minute)

``--length`` (s, default 4), ``--steps`` (questions per start, default 10), ``--starts-per-worker``
(default 6), ``--workers 8 16 32 64``, ``--runs`` (measurement 1, default 1998: 999 starts per k).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import table_head, write_csv  # noqa: E402

FIELDS = ["what", "workers", "runs", "length_s", "steps", "job_wall_s", "tasks_per_s", "busy_fraction",
          "master_result_ms", "master_select_ms", "master_write_ms", "master_selection_ms", "master_heartbeat_ms",
          "master_fsync_ms", "master_room_ms", "master_cpu_s"]


def scene_text(starts_per_k: int) -> str:
    """jobs/quick.toml with P1 elements, random starts only (Lloyd starts' layouts are
    computed by the master to find repeats: not what is measured here), ``starts_per_k``
    starts for each of k = 2, 3, no finer-mesh check and no pruning (every start runs its
    length)."""
    text = (ROOT / "jobs" / "quick.toml").read_text()
    text = re.sub(r"^order = 2$", "order = 1", text, flags=re.M)
    text = re.sub(r"^starts_per_k = \d+", f"starts_per_k = {starts_per_k}", text, flags=re.M)
    text = re.sub(r"^(lloyd_fraction|error_estimate|prune_first_step|skip_repeated_starts) = .*\n", "", text,
                  flags=re.M)
    extra = "lloyd_fraction = 0.0\nerror_estimate = false\nprune_first_step = 0\nskip_repeated_starts = false\n"
    return text.replace("\n[multistart]\n", "\n[multistart]\n" + extra, 1)


# --- the job (every rank runs this under mpirun) ---------------------------------------------

def make_templates(path: Path) -> None:
    """A stored run per k of the scene: two real starts of 2 steps (about 20 s)."""
    scene = path.with_suffix(".toml")
    scene.write_text(scene_text(1))
    subprocess.run([str(Path(sys.executable).parent / "mscap"), "run", str(scene), "-o", str(path), "-q",
                    "--max-iterations", "2"], check=True, env=dict(os.environ, OMP_NUM_THREADS="1"))


def templates(path: Path) -> dict:
    """The stored run per k of :func:`make_templates`."""
    from mscap.service.store import finished_ids, read_run, read_store

    with read_store(path) as store:
        return {read_run(store, rid).k: read_run(store, rid) for rid in sorted(finished_ids(store, failed=False))}


def job(args) -> None:
    """One multi-start of synthetic starts; rank 0 prints its measurements as JSON."""
    from mpi4py import MPI

    from mscap.scene import load_scene
    from mscap.service import multistart
    from mscap.service.heartbeat import Progress

    comm = MPI.COMM_WORLD
    made = templates(Path(args.templates)) if comm.Get_rank() == 0 else None
    made = comm.bcast(made, root=0)
    rng = np.random.default_rng(comm.Get_rank())
    timers = {"write": [], "select": [], "selection": [], "heartbeat": [], "commit": [], "room": [], "stored_at": []}

    def timed(name, fn):
        def wrapper(*a, **kw):
            t0 = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                timers[name].append(time.perf_counter() - t0)
        return wrapper

    def synthetic_start(scene, config, rank=0, max_iterations=None, ask=None):
        start, template = time.perf_counter(), made[config.k]
        final = template.final_capacitance_pF * (1 + 0.02 * rng.random(template.final_capacitance_pF.shape))
        for step in range(1, args.steps + 1):
            time.sleep(args.length / args.steps)
            if ask is not None:
                ask(Progress(config.id, config.k, step, 0.5, 0.5, False, "min_l1"))
        return replace(template, seed=config.seed, init=config.init, rank=rank, final_capacitance_pF=final,
                       wall_s=time.perf_counter() - start)

    multistart.run_start = synthetic_start
    from mscap.outfile import ResultsFile

    ResultsFile.commit = timed("commit", ResultsFile.commit)
    ResultsFile.make_room = timed("room", ResultsFile.make_room)
    written = multistart.write_run

    def write_run(store, record):
        timers["stored_at"].append(time.perf_counter())
        return written(store, record)
    multistart.write_run = timed("write", write_run)
    multistart.select = timed("select", multistart.select)
    multistart.write_selection = timed("selection", multistart.write_selection)
    # the master's own handling of a start's question (the message cost is in its CPU time)
    multistart.Heartbeat.update = timed("heartbeat", multistart.Heartbeat.update)
    scene = load_scene(args.scene)
    cpu, t0 = time.process_time(), time.perf_counter()
    summary = multistart.run_multistart(scene, args.output, comm, force=True, heartbeat_s=0, calibrate=False)
    wall = time.perf_counter() - t0
    if comm.Get_rank() == 0:
        print(json.dumps({"summary": summary, "wall_s": wall, "master_cpu_s": time.process_time() - cpu,
                          "timers": {k: v for k, v in timers.items()}}), flush=True)


# --- the driver -------------------------------------------------------------------------------

def mpi_env() -> dict[str, str]:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", OMPI_MCA_rmaps_base_oversubscribe="1")
    if os.geteuid() == 0:
        env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    return env


def launch(ranks: int, scene: Path, output: Path, template: Path, length: float, steps: int) -> dict:
    """The job on ``ranks`` ranks; its JSON line."""
    command = ([shutil.which("mpirun") or "mpirun", "-n", str(ranks), "--oversubscribe"] if ranks > 1 else []) + \
        [sys.executable, __file__, "--job", "--scene", str(scene), "--output", str(output),
         "--templates", str(template), "--length", str(length), "--steps", str(steps)]
    out = subprocess.run(command, env=mpi_env(), capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"{' '.join(command)} failed ({out.returncode}):\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def per_result_ms(timers: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per stored run (in order): the master's write, select and write-selection times (ms)."""
    n = len(timers["write"])
    write = 1e3 * np.asarray(timers["write"][:n])
    # select runs once per result (and once more at the start and the end)
    select = 1e3 * np.asarray(timers["select"][1:n + 1])
    selection = 1e3 * np.asarray(timers["selection"][:n])
    return write, select, selection


def steady_rate(stored_at: list) -> float:
    """Results stored per second between the first and the last (the job's start-up and the
    scene's loading left out)."""
    return (len(stored_at) - 1) / (stored_at[-1] - stored_at[0]) if len(stored_at) > 1 else math.nan


def row(what, workers, result, runs, length, steps) -> dict:
    write, select, selection = per_result_ms(result["timers"])
    heartbeats = result["timers"]["heartbeat"]
    busy = runs * length  # the synthetic starts' own wall (their sleeps)
    return {"what": what, "workers": workers, "runs": runs, "length_s": length, "steps": steps,
            "job_wall_s": result["wall_s"], "tasks_per_s": steady_rate(result["timers"]["stored_at"]),
            "busy_fraction": busy / (max(workers, 1) * result["wall_s"]) if length else math.nan,
            "master_result_ms": float(np.mean(write + select + selection)),
            "master_select_ms": float(np.mean(select)), "master_write_ms": float(np.mean(write)),
            "master_selection_ms": float(np.mean(selection)),
            "master_heartbeat_ms": 1e3 * float(np.mean(heartbeats)) if heartbeats else math.nan,
            "master_fsync_ms": 1e3 * float(np.sum(result["timers"]["commit"])) / len(write),
            "master_room_ms": 1e3 * float(np.sum(result["timers"]["room"])) / len(write),
            "master_cpu_s": result["master_cpu_s"]}


def plot(series, rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    n = np.arange(1, len(series["write"]) + 1)
    a.plot(n, series["write"] + series["selection"], ".", ms=2, label="write_run + write_selection (fsync)")
    a.plot(n, series["select"], ".", ms=2, label="select over the stored runs")
    a.set_xlabel("runs stored")
    a.set_ylabel("master's time per result (ms)")
    a.set_title("The master's work per finished start")
    a.legend()
    farm_rows = [r for r in rows if r["what"] == "workers" and r["length_s"]]
    w = [r["workers"] for r in farm_rows]
    b.plot(w, [r["busy_fraction"] for r in farm_rows], "o-", label="workers' busy fraction")
    b.set_xscale("log", base=2)
    b.set_ylim(0, 1.05)
    b.set_xlabel("workers (oversubscribed, synthetic starts)")
    b.set_ylabel("busy fraction")
    b.set_title(f"{farm_rows[0]['length_s']:g}-s starts, {farm_rows[0]['steps']} questions each")
    b2 = b.twinx()
    zero = [r for r in rows if r["what"] == "workers" and not r["length_s"]]
    b2.plot([r["workers"] for r in zero], [r["tasks_per_s"] for r in zero], "s--", color="C1",
            label="tasks per second, zero-length starts (the master's limit)")
    b2.set_ylabel("tasks (results) per second")
    handles = [h for ax in (b, b2) for h in ax.get_legend_handles_labels()[0]]
    fig.legend(handles=handles, loc="lower center", ncol=2, fontsize=8)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--job", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--scene", help=argparse.SUPPRESS)
    parser.add_argument("--output", help=argparse.SUPPRESS)
    parser.add_argument("--templates", help=argparse.SUPPRESS)
    parser.add_argument("--length", type=float, default=4.0, help="seconds per synthetic start")
    parser.add_argument("--steps", type=int, default=10, help="questions to the master per start")
    parser.add_argument("--starts-per-worker", type=int, default=6)
    parser.add_argument("--workers", type=int, nargs="+", default=[8, 16, 32, 64])
    parser.add_argument("--runs", type=int, default=1998, help="runs of measurement 1 (at most 1998: 999 per k)")
    parser.add_argument("--quick", action="store_true", help="W = 4, 8; 200 runs; output to a temporary directory")
    parser.add_argument("--csv", default=str(ROOT / "docs" / "farm_scale.csv"))
    parser.add_argument("--png", default=str(ROOT / "docs" / "farm_scale.png"))
    args = parser.parse_args()
    if args.job:
        return job(args)
    work = Path(tempfile.mkdtemp(prefix="mscap-farm-"))
    if args.quick:
        args.workers, args.runs = [4, 8], 200
        args.csv, args.png = str(work / "farm_scale.csv"), str(work / "farm_scale.png")
    template = work / "templates.h5"
    print(f"files in {work}", flush=True)
    make_templates(template)

    # 1. The master alone, zero-length starts: its cost per result as the file grows.
    scene = work / "writer.toml"
    scene.write_text(scene_text(args.runs // 2))
    t0 = time.perf_counter()
    result = launch(1, scene, work / "writer.h5", template, 0.0, args.steps)
    write, select, selection = per_result_ms(result["timers"])
    series = {"write": write, "select": select, "selection": selection}
    rows = [row("master", 0, result, len(write), 0.0, args.steps)]
    size_mb = (work / "writer.h5").stat().st_size / 1e6
    print(f"1. {len(write)} zero-length starts on one rank in {time.perf_counter() - t0:.0f} s; file {size_mb:.1f} MB",
          flush=True)
    quarter = max(len(write) // 4, 1)
    for name, values in (("write_run", write), ("write_selection", selection), ("select", select)):
        print(f"   {name}: first {quarter} runs {np.median(values[:quarter]):.2f} ms, last {quarter} "
              f"{np.median(values[-quarter:]):.2f} ms (medians)", flush=True)

    # 2. W workers: zero-length starts (what the master can hand out and store per second),
    #    then starts of --length s (the workers' busy fraction).
    for workers in args.workers:
        for length in (0.0, args.length):
            runs = (args.starts_per_worker if length else 20) * workers
            scene = work / f"w{workers}.toml"
            scene.write_text(scene_text(math.ceil(runs / 2)))
            result = launch(workers + 1, scene, work / f"w{workers}.h5", template, length, args.steps)
            rows.append(row("workers", workers, result, 2 * math.ceil(runs / 2), length, args.steps))
            r = rows[-1]
            print(f"2. {workers} workers: {r['runs']} starts of {length:g} s in {r['job_wall_s']:.1f} s: "
                  f"{r['tasks_per_s']:.1f} tasks/s, busy {r['busy_fraction']:.2f}, master per result "
                  f"{r['master_result_ms']:.1f} ms, master CPU {r['master_cpu_s']:.1f} s", flush=True)

    write_csv(rows, Path(args.csv), FIELDS)
    plot(series, rows, Path(args.png))
    lines = table_head("| workers | starts × length s | job wall s | results/s | busy fraction | master per result ms "
                       "(write_run / select / write_selection; of which flush + fsync, room) | master CPU s |")
    for r in rows:
        lines.append(f"| {r['workers'] or '1 rank'} | {r['runs']} × {r['length_s']:g} | {r['job_wall_s']:.1f} "
                     f"| {r['tasks_per_s']:.1f} | {r['busy_fraction']:.2f} | {r['master_result_ms']:.1f} "
                     f"({r['master_write_ms']:.1f} / {r['master_select_ms']:.2f} / {r['master_selection_ms']:.1f}; "
                     f"{r['master_fsync_ms']:.1f}, {r['master_room_ms']:.1f}) "
                     f"| {r['master_cpu_s']:.1f} |")
    print("\n".join(lines))
    # The model: the master is busy t_record(N) + q t_question per start (the first from
    # measurement 1 at N runs stored; q t_question bounded above by the master's CPU per start
    # in the zero-length jobs, which includes the record's CPU too) and saturates at
    # W* = L / that.
    zero = [r for r in rows if r["what"] == "workers" and not r["length_s"]]
    per_start_cpu = max(r["master_cpu_s"] / r["runs"] for r in zero)
    record = write + select + selection
    fit = np.polyfit(np.arange(1, len(record) + 1), record, 1)  # ms, ms per stored run
    print(f"master per start: record {fit[1]:.1f} ms + {1e3 * fit[0]:.2f} µs × runs stored, "
          f"messages ≤ {1e3 * per_start_cpu:.1f} ms (its CPU per zero-length start)")
    for length in (10.0, 60.0, 600.0, 3600.0):
        limits = []
        for stored in (1000, 10000):
            busy = (fit[1] + fit[0] * stored) / 1e3 + per_start_cpu
            limits.append(f"{length / busy:,.0f} workers with {stored} runs stored")
        print(f"model: {length:.0f}-s starts ({args.steps} questions each): the master saturates at "
              + ", ".join(limits))
    print(f"wrote {args.csv} and {args.png}")


if __name__ == "__main__":
    main()
