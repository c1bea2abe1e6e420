"""A start's CPU time and peak memory, measured by its worker (``mscap.service.usage``),
stored with the run and summed by ``mscap inspect``."""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace

import h5py
import numpy as np
import pytest

from mscap.cli import main
from mscap.fem.simulate import release_freed_memory
from mscap.service.report import cost, cost_text
from mscap.service.store import open_store, read_run, read_store, write_run
from mscap.service.usage import Meter, peak_rss_mb, reset_peak
from tests.conftest import synthetic_record


def test_the_meter_counts_this_process_cpu_not_its_sleep():
    # Bounds that hold however busy the machine is: a sleep costs no CPU, and one thread
    # cannot spend more CPU than the wall time it ran for.
    meter = Meter()
    time.sleep(0.3)
    slept = meter.cpu_s
    assert slept < 0.05
    wall, cpu = time.perf_counter(), time.process_time()
    while time.process_time() - cpu < 0.2:  # busy until this thread has had 0.2 s of a core
        pass
    wall = time.perf_counter() - wall
    busy = meter.cpu_s - slept
    assert 0.2 <= busy <= wall + 0.01


def test_the_peak_sees_an_allocation_and_a_new_meter_forgets_it():
    meter = Meter()
    before = meter.peak_rss_mb  # what the process holds now, where the peak was reset (Linux)
    block = np.ones(200 * 2**20 // 8)  # 200 MB, every page touched
    assert meter.peak_rss_mb >= before + 160 and meter.peak_rss_mb >= peak_rss_mb() - 1e-9
    peak = meter.peak_rss_mb
    del block
    release_freed_memory()  # as a worker does before each start: the heap's free pages go back
    if reset_peak():  # Linux: the high-water mark goes back to what the process holds now
        assert Meter().peak_rss_mb < peak - 120
    else:  # elsewhere the peak so far: an upper bound
        assert Meter().peak_rss_mb >= peak


@pytest.fixture
def scene(free_poses_scene):
    return free_poses_scene(k_max=4)


def test_usage_round_trips_and_inspect_sums_it(tmp_path, scene, capsys):
    path = tmp_path / "r.h5"
    runs = [replace(synthetic_record(2, 2000), cpu_s=1800.0, error_estimate_cpu_s=360.0, peak_rss_mb=512.5),
            replace(synthetic_record(3, 3000), cpu_s=5400.0, peak_rss_mb=900.25),  # unchecked
            synthetic_record(3, 3001)]  # stored before mscap recorded its cost: NaN
    with open_store(path, scene) as store:
        for record in runs:
            write_run(store, record)
        back = read_run(store, "k2_s2000_random")
        assert (back.cpu_s, back.error_estimate_cpu_s, back.peak_rss_mb) == (1800.0, 360.0, 512.5)
        assert math.isnan(read_run(store, "k3_s3001_random").cpu_s)
    with read_store(path) as store:
        c = cost(store)
    assert (c.runs, c.measured, c.run_cpu_s, c.check_cpu_s) == (3, 2, 7200.0, 360.0)
    assert c.core_hours == pytest.approx(2.1) and (c.peak_rss_mb, c.peak_run) == (900.25, "k3_s3000_random")
    assert cost_text(c) == ("cost: 2.1 core-hours of CPU (runs 2, finer-mesh checks 0.1) over 2 runs (1 more stored "
                            "before mscap recorded CPU time); largest worker peak 900 MB (run k3_s3000_random)")
    assert main(["inspect", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["cost"] == {
        "runs": 3, "runs_measured": 2, "run_cpu_s": 7200.0, "check_cpu_s": 360.0, "core_hours": 2.1,
        "peak_rss_mb": 900.25, "peak_run": "k3_s3000_random",
        "calibration_wall_s": None, "calibration_simulation_s": None}
    assert main(["inspect", str(path)]) == 0
    assert cost_text(c) in capsys.readouterr().out
    assert main(["inspect", str(path), "--run", "k2_s2000_random"]) == 0
    assert ("cost on its worker: 1800.0 CPU-s + 360.0 for the finer-mesh check, peak resident memory 512 MB"
            in capsys.readouterr().out)


def test_a_file_written_before_the_cost_was_stored_says_so(tmp_path, scene):
    path = tmp_path / "r.h5"
    with open_store(path, scene) as store:
        write_run(store, synthetic_record(2, 2000))
    with h5py.File(path, "r+") as f:  # as an older mscap wrote it: no such attributes
        for name in ("cpu_s", "error_estimate_cpu_s", "peak_rss_mb"):
            del f["runs/k2_s2000_random"].attrs[name]
    with read_store(path) as store:
        assert math.isnan(read_run(store, "k2_s2000_random").peak_rss_mb)
        assert cost_text(cost(store)) == "cost: no CPU time stored (1 run, written before mscap recorded it)"


def test_a_file_with_no_run_says_so(tmp_path, scene):
    """Not "written before mscap recorded it": nothing was stored yet (issue 49)."""
    path = tmp_path / "r.h5"
    open_store(path, scene).close()
    with read_store(path) as store:
        assert cost_text(cost(store)) == "cost: no run stored yet"
