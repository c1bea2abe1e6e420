"""The multi-start service: ``mpirun -n N mscap run`` on a tiny scene (coarse mesh, three
poses, k ∈ {2, 3}, two starts each, two L-BFGS iterations per level)."""

from __future__ import annotations

import copy
import json
import math
import os
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from mscap.service.store import finished_ids, read_run, read_store
from tests.conftest import SMALL_SCENE, to_toml

MSCAP = str(Path(sys.executable).with_name("mscap"))
ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1", OMP_NUM_THREADS="1")
needs_mpirun = pytest.mark.skipif(shutil.which("mpirun") is None, reason="no mpirun (make installs openmpi-bin)")


def tiny_scene() -> dict:
    data = copy.deepcopy(SMALL_SCENE)
    data["mesh"] = {"edge_length_mm": 4.0, "edge_length_outline_mm": 1.0, "grading_distance_mm": 2.0}
    data["elastic"] = {"edge_length_mm": 6.0, "order": 1}  # P1 as measured (pokes get P2 unless told)
    data["poses"] = [
        {"name": "left", "kind": "poke", "center_mm": [10.0, 10.0], "radius_mm": 4.0, "depth_mm": 2.0,
         "held_edges": ["x_min", "x_max"]},
        {"name": "right", "kind": "poke", "center_mm": [20.0, 10.0], "radius_mm": 4.0, "depth_mm": 2.0,
         "held_edges": ["x_min", "x_max"]},
        {"name": "pull", "kind": "stretch", "mode": "uniaxial", "stretch": 1.2, "grips": "roller"}]
    data["multistart"] = {"k_min": 2, "k_max": 3, "starts_per_k": 2}
    # The service's bookkeeping, not the optimiser, is tested here: these P1 pokes at h =
    # 1.5 R carry a 51 % bias (mscap.design.resolution), with which the line search's error
    # guard ends most starts after a step, and runs that step a few times are needed.
    data["optimizer"] = {"resolve_steps": False}
    return data


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("multistart") / "tiny.toml"
    path.write_text(to_toml(tiny_scene()))
    return path


