# Shared by mscap_run.sbatch and mscap_array.sbatch (sourced, after `cd "$MSCAP_REPO"`):
# the environment of a job, the choice of launcher, and a launch that stops cleanly.
#
#   mscap_environment NAME     activate the venv, one thread per rank, OpenMPI as root
#   mscap_launcher NAME        sets `ranks` (RANKS, below) and the array `launcher`: srun or
#                              mpirun (LAUNCHER, below); says on stdout what the job has and uses
#   mscap_check_room NAME [DIR...]  refuses (status 2) a file-size limit or a disk too small for MPI
#   mscap_launch NAME ARGS...  runs `launcher mscap ARGS...`, passes a stop on, returns its status
#
# LAUNCHER (environment):
#   auto    (default) inside a SLURM job: srun if one probe task shows srun can start an MPI
#           program here, else mpirun inside the allocation (with the reason); outside a job: mpirun
#   srun    srun with SRUN_ARGS (e.g. --mpi=pmix), no probe
#   mpirun  mpirun -n $ranks (OpenMPI reads the allocation); outside SLURM -n $NTASKS
#
# RANKS (environment): how many MPI ranks the job starts.
#   auto    (default) inside a job: a worker on every CPU SLURM gave the job, plus the master,
#           which idles (< 1 % of a core) and shares one; never fewer than the job's tasks (a
#           job asking `--ntasks=3 -O` on one CPU gets its 3). Outside a job: NTASKS (1).
#   tasks   exactly the job's tasks, SLURM_NTASKS
#   N       N ranks (2 at least: the master and a worker)
# More ranks than tasks start with `srun --overcommit` or `mpirun --oversubscribe`.
#
# Stopping (SLURM's `--signal=B:TERM@120` before the time limit, or Ctrl-C by hand) asks
# mscap's master, and only it, to stop: it stores what has finished and ends the job with
# status 0. The two launchers need different routes, measured on SLURM 22.05 with OpenMPI 4.1
# (slurm/README.md): a TERM to srun makes srun SIGKILL every task, so the script signals the
# job's steps instead (`scancel --signal=TERM JOB`, which leaves the batch script alone); a TERM
# to mpirun makes mpirun kill the ranks, while SIGUSR1 is passed on to every rank untouched,
# so mpirun gets SIGUSR1. A signal to any rank is a stop of the whole job: a worker that gets
# TERM or USR1 tells the master (mscap/farm.py). When the launcher itself is signalled
# (`scancel JOB` signals every process of the job, mpirun and srun included), it may end the
# job with a status of its own after mscap's clean stop (mpirun exits 1 after a TERM, whatever
# the ranks do): mscap's master writes the stop into $MSCAP_STOP_FILE, and the launch then
# reports the stop's status, 0 (slurm/README.md, "Exit statuses").

mscap_environment() {
    local name="$1"
    if [[ -f "$MSCAP_VENV/bin/activate" ]]; then
        set +u
        # shellcheck disable=SC1091
        source "$MSCAP_VENV/bin/activate"
        set -u
    elif command -v mscap >/dev/null 2>&1; then
        echo "$name: no venv at $MSCAP_VENV, using $(command -v mscap)" >&2
    else
        echo "$name: no venv at $MSCAP_VENV and no mscap on PATH (set MSCAP_VENV, or run make)" >&2
        exit 1
    fi
    mscap_forget_mpi_parent
    # One thread per rank: each worker runs its own PETSc on COMM_SELF.
    export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
    if [[ "$(id -u)" == 0 ]]; then   # containers: OpenMPI refuses root otherwise
        export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
    fi
}

# A process that has called MPI_Init as a singleton (python with mpi4py imported, e.g. a
# notebook or a test runner that submits the job) puts its PMIx server's address and
# OpenMPI's singleton settings into its environment; `sbatch --export=ALL` carries them into
# the job, where mpirun and the ranks then fail in orte_init ("getting local rank failed").
# They never belong to this job: drop them (the user's own OMPI_MCA_* settings stay).
mscap_forget_mpi_parent() {
    local name
    for name in $(compgen -e); do
        case "$name" in
            PMIX_*|ORTE_*|OMPI_MCA_ess|OMPI_MCA_pmix|OMPI_MCA_orte_*|OMPI_APP_CTX_NUM_PROCS) unset "$name" ;;
        esac
    done
}

