#!/usr/bin/env bash
# One pod of a Kubernetes Indexed Job (deploy/k8s/job/particles-indexed-job.yaml) or one task of a Slurm job array
# (deploy/slurm/surfacer-array.sbatch): surfaces its share of a long particle frame sequence with the in-process
# server (`surfacer --local`) and writes the frames under their GLOBAL numbers, so the union of all pods' output is
# exactly what one `surfacer run particles` over the whole sequence would name by input frame number.
#
# Environment (every number a non-negative integer):
#   JOB_COMPLETION_INDEX  this pod's index, 0..JOB_COMPLETIONS-1 (set by Kubernetes for completionMode: Indexed)
#   SLURM_ARRAY_TASK_ID   the index when JOB_COMPLETION_INDEX is unset (set by Slurm in each task of an array;
#                         the sbatch script passes FRAMES_PER_POD, so a resubmitted subset of the array keeps its
#                         ranges)
#   JOB_COMPLETIONS       the Job's spec.completions (needed unless FRAMES_PER_POD is given)
#   FRAMES_TOTAL          number of frames in the sequence
#   FRAME_FIRST           number of the first frame in INPUT_PATTERN (default 0)
#   FRAMES_PER_POD        frames per pod (default: ceil(FRAMES_TOTAL / JOB_COMPLETIONS))
#   INPUT_PATTERN         particle file pattern, e.g. /input/fluid_{:04d}.bgeo (see `surfacer run particles --help`)
#   R_INNER               inner radius (scene units). Required: --derive-r-inner would derive a different radius
#                         in every pod (from each pod's first frame) and the surface would jump at range borders.
#   OUT_DIR               output directory shared by all pods (a ReadWriteMany volume)
#   SURFACER_ARGS         optional extra `run particles` flags, split on spaces, e.g. "--format ply --r-outer 0.03"
#   SURFACER_WORKERS      optional worker threads of the in-process server (default 0: one per core)
#   SURFACER              optional path of the CLI (default: surfacer on PATH)
#
# Pod i surfaces frames START..END, START = FRAME_FIRST + i * FRAMES_PER_POD, END = min(START + FRAMES_PER_POD,
# FRAME_FIRST + FRAMES_TOTAL) - 1. The CLI names each frame by its input's frame number (frame_<START+k>), so the
# pod writes into OUT_DIR/.part-<i>/ and then moves the files to OUT_DIR/ with mv, an atomic rename on the same file
# system: a reader never sees a partial frame. Its stats.csv (whose frame column counts from 0) goes to
# OUT_DIR/stats/part-<i>.csv with the frame column made global. A retried pod starts its part directory afresh and
# overwrites its own frames, so retries are safe.
#
# Exit status: 0 done (or nothing to do: the index lies past the sequence), 2 bad environment, otherwise the CLI's
# exit status (3 unreachable, 4 job failed, 5 cancelled, 6 frame integrity; see `surfacer --help`), or 1 when the
# CLI's output does not hold exactly the expected frames.
set -euo pipefail

log() { echo "ts=$(date -u +%Y-%m-%dT%H:%M:%SZ) level=$1 event=$2 ${*:3}" >&2; }
die_env() {
  echo "indexed-job-entry: $*" >&2
  exit 2
}

