#!/bin/bash
# The SLURM scripts against a real SLURM: a private one-node cluster on this machine.
#
#   slurm/selftest.sh            skip (status 0, a "skipped:" line) where it cannot run
#   slurm/selftest.sh --require  fail instead of skipping (.ci/run)
#   slurm/selftest.sh --keep     keep the cluster's directory (config, logs, results)
#   slurm/selftest.sh --install  only install what it needs and exit (.ci/run, before make test)
#
# Needs root on Debian with slurmctld, slurmd, slurm-client, munge and libpmix-dev (for srun
# --mpi=pmix) installed: the self-test itself installs nothing (the test suite runs it), it
# skips naming what is missing; --install apt-gets them. And no SLURM controller already
# running here (a cluster's login node keeps its own SLURM untouched: the test skips). It writes a
# slurm.conf for this host (all CPUs, one partition, proctrack/cgroup) into a temporary
# directory, starts munged (on its own socket), slurmctld and slurmd, cancels its jobs and
# stops the daemons by PID at the end, whatever happens.
# On jobs/quick.toml (with P1 elastic elements) and short runs, it checks four things a
# cluster user relies on:
#   1. a single job (slurm/mscap_run.sbatch) completes and stores its runs, and says on
#      stdout the tasks and CPUs it was given, the ranks it runs and the launcher it chose;
#   2. a job array with its dependent merge (slurm/submit_array.sh) merges every part;
#   3. `scancel` stops a job cleanly under each launcher ("stopping" logged, exit status 0),
#      and resubmitting the same command completes it (resume);
#   4. a job that reaches its --signal=B:TERM warning before the time limit stops cleanly:
#      finished runs stored, "stopped" logged, state COMPLETED (exit 0) or TIMEOUT, and a
#      resubmission continues a start the limit cut from the step it reached to its end; once
#      with mpirun inside the allocation, once with srun --mpi=pmix where srun has PMIx;
#   5. a job submitted with --requeue and requeued while it runs (a preemption) stops
#      cleanly, runs again and completes, continuing the starts it kept;
#   6. two nodes (a second cluster, its nodes in network namespaces): a multi-start with a
#      worker on each node stores the one-node job's runs bit for bit; a node killed
#      mid-run loses no announced run, and a rerun completes the rest.
# About 4 minutes on 2 cores.
set -euo pipefail

REQUIRE=0
KEEP=0
INSTALL=0
for a in "$@"; do
    case "$a" in
        --require) REQUIRE=1 ;;
        --keep) KEEP=1 ;;
        --install) INSTALL=1 ;;
        -h|--help) sed -n '2,/^set -euo/p' "${BASH_SOURCE[0]}" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
        *) echo "selftest: unknown argument $a" >&2; exit 2 ;;
    esac
done

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# Run from a process that has called MPI_Init (a test runner with mpi4py imported), the
# environment holds that process's PMIx/OpenMPI singleton settings: the jobs must not see them.
# shellcheck source=common.sh
source "$REPO/slurm/common.sh"
mscap_forget_mpi_parent
VENV="${MSCAP_VENV:-$REPO/.venv}"

skip() {
    if (( REQUIRE )); then
        echo "selftest: FAILED: cannot run here: $*" >&2
        exit 1
    fi
    echo "selftest: skipped: $*"
    exit 0
}
fail() { echo "selftest: FAILED: $*" >&2; exit 1; }
say() { echo "selftest: $*"; }