def mscap_run(n: int, scene: Path, out: Path, *extra, timeout: float = 300) -> subprocess.CompletedProcess:
    command = [MSCAP, "run", str(scene), "-o", str(out), "--max-iterations", "2", *extra]
    if n > 1:
        command = ["mpirun", "-n", str(n), "--oversubscribe", *command]
    return subprocess.run(command, env=ENV, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def three_ranks(scene_file, tmp_path_factory):
    if shutil.which("mpirun") is None:
        pytest.skip("no mpirun")
    out = tmp_path_factory.mktemp("n3") / "results.h5"
    done = mscap_run(3, scene_file, out)
    assert done.returncode == 0, done.stderr
    return out, done


@needs_mpirun
def test_three_ranks_write_a_complete_file(three_ranks, capsys):
    from mscap.cli import main

    out, done = three_ranks
    store = read_store(out)
    assert finished_ids(store) == {"k2_s2000_lloyd", "k2_s2001_random", "k3_s3000_lloyd", "k3_s3001_random"}
    ranks = {read_run(store, rid).rank for rid in finished_ids(store)}
    assert ranks <= {1, 2} and ranks  # the master only schedules and writes
    store.close()
    # One progress line per run, on stderr. The largest k is handed out first (one k = 3
    # start per worker), so no k = 2 start can finish before a k = 3 one.
    progress = [line for line in done.stderr.splitlines() if line.startswith("[") and not line.startswith("[rank ")]
    assert len(progress) == 4 and progress[0].startswith("[1/4] k3_")
    # advice about the scene (P1 under pokes) once, from the first worker, not once per worker
    advice = [line for line in done.stderr.splitlines() if "P1 elements lock where the sheet bends" in line]
    assert len(advice) == 1 and advice[0].startswith("[rank 1] WARNING"), advice
    # Each ends with the runs left and the ETA (mscap.service.forecast), known from the
    # first finished run on and nothing after the last.
    assert all(re.search(r"\d left, ETA (\d+ s|\d+ min|\d+ h \d\d min)$", line) for line in progress), progress
    assert progress[-1].endswith("0 left, ETA 0 s")
    assert main(["inspect", str(out), "--json"]) == 0
    table = json.loads(capsys.readouterr().out)
    assert table["runs_total"] == 4 and table["chosen_k"] in (2, 3)
    assert [row["k"] for row in table["per_k"]] == [2, 3]
    assert all(row["runs_ok"] == 2 and row["runs_failed"] == 0 for row in table["per_k"])
    assert all(0 < row["best_error_estimate"] < 0.3 for row in table["per_k"])
    assert main(["inspect", str(out), "--runs"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:3] == ["run", "status", "its"] and len(lines) == 5 and "%" in lines[1]
    # Every run carries its worker's CPU seconds and peak memory (mscap.service.usage): a
    # worker's CPU is positive and at most the machine's cores' worth of its wall (how much
    # of its wall it gets depends on what else runs: 8 % beside four busy processes on 2
    # cores); its peak holds the mesh and the solvers, far below 1 GB.
    cost = table["cost"]
    assert cost["runs"] == cost["runs_measured"] == 4 and cost["check_cpu_s"] > 0
    with read_store(out) as store:
        runs = [read_run(store, rid) for rid in finished_ids(store)]
    for r in runs:
        assert 0 < r.cpu_s < (os.cpu_count() or 1) * r.wall_s + 0.5, r.id
        assert 30 < r.peak_rss_mb < 1000, r.id
        assert r.checked == math.isfinite(r.error_estimate_cpu_s)
    assert cost["peak_rss_mb"] == max(r.peak_rss_mb for r in runs)


@needs_mpirun
def test_the_best_run_of_each_k_stores_its_finer_mesh_check(three_ranks, scene_file):
    """The stored check is the final layout simulated on ``finer(scene)``; a run left
    unchecked is beaten by a checked run of its k."""
    from dataclasses import replace

    from mscap.service.accuracy import finer, relative_difference
    from mscap.geometry.layout import Layout
    from mscap.scene import load_scene
    from mscap.fem.simulate import simulate

    out, _ = three_ranks
    scene = load_scene(scene_file)
    with read_store(out) as store:
        runs = [read_run(store, rid) for rid in sorted(finished_ids(store))]
    for k in (2, 3):
        mine = [r for r in runs if r.k == k]
        best = max(mine, key=lambda r: r.metric)
        assert best.checked
        assert all(r.checked or r.metric < best.metric for r in mine)
    record = max((r for r in runs if r.k == 2), key=lambda r: r.metric)
    layout = Layout(tuple(record.final_outlines))
    sheet, elastic = finer(replace(scene.sheet, layout=layout), scene.elastic)
    fine = simulate(scene, sheet=sheet, elastic=elastic).capacitance_pF
    np.testing.assert_allclose(record.finer_capacitance_pF, fine, rtol=1e-9)
    assert record.error_estimate == pytest.approx(relative_difference(record.final_capacitance_pF, fine), rel=1e-9)
    assert record.error_estimate_wall_s > 0 and record.finer_metric_pF > 0
    # the pose-to-pose distances' error, pair by pair, and the metric's
    coarse_c, fine_c = record.final_capacitance_pF, fine
    n = len(fine_c)
    pairs = [(a, b) for a in range(n) for b in range(a + 1, n)]
    worst = max(abs(np.abs(coarse_c[a] - coarse_c[b]).sum() / np.abs(fine_c[a] - fine_c[b]).sum() - 1)
                for a, b in pairs)
    assert record.signal_error == pytest.approx(worst, rel=1e-9)
    assert record.metric_error == pytest.approx(abs(record.metric / record.finer_metric_pF - 1), rel=1e-9)


@needs_mpirun
def test_results_do_not_depend_on_the_number_of_ranks(three_ranks, scene_file, tmp_path):
    out3, _ = three_ranks
    out2 = tmp_path / "n2.h5"
    done = mscap_run(2, scene_file, out2, "-q")
    assert done.returncode == 0, done.stderr
    a, b = read_store(out3), read_store(out2)
    assert finished_ids(a) == finished_ids(b)
    for rid in finished_ids(a):
        ra, rb = read_run(a, rid), read_run(b, rid)
        # Measured: identical to the last bit.
        np.testing.assert_allclose(rb.final_capacitance_pF, ra.final_capacitance_pF, rtol=1e-10, atol=0)
        for pa, pb in zip(ra.final_outlines, rb.final_outlines):
            np.testing.assert_allclose(pb, pa, rtol=0, atol=1e-10)


@needs_mpirun
def test_a_different_scene_is_refused_without_hanging_the_workers(three_ranks, tmp_path):
    out, _ = three_ranks
    other = tiny_scene()
    other["multistart"]["starts_per_k"] = 3
    path = tmp_path / "other.toml"
    path.write_text(to_toml(other))
    done = mscap_run(2, path, out, timeout=120)
    assert done.returncode != 0
    assert "mscap: error:" in done.stderr and str(out) in done.stderr


def test_an_interrupted_job_resumes_with_only_the_missing_runs(scene_file, tmp_path, monkeypatch):
    # One process (no mpirun): the master runs every start itself. The first call stops
    # after k = 2 (as a job killed then would have stored); the rerun does only k = 3.
    from mpi4py import MPI

    from mscap.service import multistart
    from mscap.scene import load_scene

    scene = load_scene(scene_file)
    out = tmp_path / "resume.h5"
    lines = []
    first = multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=1,
                                      select_configs=lambda c: c.k == 2, progress=lines.append)
    assert first["choice"].startswith("chosen k = 2 ") and "resol" in first["choice"]  # resolved / not / unknown
    assert {k: v for k, v in first.items() if k != "choice"} == {"runs_done": 2, "runs_failed": 0, "stopped": False}
    store = read_store(out)
    before = {rid: read_run(store, rid).wall_s for rid in finished_ids(store)}
    store.close()
    ran = []
    real = multistart.run_start
    monkeypatch.setattr(multistart, "run_start", lambda s, c, *a, **k: ran.append(c.id) or real(s, c, *a, **k))
    second = multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=1, progress=lines.append)
    assert second["runs_done"] == 2 and sorted(ran) == ["k3_s3000_lloyd", "k3_s3001_random"]
    assert "2 runs already stored, 2 to do" in lines[-3]
    store = read_store(out)
    assert len(finished_ids(store)) == 4
    assert {rid: read_run(store, rid).wall_s for rid in before} == before  # not redone


