#!/usr/bin/env bash
# The main job on a fresh machine: build, then a full simulated capture of
# satin (calibration on first use, capture through the emulated rig's
# serial line, streaming fit, material, renders) and its evaluation.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cargo build --release --quiet --bins
out="${1:-runs/satin}"
if [ -e "$out" ]; then
  out="$out-$(date -u +%Y%m%dT%H%M%SZ)"
fi
./target/release/capture --sample satin --out "$out"
./target/release/refl eval "$out" | tee "$out/eval.json"
echo "capture, material, renders and report: $out" >&2
