"""``mscap.farm.run`` with batches (what ``mscap fit`` farms: one batch of forwards per
iteration): the workers wait between the master's calls, get every task of each batch
once, and are let go when the master returns."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
import textwrap

import pytest

ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")

SCRIPT = textwrap.dedent("""
    import sys
    from mpi4py import MPI
    from mscap import farm

    comm = MPI.COMM_WORLD

    def make_work(ask):
        return lambda task: (task, task ** 2, comm.Get_rank())

    def master(execute, stop):
        out = []
        for size in (1, 5, 0, 2, 7):  # fewer tasks than workers, more, none
            got = []
            execute(list(range(size)), got.append)
            out.append(sorted(got))
        return out

    result = farm.run(comm, make_work, master, "stopped", print, batches=True)
    if comm.Get_rank() == 0:
        for batch in result:
            print(" ".join(f"{t}:{v}" for t, v, _ in batch))
        print("ranks", sorted({r for batch in result for _, _, r in batch}))
    print("done", comm.Get_rank())
""")


@pytest.mark.parametrize("ranks", [1, 4])
def test_every_batch_is_done_once_and_every_rank_ends(tmp_path, ranks):
    if ranks > 1 and shutil.which("mpirun") is None:
        pytest.skip("no mpirun (make installs openmpi-bin)")
    script = tmp_path / "batches.py"
    script.write_text(SCRIPT)
    command = [sys.executable, str(script)]
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), "--oversubscribe", *command]
    done = subprocess.run(command, env=ENV, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    batches = [line for line in lines if not line.startswith(("done", "ranks"))]
    assert batches == ["0:0", "0:0 1:1 2:4 3:9 4:16", "", "0:0 1:1", " ".join(f"{t}:{t * t}" for t in range(7))]
    assert sorted(line for line in lines if line.startswith("done")) == [f"done {r}" for r in range(ranks)]
    workers = [0] if ranks == 1 else list(range(1, ranks))
    ranks_line = next(line for line in lines if line.startswith("ranks"))
    assert set(ast.literal_eval(ranks_line.split(" ", 1)[1])) <= set(workers)
