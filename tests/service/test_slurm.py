"""The SLURM scripts in slurm/: syntax, and the commands they issue.

Each script runs with stand-in `srun`, `sbatch`, `scancel`, `mpirun` and `mscap` executables
on a PATH that holds nothing else of SLURM's or MPI's (the system's tools are reached through
a directory of links that leaves those out), so the tests mean the same on a machine with
SLURM installed (a cluster's login node) as on one without. The stand-ins are tiny shell
scripts that append their name and argv to a log (fields separated by \\x1f, calls by
\\x1e); the stand-in sbatch prints a job id (12345, 12346, ... in order). The real SLURM
is exercised by slurm/selftest.sh (tests/service/test_slurm_real.py).
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SLURM = ROOT / "slurm"
SCRIPTS = ["mscap_run.sbatch", "mscap_array.sbatch", "submit_array.sh"]
BASH = shutil.which("bash") or "/bin/bash"

LOGGER = """#!/bin/sh
{ printf '%s\\037' "$(basename "$0")"; printf '%s\\037' "$@"; printf '\\036'; } >> "$STANDIN_LOG"
"""

SBATCH = LOGGER + """n=$(cat "$STANDIN_LOG.jobs" 2>/dev/null || echo 12345)
echo $((n + 1)) > "$STANDIN_LOG.jobs"
parsable=0
for a in "$@"; do [ "$a" = --parsable ] && parsable=1; done
if [ "$parsable" = 1 ] && [ -z "${STANDIN_SBATCH_PLAIN:-}" ]; then
    echo "$n${STANDIN_SBATCH_CLUSTER:+;$STANDIN_SBATCH_CLUSTER}"
else
    echo "Submitted batch job $n"
fi
"""

# A launcher that stays up until told to stop, like mscap: records the stop signal it receives
# and exits 0. Its pid is where the stand-in scancel finds it.
SLOW = LOGGER + """trap 'echo TERM >> "$STANDIN_LOG.signals"; exit 0' TERM
trap 'echo USR1 >> "$STANDIN_LOG.signals"; exit 0' USR1
echo $$ > "$STANDIN_LOG.pid"
touch "$STANDIN_LOG.started"
i=0
while [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
"""

# scancel --signal=TERM JOB: SLURM signals the job's steps, i.e. the stand-in launcher.
SCANCEL = LOGGER + """kill -TERM "$(cat "$STANDIN_LOG.pid")"
"""

# srun on a machine whose OpenMPI lacks SLURM's PMI (Debian's): the probe's MPI_Init fails.
SRUN_NO_PMI = LOGGER + """case "$*" in *mpi4py*)
    echo 'The application appears to have been direct launched using "srun",' >&2
    echo "but OMPI was not built with SLURM's PMI support and therefore cannot" >&2
    exit 1 ;;