# require_uint NAME [DEFAULT]: the variable's value, checked to be a non-negative integer.
require_uint() {
  local name=$1 value
  if [ $# -ge 2 ]; then value=${!name:-$2}; else value=${!name:-}; fi
  [ -n "$value" ] || die_env "$name is not set; see the header of this script for what it means"
  [[ $value =~ ^[0-9]+$ ]] || die_env "$name ($value) must be a non-negative integer"
  echo $((10#$value))
}

if [ -n "${JOB_COMPLETION_INDEX:-}" ] || [ -z "${SLURM_ARRAY_TASK_ID:-}" ]; then
  INDEX_VAR=JOB_COMPLETION_INDEX
else
  INDEX_VAR=SLURM_ARRAY_TASK_ID
fi
INDEX=$(require_uint "$INDEX_VAR")
TOTAL=$(require_uint FRAMES_TOTAL)
FIRST=$(require_uint FRAME_FIRST 0)
[ "$TOTAL" -gt 0 ] || die_env "FRAMES_TOTAL (0) must be > 0"
if [ -n "${FRAMES_PER_POD:-}" ]; then
  PER_POD=$(require_uint FRAMES_PER_POD)
  [ "$PER_POD" -gt 0 ] || die_env "FRAMES_PER_POD (0) must be > 0"
  if [ -n "${JOB_COMPLETIONS:-}" ]; then
    COMPLETIONS=$(require_uint JOB_COMPLETIONS)
    [ $((PER_POD * COMPLETIONS)) -ge "$TOTAL" ] ||
      die_env "FRAMES_PER_POD ($PER_POD) x JOB_COMPLETIONS ($COMPLETIONS) < FRAMES_TOTAL ($TOTAL): frames" \
        "$((PER_POD * COMPLETIONS))..$((TOTAL - 1)) would never be surfaced; raise completions or FRAMES_PER_POD"
    [ "$INDEX" -lt "$COMPLETIONS" ] || die_env "$INDEX_VAR ($INDEX) must be < JOB_COMPLETIONS ($COMPLETIONS)"
  fi
else
  [ -n "${JOB_COMPLETIONS:-}" ] || die_env "set JOB_COMPLETIONS (the Job's spec.completions) or FRAMES_PER_POD"
  COMPLETIONS=$(require_uint JOB_COMPLETIONS)
  [ "$COMPLETIONS" -gt 0 ] || die_env "JOB_COMPLETIONS (0) must be > 0"
  [ "$INDEX" -lt "$COMPLETIONS" ] || die_env "$INDEX_VAR ($INDEX) must be < JOB_COMPLETIONS ($COMPLETIONS)"
  PER_POD=$(((TOTAL + COMPLETIONS - 1) / COMPLETIONS))
fi
[ -n "${INPUT_PATTERN:-}" ] || die_env "INPUT_PATTERN is not set (e.g. /input/fluid_{:04d}.bgeo)"
[ -n "${OUT_DIR:-}" ] || die_env "OUT_DIR is not set (the shared output directory)"
[ -n "${R_INNER:-}" ] || die_env "R_INNER is not set (inner radius in scene units; every pod must use the same one)"
WORKERS=$(require_uint SURFACER_WORKERS 0)
CLI=${SURFACER:-surfacer}

START=$((FIRST + INDEX * PER_POD))
STOP=$((FIRST + TOTAL)) # one past the last frame of the sequence
if [ "$START" -ge "$STOP" ]; then
  log info range_empty "index=$INDEX start=$START last=$((STOP - 1))"
  exit 0
fi
END=$((START + PER_POD - 1))
[ "$END" -lt "$STOP" ] || END=$((STOP - 1))
COUNT=$((END - START + 1))
log info range "index=$INDEX start=$START end=$END frames=$COUNT"

mkdir -p "$OUT_DIR" "$OUT_DIR/stats"
PART="$OUT_DIR/.part-$INDEX"
rm -rf "$PART"

read -r -a EXTRA <<<"${SURFACER_ARGS:-}"
status=0
"$CLI" --local --workers "$WORKERS" run particles --input "$INPUT_PATTERN" --start "$START" --end "$END" \
  --r-inner "$R_INNER" -o "$PART" "${EXTRA[@]}" || status=$?
if [ "$status" -ne 0 ]; then
  log error surfacer_failed "index=$INDEX exit=$status"
  exit "$status"
fi

# Check first, rename second: nothing is published unless the part holds exactly frames START..END.
declare -A seen=()
files=()
shopt -s nullglob
for path in "$PART"/frame_*; do
  name=${path##*/}
  [[ $name =~ ^frame_([0-9]+)\.([A-Za-z0-9]+)$ ]] || continue
  local_index=$((10#${BASH_REMATCH[1]} - START))
  if [ "$local_index" -lt 0 ] || [ "$local_index" -ge "$COUNT" ]; then
    log error unexpected_frame "index=$INDEX file=$name frames=$COUNT"
    exit 1
  fi
  seen[$local_index]=1
  files+=("$path")
done
if [ "${#seen[@]}" -ne "$COUNT" ]; then
  log error missing_frames "index=$INDEX expected=$COUNT written=${#seen[@]} dir=$PART"
  exit 1
fi

for path in "${files[@]}"; do
  name=${path##*/}
  mv -f -- "$path" "$OUT_DIR/${path##*/}"
done
if [ -f "$PART/stats.csv" ]; then
  awk -F, -v OFS=, -v start="$START" 'NR == 1 || $1 !~ /^[0-9]+$/ { print; next } { $1 = $1 + start; print }' \
    "$PART/stats.csv" >"$PART/stats.global.csv"
  mv -f -- "$PART/stats.global.csv" "$OUT_DIR/stats/part-$INDEX.csv"
fi
rm -rf "$PART"
log info range_done "index=$INDEX start=$START end=$END frames=$COUNT out=$OUT_DIR"
