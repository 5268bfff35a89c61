#!/usr/bin/env bash
# One farm task of a frostvdb job; every template in scripts/farm/ calls this (docs/farm.md).
#   frostvdb-task.sh frames SCENE OUT A-B   [frostvdb run options]   frames A..B of a scene whose
#                                             frames are independent (gas): any order, in parallel
#   frostvdb-task.sh seed   SCENE OUT SEED  [options]   one seed of a seed sweep (DLA seeds,
#                                             snowflake batches) into OUT/seed_<SEED>/
#   frostvdb-task.sh chain  SCENE OUT LAST  [options]   history-dependent frost: frames up to LAST,
#                                             continuing from OUT's checkpoint when there is one
# A chain task is idempotent and self-healing: whichever chain tasks ran before (or failed, or
# were pre-empted), it continues from the newest checkpoint and leaves frames 1..LAST complete.
# Chain tasks of one OUT take a lock (flock OUT/.frostvdb.lock), so two never run at once.
# Environment: FROSTVDB (the binary; default: frostvdb on PATH, else build/bin/frostvdb of this
# checkout), FROSTVDB_CHECKPOINT (chain checkpoints, default 10m), FROSTVDB_THREADS (default 0:
# all cores; Slurm's SLURM_CPUS_PER_TASK when set).
set -euo pipefail
if [ $# -lt 4 ]; then
  sed -n '2,15p' "${BASH_SOURCE[0]}" >&2
  exit 2
fi
mode=$1 scene=$2 out=$3 arg=$4
shift 4
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
bin="${FROSTVDB:-$(command -v frostvdb || echo "$root/build/bin/frostvdb")}"
threads="${FROSTVDB_THREADS:-${SLURM_CPUS_PER_TASK:-0}}"
common=(--threads "$threads" -q)

case "$mode" in
frames)
  [[ "$arg" =~ ^[0-9]+(-[0-9]+)?$ ]] || { echo "frostvdb-task: frames wants A-B, got '$arg'" >&2; exit 2; }
  exec "$bin" run "$scene" --out "$out" --frames "$arg" "${common[@]}" "$@"
  ;;
seed)
  [[ "$arg" =~ ^[0-9]+$ ]] || { echo "frostvdb-task: seed wants a number, got '$arg'" >&2; exit 2; }
  exec "$bin" run "$scene" --out "$out/seed_$arg" --seed "$arg" "${common[@]}" "$@"
  ;;
chain)
  [[ "$arg" =~ ^[0-9]+$ ]] || { echo "frostvdb-task: chain wants the last frame, got '$arg'" >&2; exit 2; }
  mkdir -p "$out"
  exec 9>"$out/.frostvdb.lock"
  flock 9
  resume=()
  if compgen -G "$out/*.checkpoint" >/dev/null; then resume=(--resume "$out"); fi
  "$bin" run "$scene" --out "$out" --frames "1-$arg" --checkpoint-every "${FROSTVDB_CHECKPOINT:-10m}" \
    "${resume[@]}" "${common[@]}" "$@"
  ;;
*)
  echo "frostvdb-task: mode must be frames, seed or chain, got '$mode'" >&2
  exit 2
  ;;
esac
