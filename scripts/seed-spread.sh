#!/usr/bin/env bash
# How much one setting's render errors move with the simulator's noise seed:
# N simulated captures of SAMPLE at QUALITY, each on the embedded rig with
# [sim] seed = 1..N, scored by `refl eval --no-holdout`; prints each model's
# errors, their mean and standard deviation.
#
#   bash scripts/seed-spread.sh [SAMPLE] [N] [QUALITY] [BIN]
#
# BIN holds `capture` and `refl` (default: this tree's release build).
set -euo pipefail
cd "$(dirname "$0")/.."
sample="${1:-satin}" n="${2:-4}" quality="${3:-fast}" bin="${4:-}"
if [ -z "$bin" ]; then
  cargo build --release --quiet --bins
  bin="$PWD/target/release"
fi
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
export REFLECTOMETER_DATA="$out/data" RUST_LOG=warn
for s in $(seq 1 "$n"); do
  sed "s/^seed = .*/seed = $s/; s/^name = .*/name = \"sim-seed-$s\"/" crates/config/rigs/sim.toml >"$out/rig$s.toml"
  "$bin/capture" --rig "$out/rig$s.toml" --sample "$sample" --quality "$quality" --no-daemon --out "$out/c$s" >/dev/null 2>&1
  "$bin/refl" eval "$out/c$s" --json --px 64 --no-holdout >"$out/e$s.json" 2>/dev/null
done
python3 - "$out" "$n" "$sample" "$quality" <<'PY'
import json, statistics, sys
out, n, sample, quality = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
evs = [json.load(open(f"{out}/e{s}.json")) for s in range(1, n + 1)]
print(f"render error of {sample} at {quality} over seeds 1..{n}")
for m in evs[0]["models"]:
    v = [e["models"][m]["render_rel_rmse"] for e in evs]
    mean, sd = statistics.mean(v), statistics.stdev(v) if n > 1 else 0.0
    print(f"  {m:18} {' '.join(f'{x:.4f}' for x in v)}  mean {mean:.4f}  sd {sd:.4f} ({100 * sd / mean:.1f}%)")
PY
