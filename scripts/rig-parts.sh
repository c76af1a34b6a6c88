#!/usr/bin/env bash
# What each part of a perturbed simulated rig costs a fit: the same
# captures on the ideal rig, on `perturbed:SEED` with one part perturbed at
# a time (camera, leds, gantry, sample, sensor, drift; RIGFILE.md), and with all,
# each calibrated as `capture` does on first use. One row per (sample, rig):
# NDF errors on observed cells and over the hemisphere, and render errors
# of the synthesized model and of `auto` (`refl eval --json`).
# --rigs "R1 R2 ..." scores those simulated rigs instead (e.g. "ideal
# perturbed:1 perturbed:2": the same sample across drawn rigs).
#
#   bash scripts/rig-parts.sh [--quality Q] [--bin DIR] [--seed N] [--rigs LIST] [--out DIR] SAMPLE...
set -euo pipefail
cd "$(dirname "$0")/.."
quality=fast
bin=""
seed=1
rigs=""
out=runs/rig-parts
while [ $# -gt 0 ]; do
  case "$1" in
    --quality) quality="$2"; shift 2 ;;
    --bin) bin="$2"; shift 2 ;;
    --seed) seed="$2"; shift 2 ;;
    --rigs) rigs="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    *) break ;;
  esac
done
[ $# -gt 0 ] || { echo "usage: rig-parts.sh [--quality Q] [--bin DIR] [--seed N] [--rigs LIST] [--out DIR] SAMPLE..." >&2; exit 2; }
[ -n "$rigs" ] || rigs="ideal $(for p in camera leds gantry sample sensor drift; do echo "perturbed:$seed:$p"; done) perturbed:$seed"
. scripts/common.sh
release_bins
out="$(absolute_dir "$out")"
export RUST_LOG=warn
printf '%-14s %-36s %8s %8s %8s %8s\n' sample rig ndf_obs ndf_full synth auto
for sample in "$@"; do
  for rig in $rigs; do
    dir="$out/$sample-${rig//[:+]/-}"
    rm -rf "$dir" "$dir.data"
    REFLECTOMETER_DATA="$dir.data" "$bin/capture" --quality "$quality" --no-daemon --sample "$sample" \
      --sim-rig "$rig" --out "$dir" >/dev/null 2>"$dir.log"
    "$bin/refl" eval "$dir" --json --px 64 --no-holdout >"$dir.eval.json" 2>>"$dir.log"
    python3 - "$sample" "$rig" "$dir.eval.json" <<'PY'
import json, sys
sample, rig, path = sys.argv[1:]
m = json.load(open(path))["models"]
s = m.get("synthesized") or m.get("partial") or {}
f = lambda v: "-" if v is None else f"{v:.4f}"
print(f"{sample:14} {rig:36} {f(s.get('ndf_rel_l2_observed')):>8} {f(s.get('ndf_rel_l2_full')):>8} "
      f"{f(s.get('render_rel_rmse')):>8} "
      f"{f(m.get('auto', {}).get('render_rel_rmse')):>8}")
PY
  done
done