def test_a_beaten_run_is_the_one_kind_left_unchecked():
    """Only a run that select() ranks below a finished run of its k, whatever else
    finishes, skips its check: by the bound when runs have one, else by the min L1
    distance, ties to the smaller id; pruned, failed and other-k runs never beat it."""
    from mscap.service.multistart import Finished, beaten_by
    from mscap.service.selection import RunSummary

    nan = float("nan")
    runs = [RunSummary("k2_s2000_lloyd", 2, True, 5.0, 1.0), RunSummary("k2_s2001_random", 2, True, 7.0, 1.0),
            RunSummary("k2_s2002_random", 2, True, 9.0, 1.0, pruned=True),
            RunSummary("k2_s2003_random", 2, False, nan, 1.0), RunSummary("k3_s3000_lloyd", 3, True, 99.0, 1.0)]
    assert beaten_by(Finished("k2_s2004_random", 2, 6.0, nan), runs) == "k2_s2001_random"
    assert beaten_by(Finished("k2_s2004_random", 2, 7.5, nan), runs) is None  # the new best: checked
    assert beaten_by(Finished("k2_s2004_random", 2, 7.0, nan), runs) == "k2_s2001_random"  # a tie, larger id
    assert beaten_by(Finished("k2_s2000_random", 2, 7.0, nan), runs) is None  # a tie, smaller id
    assert beaten_by(Finished("k4_s4000_lloyd", 4, 1.0, nan), runs) is None  # the first of its k
    # Read-back scenes rank by the bound (smaller is better), not by the min L1 distance.
    bound = [RunSummary("k2_s2000_lloyd", 2, True, 5.0, 1.0, bound_mm=0.30),
             RunSummary("k2_s2001_random", 2, True, 9.0, 1.0, bound_mm=0.40)]
    assert beaten_by(Finished("k2_s2002_random", 2, 20.0, 0.35), bound) == "k2_s2000_lloyd"
    assert beaten_by(Finished("k2_s2002_random", 2, 1.0, 0.29), bound) is None


def test_only_runs_that_can_be_a_ks_best_are_checked(scene_file, tmp_path):
    """One process runs the starts in a fixed order (k = 3 first, then by seed): the first
    run of each k is checked, a later one only if it beats the earlier; every run is with
    check_all_runs, and the selection and its verdict are the same either way."""
    from dataclasses import replace

    from mpi4py import MPI

    from mscap.service import multistart
    from mscap.scene import load_scene

    scene = load_scene(scene_file)
    results = {}
    for check_all in (False, True):
        everything = replace(scene, multistart=replace(scene.multistart, check_all_runs=check_all))
        out = tmp_path / f"check_all_{check_all}.h5"
        summary = multistart.run_multistart(everything, str(out), MPI.COMM_SELF, max_iterations=1)
        with read_store(out) as store:
            results[check_all] = (summary["choice"], {rid: read_run(store, rid) for rid in finished_ids(store)})
    (choice, lean), (choice_all, every) = results[False], results[True]
    assert all(r.checked for r in every.values())
    for first, second in (("k3_s3000_lloyd", "k3_s3001_random"), ("k2_s2000_lloyd", "k2_s2001_random")):
        assert lean[first].checked
        assert lean[second].checked == (lean[second].metric > lean[first].metric)
        np.testing.assert_array_equal(lean[second].final_capacitance_pF, every[second].final_capacitance_pF)
    assert sum(not r.checked for r in lean.values()) >= 1  # the tiny scene leaves at least one unchecked
    assert choice == choice_all and "resolved" in choice