esac
"""

#: What the scripts must not find on PATH outside the stand-ins.
SHADOWED = {"srun", "sbatch", "scancel", "squeue", "scontrol", "sinfo", "salloc", "mpirun", "mpiexec",
            "orterun", "mscap"}


@pytest.fixture(scope="module")
def system_bin(tmp_path_factory) -> Path:
    """Links to every program of /usr/bin and /bin but SLURM's, MPI's and mscap."""
    links = tmp_path_factory.mktemp("system-bin")
    for directory in (Path("/usr/bin"), Path("/bin")):
        for program in directory.iterdir():
            target = links / program.name
            if program.name not in SHADOWED and not target.exists():
                target.symlink_to(program)
    return links


def calls(log: Path) -> list[list[str]]:
    """[name, arg1, arg2, ...] per stand-in call, in order."""
    if not log.exists():
        return []
    text = log.read_text()
    return [rec.split("\x1f")[:-1] for rec in text.split("\x1e")[:-1]]


def option(argv: list[str], name: str) -> str:
    """The value of `name VALUE` or `name=VALUE` in argv."""
    for i, a in enumerate(argv):
        if a == name:
            return argv[i + 1]
        if a.startswith(name + "="):
            return a[len(name) + 1:]
    raise AssertionError(f"{name} not in {argv}")


def mscap_args(call: list[str]) -> list[str]:
    """The argv after `mscap` in a launcher call (srun ... mscap ARGS / mpirun -n N mscap ARGS)."""
    return call[call.index("mscap") + 1:]


class Env:
    def __init__(self, tmp: Path, system_bin: Path, tools=("srun", "sbatch", "scancel", "mpirun", "mscap")):
        self.tmp = tmp
        self.bin = tmp / "bin"
        self.bin.mkdir()
        self.log = tmp / "calls.log"
        for tool in tools:
            self.add(tool, {"sbatch": SBATCH, "scancel": SCANCEL}.get(tool, LOGGER))
        # No venv at MSCAP_VENV: the scripts fall back to the mscap on PATH (the stand-in).
        self.env = {
            "PATH": f"{self.bin}:{system_bin}",
            "HOME": str(tmp),
            "STANDIN_LOG": str(self.log),
            "MSCAP_REPO": str(tmp),
            "MSCAP_VENV": str(tmp / "no-venv"),
        }

    def add(self, tool: str, text: str) -> None:
        path = self.bin / tool
        path.write_text(text)
        path.chmod(0o755)

    def remove(self, tool: str) -> None:
        (self.bin / tool).unlink()

    def run(self, script: str, *args: str, check=True, **env) -> subprocess.CompletedProcess:
        proc = subprocess.run([BASH, str(SLURM / script), *args], cwd=self.tmp,
                              env={**self.env, **env}, capture_output=True, text=True, timeout=30)
        if check:
            assert proc.returncode == 0, proc.stderr
        return proc

    @property
    def calls(self):
        return calls(self.log)

    @property
    def launches(self):
        """The calls that start mscap (not srun's probe of MPI)."""
        return [c for c in self.calls if "mscap" in c]


@pytest.fixture
def sandbox(tmp_path, system_bin):
    return Env(tmp_path, system_bin)


@pytest.mark.parametrize("script", SCRIPTS)
def test_bash_syntax(script):
    text = (SLURM / script).read_text()
    assert text.startswith("#!/bin/bash\n")
    assert "set -euo pipefail" in text
    subprocess.run([BASH, "-n", str(SLURM / script)], check=True, timeout=10)


@pytest.mark.parametrize("script", ["mscap_run.sbatch", "mscap_array.sbatch"])
def test_sbatch_headers(script):
    lines = (SLURM / script).read_text().splitlines()
    header = {ln.split()[1].split("=")[0] for ln in lines if ln.startswith("#SBATCH ")}
    assert {"--ntasks", "--time", "--job-name", "--output"} <= header
    assert any(ln.startswith("# module load") for ln in lines)      # site lines, commented
    assert not any(ln.startswith("module ") for ln in lines)


# --- mscap_run.sbatch -------------------------------------------------------------------------

def test_run_uses_srun_with_scene_and_output(sandbox):
    sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", SLURM_NTASKS="8",
                SCENE="jobs/grid3x3.toml", OUT="out/grid.h5")
    (call,) = sandbox.launches
    assert call[0] == "srun"
    assert mscap_args(call) == ["run", "jobs/grid3x3.toml", "-o", "out/grid.h5"]
    assert (sandbox.tmp / "out").is_dir()


def test_run_defaults_and_restrictions(sandbox):
    sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", SLURM_NTASKS="4", K_MIN="2", K_MAX="4",
                SEEDS="0:5", QUIET="1", MSCAP_ARGS="--force", SRUN_ARGS="--mpi=pmix")
    (call,) = sandbox.launches
    assert call[:3] == ["srun", "--mpi=pmix", "mscap"]
    assert mscap_args(call) == ["run", "jobs/poking.toml", "-o", "results.h5", "--k-min", "2",
                                "--k-max", "4", "--seeds", "0:5", "--quiet", "--force"]


def test_run_positional_arguments_win(sandbox):
    sandbox.run("mscap_run.sbatch", "jobs/a b.toml", "r.h5", SLURM_JOB_ID="77", SCENE="x.toml")
    (call,) = sandbox.launches
    assert mscap_args(call)[:4] == ["run", "jobs/a b.toml", "-o", "r.h5"]


def test_run_falls_back_to_mpirun_without_srun(sandbox):
    sandbox.remove("srun")
    proc = sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", SLURM_NTASKS="6", OUT="r.h5")
    (call,) = sandbox.launches
    assert call[:4] == ["mpirun", "-n", "6", "mscap"]
    assert mscap_args(call) == ["run", "jobs/poking.toml", "-o", "r.h5"]
    assert "using" in proc.stderr                     # no venv: told which mscap it uses


def test_run_outside_slurm_uses_mpirun(sandbox):
    sandbox.run("mscap_run.sbatch", NTASKS="3")      # srun present but no job: not used
    (call,) = sandbox.launches
    assert call[:4] == ["mpirun", "-n", "3", "mscap"]