# Can srun start an MPI program in this job? One task, one MPI_Init. Prints the reason when not.
srun_can_start_mpi() {
    local out
    if out="$(srun --ntasks=1 --nodes=1 "${srun_extra[@]}" python3 -c \
            'from mpi4py import MPI; MPI.COMM_WORLD.Barrier()' 2>&1)"; then
        return 0
    fi
    if grep -q "PMI" <<< "$out"; then
        echo "srun cannot start this MPI: it was not built with SLURM's PMI support (OpenMPI: \"direct launched" \
             "using srun ... not built with SLURM's PMI support\"; give srun the PMI flavour it needs with" \
             "SRUN_ARGS=--mpi=pmix, see srun --mpi=list)"
    else
        echo "srun cannot start an MPI program here: $(grep -m1 -i "error" <<< "$out" || tail -n1 <<< "$out")"
    fi
    return 1
}

# The CPUs of this job's allocation: SLURM_JOB_CPUS_PER_NODE, e.g. "4(x2),2" -> 10 (0 if unset).
allocation_cpus() {
    local part total=0 parts=()
    IFS=, read -r -a parts <<< "${SLURM_JOB_CPUS_PER_NODE:-}"
    for part in ${parts[@]+"${parts[@]}"}; do
        if [[ "$part" =~ ^([0-9]+)\(x([0-9]+)\)$ ]]; then
            total=$(( total + BASH_REMATCH[1] * BASH_REMATCH[2] ))
        elif [[ "$part" =~ ^[0-9]+$ ]]; then
            total=$(( total + part ))
        else
            echo 0; return
        fi
    done
    echo "$total"
}

# Sets `ranks` from RANKS (above) and says on stdout what the job was given and what it runs.
mscap_ranks() {
    local name="$1" mode="${RANKS:-auto}" tasks="${SLURM_NTASKS:-}" cpus how
    if [[ -z "${SLURM_JOB_ID:-}" || -z "$tasks" ]]; then
        case "$mode" in
            auto|tasks) ranks="${NTASKS:-1}"; how="NTASKS" ;;
            *) ranks="$mode"; how="RANKS" ;;
        esac
        [[ "$ranks" =~ ^[1-9][0-9]*$ ]] || { echo "$name: $how must be a positive number, not '$ranks'" >&2; exit 2; }
        echo "$name: not in a SLURM job: $ranks rank(s) ($how)"
        return 0
    fi
    cpus="$(allocation_cpus)"
    case "$mode" in
        auto)
            ranks="$tasks"
            (( cpus + 1 > ranks )) && ranks=$(( cpus + 1 ))
            how="RANKS=auto: a worker per CPU, the master shares one"
            (( ranks == tasks && cpus + 1 < tasks )) && how="RANKS=auto: the job's $tasks tasks on $cpus CPU(s)"
            (( cpus )) || how="RANKS=auto: the job's tasks, its CPUs unknown"
            ;;
        tasks) ranks="$tasks"; how="RANKS=tasks: the job's tasks" ;;
        *)
            [[ "$mode" =~ ^[0-9]+$ ]] && (( mode >= 2 )) \
                || { echo "$name: RANKS must be auto, tasks or a number of ranks of at least 2, not '$mode'" >&2; exit 2; }
            ranks="$mode"; how="RANKS=$mode"
            ;;
    esac
    local limit="" partition="${SLURM_JOB_PARTITION:-?}"
    if command -v squeue >/dev/null 2>&1; then
        limit="$(squeue -h -j "$SLURM_JOB_ID" -o %l 2>/dev/null | head -n1)" || limit=""
    fi
    echo "$name: job $SLURM_JOB_ID (partition $partition, time limit ${limit:-unknown}) has $tasks task(s)," \
         "${cpus/#0/?} CPU(s) on ${SLURM_NNODES:-1} node(s) (${SLURM_JOB_NODELIST:-?}): $ranks ranks," \
         "the master and $(( ranks - 1 )) worker(s) ($how)"
    if (( ranks < 2 )); then
        echo "$name: 1 rank has no worker: ask for --ntasks=2 at least, or set RANKS" >&2
        exit 2
    fi
}