def test_a_best_run_left_unchecked_is_checked_when_the_job_resumes(scene_file, tmp_path, monkeypatch):
    """A k's best stored without its check (here the check fails; a stop between a run and
    its check does the same) gets it on the next run of the job, and the verdict with it."""
    from mpi4py import MPI

    from mscap.service import multistart
    from mscap.scene import load_scene

    scene = load_scene(scene_file)
    out, lines = tmp_path / "pending.h5", []
    real = multistart.estimate_error

    def broken(*args, **kwargs):
        raise MemoryError("the finer mesh does not fit (forced by the test)")
    monkeypatch.setattr(multistart, "estimate_error", broken)
    first = multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=1,
                                      select_configs=lambda c: c.k == 2)
    assert "resolution unknown" in first["choice"]
    monkeypatch.setattr(multistart, "estimate_error", real)
    second = multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=1,
                                       select_configs=lambda c: c.k == 2, progress=lines.append)
    assert second["runs_done"] == 1 and "resolution unknown" not in second["choice"]
    best = second["choice"].split("(run ")[1].split(")")[0]
    assert f"1 of them the finer-mesh check of {best}" in "\n".join(lines)
    with read_store(out) as store:
        assert read_run(store, best).checked
    third = multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=1,
                                      select_configs=lambda c: c.k == 2)
    assert third["runs_done"] == 0  # nothing pending any more


def test_a_stopping_job_keeps_a_finished_run_without_its_check(scene_file):
    from types import SimpleNamespace

    from mscap import farm
    from mscap.service import multistart
    from mscap.scene import load_scene

    record = SimpleNamespace(id="k2_s2000_lloyd", k=2, metric=1.0, bound_mm=float("nan"))

    def stopping(question):
        raise farm.Abandoned

    scene = load_scene(scene_file)
    assert multistart._with_check(scene, scene.sheet, record, None, None, stopping) is record


def test_a_start_that_fails_midway_keeps_its_history(scene_file, tmp_path, monkeypatch):
    # Nothing a start did is lost when it dies: the optimiser's rows up to the failure
    # and the initial layout are stored with the error (a poking paper start at k = 6
    # failed after 467 s and 64 steps, and its file held none of them).
    from mpi4py import MPI

    from mscap.design import optimizer
    from mscap.errors import ElasticError
    from mscap.scene import load_scene
    from mscap.service import multistart

    real, calls = optimizer._gradient, []

    def failing(design, evaluation):
        calls.append(1)
        if len(calls) == 3:
            raise ElasticError("pose p0: Newton failed at load step 1 (forced by the test)")
        return real(design, evaluation)
    monkeypatch.setattr(optimizer, "_gradient", failing)
    out = tmp_path / "midway.h5"
    scene = load_scene(scene_file)
    multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=4,
                              select_configs=lambda c: c.id == "k2_s2000_lloyd")
    store = read_store(out)
    run = read_run(store, "k2_s2000_lloyd")
    store.close()
    assert run.status == "failed" and "Newton failed at load step 1 (forced" in run.error
    assert list(run.history["event"][:1]) == ["start"] and len(run.history["J"]) == 2 and run.iterations == 1
    assert len(run.initial_outlines) == 2 and run.final_outlines == ()


def test_a_failing_start_is_recorded_and_the_others_complete(scene_file, tmp_path, monkeypatch):
    from mpi4py import MPI

    from mscap.design import pipeline as design

    from mscap.service import multistart
    from mscap.errors import MeshError
    from mscap.scene import load_scene

    real = design.build_design

    def build(scene, **kwargs):
        if kwargs["sheet"].layout.k == 3:  # the start's layout
            raise MeshError("gmsh failed to mesh the sheet (forced by the test)")
        return real(scene, **kwargs)
    monkeypatch.setattr(design, "build_design", build)
    out = tmp_path / "fail.h5"
    summary = multistart.run_multistart(load_scene(scene_file), str(out), MPI.COMM_SELF, max_iterations=1)
    assert {k: v for k, v in summary.items() if k != "choice"} == {"runs_done": 4, "runs_failed": 2, "stopped": False}
    store = read_store(out)
    failed = read_run(store, "k3_s3000_lloyd")
    assert failed.status == "failed" and "MeshError: gmsh failed to mesh the sheet (forced" in failed.error
    assert read_run(store, "k2_s2000_lloyd").ok
    store.close()
    # A plain rerun skips the failed runs; --retry-failed runs exactly those again.
    monkeypatch.setattr(design, "build_design", real)
    scene = load_scene(scene_file)
    assert multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=1)["runs_done"] == 0
    again = multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=1, retry_failed=True)
    assert {k: v for k, v in again.items() if k != "choice"} == {"runs_done": 2, "runs_failed": 0, "stopped": False}
    store = read_store(out)
    assert all(read_run(store, rid).ok for rid in finished_ids(store)) and len(finished_ids(store)) == 4