def test_run_sets_one_thread_and_activates_venv(sandbox):
    venv = sandbox.tmp / "venv"
    (venv / "bin").mkdir(parents=True)
    # An activate script that puts a different mscap first and is written without `set -u` care.
    (venv / "bin" / "activate").write_text(f'PATH="{venv}/bin:$PATH"; export VIRTUAL_ENV="{venv}"\n'
                                           'echo "$UNSET_IN_ACTIVATE" > /dev/null\n')
    mscap = venv / "bin" / "mscap"
    mscap.write_text('#!/bin/sh\necho "$OMP_NUM_THREADS $VIRTUAL_ENV" > "$STANDIN_LOG.venv"\n')
    mscap.chmod(0o755)
    sandbox.remove("srun")
    sandbox.remove("mpirun")
    sandbox.add("mpirun", LOGGER + 'shift 2; exec "$@"\n')   # mpirun -n N CMD...: run CMD once
    sandbox.run("mscap_run.sbatch", MSCAP_VENV=str(venv), SLURM_JOB_ID="77", SLURM_NTASKS="2")
    assert (sandbox.tmp / "calls.log.venv").read_text().split() == ["1", str(venv)]


def test_run_drops_an_mpi_singletons_settings_from_the_submitting_process(sandbox):
    """A job submitted from a process that called MPI_Init (python with mpi4py imported)
    inherits, through --export=ALL, that process's PMIx server address and OpenMPI singleton
    settings (measured: the real self-test then failed in orte_init, "getting local rank
    failed"). The launcher must not see them; the user's own OpenMPI settings stay."""
    sandbox.remove("mpirun")
    sandbox.add("mpirun", LOGGER + 'env | grep -E "^(PMIX|OMPI|ORTE)_" | sort > "$STANDIN_LOG.env"\n')
    singleton = {"PMIX_SERVER_URI2": "1356070912.0;tcp4://127.0.0.1:40179", "PMIX_RANK": "0",
                 "OMPI_MCA_ess": "singleton", "OMPI_MCA_pmix": "^s1,s2,cray,isolated",
                 "OMPI_MCA_orte_launch": "1", "OMPI_APP_CTX_NUM_PROCS": "1", "ORTE_SCHIZO_DETECTION": "ORTE"}
    sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", LAUNCHER="mpirun",
                OMPI_MCA_btl="self,vader", **singleton)
    seen = (sandbox.tmp / "calls.log.env").read_text().split()
    assert "OMPI_MCA_btl=self,vader" in seen
    assert not [v for v in seen if v.split("=")[0] in singleton]


def test_run_fails_without_mscap(sandbox):
    sandbox.remove("mscap")
    proc = sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", check=False)
    assert proc.returncode == 1 and "MSCAP_VENV" in proc.stderr
    assert sandbox.calls == []


def test_run_passes_exit_status(sandbox):
    sandbox.add("srun", LOGGER + "exit 3\n")
    proc = sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", LAUNCHER="srun", check=False)
    assert proc.returncode == 3


def test_auto_launcher_probes_srun_once(sandbox):
    sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", SLURM_NTASKS="4", SRUN_ARGS="--mpi=pmix")
    probe, launch = sandbox.calls
    assert probe[:4] == ["srun", "--ntasks=1", "--nodes=1", "--mpi=pmix"] and "mpi4py" in probe[-1]
    assert launch[:3] == ["srun", "--mpi=pmix", "mscap"]


def test_auto_launcher_uses_mpirun_when_srun_lacks_pmi(sandbox):
    """Debian's OpenMPI under srun: the job runs with mpirun inside the allocation, and says why."""
    sandbox.add("srun", SRUN_NO_PMI)
    proc = sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", SLURM_NTASKS="4")
    (call,) = sandbox.launches
    assert call[:4] == ["mpirun", "-n", "4", "mscap"]
    # The choice and its reason are on stdout (the job's output), not only among the errors.
    assert "not built with SLURM's PMI support" in proc.stdout and "SRUN_ARGS=--mpi=pmix" in proc.stdout
    assert "launcher mpirun -n 4 (LAUNCHER=auto: srun cannot" in proc.stdout
    assert "using mpirun inside the allocation" in proc.stdout


