#!/usr/bin/env bash
# Refit a stored capture with one of its inputs changed, into a new
# directory, and score it (`refl eval --json --px 64`, as eval-all.sh does):
# which stage or which frames a figure comes from.
#
#   bash scripts/refit-variant.sh [--bin DIR] [--data DIR]
#                                 [--drop-shorter] [--no-pooling]
#                                 [--turn-members | --no-turn-members]
#                                 [--ndf-theta N] [--kernel-scale X] CAPTURE OUT
#
# --drop-shorter leaves out the frames of an HDR bracket's shorter
# exposures (a partial fit: the capture as if it had one exposure);
# --no-pooling fits every point's NDF from its own samples (the capture's
# settings without `pool`); --turn-members lets the pool turn each member
# to its cluster's lobe axis where held-out samples say it pays
# (`fit::pooled::PoolSettings::turn`, on in the presets; for a capture made
# before it was), --no-turn-members pools without turning; --ndf-theta N
# fits tables of N rings by 3N sectors (as
# `capture --ndf-theta`); --kernel-scale X sets the splat kernel's width
# as a fraction of the local half-vector spacing
# (`FitSettings::kernel_scale`, 0.5 in the presets). The frames are
# linked, not copied; CAPTURE is not changed. --data names the data
# directory holding the capture's calibrations (default: CAPTURE's
# parent's `data`, where eval-all.sh puts it). OUT/eval.json is the score,
# OUT.log the log.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=""
data=""
drop_shorter=0
no_pooling=0
turn_members=""
ndf_theta=""
kernel_scale=""
while [ $# -gt 0 ]; do
  case "$1" in
    --bin) bin="$2"; shift 2 ;;
    --data) data="$2"; shift 2 ;;
    --drop-shorter) drop_shorter=1; shift ;;
    --no-pooling) no_pooling=1; shift ;;
    --turn-members) turn_members=1; shift ;;
    --no-turn-members) turn_members=0; shift ;;
    --ndf-theta) ndf_theta="$2"; shift 2 ;;
    --kernel-scale) kernel_scale="$2"; shift 2 ;;
    *) break ;;
  esac
done
[ $# -eq 2 ] || { sed -n 2,25p "$0" >&2; exit 2; }
src="$(cd "$1" && pwd)"
. scripts/common.sh
release_bins
out="$2"
rm -rf "$out"
out="$(absolute_dir "$out")"
export REFLECTOMETER_DATA="${data:-$(dirname "$src")/data}"
ln -s "$src/frames" "$out/frames"
python3 - "$src" "$out" "$drop_shorter" "$no_pooling" "$turn_members" "$ndf_theta" "$kernel_scale" <<'PY'
import json, sys
src, out = sys.argv[1], sys.argv[2]
drop_shorter, no_pooling = (a == "1" for a in sys.argv[3:5])
turn_members = sys.argv[5]
ndf_theta, kernel_scale = sys.argv[6], sys.argv[7]
info = json.load(open(f"{src}/capture.json"))
if ndf_theta:
    info["settings"]["fit"]["grid"] = {"n_theta": int(ndf_theta), "n_phi": 3 * int(ndf_theta)}
if kernel_scale:
    info["settings"]["fit"]["kernel_scale"] = float(kernel_scale)
if no_pooling:
    info["settings"]["pool"] = None
if turn_members and info["settings"].get("pool"):
    info["settings"]["pool"]["turn"] = turn_members == "1"
json.dump(info, open(f"{out}/capture.json", "w"), indent=2)
dropped = 0
with open(f"{out}/manifest.jsonl", "w") as m:
    for line in open(f"{src}/manifest.jsonl"):
        f = json.loads(line)["frame"]
        if drop_shorter and f["kind"] == "shot" and f["exposure"] > 0:
            dropped += 1
            continue
        m.write(line)
print(f"refit-variant: {dropped} shorter-exposure frames left out", file=sys.stderr)
PY
partial=()
[ "$drop_shorter" -eq 1 ] && partial=(--partial)
"$bin/refl" fit "${partial[@]}" "$out" >"$out.log" 2>&1
"$bin/refl" eval "$out" --json --px 64 >"$out/eval.json" 2>>"$out.log"
echo "refit-variant: $out/eval.json" >&2