def test_lloyd_starts_that_repeat_a_layout_are_skipped(tmp_path, monkeypatch):
    """Ten Lloyd starts at k = 2 on the 30 × 20 mm sheet give four distinct layouts (two
    tessellations, each in two plate orders): the master runs those four and says which
    starts it skipped and why; a rerun skips them again; ``--keep-repeated-starts`` runs
    them all."""
    from mpi4py import MPI

    from mscap.scene import load_scene
    from mscap.scene.loader import with_overrides
    from mscap.service import multistart
    from mscap.service.selection import repeated_starts
    from mscap.service.store import failed_record

    data = tiny_scene()
    data["multistart"] = {"k_min": 2, "k_max": 2, "starts_per_k": 10, "lloyd_fraction": 1.0}
    path = tmp_path / "lloyd.toml"
    path.write_text(to_toml(data))
    scene = load_scene(path)
    repeats = repeated_starts(scene)
    ran, lines = [], []
    monkeypatch.setattr(multistart, "run_start", lambda s, c, *a, **k: ran.append(c.id)
                        or failed_record(c.k, c.seed, c.init, "not run (test)", 0.0, 0))
    out = str(tmp_path / "lloyd.h5")
    summary = multistart.run_multistart(scene, out, MPI.COMM_SELF, progress=lines.append)
    assert len(ran) == 10 - len(repeats) == 4 and not set(ran) & set(repeats)
    assert summary["runs_done"] == 4
    skipped = next(line for line in lines if line.startswith("skipped"))
    assert f"skipped {len(repeats)} Lloyd starts" in skipped and "k2_s2002_lloyd (= k2_s2000_lloyd)" in skipped
    ran.clear()
    multistart.run_multistart(scene, out, MPI.COMM_SELF, retry_failed=True, progress=lines.append)
    assert len(ran) == 4 and not set(ran) & set(repeats)
    # mscap run --keep-repeated-starts runs all ten.
    ran.clear()
    keep = with_overrides(scene, keep_repeated_starts=True)
    multistart.run_multistart(keep, str(tmp_path / "all.h5"), MPI.COMM_SELF, progress=lines.append)
    assert len(ran) == 10


def session_members(sid: int) -> list[int]:
    """Live processes of session ``sid`` (zombies, already dead, left out)."""
    members = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()  # state, ppid, pgrp, session, ...
            if int(fields[3]) == sid and fields[0] != "Z":
                members.append(int(entry.name))
    return members


def signal_session(sid: int, signum: int) -> None:
    for pid in session_members(sid):
        try:
            os.kill(pid, signum)
        except ProcessLookupError:
            pass


