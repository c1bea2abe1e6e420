#!/bin/bash
# Submit an mscap job array (one task per k value, or per seed chunk) and a merge job that
# runs after the whole array has ended (afterany: parts of failed or timed-out tasks are
# merged too; missing parts are reported and skipped).
#
#   slurm/submit_array.sh jobs/grid3x3.toml
#   slurm/submit_array.sh --k-min 2 --k-max 4 --outdir out/grid jobs/grid3x3.toml -- --ntasks=16 --time=2:00:00
#   slurm/submit_array.sh --split seeds --seed-chunk 5 jobs/grid3x3.toml
#
# Options (environment variable in brackets):
#   --outdir DIR        parts and merged file go here       [OUTDIR]      (results/<scene name>)
#   --merged FILE       merged file                          [MERGED]      (OUTDIR/all.h5)
#   --split k|seeds     one task per k, or per seed chunk    [SPLIT]       (k)
#   --k-min K --k-max K k range                              [K_MIN K_MAX] (scene's [multistart], else 2..6)
#   --seed-chunk S      seeds per task (--split seeds)       [SEED_CHUNK]  (5)
#   --seeds-total N     starts per k   (--split seeds)       [SEEDS_TOTAL] (scene's starts_per_k, else 25)
#   --max-parallel M    at most M array tasks at once        [MAX_PARALLEL]
#   -- ARGS             further sbatch arguments for the array job (--ntasks, --time, --partition, ...);
#                       an --export=LIST here adds LIST's variables (LAUNCHER, SRUN_ARGS, MSCAP_ARGS, ...)
# MSCAP_REPO (default: this script's repository) and MSCAP_VENV are passed to the jobs.
# Prints the array and merge job ids.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
MSCAP_REPO="${MSCAP_REPO:-$(dirname "$here")}"
MSCAP_VENV="${MSCAP_VENV:-$MSCAP_REPO/.venv}"
SPLIT="${SPLIT:-k}"
SEED_CHUNK="${SEED_CHUNK:-5}"
OUTDIR="${OUTDIR:-}"
MERGED="${MERGED:-}"
K_MIN="${K_MIN:-}"
K_MAX="${K_MAX:-}"
SEEDS_TOTAL="${SEEDS_TOTAL:-}"
MAX_PARALLEL="${MAX_PARALLEL:-}"
SCENE="${SCENE:-}"
sbatch_extra=()

usage() { sed -n '2,/^set -euo/p' "${BASH_SOURCE[0]}" | sed '$d; s/^# \{0,1\}//'; }
die() { echo "submit_array: $*" >&2; exit 2; }

while (( $# )); do
    case "$1" in
        --outdir) OUTDIR="$2"; shift 2 ;;
        --merged) MERGED="$2"; shift 2 ;;
        --split) SPLIT="$2"; shift 2 ;;
        --k-min) K_MIN="$2"; shift 2 ;;
        --k-max) K_MAX="$2"; shift 2 ;;
        --seed-chunk) SEED_CHUNK="$2"; shift 2 ;;
        --seeds-total) SEEDS_TOTAL="$2"; shift 2 ;;
        --max-parallel) MAX_PARALLEL="$2"; shift 2 ;;
        -h|--help) usage; exit 0 ;;
        --) shift; sbatch_extra=("$@"); break ;;
        -*) die "unknown option $1 (sbatch arguments go after --)" ;;
        *) SCENE="$1"; shift ;;
    esac
done
SCENE="${SCENE:-jobs/poking.toml}"
[[ -f "$SCENE" ]] || die "scene $SCENE not found"

