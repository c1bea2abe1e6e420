"""Before MPI starts (issue 48): a file-size limit or a session directory MPI's start-up
cannot live with is one line, not a dozen PMIx errors from inside ``MPI_Init``. (The limit
itself, under a real ``ulimit -f``, is tests/service/test_multistart.py's.)"""

from __future__ import annotations

import os
import sys
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
