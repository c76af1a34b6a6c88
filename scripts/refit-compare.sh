#!/usr/bin/env bash
# Refit stored captures with two builds of the fitter and compare them: a
# change meant to make the fit faster (or otherwise leave it as it was) must
# give the same material, byte for byte, and says by how much it is faster.
#
#   bash scripts/refit-compare.sh --base DIR [--bin DIR] [--data DIR] OUT CAPTURE...
#
# --base names the directory holding the other build's `refl` (e.g. a
# release build of the commit before the change, copied aside); --bin this
# build's (default: this tree's release build, built first). --data names
# the data directory holding the captures' calibrations (default: each
# capture's parent's `data`, where scripts/eval-all.sh puts it). Each
# capture is refitted by each build into OUT/NAME.base and OUT/NAME.new (the
# frames linked, not copied; the captures are not changed). One line per
# capture: each build's time after the last frame (`report.json`
# `timings.fit_total_after_capture_s`) and whether every material file is
# the same (the EXR files byte for byte, `material.json` less its
# timings), else which differ. Exit status 1 if any differs.
set -euo pipefail
cd "$(dirname "$0")/.."
base=""
bin=""
data=""
while [ $# -gt 0 ]; do
  case "$1" in
    --base) base="$(cd "$2" && pwd)"; shift 2 ;;
    --bin) bin="$(cd "$2" && pwd)"; shift 2 ;;
    --data) data="$(cd "$2" && pwd)"; shift 2 ;;
    *) break ;;
  esac
done
[ -n "$base" ] && [ $# -ge 2 ] || { sed -n 2,18p "$0" >&2; exit 2; }
. scripts/common.sh
release_bins
out="$(absolute_dir "$1")"
shift
export RUST_LOG=warn
status=0
for capture in "$@"; do
  src="$(cd "$capture" && pwd)"
  name="$(basename "$src")"
  export REFLECTOMETER_DATA="${data:-$(dirname "$src")/data}"
  for side in base new; do
    dir="$out/$name.$side"
    rm -rf "$dir"
    mkdir -p "$dir"
    ln -s "$src/frames" "$dir/frames"
    cp "$src/capture.json" "$src/manifest.jsonl" "$dir/"
    b="$bin"
    [ "$side" = base ] && b="$base"
    "$b/refl" fit "$dir" >"$dir.log" 2>&1 || { echo "refit-compare: $name: the $side build's fit failed ($dir.log)" >&2; exit 1; }
  done
  ta="$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["timings"]["fit_total_after_capture_s"])' "$out/$name.base/report.json")"
  tb="$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["timings"]["fit_total_after_capture_s"])' "$out/$name.new/report.json")"
  same="$(python3 scripts/same-material.py "$out/$name.base/material" "$out/$name.new/material")" || status=1
  python3 -c 'import sys; n, a, b, s = sys.argv[1:]; a, b = float(a), float(b); print(f"{n:24} base {a:7.2f} s  new {b:7.2f} s  ({b / a:.2f}x)  {s}")' \
    "$name" "$ta" "$tb" "$same"
done
exit "$status"