abspath() { case "$1" in /*) printf '%s' "$1" ;; *) printf '%s/%s' "$PWD" "$1" ;; esac; }
SCENE="$(abspath "$SCENE")"
name="$(basename "$SCENE" .toml)"
OUTDIR="$(abspath "${OUTDIR:-results/$name}")"
MERGED="$(abspath "${MERGED:-$OUTDIR/all.h5}")"
for v in "$SCENE" "$OUTDIR" "$MSCAP_REPO" "$MSCAP_VENV"; do
    [[ "$v" != *,* ]] || die "paths must not contain commas (sbatch --export): $v"
done

# k range and starts per k from the scene's [multistart] table when not given; whether the
# multi-start ends by calibrating its designs ([calibration] and calibrate_best > 0).
read -r scene_kmin scene_kmax scene_starts calibrates < <(python3 - "$SCENE" <<'PY' 2>/dev/null || echo "2 6 25 0"
import sys, tomllib
data = tomllib.load(open(sys.argv[1], "rb"))
m = data.get("multistart", {})
calibrates = int("calibration" in data and m.get("calibrate_best", 3) > 0)
print(m.get("k_min", 2), m.get("k_max", 6), m.get("starts_per_k", 25), calibrates)
PY
)
K_MIN="${K_MIN:-$scene_kmin}"
K_MAX="${K_MAX:-$scene_kmax}"
SEEDS_TOTAL="${SEEDS_TOTAL:-$scene_starts}"
for v in "$K_MIN" "$K_MAX" "$SEED_CHUNK" "$SEEDS_TOTAL"; do
    [[ "$v" =~ ^[0-9]+$ ]] || die "not a non-negative integer: '$v'"
done
(( K_MIN <= K_MAX )) || die "k_min $K_MIN exceeds k_max $K_MAX"

# A user's --export after `--` (e.g. --export=ALL,SRUN_ARGS=--mpi=pmix) would replace the one
# that carries the scene and the output directory: its variables join ours instead.
user_exports=""
sbatch_args=()
for a in ${sbatch_extra[@]+"${sbatch_extra[@]}"}; do
    case "$a" in
        --export=*)
            IFS=, read -r -a entries <<< "${a#--export=}"
            for e in "${entries[@]}"; do
                case "$e" in
                    ALL|"") ;;
                    NONE|NIL) die "--export=$e would drop the settings the array tasks need; name the variables to add" ;;
                    *) user_exports+=",$e" ;;
                esac
            done
            ;;
        --export) die "give sbatch's --export as --export=LIST after --" ;;
        *) sbatch_args+=("$a") ;;
    esac
done

parts=()
export_vars="ALL$user_exports,SCENE=$SCENE,OUTDIR=$OUTDIR,SPLIT=$SPLIT,MSCAP_REPO=$MSCAP_REPO,MSCAP_VENV=$MSCAP_VENV"
case "$SPLIT" in
    k)
        array="${K_MIN}-${K_MAX}"
        for (( k = K_MIN; k <= K_MAX; k++ )); do parts+=("$OUTDIR/results_k${k}.h5"); done
        ;;
    seeds)
        (( SEED_CHUNK > 0 && SEEDS_TOTAL > 0 )) || die "--seed-chunk and --seeds-total must be positive"
        ntask=$(( (SEEDS_TOTAL + SEED_CHUNK - 1) / SEED_CHUNK ))
        array="0-$(( ntask - 1 ))"
        for (( i = 0; i < ntask; i++ )); do
            a=$(( i * SEED_CHUNK )); b=$(( a + SEED_CHUNK )); (( b <= SEEDS_TOTAL )) || b="$SEEDS_TOTAL"
            parts+=("$OUTDIR/results_seeds${a}-${b}.h5")
        done
        export_vars+=",SEED_CHUNK=$SEED_CHUNK,SEEDS_TOTAL=$SEEDS_TOTAL,K_MIN=$K_MIN,K_MAX=$K_MAX"
        ;;
    *) die "--split must be k or seeds, not '$SPLIT'" ;;
esac
[[ -n "$MAX_PARALLEL" ]] && array+="%$MAX_PARALLEL"
mkdir -p "$OUTDIR"

# `sbatch --parsable` prints "id" or "id;cluster"; older/wrapped sbatch may print "Submitted batch job id".
job_id() {
    local out="$1" id
    id="$(printf '%s\n' "$out" | awk 'NF { line = $0 } END { print line }')"   # last non-empty line
    id="${id##*Submitted batch job }"
    id="${id%%;*}"
    id="$(printf '%s' "$id" | tr -d '[:space:]')"
    [[ "$id" =~ ^[0-9]+$ ]] || die "cannot read a job id from sbatch output: $out"
    printf '%s' "$id"
}

array_out="$(sbatch --parsable --array="$array" --export="$export_vars" \
    ${sbatch_args[@]+"${sbatch_args[@]}"} "$here/mscap_array.sbatch")"
array_id="$(job_id "$array_out")"

# The merge job runs under /bin/sh: POSIX only, every path single-quoted.
q() { local s="${1//\'/\'\\\'\'}"; printf "'%s'" "$s"; }
plist=""
for p in "${parts[@]}"; do plist+=" $(q "$p")"; done
merge_cmd="set -eu; cd $(q "$MSCAP_REPO"); if [ -x $(q "$MSCAP_VENV/bin/mscap") ]; then PATH=$(q "$MSCAP_VENV/bin"):\$PATH; fi; set --; for f in$plist; do if [ -e \"\$f\" ]; then set -- \"\$@\" \"\$f\"; else echo \"mscap merge: missing part \$f (its array task failed?)\" >&2; fi; done; if [ \$# -eq 0 ]; then echo 'mscap merge: no parts to merge' >&2; exit 1; fi; mscap merge \"\$@\" -o $(q "$MERGED") --force"
# A part runs some starts only and does not calibrate: the merged file's `mscap run` does
# (every run is stored, only the calibration is left; docs/calibration.md).
(( calibrates )) && merge_cmd+="; mscap run $(q "$SCENE") -o $(q "$MERGED")"

merge_out="$(sbatch --parsable --dependency="afterany:$array_id" --job-name=mscap-merge \
    --ntasks=1 --time=00:30:00 --output="$OUTDIR/mscap-merge-%j.out" --wrap="$merge_cmd")"
merge_id="$(job_id "$merge_out")"

echo "array job $array_id: --array=$array, ${#parts[@]} parts in $OUTDIR"
echo "merge job $merge_id: after job $array_id ends, mscap merge -> $MERGED (log $OUTDIR/mscap-merge-$merge_id.out)$( (( calibrates )) && echo ", then mscap run calibrates its best designs")"
