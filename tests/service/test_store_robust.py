"""Nothing lost, nothing hung (issue 21): the results file under contention, a full disk
and a failing rank. Starts are synthetic (``run_start`` replaced by a record maker), so
every test is about the service and the store, not the optimiser."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from mscap.scene import load_scene
from mscap.service.store import StoreError, finished_ids, open_store, read_run, read_store, write_run
from tests.conftest import synthetic_record, to_toml
from tests.service.test_multistart import ENV, needs_mpirun, session_members, tiny_scene
from tests.service.test_store import writer_script

ROOT = Path(__file__).resolve().parents[2]

#: A Python program that runs ``mscap run`` with every start replaced by a synthetic record
#: (instant), after ``fault`` (Python code: the tests inject failures) and with the file
#: size limited to ``limit`` bytes (``ulimit -f``), set once MPI is up (its shared-memory
#: files are not the store's); SIGXFSZ is ignored, so a write past the limit fails with
#: EFBIG, as on a full disk.
RUN_SCRIPT = textwrap.dedent("""
    import resource, signal, sys
    from mpi4py import MPI
    MPI.COMM_WORLD.Barrier()
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    limit = {limit}
    if limit is not None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    sys.path.insert(0, {root!r})
    from mscap.service import multistart
    from tests.conftest import synthetic_record

    def synthetic_start(scene, config, rank=0, *args, **kwargs):
        return synthetic_record(config.k, config.seed, config.init, rank=rank)
    multistart.run_start = synthetic_start
    {fault}
    from mscap.cli import main
    sys.exit(main(["run", {scene!r}, "-o", {out!r}, *{extra!r}]))