[[ "$(id -u)" == 0 ]] || skip "needs root (starts SLURM daemons)"
command -v dpkg-query >/dev/null 2>&1 || skip "not a Debian system"
packages=(slurmctld slurmd slurm-client munge libpmix-dev)   # libpmix-dev: srun --mpi=pmix
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}\n' "$p" 2>/dev/null | grep -q '^install ok installed' || missing+=("$p")
done
if (( INSTALL )); then
    if (( ${#missing[@]} )); then
        say "installing ${missing[*]}"
        { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
            "${missing[@]}"; } >/dev/null 2>&1 || fail "apt-get could not install ${missing[*]}"
    fi
    say "installed: ${packages[*]}"
    exit 0
fi
(( ${#missing[@]} == 0 )) || skip "not installed: ${missing[*]} (slurm/selftest.sh --install installs them; .ci/run does)"
[[ -x "$VENV/bin/mscap" ]] || skip "no mscap in $VENV (run make install first)"
if pgrep -x slurmctld >/dev/null 2>&1; then
    skip "a slurmctld already runs on this machine; the self-test builds its own cluster only where there is none"
fi
[[ -r /etc/munge/munge.key ]] || skip "no munge key at /etc/munge/munge.key"

dir="$(mktemp -d /tmp/mscap-slurm.XXXXXX)"
host="$(hostname -s)"
cpus="$(env -u OMP_NUM_THREADS -u OMP_THREAD_LIMIT nproc)"   # nproc obeys OMP_NUM_THREADS
pids=()
confs=()   # the clusters' slurm.conf files (the second: section 6)
links=()   # network links of section 6's nodes
cleanup() {
    local status=$?
    # Jobs first: a job left running outlives the daemons (its slurmstepd and ranks go on).
    local conf
    for conf in ${confs[@]+"${confs[@]}"}; do
        command -v squeue >/dev/null 2>&1 || break
        SLURM_CONF="$conf" scancel --full --quiet $(SLURM_CONF="$conf" squeue -h -o %i 2>/dev/null) 2>/dev/null || true
        for _ in $(seq 60); do [[ -z "$(SLURM_CONF="$conf" squeue -h -o %i 2>/dev/null)" ]] && break; sleep 0.5; done
    done
    for pid in ${pids[@]+"${pids[@]}"}; do kill -TERM "$pid" 2>/dev/null || true; done
    for pid in ${pids[@]+"${pids[@]}"}; do
        for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        kill -KILL "$pid" 2>/dev/null || true
    done
    for link in ${links[@]+"${links[@]}"}; do ip link del "$link" 2>/dev/null || true; done
    if (( KEEP )); then say "kept $dir"; else rm -rf "$dir"; fi
    exit "$status"
}
trap cleanup EXIT

# Two free ports: a controller's and its node daemons'.
free_ports() {
    python3 -c '
import socket
ports = []
for _ in range(2):
    s = socket.socket(); s.bind(("", 0)); ports.append(s.getsockname()[1]); s.close()
print(*ports)'
}
read -r ctld_port slurmd_port < <(free_ports)

mkdir -p "$dir"/{state,spool,log,munge,results}
chmod 700 "$dir/munge"
cat > "$dir/slurm.conf" <<EOF
ClusterName=mscap-selftest
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$dir/munge/munge.socket
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/cgroup
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
KillWait=10
MinJobAge=600
NodeName=$host CPUs=$cpus State=UNKNOWN
PartitionName=selftest Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
printf 'CgroupPlugin=autodetect\nConstrainCores=no\nConstrainRAMSpace=no\n' > "$dir/cgroup.conf"
export SLURM_CONF="$dir/slurm.conf"
confs+=("$SLURM_CONF")

/usr/sbin/munged --socket="$dir/munge/munge.socket" --pid-file="$dir/munge/munged.pid" \
    --log-file="$dir/log/munged.log" --seed-file="$dir/munge/seed" --force \
    || fail "munged did not start ($(tail -n2 "$dir/log/munged.log" 2>/dev/null))"
pids+=("$(cat "$dir/munge/munged.pid")")
slurmctld -f "$SLURM_CONF" || fail "slurmctld did not start"
for _ in $(seq 50); do [[ -s "$dir/slurmctld.pid" ]] && break; sleep 0.1; done
pids+=("$(cat "$dir/slurmctld.pid")")
slurmd -f "$SLURM_CONF" || fail "slurmd did not start"
for _ in $(seq 50); do [[ -s "$dir/slurmd.pid" ]] && break; sleep 0.1; done
pids+=("$(cat "$dir/slurmd.pid")")
for _ in $(seq 150); do
    [[ "$(sinfo -h -o %T 2>/dev/null)" == idle ]] && break
    sleep 0.2
done
[[ "$(sinfo -h -o %T 2>/dev/null)" == idle ]] || fail "the node did not come up: $(sinfo 2>&1; tail -n5 "$dir/log/slurmd.log")"
say "one-node SLURM $(sinfo -V | cut -d' ' -f2) up on $host ($cpus CPUs), daemons ${pids[*]}"

cd "$REPO"
export MSCAP_VENV="$VENV"
res="$dir/results"
# The default scene with P1 elastic elements: the self-test checks the cluster plumbing,
# not the physics, and P2 (jobs/quick.toml says why it uses it) costs 3-4 times as much.
SCENE="$dir/quick.toml"
sed 's/^order = 2$/order = 1/' "$REPO/jobs/quick.toml" > "$SCENE"
state() { scontrol show job "$1" 2>/dev/null | grep -o 'JobState=[A-Z_]*' | head -n1 | cut -d= -f2; }
exit_code() { scontrol show job "$1" 2>/dev/null | grep -o ' ExitCode=[0-9:]*' | head -n1 | cut -d= -f2; }
wait_job() {   # wait_job ID SECONDS: until the job has ended
    local id="$1" t0=$SECONDS
    while (( SECONDS - t0 < $2 )); do
        case "$(state "$id")" in PENDING|RUNNING|CONFIGURING|COMPLETING|REQUEUED|REQUEUE_FED|"") sleep 1 ;; *) return 0 ;; esac
    done
    fail "job $id still $(state "$id") after $2 s"
}
first_run() {   # first_run LOG WHAT: until the job logging to LOG has stored a run
    local t0=$SECONDS
    until grep -q '^\[1/' "$1" 2>/dev/null; do
        (( SECONDS - t0 < 300 )) || fail "$2 stored no run in 300 s"
        sleep 0.5
    done
}
stored_ids() {   # the ids of the finished runs in an HDF5 file, sorted, one a line
    "$VENV/bin/python" -c "import sys
from mscap.service.store import finished_ids, read_store
with read_store(sys.argv[1]) as f: print('\n'.join(sorted(finished_ids(f))))" "$1"
}
stored() {   # the number of finished runs in an HDF5 file
    "$VENV/bin/python" - "$1" <<'PY'
import sys, h5py
with h5py.File(sys.argv[1], "r") as f:
    print(sum(1 for g in f.get("runs", {}).values() if g.attrs.get("status") in ("ok", "failed", "pruned")))
PY
}
# Short runs of the default scene; -O puts the master and both workers on this node's CPUs.
short="--max-iterations 2"

# 4. The time limit (first: it runs beside the others), with mpirun inside the allocation and,
#    where srun can start OpenMPI (PMIx), with srun: the two stop routes of slurm/common.sh.
#    SLURM sends the warning up to 60 s earlier than asked, so 90 s before a 3-minute limit
#    comes 30 to 90 s into the job.
per_k=24
submit_timelimit() {   # submit_timelimit LAUNCHER [SRUN_ARGS]
    sbatch --parsable --time=00:03:00 --signal=B:TERM@90 --ntasks=3 -O -o "$res/timelimit-$1-%j.out" \
        --export=ALL,SCENE="$SCENE",OUT="$res/timelimit-$1.h5",LAUNCHER="$1",SRUN_ARGS="${2:-}",MSCAP_ARGS="--starts-per-k $per_k" \
        slurm/mscap_run.sbatch
}
# 24 starts for each k of the scene's range: more runs than fit before the warning (with 8,
# 16 runs of about 6 s each could all end before a warning 90 s in).
total=$("$VENV/bin/python" -c "import sys, tomllib; m = tomllib.load(open(sys.argv[1], 'rb'))['multistart']; print($per_k * (m['k_max'] - m['k_min'] + 1))" "$SCENE")
timelimit=("mpirun $(submit_timelimit mpirun)")
if srun --mpi=list 2>&1 | grep -q pmix; then
    timelimit+=("srun $(submit_timelimit srun --mpi=pmix)")
else
    say "srun has no PMIx plugin here (libpmix-dev): the time limit is checked with mpirun only"
fi

# 1. A single job.
one=$(sbatch --parsable --ntasks=3 -O -o "$res/single-%j.out" \
    --export=ALL,SCENE="$SCENE",OUT="$res/single.h5",K_MIN=2,K_MAX=2,SEEDS=0:2,MSCAP_ARGS="$short" \
    slurm/mscap_run.sbatch)
wait_job "$one" 300
[[ "$(state "$one")" == COMPLETED ]] || fail "single job $one: $(state "$one"); log: $(tail -n5 "$res/single-$one.out")"
[[ "$(stored "$res/single.h5")" == 2 ]] || fail "single job $one stored $(stored "$res/single.h5") runs, not 2"
sized="$(grep -m1 ' ranks, the master and ' "$res/single-$one.out" || true)"
[[ "$sized" == *"has 3 task(s), 1 CPU(s) on 1 node(s)"*": 3 ranks, the master and 2 worker(s)"* ]] \
    || fail "single job $one did not say its size (3 tasks on 1 CPU: 3 ranks): '$sized'"
grep -q '^mscap_run: launcher ' "$res/single-$one.out" || fail "single job $one did not say its launcher on stdout"
say "1. single job $one: COMPLETED, 2 runs stored; it said its size and launcher ($(grep -m1 '^mscap_run: launcher ' "$res/single-$one.out" | cut -d' ' -f3-))"

# 2. An array (one task per seed, k = 2) and its merge.
out=$(slurm/submit_array.sh --split seeds --seed-chunk 1 --seeds-total 2 --k-min 2 --k-max 2 \
    --outdir "$res/array" "$SCENE" -- --ntasks=2 -O -o "$res/array-%A_%a.out" --export=MSCAP_ARGS="$short")
merge=$(grep -o 'merge job [0-9]*' <<< "$out" | cut -d' ' -f3)
[[ -n "$merge" ]] || fail "submit_array.sh printed no merge job: $out"
wait_job "$merge" 300
[[ "$(state "$merge")" == COMPLETED ]] || fail "merge job $merge: $(state "$merge")"
[[ "$(stored "$res/array/all.h5")" == 2 ]] || fail "the merged file holds $(stored "$res/array/all.h5") runs, not 2"
say "2. array + merge: parts $(cd "$res/array" && ls results_*.h5 | tr '\n' ' ')merged by job $merge into all.h5 (2 runs)"

# 3. scancel after the first stored run, under each launcher: the job ends with mscap's
#    clean stop (the "stopping" line, exit status 0); then the same submission resumes.
submit_resume() {   # submit_resume LAUNCHER [SRUN_ARGS]
    sbatch --parsable --ntasks=3 -O -o "$res/resume-$1-%j.out" \
        --export=ALL,SCENE="$SCENE",OUT="$res/resume-$1.h5",K_MIN=3,K_MAX=3,SEEDS=0:4,LAUNCHER="$1",SRUN_ARGS="${2:-}",MSCAP_ARGS="$short --starts-per-k 4" \
        slurm/mscap_run.sbatch
}
cancels=("mpirun")
srun --mpi=list 2>&1 | grep -q pmix && cancels+=("srun --mpi=pmix")
declare -A cancelled=()
for entry in "${cancels[@]}"; do   # side by side: each is cancelled once it has stored a run
    read -r how how_args <<< "$entry"
    cancelled[$how]=$(submit_resume "$how" "${how_args:-}")
done
for entry in "${cancels[@]}"; do
    read -r how how_args <<< "$entry"
    first=${cancelled[$how]}
    first_run "$res/resume-$how-$first.out" "job $first ($how)"
    scancel "$first"
done
for entry in "${cancels[@]}"; do
    read -r how how_args <<< "$entry"
    first=${cancelled[$how]}
    log="$res/resume-$how-$first.out"
    wait_job "$first" 120
    before=$(stored "$res/resume-$how.h5")
    (( before >= 1 && before < 4 )) || fail "the cancelled job $first ($how) left $before runs (expected 1 to 3)"
    grep -q '^stopping (SIG' "$log" || fail "the cancelled job $first ($how) logged no 'stopping' line: $(tail -n5 "$log")"
    grep -q '^mscap_run: exit status 0,' "$log" \
        || fail "the cancelled job $first ($how) did not end with status 0: $(tail -n5 "$log")"
    say "3. scancel ($how): job $first $(state "$first") with $before runs stored; its log:"
    grep -E '^mscap_run: (stop|exit|mpirun|srun)|^stopp|CANCELLED|Killed|Terminated|: stopped at step' "$log" \
        | sed 's/^/       /'
done
second=$(submit_resume "$how" "${how_args:-}")
wait_job "$second" 300
[[ "$(state "$second")" == COMPLETED ]] || fail "resumed job $second: $(state "$second")"
# The rerun does the missing starts, plus the finer-mesh check of a k's best that the
# cancel reached between its run and its check (stored unchecked, not lost).
todo=$(sed -n "s/.*$before runs already stored, \([0-9]*\) to do.*/\1/p" "$res/resume-$how-$second.out")
[[ -n "$todo" ]] && (( todo >= 4 - before )) \
    || fail "job $second did not resume: $(grep 'to do' "$res/resume-$how-$second.out")"
[[ "$(stored "$res/resume-$how.h5")" == 4 ]] || fail "after the resume $(stored "$res/resume-$how.h5") runs, not 4"
# A start busy at the cancel kept its optimiser state (docs/hdf5.md "In-start checkpoints"):
# the resubmission continues it and deletes the state once its run is stored.
if grep -q ': stopped at step .*its state is kept' "$res/resume-$how-${cancelled[$how]}.out"; then
    grep -q 'from \(its\|their\) stored state' "$res/resume-$how-$second.out" \
        || fail "job $second did not continue the starts job ${cancelled[$how]} kept: $(grep 'to do' "$res/resume-$how-$second.out")"
    [[ ! -e "$res/resume-$how.h5.checkpoints" ]] || fail "job $second left $res/resume-$how.h5.checkpoints behind"
    grep 'stored state' "$res/resume-$how-$second.out" | sed 's/^/       /'
fi
say "3. resubmitted ($how): job $second resumed the other $(( 4 - before ))"

# 5. A requeued job (what a preemptible partition with PreemptMode=REQUEUE does to it):
#    SLURM signals the job as scancel does, then starts the same script again, on the same
#    OUT: the stop keeps the busy starts' states and the second run continues them.
#    SLURM holds a requeued job for about 2 minutes (its EligibleTime is the requeue plus
#    121 s, Reason=BeginTime, measured with SLURM 22.05); the self-test makes it eligible at
#    once, as an administrator may (`scontrol update jobid=... StartTime=now`).
rq=$(sbatch --parsable --requeue --open-mode=append --ntasks=3 -O -o "$res/requeue-%j.out" \
    --export=ALL,SCENE="$SCENE",OUT="$res/requeue.h5",K_MIN=3,K_MAX=3,SEEDS=0:3,MSCAP_ARGS="$short --starts-per-k 3" \
    slurm/mscap_run.sbatch)
log="$res/requeue-$rq.out"
first_run "$log" "job $rq (requeue)"
scontrol requeue "$rq" || fail "scontrol requeue $rq failed"
t0=$SECONDS
until [[ "$(scontrol show job "$rq" 2>/dev/null | grep -o 'Restarts=[0-9]*' | cut -d= -f2)" -ge 1 ]]; do
    (( SECONDS - t0 < 60 )) || fail "job $rq was not requeued: $(scontrol show job "$rq" | head -n3)"
    sleep 0.5
done
for _ in $(seq 120); do   # until the first run has stopped and the job pends again
    [[ "$(state "$rq")" == PENDING ]] && break
    sleep 0.5
done
if [[ "$(state "$rq")" == PENDING ]]; then   # (a SLURM that does not hold it: nothing to lift)
    scontrol update jobid="$rq" StartTime=now || fail "scontrol update jobid=$rq StartTime=now failed"
fi
wait_job "$rq" 600
[[ "$(state "$rq")" == COMPLETED ]] || fail "requeued job $rq: $(state "$rq"); log: $(tail -n5 "$log")"
[[ "$(stored "$res/requeue.h5")" == 3 ]] || fail "requeued job $rq stored $(stored "$res/requeue.h5") runs, not 3"
grep -q '^stopping (SIG' "$log" || fail "requeued job $rq logged no 'stopping' line: $(tail -n5 "$log")"
if grep -q ': stopped at step .*its state is kept' "$log"; then
    grep -q 'from \(its\|their\) stored state' "$log" || fail "requeued job $rq did not continue its kept starts"
fi
[[ ! -e "$res/requeue.h5.checkpoints" ]] || fail "requeued job $rq left $res/requeue.h5.checkpoints behind"
say "5. requeue: job $rq ran twice (Restarts=1), $(stored "$res/requeue.h5") runs stored; its log:"
grep -E '^mscap_run: (stop|exit)|^stopp|: stopped at step|stored state|runs already stored' "$log" | sed 's/^/       /'

# 6. Two nodes: a second cluster on this machine whose two slurmd run each in its own
#    network and UTS namespace (hosts node1 and node2 on a private bridge, one CPU each; the
#    controller on the host, munged shared). One multi-start with its master and a worker
#    on node1 and a worker on node2 (mpirun inside the allocation; OpenMPI starts node2's
#    ranks through srun) stores the same file as section 1's one-node job, run for run and
#    bit for bit; then node2 is killed (every process in its namespace, SIGKILL: a node
#    crash) while a job runs on both nodes: the job fails, every run it announced is in its
#    file, and a rerun on node1 alone runs the rest.
two_nodes() {
    local conf="$dir/two/slurm.conf" net n pid ctl2 p1 p2 i
    for cmd in ip unshare; do
        command -v "$cmd" >/dev/null 2>&1 || { why="no $cmd"; return 1; }
    done
    net=""
    for i in $(seq 20 250); do   # a private /24 no interface of this machine uses
        ip -o -4 addr 2>/dev/null | grep -q " 10\.213\.$i\." || { net="10.213.$i"; break; }
    done
    [[ -n "$net" ]] || { why="no free 10.213.x.0/24"; return 1; }
    mkdir -p "$dir/two"/{state,spool,log}
    printf '127.0.0.1 localhost\n%s.1 %s\n%s.2 node1\n%s.3 node2\n' "$net" "$host" "$net" "$net" > "$dir/two/hosts"
    local bridge="msb$$"
    ip link add "$bridge" type bridge 2>/dev/null || { why="cannot create a network bridge (no CAP_NET_ADMIN?)"; return 1; }
    links+=("$bridge")
    ip addr add "$net.1/24" dev "$bridge" && ip link set "$bridge" up || { why="cannot configure $bridge"; return 1; }
    read -r p1 p2 < <(free_ports)
    sed -e "s/^ClusterName=.*/ClusterName=mscap-two/" -e "s/^SlurmctldHost=.*/SlurmctldHost=$host($net.1)/" \
        -e "s/^SlurmctldPort=.*/SlurmctldPort=$p1/" -e "s/^SlurmdPort=.*/SlurmdPort=$p2/" \
        -e "s|$dir/state|$dir/two/state|; s|^SlurmdSpoolDir=.*|SlurmdSpoolDir=$dir/two/spool/%n|" \
        -e "s|^SlurmctldPidFile=.*|SlurmctldPidFile=$dir/two/slurmctld.pid|" \
        -e "s|^SlurmdPidFile=.*|SlurmdPidFile=$dir/two/slurmd-%n.pid|" \
        -e "s|^SlurmctldLogFile=.*|SlurmctldLogFile=$dir/two/log/slurmctld.log|" \
        -e "s|^SlurmdLogFile=.*|SlurmdLogFile=$dir/two/log/slurmd-%n.log|" \
        -e "s|^ProctrackType=.*|ProctrackType=proctrack/pgid|" -e "s|^KillWait=.*|KillWait=10\nSlurmdTimeout=10|" \
        -e "/^NodeName=/d; /^PartitionName=/d" "$dir/slurm.conf" > "$conf"
    printf 'NodeName=node1 NodeAddr=%s.2 CPUs=1 State=UNKNOWN\nNodeName=node2 NodeAddr=%s.3 CPUs=1 State=UNKNOWN\n' \
        "$net" "$net" >> "$conf"
    echo "PartitionName=two Nodes=node1,node2 Default=YES MaxTime=INFINITE State=UP" >> "$conf"
    cp "$dir/cgroup.conf" "$dir/two/cgroup.conf"
    confs+=("$conf")
    slurmctld -f "$conf" || { why="the second slurmctld did not start"; return 1; }
    for _ in $(seq 50); do [[ -s "$dir/two/slurmctld.pid" ]] && break; sleep 0.1; done
    ctl2="$(cat "$dir/two/slurmctld.pid")"
    pids+=("$ctl2")
    for n in 1 2; do
        # The node's shell takes the name, the hosts file and, once its end of the link is
        # moved in, the address; then it becomes slurmd (its pid is the node's).
        mkdir -p "$dir/two/spool/node$n"
        ( unshare --net --uts --mount bash -c "echo \$\$ > '$dir/two/node$n.pid'; hostname node$n
            mount --bind '$dir/two/hosts' /etc/hosts
            while [ ! -e '$dir/two/node$n.go' ]; do sleep 0.05; done
            ip link set lo up && ip addr add $net.$(( n + 1 ))/24 dev eth0 && ip link set eth0 up || exit 1
            exec slurmd -D -f '$conf'" > "$dir/two/log/node$n.out" 2>&1 & )   # not a job of this shell
        for _ in $(seq 100); do [[ -s "$dir/two/node$n.pid" ]] && break; sleep 0.05; done
        pid="$(cat "$dir/two/node$n.pid" 2>/dev/null)"
        [[ -n "$pid" ]] || { why="node$n's namespace did not start"; return 1; }
        pids+=("$pid")
        ip link add "msv$$n$n" type veth peer name eth0 netns "$pid" || { why="cannot link node$n"; return 1; }
        links+=("msv$$n$n")
        ip link set "msv$$n$n" master "$bridge" up
        touch "$dir/two/node$n.go"
    done
    for _ in $(seq 150); do
        [[ "$(SLURM_CONF="$conf" sinfo -h -o %T 2>/dev/null)" == idle ]] && break
        sleep 0.2
    done
    [[ "$(SLURM_CONF="$conf" sinfo -h -o %T 2>/dev/null)" == idle ]] \
        || { why="the two nodes did not come up: $(SLURM_CONF="$conf" sinfo -h 2>&1 | tr '\n' ' '; tail -n3 "$dir"/two/log/*.log)"; return 1; }
}
same_runs() {   # same_runs A.h5 B.h5: every run of A in B, its results bit for bit
    "$VENV/bin/python" - "$1" "$2" <<'PY'
import sys
import numpy as np
from mscap.service.store import finished_ids, read_run, read_store
with read_store(sys.argv[1]) as a, read_store(sys.argv[2]) as b:
    ids = sorted(finished_ids(a))
    if ids != sorted(finished_ids(b)):
        sys.exit(f"runs differ: {ids} against {sorted(finished_ids(b))}")
    for rid in ids:
        x, y = read_run(a, rid), read_run(b, rid)
        same = x.status == y.status and np.array_equal(x.final_capacitance_pF, y.final_capacitance_pF) and all(
            np.array_equal(p, q) for p, q in zip(x.final_outlines, y.final_outlines))
        if not same:
            sys.exit(f"{rid} differs")
print(len(ids))
PY
}
why=""
if ! two_nodes; then
    (( REQUIRE )) && fail "6. two nodes: $why"
    say "6. skipped: two nodes cannot be made here ($why)"
    why=skip
fi
if [[ "$why" != skip ]]; then
    one_conf="$SLURM_CONF"
    export SLURM_CONF="$dir/two/slurm.conf"
    two=$(sbatch --parsable -N2 --ntasks=3 -O -o "$res/two-%j.out" \
        --export=ALL,SCENE="$SCENE",OUT="$res/two.h5",K_MIN=2,K_MAX=2,SEEDS=0:2,LAUNCHER=mpirun,MSCAP_ARGS="$short" \
        slurm/mscap_run.sbatch)
    wait_job "$two" 300
    [[ "$(state "$two")" == COMPLETED ]] || fail "two-node job $two: $(state "$two"); log: $(tail -n5 "$res/two-$two.out")"
    grep -q 'to do on 2 workers on 2 hosts (node1: 1, node2: 1)' "$res/two-$two.out" \
        || fail "two-node job $two did not run a worker on each node: $(grep 'to do' "$res/two-$two.out")"
    grep -q ', rank 2); ' "$res/two-$two.out" || fail "node2's worker (rank 2) stored no run"
    n=$(same_runs "$res/single.h5" "$res/two.h5") || fail "two-node job $two and one-node job $one differ: $n"
    say "6. two nodes: job $two on node1 + node2 ($(grep -o 'on 2 hosts ([^)]*)' "$res/two-$two.out")):" \
        "its $n runs equal section 1's one-node runs bit for bit"
    # A node dies mid-run.
    crash=$(sbatch --parsable -N2 --ntasks=3 -O -o "$res/crash-%j.out" \
        --export=ALL,SCENE="$SCENE",OUT="$res/crash.h5",K_MIN=2,K_MAX=2,SEEDS=0:8,LAUNCHER=mpirun,MSCAP_ARGS="$short --starts-per-k 8" \
        slurm/mscap_run.sbatch)
    first_run "$res/crash-$crash.out" "job $crash (two nodes)"
    node2="$(cat "$dir/two/node2.pid")"
    netns="$(readlink "/proc/$node2/ns/net")"
    for p in /proc/[0-9]*; do
        [[ "$(readlink "$p/ns/net" 2>/dev/null)" == "$netns" ]] && kill -KILL "${p#/proc/}" 2>/dev/null || true
    done
    wait_job "$crash" 120
    announced=$(sed -n 's/^\[[0-9]*\/[0-9]*\] \([^:]*\): .*/\1/p' "$res/crash-$crash.out" | sort)
    kept=$(stored_ids "$res/crash.h5")
    [[ -n "$announced" ]] || fail "job $crash announced no run before node2 died"
    missing=$(comm -23 <(echo "$announced") <(echo "$kept"))
    [[ -z "$missing" ]] || fail "node2's crash lost runs job $crash had announced: $missing"
    before=$(stored "$res/crash.h5")
    say "6. node2 killed while job $crash ran: the job ended $(state "$crash") (ExitCode $(exit_code "$crash")); the" \
        "$(wc -w <<< "$announced") run(s) it announced are stored ($before in the file); its log:"
    grep -E '^ORTE|^stopp|: stopped at step|^mscap_run: (mpirun exited|exit)' "$res/crash-$crash.out" | sed 's/^/       /'
    (( before < 8 )) || fail "job $crash finished every start before node2 died: nothing was left to lose"
    rerun=$(sbatch --parsable -N1 -w node1 --ntasks=3 -O -o "$res/crash-rerun-%j.out" \
        --export=ALL,SCENE="$SCENE",OUT="$res/crash.h5",K_MIN=2,K_MAX=2,SEEDS=0:8,LAUNCHER=mpirun,MSCAP_ARGS="$short --starts-per-k 8" \
        slurm/mscap_run.sbatch)
    wait_job "$rerun" 300
    [[ "$(state "$rerun")" == COMPLETED ]] || fail "rerun $rerun on node1: $(state "$rerun"); log: $(tail -n5 "$res/crash-rerun-$rerun.out")"
    [[ "$(stored "$res/crash.h5")" == 8 ]] || fail "after the rerun $(stored "$res/crash.h5") runs, not 8"
    say "6. rerun on node1 alone: job $rerun ran the other $(( 8 - before )); 8 runs stored"
    export SLURM_CONF="$one_conf"
fi

# 4, continued.
for entry in "${timelimit[@]}"; do
    read -r how tl <<< "$entry"
    wait_job "$tl" 400
    log="$res/timelimit-$how-$tl.out"
    tl_state="$(state "$tl")"
    [[ "$tl_state" == COMPLETED || "$tl_state" == TIMEOUT ]] \
        || fail "time-limited job $tl ($how) ended $tl_state; log: $(tail -n5 "$log")"
    grep -q 'stopped: the finished runs are stored' "$log" \
        || fail "time-limited job $tl ($how) logged no 'stopped' line: $(tail -n5 "$log")"
    n=$(stored "$res/timelimit-$how.h5")
    (( n >= 1 && n < total )) || fail "time-limited job $tl ($how) stored $n runs (expected 1 to $(( total - 1 )))"
    say "4. time limit ($how): job $tl $tl_state (ExitCode $(exit_code "$tl")), $n of $total runs stored; its log:"
    grep -E '^mscap_run: (stop|exit|mpirun|srun)|^stopp|CANCELLED|Killed|Terminated|: stopped at step' "$log" \
        | sed 's/^/       /'
    # A start the time limit cut: the resubmission (restricted to it) continues it to its end.
    cut="$(sed -n 's/^\(k\([0-9]*\)_s[0-9]*_[a-z]*\): stopped at step \([0-9]*\).*/\1 \2 \3/p' "$log" | head -n1)"
    [[ -n "$cut" ]] || fail "time-limited job $tl ($how) kept no busy start's state"
    read -r run k step <<< "$cut"
    seed="${run#k${k}_s}"; seed="${seed%%_*}"; index=$(( seed - 1000 * k ))
    again=$(sbatch --parsable --ntasks=3 -O -o "$res/timelimit-again-$how-%j.out" \
        --export=ALL,SCENE="$SCENE",OUT="$res/timelimit-$how.h5",K_MIN="$k",K_MAX="$k",SEEDS="$index:$(( index + 1 ))",LAUNCHER="$how",SRUN_ARGS="$( [[ $how == srun ]] && echo --mpi=pmix )",MSCAP_ARGS="--starts-per-k $per_k" \
        slurm/mscap_run.sbatch)
    wait_job "$again" 300
    alog="$res/timelimit-again-$how-$again.out"
    [[ "$(state "$again")" == COMPLETED ]] || fail "resubmission $again ($how): $(state "$again"); $(tail -n5 "$alog")"
    grep -q "continues from its stored state: $run (step $step)" "$alog" \
        || fail "resubmission $again did not continue $run from step $step: $(grep -i 'stored state\|to do' "$alog")"
    grep -q "\] $run: ok" "$alog" || fail "resubmission $again did not finish $run: $(tail -n5 "$alog")"
    [[ ! -e "$res/timelimit-$how.h5.checkpoints/$run.h5" ]] || fail "resubmission $again left $run's state behind"
    say "4. resubmitted ($how): job $again continued $run from step $step, the step the time limit cut, to its end"
done
say "passed"