@needs_mpirun
@pytest.mark.parametrize("signal_name", ["SIGTERM", "SIGKILL"])
def test_a_killed_job_leaves_a_readable_file_and_the_rerun_completes_it(scene_file, tmp_path, signal_name):
    # SIGTERM is what SLURM sends at the time limit; SIGKILL is `kill -9` of the whole job.
    import signal
    import time

    out = tmp_path / "killed.h5"
    command = ["mpirun", "-n", "3", "--oversubscribe", MSCAP, "run", str(scene_file), "-o", str(out),
               "--max-iterations", "2"]
    job = subprocess.Popen(command, env=ENV, stderr=subprocess.PIPE, text=True, start_new_session=True)
    for line in job.stderr:  # wait for the first stored run
        if line.startswith("[1/"):
            break
    # mpirun puts every rank in a process group of its own, in mpirun's session: signal the
    # whole session, as SLURM signals every process of a job step, and wait until it is gone.
    signal_session(job.pid, getattr(signal, signal_name))
    job.communicate(timeout=60)
    deadline = time.monotonic() + 60
    while session_members(job.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not session_members(job.pid), "ranks outlived the killed job"
    store = read_store(out)  # opens after any kill
    before = {rid: read_run(store, rid).wall_s for rid in finished_ids(store)}
    store.close()
    assert 1 <= len(before) <= 4
    done = mscap_run(3, scene_file, out)
    assert done.returncode == 0, done.stderr
    # The rerun does the missing starts, and the check of a k's best that the stop reached
    # between its run and its check (stored unchecked rather than lost).
    stored, todo = map(int, re.search(r"(\d+) runs already stored, (\d+) to do", done.stderr).groups())
    pending = todo - (4 - len(before))
    assert stored == len(before) and pending >= 0
    assert pending == 0 or f"{pending} of them the finer-mesh check" in done.stderr
    store = read_store(out)
    assert len(finished_ids(store)) == 4
    runs = [read_run(store, rid) for rid in finished_ids(store)]
    assert {r.id: r.wall_s for r in runs if r.id in before} == before
    assert all(max((r for r in runs if r.k == k), key=lambda r: r.metric).checked for k in (2, 3))


def rank_pid(session: int, rank: int) -> int:
    """The pid of MPI rank ``rank`` among the processes of ``session`` (mpirun's)."""
    for pid in session_members(session):
        try:
            environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if f"OMPI_COMM_WORLD_RANK={rank}".encode() in environ:
            return pid
    raise AssertionError(f"no rank {rank} in session {session}")


@needs_mpirun
@pytest.mark.parametrize("target, signal_name, status", [
    ("mpirun", "SIGUSR1", 0),  # the SLURM scripts' route: mpirun passes it on to every rank
    ("rank 1", "SIGTERM", 0),  # a signal to one worker alone stops the job like one to the master
    ("mpirun", "SIGTERM", 1),  # mpirun kills the ranks 1 s after it passes a TERM on, and exits 1
])
def test_a_signal_to_any_rank_or_to_mpirun_stops_the_job_cleanly(scene_file, tmp_path, target, signal_name,
                                                                 status):
    """A stop signal to mpirun or to any rank: the master says "stopping (...)" at once and
    writes it to $MSCAP_STOP_FILE; what finished is stored. The job then ends on its own
    with exit 0 and "stopped" (the master aborts busy workers), except that mpirun answers a
    TERM by killing the ranks and exiting 1, whatever they do (OpenMPI 4.1; the job scripts
    report the stop file's clean stop as 0, slurm/README.md "Exit statuses")."""
    import signal
    import time

    out, stop_file = tmp_path / "stopped.h5", tmp_path / "stop"
    command = ["mpirun", "-n", "3", "--oversubscribe", MSCAP, "run", str(scene_file), "-o", str(out),
               "--max-iterations", "2"]
    job = subprocess.Popen(command, env={**ENV, "MSCAP_STOP_FILE": str(stop_file)}, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True, start_new_session=True)
    for line in job.stderr:
        if line.startswith("[1/"):
            break
    os.kill(job.pid if target == "mpirun" else rank_pid(job.pid, 1), getattr(signal, signal_name))
    stdout, stderr = job.communicate(timeout=60)
    assert job.returncode == status, stderr
    reason = f"{signal_name} to rank {0 if target == 'mpirun' else 1}"
    assert f"stopping ({reason}): everything finished is stored" in stderr
    if status == 0:
        assert "exited on signal" not in stderr               # no rank died of the signal
        assert "stopped: the finished runs are stored" in stderr
        assert stop_file.read_text() == "stopped\n"
        # the answer of a stopped job is the stored runs' so far, and says so
        assert re.search(r"^so far \(\d+ tasks? left: the job stopped; rerun the same command", stdout, flags=re.M), stdout
    else:  # killed during the stop or, when the busy workers reached a checkpoint within 1 s, after it
        assert stop_file.read_text() in (f"stopping {reason}\n", "stopped\n")
    deadline = time.monotonic() + 30
    while session_members(job.pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not session_members(job.pid), "ranks outlived the stopped job"
    store = read_store(out)
    assert 1 <= len(finished_ids(store)) < 4
    store.close()


def test_no_mpi_start_under_a_file_size_limit_it_cannot_live_with(scene_file, tmp_path):
    """Under ``ulimit -f 1024`` OpenMPI's start-up dies in MPI_Init with a dozen PMIx lines;
    mscap says why in one line before it starts MPI, and exits 2."""
    import resource

    from mscap.cli.common import MIN_FILE_SIZE_LIMIT_BYTES

    def small_limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (2**20, 2**20))

    done = subprocess.run([MSCAP, "run", str(scene_file), "-o", str(tmp_path / "r.h5")], env=ENV,
                          capture_output=True, text=True, preexec_fn=small_limit, timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip() == (f"mscap: error: the file size limit (ulimit -f) is 1024 KB: MPI's start-up "
                                   f"needs at least {MIN_FILE_SIZE_LIMIT_BYTES // 1024} KB (raise it: ulimit -f "
                                   f"unlimited)")
    assert not (tmp_path / "r.h5").exists()


@needs_mpirun
def test_heartbeat_bounds_the_silence_while_starts_run(scene_file, tmp_path):
    """With --heartbeat 1 no gap between stderr lines exceeds the interval by much while
    starts run, and the status lines name the busy workers' runs, steps and metrics."""
    import re
    import time

    out = tmp_path / "heartbeat.h5"
    command = ["mpirun", "-n", "3", "--oversubscribe", MSCAP, "run", str(scene_file), "-o", str(out),
               "--max-iterations", "4", "--heartbeat", "1"]
    job = subprocess.Popen(command, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stamps, lines = [], []
    for line in job.stderr:
        stamps.append(time.monotonic())
        lines.append(line.rstrip())
    job.wait(timeout=120)
    assert job.returncode == 0
    first = next(i for i, ln in enumerate(lines) if "to do on" in ln)
    last = max(i for i, ln in enumerate(lines) if ln.startswith("[4/4]"))
    gaps = [b - a for a, b in zip(stamps[first:last], stamps[first + 1:last + 1])]
    assert max(gaps) < 1 + 1.5, (max(gaps), lines)
    beats = [ln for ln in lines if ln.startswith("... ")]
    assert beats
    assert any(re.search(r"rank [12] k\d_s\d{4}_(lloyd|random): step \d+, [0-9.]+ pF, \d+ s", ln) for ln in beats)


@needs_mpirun
def test_a_rank_done_early_waits_for_the_others_without_a_core(tmp_path):
    """``farm.quiet_barrier``: every rank passes it before leaving ``farm.run``, so none waits
    in ``MPI_Finalize``, where OpenMPI polls at full speed. Rank 1 arrives 1.5 s before
    rank 0; its CPU over the wait stays a small fraction of it."""
    script = tmp_path / "barrier.py"
    script.write_text(textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(ROOT)!r})
        from mpi4py import MPI
        from mscap.farm import quiet_barrier
        comm = MPI.COMM_WORLD
        if comm.Get_rank() == 0:
            time.sleep(1.5)
        cpu, wall = time.process_time(), time.perf_counter()
        quiet_barrier(comm)
        print(comm.Get_rank(), time.process_time() - cpu, time.perf_counter() - wall, flush=True)
    """))
    done = subprocess.run(["mpirun", "-n", "2", "--oversubscribe", sys.executable, str(script)], env=ENV,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    rows = {int(r): (float(c), float(w)) for r, c, w in (line.split() for line in done.stdout.splitlines())}
    cpu, wall = rows[1]
    assert wall > 1.0  # it did wait for rank 0
    assert cpu < 0.2 * wall, rows  # polling at full speed would spend about the whole wait


def _one_start(tmp_path):
    from mscap.scene import load_scene

    data = tiny_scene()
    data["multistart"] = {"k_min": 2, "k_max": 2, "starts_per_k": 1, "error_estimate": False}
    path = tmp_path / "one.toml"
    path.write_text(to_toml(data))
    return load_scene(path)


def _sigterm_at_step(monkeypatch, step: int):
    """SIGTERM to this process while the start reports its step ``step`` (the master then
    abandons it at that question); returns the real ``Progress``, to put back."""
    import signal

    from mscap.service import multistart

    made = multistart.Progress

    def stopping(*args, **kwargs):
        progress = made(*args, **kwargs)
        if progress.iteration == step:
            os.kill(os.getpid(), signal.SIGTERM)
        return progress

    monkeypatch.setattr(multistart, "Progress", stopping)
    return made


def test_a_start_stopped_midway_continues_where_it_stopped(tmp_path, monkeypatch, capsys):
    """Issue 49 item 1: a job stopped while its start runs keeps the start's optimiser
    state beside the results file; the rerun continues it and stores the run the
    uninterrupted job stores (the same events, J to 1e-7), then deletes the state."""
    from mpi4py import MPI

    from mscap.service import checkpoints, multistart

    scene = _one_start(tmp_path)
    whole_file = tmp_path / "whole.h5"
    multistart.run_multistart(scene, str(whole_file), MPI.COMM_SELF, max_iterations=4)
    with read_store(whole_file) as store:
        whole = read_run(store, "k2_s2000_lloyd")
    assert list(whole.history["event"]).count("step") >= 3, whole.history["event"]

    made = _sigterm_at_step(monkeypatch, 2)  # SLURM's SIGTERM arrives during the second step
    out, lines = tmp_path / "stopped.h5", []
    first = multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=4, progress=lines.append)
    assert first["stopped"] and first["runs_done"] == 0
    assert checkpoints.stored(out) == ["k2_s2000_lloyd"]
    # the state at the top of the step that was stopped: one step lost, not the start
    assert any("k2_s2000_lloyd: stopped at step 1 (level 0); its state is kept in" in line for line in lines), lines
    from mscap.cli import main

    capsys.readouterr()
    assert main(["inspect", str(out)]) == 0
    assert "a rerun of the same command continues them): k2_s2000_lloyd (step 1)" in capsys.readouterr().out
    monkeypatch.setattr(multistart, "Progress", made)
    second = multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=4, progress=lines.append)
    assert second["runs_done"] == 1 and not second["stopped"]
    assert any("1 start continues from its stored state: k2_s2000_lloyd (step 1)" in line for line in lines), lines
    with read_store(out) as store:
        resumed = read_run(store, "k2_s2000_lloyd")
    assert list(resumed.history["event"]) == list(whole.history["event"])
    np.testing.assert_allclose(resumed.history["J"], whole.history["J"], rtol=1e-7)
    np.testing.assert_allclose(resumed.final_capacitance_pF, whole.final_capacitance_pF, rtol=1e-6)
    assert checkpoints.stored(out) == [] and not checkpoints.directory(out).exists()


def test_a_damaged_checkpoint_is_said_deleted_and_its_start_runs_afresh(tmp_path):
    from mpi4py import MPI

    from mscap.service import checkpoints, multistart

    scene = _one_start(tmp_path)
    out, lines = tmp_path / "r.h5", []
    checkpoints.directory(out).mkdir()
    (checkpoints.directory(out) / "k2_s2000_lloyd.h5").write_bytes(b"not HDF5 at all")
    done = multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=1, progress=lines.append)
    assert done["runs_done"] == 1
    said = [line for line in lines if "not a readable optimiser state" in line]
    assert len(said) == 1 and said[0].endswith("deleted; k2_s2000_lloyd runs from its beginning"), lines
    assert checkpoints.stored(out) == []


def test_a_busy_start_sends_its_state_every_checkpoint_interval(tmp_path, monkeypatch):
    """``checkpoint_minutes``: the master stores the state while the start runs (here at
    every iteration) and deletes it once the run is stored."""
    import dataclasses

    from mpi4py import MPI

    from mscap.service import checkpoints, multistart

    scene = _one_start(tmp_path)
    scene = dataclasses.replace(scene, multistart=dataclasses.replace(scene.multistart, checkpoint_minutes=1e-9))
    saved, save = [], checkpoints.save
    monkeypatch.setattr(checkpoints, "save", lambda results, rid, state: saved.append(
        (rid, state.iteration, checkpoints.directory(results).exists())) or save(results, rid, state))
    out = tmp_path / "r.h5"
    multistart.run_multistart(scene, str(out), MPI.COMM_SELF, max_iterations=3)
    assert [s[:2] for s in saved][:3] == [("k2_s2000_lloyd", 0), ("k2_s2000_lloyd", 1), ("k2_s2000_lloyd", 2)]
    assert not checkpoints.directory(out).exists()  # the run is stored: its state is gone


def test_a_state_that_cannot_be_kept_is_said_and_the_job_ends_normally(tmp_path, monkeypatch):
    """A full disk (or any write error) at a stop: the start is said not kept, the job
    ends as a clean stop, and the rerun runs that start from its beginning."""
    from mpi4py import MPI

    from mscap.errors import MscapError
    from mscap.service import checkpoints, multistart

    def full(*args):
        raise MscapError("r.h5.checkpoints/k2_s2000_lloyd.h5: cannot write (No space left on device)")

    monkeypatch.setattr(checkpoints, "save", full)
    _sigterm_at_step(monkeypatch, 2)
    out, lines = tmp_path / "r.h5", []
    first = multistart.run_multistart(_one_start(tmp_path), str(out), MPI.COMM_SELF, max_iterations=4,
                                      progress=lines.append)
    assert first["stopped"] and first["runs_done"] == 0
    said = [line for line in lines if "k2_s2000_lloyd: stopped at step" in line]
    assert len(said) == 1 and "not kept (" in said[0] and said[0].endswith("a rerun runs it from its beginning")
    assert checkpoints.stored(out) == []


def test_the_start_line_names_the_workers_hosts_when_there_are_several():
    """On two SLURM nodes the master's first line says where its workers run (slurm/selftest.sh
    section 6 reads it); on one host it says nothing more."""
    from mscap.service.multistart import on_hosts

    assert on_hosts(["node1", "node2", "node1"]) == " on 2 hosts (node1: 2, node2: 1)"
    assert on_hosts(["vm", "vm"]) == "" and on_hosts([]) == ""

