"""The SLURM scripts on a real SLURM (slurm/selftest.sh, about 4 minutes): a one-node cluster,
then a two-node one whose nodes are network namespaces of this machine (section 6).

The self-test runs its own cluster from Debian's SLURM and munge and stops it; it installs
nothing (``slurm/selftest.sh --install`` does, as .ci/run does before ``make test``). Where
it cannot run (not root, not Debian, the packages missing, a SLURM already running) it says
so and this test is skipped, unless ``MSCAP_SLURM_SELFTEST=require`` (.ci/run), which makes
that a failure. Its report goes to the terminal, so the CI log shows what passed.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_shipped_scripts_on_a_real_slurm(capsys):
    require = os.environ.get("MSCAP_SLURM_SELFTEST") == "require"
    command = [str(ROOT / "slurm" / "selftest.sh")] + (["--require"] if require else [])
    # os.environ, not this process's C environment: once a test has imported mpi4py, OpenMPI's
    # singleton has put its PMIx server's address there, which must not reach the jobs.
    proc = subprocess.run(command, capture_output=True, text=True, timeout=900, env=dict(os.environ))
    with capsys.disabled():
        print("\n" + proc.stdout + proc.stderr, end="")
    if proc.returncode == 0 and "selftest: skipped:" in proc.stdout:
        pytest.skip(proc.stdout.strip().splitlines()[-1])
    assert proc.returncode == 0, proc.stderr[-2000:]
    for check in ("1. single job", "2. array + merge", "3. scancel (mpirun)", "3. resubmitted", "4. time limit",
                  "4. resubmitted (mpirun)", "5. requeue", "6. two nodes", "6. node2 killed", "6. rerun on node1 alone", "passed"):
        assert f"selftest: {check}" in proc.stdout or (check.startswith("6.") and not require
                                                       and "selftest: 6. skipped" in proc.stdout)
