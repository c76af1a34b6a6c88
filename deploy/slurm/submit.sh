#!/usr/bin/env bash
# Fit a stored capture on a Slurm cluster, in N tiles and a merge:
#
#   deploy/slurm/submit.sh [--cpus C] [--merge-cpus M] [--partition P] CAPTURE N [SBATCH_ARG...]
#
# submits fit-tile.sbatch as an array of N tasks (`refl fit CAPTURE --tile
# K/N` for K = 0..N-1), then fit-merge.sbatch with a dependency on the
# whole array succeeding (`afterok`). Prints the two job ids ("tiles JOB"
# and "merge JOB"); `squeue`, `sacct -j JOB` follow them. Every node must
# see CAPTURE at the same path and have `refl` on its PATH (or REFL set to
# it, which is passed on). Extra arguments go to both sbatch calls
# (`--time=1:00:00`, `--mem=16G`, ...). The jobs' logs go to the directory
# sbatch is run from. --cpus sets each tile's CPUs, --merge-cpus the
# merge's (default: as the sbatch scripts ask, 2).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
opts=()
merge_opts=()
while [ $# -gt 0 ]; do
  case "$1" in
    --cpus) opts+=(--cpus-per-task="$2"); shift 2 ;;
    --merge-cpus) merge_opts+=(--cpus-per-task="$2"); shift 2 ;;
    --partition) opts+=(--partition="$2"); shift 2 ;;
    *) break ;;
  esac
done
[ $# -ge 2 ] || { sed -n 2,15p "$0" >&2; exit 2; }
capture="$(cd "$1" && pwd)"
tiles="$2"
shift 2
case "$tiles" in ''|*[!0-9]*|0) echo "submit: N must be a whole number of tiles, at least 1 (got '$tiles')" >&2; exit 2 ;; esac
[ -f "$capture/capture.json" ] || { echo "submit: $capture is not a capture (no capture.json)" >&2; exit 2; }
export CAPTURE="$capture" TILES="$tiles"
[ -n "${REFL:-}" ] && export REFL
tiles_job="$(sbatch --parsable --export=ALL --array="0-$((tiles - 1))" "${opts[@]}" "$@" "$here/fit-tile.sbatch")"
tiles_job="${tiles_job%%;*}"
merge_job="$(sbatch --parsable --export=ALL --dependency="afterok:$tiles_job" --kill-on-invalid-dep=yes "${opts[@]}" "${merge_opts[@]}" "$@" "$here/fit-merge.sbatch")"
merge_job="${merge_job%%;*}"
echo "tiles $tiles_job"
echo "merge $merge_job"