""")


@pytest.fixture
def scene_file(tmp_path) -> Path:
    data = tiny_scene()
    data["multistart"] = {"k_min": 2, "k_max": 3, "starts_per_k": 6, "error_estimate": False}
    path = tmp_path / "tiny.toml"
    path.write_text(to_toml(data))
    return path


def run_script(script: str, ranks: int = 1, timeout: float = 60) -> tuple[int, str]:
    """Run a Python program on ``ranks`` ranks (``mpirun`` if more than one) in a session of
    its own; returns its status and stderr once every process of the session has ended
    (the test fails if one outlives it by 15 s: a hung rank)."""
    command = [sys.executable, "-c", script]
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), "--oversubscribe", *command]
    job = subprocess.Popen(command, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           cwd=ROOT, start_new_session=True)
    try:
        _, stderr = job.communicate(timeout=timeout)
    finally:
        deadline = time.monotonic() + 15
        while session_members(job.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = session_members(job.pid)
        for pid in left:  # this test's own processes only
            os.kill(pid, signal.SIGKILL)
    assert not left, "ranks outlived the job"
    return job.returncode, stderr


def synthetic_run(scene: Path, out: Path, *extra: str, ranks: int = 1, fault: str = "",
                  limit: int | None = None) -> tuple[int, str]:
    """``mscap run`` with synthetic starts after ``fault`` (:data:`RUN_SCRIPT`), by :func:`run_script`."""
    return run_script(RUN_SCRIPT.format(root=str(ROOT), scene=str(scene), out=str(out), extra=list(extra),
                                        fault=textwrap.dedent(fault), limit=limit), ranks)


def announced(stderr: str) -> set[str]:
    """Run ids of the progress lines ``[n/N] <id>: ...``."""
    return set(re.findall(r"^\[\d+/\d+\] (\S+):", stderr, flags=re.M))


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("mscap: error:")]


# ---------------------------------------------------------------- a full disk
@pytest.mark.parametrize("ranks", [1, pytest.param(3, marks=needs_mpirun)])
def test_a_full_disk_stops_the_job_cleanly_and_the_rerun_completes(scene_file, tmp_path, ranks):
    """``ulimit -f`` of 200 KiB (the file takes about 80 KiB when created and 13 KiB per
    synthetic run, with 70 KiB reserved ahead): the job stops with one error line naming the
    file, the free space and the limit; no rank hangs; every announced run is in the file,
    whole; the file reads; the rerun without the limit completes the rest and keeps the
    stored runs as they were. (Before the reservation, the failing write left runs whose
    headers pointed past the end of the file, and under mpirun every rank spun forever.)"""
    out = tmp_path / "full.h5"
    code, stderr = synthetic_run(scene_file, out, ranks=ranks, limit=200 * 1024)
    assert code == 2, stderr
    assert "Traceback" not in stderr
    errors = error_lines(stderr)
    assert len(errors) == 1, stderr
    assert str(out) in errors[0] and "free on its file system" in errors[0] and "ulimit -f" in errors[0]
    stored = announced(stderr)
    assert 2 <= len(stored) < 12
    with read_store(out) as f:  # checked: every run whole
        assert finished_ids(f) == stored
        assert f["selection"].attrs["runs_total"] == len(stored)
        before = {rid: read_run(f, rid).wall_s for rid in stored}
    code, stderr = synthetic_run(scene_file, out, ranks=ranks)
    assert code == 0, stderr
    assert f"{len(stored)} runs already stored, {12 - len(stored)} to do" in stderr
    with read_store(out) as f:
        assert len(finished_ids(f)) == 12 and f["selection"].attrs["runs_total"] == 12
        assert {rid: read_run(f, rid).wall_s for rid in before} == before


def test_a_full_disk_at_creation_leaves_no_file(scene_file, tmp_path):
    """A limit below what a new file needs: one error line, no half-created file left."""
    out = tmp_path / "none.h5"
    code, stderr = synthetic_run(scene_file, out, limit=16 * 1024)
    assert code == 2 and len(error_lines(stderr)) == 1 and "Traceback" not in stderr, stderr
    assert str(out) in stderr and not out.exists()


# ---------------------------------------------------------------- contention
def test_force_on_a_file_another_process_writes_is_refused(tmp_path, free_poses_scene, capsys):
    """``mscap run --force`` (here ``open_store(force=True)``) on a file a running job holds:
    a one-line refusal naming the file; the job's file is untouched and stays readable.
    (Before: truncated by ``h5py.File(path, "w")`` before the lock refused, all runs lost.)"""
    scene = free_poses_scene(k_max=4)
    path = tmp_path / "held.h5"
    script = writer_script(path, scene, 0, """
        print("ready", flush=True)
        sys.stdin.readline()
        write_run(store, synthetic_record(3, 1))
        store.close()
    """)
    writer = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert writer.stdout.readline().strip() == "ready"
        size = path.stat().st_size
        with pytest.raises(StoreError) as info:
            open_store(path, scene, force=True)
        message = str(info.value)
        assert str(path) in message and "open for writing in another process" in message
        assert "--force never overrides" in message and "\n" not in message
        assert path.stat().st_size == size
        from mscap.cli import main

        assert main(["run", str(scene.path), "-o", str(path), "--force", "-q"]) == 2
        err = capsys.readouterr().err
        assert err.count("mscap: error:") == 1 and "open for writing in another process" in err, err
        assert path.stat().st_size == size
        from mscap.service.merge import merge

        other = tmp_path / "other.h5"
        with open_store(other, scene) as store:
            write_run(store, synthetic_record(2, 7))
        with pytest.raises(StoreError, match="open for writing in another process"):
            merge([other], path, force=True)
    finally:
        writer.communicate("\n", timeout=30)
    assert writer.returncode == 0
    with read_store(path) as f:
        assert finished_ids(f) == {"k2_s0000_random", "k3_s0001_random"}


CONTENDER = textwrap.dedent("""
    import sys, time
    sys.path.insert(0, {root!r})
    from mscap.scene import load_scene
    from mscap.service.store import StoreError, open_store, write_run
    from tests.conftest import synthetic_record
    scene = load_scene({scene!r})
    seed, start = int(sys.argv[1]), float(sys.argv[2])
    time.sleep(max(start - time.time(), 0))
    try:
        store = open_store({path!r}, scene, force=bool(int(sys.argv[3])))
    except StoreError as exc:
        print(f"refused: {{exc}}", file=sys.stderr)
        sys.exit(2)
    write_run(store, synthetic_record(2, seed))
    time.sleep(0.3)
    store.close()
