"""Before MPI starts (issue 48): a file-size limit or a session directory MPI's start-up
cannot live with is one line, not a dozen PMIx errors from inside ``MPI_Init``. (The limit
itself, under a real ``ulimit -f``, is tests/service/test_multistart.py's.)"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from mscap.cli import common
from mscap.errors import MscapError


def test_a_nearly_full_session_directory_is_refused_before_mpi_starts(monkeypatch, tmp_path):
    monkeypatch.delitem(sys.modules, "mpi4py.MPI", raising=False)  # as in a fresh `mscap run`
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    free_blocks = (common.MIN_FILE_SIZE_LIMIT_BYTES // 4096) - 1  # one 4 kB block short
    monkeypatch.setattr(os, "statvfs", lambda path: SimpleNamespace(f_bavail=free_blocks, f_frsize=4096))
    with pytest.raises(MscapError) as err:
        common.start_mpi()
    assert str(err.value) == (f"{tmp_path} has {free_blocks * 4} KB free: MPI's start-up needs at least "
                              f"{common.MIN_FILE_SIZE_LIMIT_BYTES // 1024} KB there (its session directory; "
                              f"free some or point TMPDIR elsewhere)")


def test_enough_room_starts_mpi_and_a_running_mpi_is_not_checked(monkeypatch, tmp_path):
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    blocks = common.MIN_FILE_SIZE_LIMIT_BYTES // 4096
    monkeypatch.setattr(os, "statvfs", lambda path: SimpleNamespace(f_bavail=blocks, f_frsize=4096))
    assert common.start_mpi().COMM_WORLD.Get_size() >= 1
    monkeypatch.setattr(os, "statvfs", lambda path: SimpleNamespace(f_bavail=0, f_frsize=4096))
    assert common.start_mpi().COMM_WORLD.Get_size() >= 1  # MPI runs: its start-up is behind it


@pytest.mark.parametrize("options, said", [
    (["--k-min", "3", "--k-max", "2"], "--k-min 3 --k-max 2 selects none of its starts (k 2..3, start indices 0:"),
    (["--k-min", "9"], "--k-min 9 selects none of its starts"),
    (["--seeds", "7:7"], "--seeds 7:7 selects none of its starts"),
    (["--seeds", "x:y"], "--seeds expects A:B (start indices, integers), got 'x:y'"),
])
def test_a_restriction_that_selects_no_start_is_one_line_not_a_quiet_nothing(tmp_path, capsys, options, said):
    """``run --k-min 3 --k-max 2`` ran nothing and said "0 runs this time" (issue 49)."""
    from mscap.cli import main

    out = tmp_path / "r.h5"
    quick = Path(__file__).resolve().parents[2] / "jobs" / "quick.toml"
    assert main(["run", str(quick), "-o", str(out), *options]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mscap: error: ") and said in err and "\n" not in err
    assert not out.exists()


@pytest.mark.parametrize("rank, shown", [
    (0, ["[rank 0] WARNING mscap.scene.calibration: seq outside", "[rank 0] WARNING mscap.fem.simulate: advice",
         "[rank 0] WARNING mscap.fem.simulate: plain"]),
    (1, ["[rank 1] WARNING mscap.fem.simulate: advice", "[rank 1] WARNING mscap.fem.simulate: plain"]),
    (2, ["[rank 2] WARNING mscap.fem.simulate: plain"]),
])
def test_under_mpi_the_scenes_warnings_are_said_once_and_every_line_names_its_rank(monkeypatch, rank, shown):
    """Every rank loads the scene: what loading says (a calibration sequence outside its
    training ranges, ...) comes from rank 0 alone, advice about the scene from rank 0 or
    the first worker, everything else from every rank, each line naming it."""
    import io
    import logging

    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    root = logging.getLogger()
    monkeypatch.setattr(root, "handlers", [handler])
    common.rank_logging(SimpleNamespace(Get_rank=lambda: rank, Get_size=lambda: 3))
    logging.getLogger("mscap.scene.calibration").warning("seq outside")
    logging.getLogger("mscap.fem.simulate").warning("advice", extra={"advice": True})
    logging.getLogger("mscap.fem.simulate").warning("plain")
    assert stream.getvalue().splitlines() == shown