@pytest.mark.parametrize("cpus, total, tasks, ranks, srun_extra, mpirun_extra", [
    ("2", "2", "2", 3, ["--ntasks=3", "--overcommit"], ["--oversubscribe"]),   # the default header
    ("4(x2),2", "10", "10", 11, ["--ntasks=11", "--overcommit"], ["--oversubscribe"]),
    ("1", "1", "3", 3, [], []),                             # --ntasks=3 -O: one CPU, its 3 tasks
    ("", "?", "6", 6, [], []),                              # CPUs unknown: the tasks
])
@pytest.mark.parametrize("launcher", ["srun", "mpirun"])
def test_ranks_fill_the_allocation(sandbox, launcher, cpus, total, tasks, ranks, srun_extra, mpirun_extra):
    """RANKS=auto: a worker on every CPU SLURM gave the job and the master beside them (it
    idles), never fewer ranks than tasks; what the job has and runs is said on stdout."""
    proc = sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", SLURM_NTASKS=tasks, SLURM_JOB_CPUS_PER_NODE=cpus,
                       SLURM_NNODES="1", SLURM_JOB_PARTITION="small", LAUNCHER=launcher)
    (call,) = sandbox.launches
    head = call[:call.index("mscap")]
    assert head == (["srun", *srun_extra] if launcher == "srun" else ["mpirun", "-n", str(ranks), *mpirun_extra])
    assert (f"job 77 (partition small, time limit unknown) has {tasks} task(s), {total} CPU(s) on 1 node(s)"
            in proc.stdout)
    assert f": {ranks} ranks, the master and {ranks - 1} worker(s) (RANKS=auto" in proc.stdout
    assert f"launcher {' '.join(head)} (LAUNCHER={launcher})" in proc.stdout


@pytest.mark.parametrize("ranks, head", [("tasks", ["mpirun", "-n", "4"]),
                                         ("6", ["mpirun", "-n", "6", "--oversubscribe"]),
                                         ("2", ["mpirun", "-n", "2"])])
def test_ranks_chosen_by_hand(sandbox, ranks, head):
    sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", SLURM_NTASKS="4", SLURM_JOB_CPUS_PER_NODE="4",
                LAUNCHER="mpirun", RANKS=ranks)
    (call,) = sandbox.launches
    assert call[:call.index("mscap")] == head


@pytest.mark.parametrize("env, says", [
    ({"SLURM_JOB_ID": "77", "SLURM_NTASKS": "4", "RANKS": "1"},
     "RANKS must be auto, tasks or a number of ranks of at least 2, not '1'"),
    ({"SLURM_JOB_ID": "77", "SLURM_NTASKS": "4", "RANKS": "many"}, "not 'many'"),
    ({"SLURM_JOB_ID": "77", "SLURM_NTASKS": "1", "RANKS": "tasks"}, "1 rank has no worker: ask for --ntasks=2"),
    ({"NTASKS": "0"}, "NTASKS must be a positive number, not '0'"),
])
def test_bad_rank_counts_are_one_line(sandbox, env, says):
    proc = sandbox.run("mscap_run.sbatch", check=False, **env)
    assert proc.returncode == 2 and says in proc.stderr and len(proc.stderr.strip().splitlines()) <= 2
    assert sandbox.launches == []


@pytest.mark.parametrize("launcher, first", [("srun", "srun"), ("mpirun", "mpirun")])
def test_launcher_chosen_by_hand_is_not_probed(sandbox, launcher, first):
    sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", SLURM_NTASKS="3", LAUNCHER=launcher)
    (call,) = sandbox.calls
    assert call[0] == first


def test_bad_launcher_is_refused(sandbox):
    proc = sandbox.run("mscap_run.sbatch", SLURM_JOB_ID="77", LAUNCHER="ssh", check=False)
    assert proc.returncode == 2 and "LAUNCHER must be auto, srun or mpirun" in proc.stderr
    proc = sandbox.run("mscap_run.sbatch", LAUNCHER="srun", check=False)      # no job
    assert proc.returncode == 2 and "needs a SLURM job" in proc.stderr
    assert sandbox.launches == []