""")


@pytest.mark.parametrize("force", [0, 1])
def test_two_jobs_starting_on_one_file(tmp_path, free_poses_scene, force):
    """Two processes open the same new file at the same instant, eight times over (with and
    without --force): each either writes its run or is refused with one line, never a
    traceback; the file always reads and holds exactly the runs of the processes that
    wrote. (Before: a raw BlockingIOError traceback in 7 of 20 tries, and 1 in 20 the
    winner's file left unreadable by the loser's truncation.)"""
    scene = free_poses_scene(k_max=4)
    for attempt in range(8):
        path = tmp_path / f"race{attempt}.h5"
        script = CONTENDER.format(root=str(ROOT), scene=str(scene.path), path=str(path))
        start = time.time() + 1.5  # both have imported h5py and mscap by then
        jobs = [subprocess.Popen([sys.executable, "-c", script, str(seed), str(start), str(force)], cwd=ROOT,
                                 stderr=subprocess.PIPE, text=True) for seed in (1, 2)]
        results = [(job.wait(timeout=60), job.stderr.read()) for job in jobs]
        for code, err in results:
            assert "Traceback" not in err, err
            assert code == 0 or (code == 2 and "open for writing in another process" in err), err
        wrote = {f"k2_s000{seed}_random" for seed, (code, _) in zip((1, 2), results) if code == 0}
        assert wrote
        with read_store(path) as f:
            if force:  # the later writer started over
                assert finished_ids(f) <= wrote and len(finished_ids(f)) == 1
            else:
                assert finished_ids(f) == wrote


# ---------------------------------------------------------------- no rank hangs
@needs_mpirun
@pytest.mark.parametrize("where", ["master", "worker"])
def test_an_exception_on_any_rank_ends_the_whole_job(scene_file, tmp_path, where):
    """An unexpected exception in the master's ``record`` (after the first run) or in a
    worker (outside the start's own error handling): the traceback is printed once, by
    the failing rank, and every rank ends (MPI_Abort) with a non-zero status. Before, the
    other ranks waited for it forever."""
    out = tmp_path / "fault.h5"
    fault = {"master": """
        calls = []
        real_write = multistart.write_run
        def write_run(store, record):
            calls.append(record.id)
            if len(calls) == 2:
                raise ValueError("injected fault in the master")
            return real_write(store, record)
        multistart.write_run = write_run
    """, "worker": """
        def synthetic_start(scene, config, rank=0, *args, **kwargs):
            if config.seed % 1000 == 3:
                raise ValueError("injected fault in a worker")
            return synthetic_record(config.k, config.seed, config.init, rank=rank)
        multistart.run_start = synthetic_start
    """}[where]
    code, stderr = synthetic_run(scene_file, out, ranks=3, fault=fault)
    assert code != 0
    assert stderr.count(f"ValueError: injected fault in {'the master' if where == 'master' else 'a worker'}") == 1, \
        stderr
    with read_store(out) as f:  # what was stored stays readable
        assert (len(finished_ids(f)) == 1) if where == "master" else True


def test_selection_is_current_after_every_run(scene_file, tmp_path, monkeypatch):
    """``/selection`` counts every run stored so far each time the next start begins (it
    was written only when a session ended)."""
    from mpi4py import MPI

    from mscap.service import multistart

    out = tmp_path / "sel.h5"
    seen = []

    def start(scene, config, *args, **kwargs):
        if out.exists():
            with read_store(out) as f:
                seen.append((len(finished_ids(f)), int(f["selection"].attrs["runs_total"])
                             if "selection" in f else -1))
        return synthetic_record(config.k, config.seed, config.init)
    monkeypatch.setattr(multistart, "run_start", start)
    multistart.run_multistart(load_scene(scene_file), str(out), MPI.COMM_SELF)
    assert seen[1:] == [(n, n) for n in range(1, 12)]


def test_a_write_that_fails_despite_the_reservation_is_repaired_by_the_resume(tmp_path, free_poses_scene):
    """The residual risk: room taken away between the reservation and the write (here the
    reservation is switched off under a 55 KB ``ulimit -f``). The failing write is one
    StoreError naming the file, closing raises nothing over it, readers name the damaged
    run, and the resume drops it (rebuilding the file when even its name cannot be
    deleted) and keeps every run stored before, whole. (At some limits HDF5 itself dies
    with SIGSEGV inside the failing write instead: 70 KB before the ``size_ratio`` history
    column, 60–65 KB since; which offsets do depends on the file's layout. The reservation
    is what keeps a real job from getting there.)"""
    scene = free_poses_scene(k_max=4)
    path = tmp_path / "bypassed.h5"
    script = textwrap.dedent(f"""
        import resource, signal, sys
        sys.path.insert(0, {str(ROOT)!r})
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        from mscap.scene import load_scene
        from mscap import outfile
        from mscap.service import store as st
        from tests.conftest import synthetic_record
        store = st.open_store({str(path)!r}, load_scene({str(scene.path)!r}))
        outfile.reserve = lambda *args: None
        resource.setrlimit(resource.RLIMIT_FSIZE, (55000, 55000))
        try:
            for seed in range(100):
                st.write_run(store, synthetic_record(2, seed))
                print(seed, flush=True)
        finally:
            store.close()
    """)
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("mscap.errors.StoreError: ") and str(path) in last and "ulimit -f" in last
    written = [int(line) for line in done.stdout.split()]
    assert len(written) >= 2
    with open_store(path, scene) as store:
        assert finished_ids(store) == {f"k2_s{seed:04d}_random" for seed in written}
        for seed in written:
            assert read_run(store, f"k2_s{seed:04d}_random").final_capacitance_pF.shape == (3, 2)
    with read_store(path) as f:  # checked again: whole
        assert len(finished_ids(f)) == len(written)


@pytest.mark.parametrize("kind", ["fifo", "directory"])
def test_a_results_file_that_is_not_a_file_is_refused_at_once(tmp_path, kind):
    """HDF5 opened a FIFO and waited for a writer for ever (inspect, plot and merge all hung);
    ``read_store`` looks at the file first (issue 48)."""
    path = tmp_path / "r.h5"
    os.mkfifo(path) if kind == "fifo" else path.mkdir()
    from tests.conftest import within

    with within(10), pytest.raises(StoreError, match=f"r.h5: is a {'FIFO' if kind == 'fifo' else 'directory'}, "
                                                     "not a results file"):
        read_store(path)