mscap_launcher() {
    local name="$1" mode="${LAUNCHER:-auto}" why
    mscap_ranks "$name"
    srun_extra=()
    if [[ -n "${SRUN_ARGS:-}" ]]; then
        read -r -a srun_extra <<< "$SRUN_ARGS"
    fi
    local in_job=0
    if [[ -n "${SLURM_JOB_ID:-}" ]] && command -v srun >/dev/null 2>&1; then
        in_job=1
    fi
    case "$mode" in
        auto)
            if (( in_job )) && why="$(srun_can_start_mpi)"; then
                mode=srun
                why="LAUNCHER=auto: a probe task started MPI under srun"
            elif (( in_job )); then
                why="LAUNCHER=auto: $why; using mpirun inside the allocation"
                mode=mpirun
            else
                why="LAUNCHER=auto: not in a SLURM job"
                mode=mpirun
            fi
            ;;
        srun)
            (( in_job )) || { echo "$name: LAUNCHER=srun needs a SLURM job and srun" >&2; exit 2; }
            why="LAUNCHER=srun"
            ;;
        mpirun) why="LAUNCHER=mpirun" ;;
        *) echo "$name: LAUNCHER must be auto, srun or mpirun, not '$mode'" >&2; exit 2 ;;
    esac
    local tasks="${SLURM_NTASKS:-$ranks}"
    if [[ "$mode" == srun ]]; then
        launcher=(srun "${srun_extra[@]}")
        if (( ranks > tasks )); then
            launcher+=(--ntasks="$ranks" --overcommit)
        elif (( ranks < tasks )); then
            launcher+=(--ntasks="$ranks")
        fi
    else
        launcher=(mpirun -n "$ranks")
        (( ranks > tasks )) && launcher+=(--oversubscribe)
    fi
    echo "$name: launcher ${launcher[*]} ($why)"
}

# Ask mscap's master to stop (see the top of this file).
mscap_stop() {
    local name="$1"
    echo "$name: stop requested ($(date -u '+%F %T') UTC): mscap stores what has finished and stops" >&2
    [[ -n "$child" ]] || return 0
    if [[ "${launcher[0]}" == srun ]]; then
        scancel --signal=TERM "$SLURM_JOB_ID" 2>/dev/null || kill -TERM "$child" 2>/dev/null || true
    else
        kill -USR1 "$child" 2>/dev/null || true
    fi
}

# MPI's start-up writes its shared-memory segments into the session directory (TMPDIR, else
# /tmp): under a file-size limit of 1 MB, or on a full disk, OpenMPI 4.1 dies in MPI_Init with
# a dozen PMIx lines before mscap can say anything (measured: `ulimit -f 1024` fails, 4096 runs).
# Refuse such a start in one line instead (16 MB: four times what the start-up needed).
MSCAP_MIN_FILE_KB=16384

mscap_check_room() {
    local name="$1" limit dir free
    limit="$(ulimit -f)"
    if [[ "$limit" != unlimited ]] && (( limit < MSCAP_MIN_FILE_KB )); then
        echo "$name: the file size limit (ulimit -f) is $limit KB: MPI's start-up needs" \
             "at least $MSCAP_MIN_FILE_KB KB (raise it: ulimit -f unlimited)" >&2
        exit 2
    fi
    for dir in "${TMPDIR:-/tmp}" "$@"; do
        [[ -d "$dir" ]] || continue
        free="$(df -Pk "$dir" 2>/dev/null | awk 'NR == 2 {print $4}')"
        if [[ -n "$free" ]] && (( free < MSCAP_MIN_FILE_KB )); then
            echo "$name: $dir has $free KB free: MPI's start-up needs at least" \
                 "$MSCAP_MIN_FILE_KB KB there" >&2
            exit 2
        fi
    done
}

mscap_launch() {
    local name="$1"
    shift
    echo "$name: ${launcher[*]} mscap $* (job ${SLURM_JOB_ID:-none}, $(date -u '+%F %T') UTC)" >&2
    local stopfile
    stopfile="$(mktemp "${TMPDIR:-/tmp}/mscap-stop.XXXXXX")"
    export MSCAP_STOP_FILE="$stopfile"
    # The launcher runs in the background so the trap runs while it does (a signal that comes
    # before the launcher's pid is known is passed on just after).
    child=""
    stop=0
    trap 'stop=1; mscap_stop "$name"' TERM INT
    "${launcher[@]}" mscap "$@" &
    child=$!
    if (( stop )); then mscap_stop "$name"; fi
    status=0
    wait "$child" || status=$?
    while kill -0 "$child" 2>/dev/null; do   # wait returned early because of a signal
        status=0
        wait "$child" || status=$?
    done
    trap - TERM INT
    if (( status != 0 )) && grep -q '^stop' "$stopfile" 2>/dev/null; then
        local from=""
        if (( ! stop )); then   # the launcher stopped the ranks itself (mpirun TERMs them when
            # it loses a node or a rank: "ORTE has lost communication ...")
            from=" (the stop did not come through this script: a node or rank lost? see the"
            from+=" launcher's lines above; the rerun runs what it lost)"
        fi
        echo "$name: ${launcher[0]} exited $status after mscap's clean stop ($(head -n1 "$stopfile")):" \
             "the finished work is stored; status 0$from" >&2
        status=0
    fi
    rm -f "$stopfile"
    unset MSCAP_STOP_FILE
}