@pytest.mark.parametrize("script", ["mscap_run.sbatch", "mscap_array.sbatch"])
@pytest.mark.parametrize("launcher, route, received", [
    ("srun", ["scancel", "--signal=TERM", "77"], "TERM"),   # srun would SIGKILL its tasks on a TERM
    ("mpirun", None, "USR1"),                                # mpirun passes USR1 on to every rank
])
def test_stop_reaches_mscap_without_killing_it(sandbox, script, launcher, route, received):
    """SLURM's --signal=B:TERM@120 (or scancel) reaches the batch shell: it must ask mscap's
    master to stop by the route that does not kill the ranks, and return mscap's status."""
    sandbox.add(launcher, SLOW)
    proc = subprocess.Popen([BASH, str(SLURM / script)], cwd=sandbox.tmp,
                            env={**sandbox.env, "SLURM_JOB_ID": "77", "SLURM_ARRAY_TASK_ID": "2",
                                 "LAUNCHER": launcher},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    started = sandbox.tmp / "calls.log.started"
    deadline = time.monotonic() + 10
    while not started.exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert started.exists()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=10)
    assert (sandbox.tmp / "calls.log.signals").read_text().split() == [received]
    assert proc.returncode == 0, err
    assert "stop requested" in err
    scancels = [c for c in sandbox.calls if c[0] == "scancel"]
    assert scancels == ([route] if route else [])


@pytest.mark.parametrize("script", ["mscap_run.sbatch", "mscap_array.sbatch"])
@pytest.mark.parametrize("written, launcher_status, status", [
    ("stopping SIGTERM to rank 0", 1, 0),  # mpirun after a TERM: mscap stopped cleanly, killed after
    ("stopped", 137, 0),                   # the ranks ended, the launcher reported a signal
    ("error", 1, 1),                       # the stop began but the job failed: its status stands
    ("", 1, 1),                            # no stop: a failure
])
def test_a_launchers_status_after_mscaps_clean_stop_is_the_stops(sandbox, script, written, launcher_status,
                                                                  status):
    """mscap's master writes a clean stop into $MSCAP_STOP_FILE; a launcher that exits non-zero
    after it (mpirun answers a TERM so) does not make the job a failure. The file is removed."""
    sandbox.add("mpirun", LOGGER + f'[ -n "$MSCAP_STOP_FILE" ] && printf "{written}\\n" > "$MSCAP_STOP_FILE"\n'
                f"exit {launcher_status}\n")
    proc = sandbox.run(script, check=False, SLURM_ARRAY_TASK_ID="2", LAUNCHER="mpirun", TMPDIR=str(sandbox.tmp))
    assert proc.returncode == status, proc.stderr
    assert (f"mpirun exited {launcher_status} after mscap's clean stop ({written})" in proc.stderr) == (status == 0)
    # The script was not signalled: mpirun stopped the ranks itself (as when it loses a node,
    # slurm/selftest.sh section 6), and the job's log says so.
    assert ("the stop did not come through this script: a node or rank lost?" in proc.stderr) == (status == 0)
    assert not list(sandbox.tmp.glob("mscap-stop.*"))


@pytest.mark.parametrize("script", ["mscap_run.sbatch", "mscap_array.sbatch"])
def test_no_launch_under_a_file_size_limit_mpi_cannot_start_with(sandbox, script):
    """``ulimit -f 1024``: OpenMPI's start-up would die in MPI_Init with a dozen PMIx lines;
    the script refuses in one line, status 2, and launches nothing."""
    import resource

    def small_limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (2**20, 2**20))

    proc = subprocess.run([BASH, str(SLURM / script)], cwd=sandbox.tmp, preexec_fn=small_limit,
                          env={**sandbox.env, "SLURM_ARRAY_TASK_ID": "2"}, capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2
    assert "the file size limit (ulimit -f) is 1024 KB: MPI's start-up needs at least 16384 KB" in proc.stderr
    assert sandbox.launches == []


def test_no_launch_on_a_nearly_full_session_directory(sandbox):
    # df (a stand-in) reports 8 MB free where MPI's start-up would write its segments.
    sandbox.add("df", "#!/bin/sh\necho 'Filesystem 1024-blocks Used Available Capacity Mounted on'\n"
                      "echo \"tmpfs 16384 8192 8192 50% $2\"\n")
    proc = sandbox.run("mscap_run.sbatch", check=False, TMPDIR=str(sandbox.tmp))
    assert proc.returncode == 2
    assert f"{sandbox.tmp} has 8192 KB free: MPI's start-up needs at least 16384 KB there" in proc.stderr
    assert sandbox.launches == []


# --- mscap_array.sbatch -----------------------------------------------------------------------

@pytest.mark.parametrize("task", ["2", "3", "6"])
def test_array_task_runs_its_k(sandbox, task):
    sandbox.run("mscap_array.sbatch", SLURM_JOB_ID="90", SLURM_ARRAY_TASK_ID=task,
                SLURM_NTASKS="4", SCENE="jobs/grid3x3.toml", OUTDIR="parts")
    (call,) = sandbox.launches
    assert call[0] == "srun"
    assert mscap_args(call) == ["run", "jobs/grid3x3.toml", "-o", f"parts/results_k{task}.h5",
                                "--k-min", task, "--k-max", task]
    assert (sandbox.tmp / "parts").is_dir()


def test_array_k_split_with_seed_restriction_and_mpirun(sandbox):
    sandbox.remove("srun")
    sandbox.run("mscap_array.sbatch", SLURM_JOB_ID="90", SLURM_ARRAY_TASK_ID="4",
                SLURM_NTASKS="5", SEEDS="0:10", QUIET="1")
    (call,) = sandbox.launches
    assert call[:4] == ["mpirun", "-n", "5", "mscap"]
    assert mscap_args(call) == ["run", "jobs/poking.toml", "-o", "results/results_k4.h5",
                                "--k-min", "4", "--k-max", "4", "--seeds", "0:10", "--quiet"]


@pytest.mark.parametrize("task, seeds", [("0", "0:5"), ("1", "5:10"), ("4", "20:22")])
def test_array_task_runs_its_seed_chunk(sandbox, task, seeds):
    sandbox.run("mscap_array.sbatch", SLURM_JOB_ID="90", SLURM_ARRAY_TASK_ID=task, SPLIT="seeds",
                SEED_CHUNK="5", SEEDS_TOTAL="22", K_MIN="2", K_MAX="3")
    (call,) = sandbox.launches
    a, b = seeds.split(":")
    assert mscap_args(call) == ["run", "jobs/poking.toml", "-o",
                                f"results/results_seeds{a}-{b}.h5", "--seeds", seeds,
                                "--k-min", "2", "--k-max", "3"]


def test_array_task_beyond_seeds_does_nothing(sandbox):
    sandbox.run("mscap_array.sbatch", SLURM_JOB_ID="90", SLURM_ARRAY_TASK_ID="5", SPLIT="seeds",
                SEED_CHUNK="5", SEEDS_TOTAL="22")
    assert sandbox.calls == []


def test_array_needs_task_id_and_valid_split(sandbox):
    assert sandbox.run("mscap_array.sbatch", check=False).returncode == 2
    proc = sandbox.run("mscap_array.sbatch", SLURM_ARRAY_TASK_ID="1", SPLIT="poses", check=False)
    assert proc.returncode == 2 and "SPLIT" in proc.stderr
    assert sandbox.calls == []


# --- submit_array.sh --------------------------------------------------------------------------

def scene(tmp: Path, multistart: str = "") -> Path:
    path = tmp / "jobs" / "tiny.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text('name = "tiny"\n' + (f"[multistart]\n{multistart}\n" if multistart else ""))
    return path


def run_merge_command(sandbox: Env, wrap: str, present: list[Path]) -> list[str]:
    """Run the merge job's --wrap text under /bin/sh with some parts present; mscap's argv."""
    for p in present:
        p.write_text("")
    before = len(sandbox.calls)
    proc = subprocess.run(["/bin/sh", "-c", wrap], env=sandbox.env, capture_output=True,
                          text=True, timeout=10)
    assert proc.returncode == 0, proc.stderr
    (call,) = sandbox.calls[before:]
    assert call[0] == "mscap"
    return call[1:]


def test_submit_k_array_then_dependent_merge(sandbox):
    s = scene(sandbox.tmp, "k_min = 3\nk_max = 5")
    proc = sandbox.run("submit_array.sh", "jobs/tiny.toml", "--outdir", "parts", "--",
                       "--ntasks=16", "--time=1:00:00", MSCAP_REPO="")   # default: this repo
    array, merge = sandbox.calls
    parts = sandbox.tmp / "parts"
    assert array[0] == "sbatch" and "--parsable" in array
    assert option(array, "--array") == "3-5"                       # from the scene's [multistart]
    exports = dict(kv.split("=", 1) for kv in option(array, "--export").split(",")[1:])
    assert option(array, "--export").startswith("ALL,")
    assert exports["SCENE"] == str(s) and exports["OUTDIR"] == str(parts)
    assert exports["SPLIT"] == "k" and exports["MSCAP_REPO"] == str(ROOT)
    assert array[-3:] == ["--ntasks=16", "--time=1:00:00", str(SLURM / "mscap_array.sbatch")]

    assert merge[0] == "sbatch"
    assert option(merge, "--dependency") == "afterany:12345"
    wrap = option(merge, "--wrap")
    expected = [str(parts / f"results_k{k}.h5") for k in (3, 4, 5)]
    for p in expected:
        assert p in wrap
    assert "12345" in proc.stdout and "12346" in proc.stdout
    # Run the merge job's command: every part listed, merged file last.
    argv = run_merge_command(sandbox, wrap, [Path(p) for p in expected])
    assert argv == ["merge", *expected, "-o", str(parts / "all.h5"), "--force"]  # parts are the truth


def test_submit_merge_skips_missing_parts(sandbox):
    scene(sandbox.tmp)
    sandbox.run("submit_array.sh", "--k-min", "2", "--k-max", "4", "--merged", "m.h5",
                "jobs/tiny.toml", MSCAP_REPO=str(sandbox.tmp))
    array, merge = sandbox.calls
    assert option(array, "--array") == "2-4"
    parts = sandbox.tmp / "results" / "tiny"
    assert (parts).is_dir()
    argv = run_merge_command(sandbox, option(merge, "--wrap"),
                             [parts / "results_k2.h5", parts / "results_k4.h5"])
    assert argv == ["merge", str(parts / "results_k2.h5"), str(parts / "results_k4.h5"),
                    "-o", str(sandbox.tmp / "m.h5"), "--force"]


def test_submit_seed_split(sandbox):
    scene(sandbox.tmp, "k_min = 2\nk_max = 3\nstarts_per_k = 12")
    sandbox.run("submit_array.sh", "--split", "seeds", "--seed-chunk", "5", "--max-parallel", "2",
                "jobs/tiny.toml", MSCAP_REPO=str(sandbox.tmp))
    array, merge = sandbox.calls
    assert option(array, "--array") == "0-2%2"
    exports = option(array, "--export")
    for kv in ("SPLIT=seeds", "SEED_CHUNK=5", "SEEDS_TOTAL=12", "K_MIN=2", "K_MAX=3"):
        assert kv in exports.split(",")
    assert option(merge, "--dependency") == "afterany:12345"
    parts = sandbox.tmp / "results" / "tiny"
    expected = [parts / n for n in ("results_seeds0-5.h5", "results_seeds5-10.h5",
                                    "results_seeds10-12.h5")]
    argv = run_merge_command(sandbox, option(merge, "--wrap"), expected)
    assert argv == ["merge", *map(str, expected), "-o", str(parts / "all.h5"), "--force"]


def test_a_calibrated_scene_s_merge_job_calibrates_the_merged_file(sandbox):
    """A part runs some starts and does not calibrate (mscap.service.calibrated): the merge
    job's `mscap run` on the merged file does."""
    s = scene(sandbox.tmp, "k_min = 2\nk_max = 3")
    s.write_text(s.read_text() + '[calibration]\npose = "bend"\n')
    proc = sandbox.run("submit_array.sh", "jobs/tiny.toml", MSCAP_REPO=str(sandbox.tmp))
    _, merge = sandbox.calls
    parts = sandbox.tmp / "results" / "tiny"
    for p in ("results_k2.h5", "results_k3.h5"):
        (parts / p).write_text("")
    before = len(sandbox.calls)
    done = subprocess.run(["/bin/sh", "-c", option(merge, "--wrap")], env=sandbox.env, capture_output=True,
                          text=True, timeout=10)
    assert done.returncode == 0, done.stderr
    merged = str(parts / "all.h5")
    assert [call[1] for call in sandbox.calls[before:]] == ["merge", "run"]
    assert sandbox.calls[-1][1:] == ["run", str(s), "-o", merged]
    assert "then mscap run calibrates" in proc.stdout
    s.write_text(s.read_text().replace("k_max = 3", "k_max = 3\ncalibrate_best = 0"))
    sandbox.run("submit_array.sh", "jobs/tiny.toml", MSCAP_REPO=str(sandbox.tmp))
    assert "mscap run" not in option(sandbox.calls[-1], "--wrap")


@pytest.mark.parametrize("mode", ["plain", "cluster"])
def test_submit_reads_either_sbatch_output(sandbox, mode):
    scene(sandbox.tmp)
    env = {"STANDIN_SBATCH_PLAIN": "1"} if mode == "plain" else {"STANDIN_SBATCH_CLUSTER": "c1"}
    sandbox.run("submit_array.sh", "jobs/tiny.toml", MSCAP_REPO=str(sandbox.tmp), **env)
    _, merge = sandbox.calls
    assert option(merge, "--dependency") == "afterany:12345"


def test_submit_array_task_and_merge_agree_on_part_names(sandbox):
    """The part each array task writes is the part the merge job lists."""
    scene(sandbox.tmp, "k_min = 2\nk_max = 3")
    sandbox.run("submit_array.sh", "jobs/tiny.toml", MSCAP_REPO=str(sandbox.tmp))
    array, merge = sandbox.calls
    exports = dict(kv.split("=", 1) for kv in option(array, "--export").split(",")[1:])
    written = []
    for k in ("2", "3"):
        sandbox.run("mscap_array.sbatch", SLURM_JOB_ID="12345", SLURM_ARRAY_TASK_ID=k, **exports)
        written.append(option(sandbox.calls[-1], "-o"))
    argv = run_merge_command(sandbox, option(merge, "--wrap"), [Path(p) for p in written])
    assert argv[1:-3] == written


def test_submit_rejects_bad_input(sandbox):
    assert sandbox.run("submit_array.sh", "jobs/missing.toml", check=False).returncode == 2
    scene(sandbox.tmp)
    proc = sandbox.run("submit_array.sh", "--k-min", "5", "--k-max", "3", "jobs/tiny.toml",
                       check=False)
    assert proc.returncode == 2 and "exceeds" in proc.stderr
    assert sandbox.run("submit_array.sh", "--bogus", check=False).returncode == 2
    assert sandbox.calls == []


def test_submit_merge_uses_venv_and_odd_paths(sandbox):
    """Paths with spaces and quotes survive; the merge job puts the venv's mscap first."""
    scene(sandbox.tmp, "k_min = 2\nk_max = 3")
    venv = sandbox.tmp / "my venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "bin" / "mscap").write_text(LOGGER.replace('"$(basename "$0")"', "venv-mscap"))
    (venv / "bin" / "mscap").chmod(0o755)
    sandbox.run("submit_array.sh", "--outdir", "it's parts", "jobs/tiny.toml",
                MSCAP_REPO=str(sandbox.tmp), MSCAP_VENV=str(venv))
    _, merge = sandbox.calls
    parts = sandbox.tmp / "it's parts"
    expected = [parts / "results_k2.h5", parts / "results_k3.h5"]
    for p in expected:
        p.write_text("")
    proc = subprocess.run(["/bin/sh", "-c", option(merge, "--wrap")], env=sandbox.env,
                          capture_output=True, text=True, timeout=10)
    assert proc.returncode == 0, proc.stderr
    assert sandbox.calls[-1] == ["venv-mscap", "merge", *map(str, expected), "-o",
                                 str(parts / "all.h5"), "--force"]


def test_submit_merge_fails_with_no_parts(sandbox):
    scene(sandbox.tmp)
    sandbox.run("submit_array.sh", "jobs/tiny.toml", MSCAP_REPO=str(sandbox.tmp))
    _, merge = sandbox.calls
    proc = subprocess.run(["/bin/sh", "-c", option(merge, "--wrap")], env=sandbox.env,
                          capture_output=True, text=True, timeout=10)
    assert proc.returncode == 1 and "no parts" in proc.stderr
    assert [c[0] for c in sandbox.calls] == ["sbatch", "sbatch"]


def test_submit_export_after_dashes_adds_to_the_tasks_settings(sandbox):
    """slurm/README's `-- --export=ALL,SRUN_ARGS=...` must not replace the scene and OUTDIR."""
    s = scene(sandbox.tmp, "k_min = 2\nk_max = 3")
    sandbox.run("submit_array.sh", "jobs/tiny.toml", "--", "--ntasks=4",
                "--export=ALL,SRUN_ARGS=--mpi=pmix,LAUNCHER=srun", MSCAP_REPO=str(sandbox.tmp))
    array, _ = sandbox.calls
    assert sum(a.startswith("--export") for a in array) == 1
    exports = dict(kv.split("=", 1) for kv in option(array, "--export").split(",")[1:])
    assert exports["SCENE"] == str(s) and exports["SRUN_ARGS"] == "--mpi=pmix" and exports["LAUNCHER"] == "srun"
    assert "--ntasks=4" in array


@pytest.mark.parametrize("bad", ["--export=NONE", "--export"])
def test_submit_refuses_an_export_that_drops_the_settings(sandbox, bad):
    scene(sandbox.tmp)
    proc = sandbox.run("submit_array.sh", "jobs/tiny.toml", "--", bad, "X=1", check=False)
    assert proc.returncode == 2 and "--export" in proc.stderr
    assert sandbox.calls == []
