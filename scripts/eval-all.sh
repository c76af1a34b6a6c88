#!/usr/bin/env bash
# Score the instrument on every built-in sample and every measured RGL file
# in ../shared/data/rgl (imported with `refl import-rgl`, scanned with
# `capture --sim-material`): one simulated capture each, then `refl eval
# --json`. Prints one table row per sample and keeps each eval JSON.
#
#   bash scripts/eval-all.sh [--quality Q] [--bin DIR] [--rig FILE]
#                            [--sim-rig RIG] [--no-geometric-calibration]
#                            [--hdr N] [--bracket every|clipped] [--reeval]
#                            [--subpixels N] [OUT]
#
# --rig names a rig file (default the embedded simulated rig; e.g.
# scripts/rigs/sim-no-patches.toml, the same rig without the reference
# patches that LED drift is corrected from). --sim-rig picks the simulated
# physical rig (`ideal`, `perturbed:SEED`; default the rig file's, see
# RIGFILE.md). --no-geometric-calibration
# calibrates the rig with the dark and white scans only, so that every
# capture trusts the rig file's camera (the figures "for scale" of an
# uncalibrated rig).
# --hdr and --bracket override the preset's HDR bracket in every capture
# (`--hdr 1`: one exposure, the presets' before adaptive brackets).
# --reeval scores the captures already in OUT again with this build's
# `refl eval` (no new capture: for a change to the eval alone).
# --subpixels N renders each pixel as the mean of N x N rays (`refl eval
# --subpixels`; default one ray, the pixel's centre). With `--reeval` it
# rescores the same materials, e.g. to see how much of a render error is
# where the pixel centres fell on sub-pixel detail.
# The last two columns set the true lobe against the rig: the half-angle of
# the cone holding half the NDF's projected mass and the spacing of the
# capture's half vectors nearest its peak, degrees (`lobe_reach` in
# eval.json); a lobe far narrower than the spacing is not resolved.
# --bin names the directory holding `capture` and `refl` (default: this
# tree's release build, built first), so two builds can be compared on the
# same inputs. Without ../shared/data/rgl the RGL rows are skipped, and the
# script says so.
set -euo pipefail
cd "$(dirname "$0")/.."
quality=fast
bin=""
rig=()
no_geometry=0
reeval=0
subpixels=()
while [ $# -gt 0 ]; do
  case "$1" in
    --quality) quality="$2"; shift 2 ;;
    --bin) bin="$2"; shift 2 ;;
    --sim-rig) rig+=(--sim-rig "$2"); shift 2 ;;
    --hdr|--bracket) rig+=("$1" "$2"); shift 2 ;;
    --rig) rig+=(--rig "$(cd "$(dirname "$2")" && pwd)/$(basename "$2")"); shift 2 ;;
    --no-geometric-calibration) no_geometry=1; shift ;;
    --reeval) reeval=1; shift ;;
    --subpixels) subpixels=(--subpixels "$2"); shift 2 ;;
    *) break ;;
  esac
done
out="${1:-runs/eval-all-$quality}"
. scripts/common.sh
release_bins
out="$(absolute_dir "$out")"
export REFLECTOMETER_DATA="$out/data" RUST_LOG=warn
rgl_dir="../shared/data/rgl"

row() { # name dir
  python3 - "$1" "$2/eval.json" <<'EOF'
import json, sys
name, path = sys.argv[1], sys.argv[2]
ev = json.load(open(path))
m = ev["models"]
def r(k):
    v = m.get(k, {}).get("render_rel_rmse")
    return "-" if v is None else f"{v:.4f}"
syn = m.get("synthesized") or m.get("partial") or {}
def f(v):
    return "-" if v is None else f"{v:.4f}"
analytic = {k: v["render_rel_rmse"] for k, v in m.items()
            if k not in ("synthesized", "partial", "auto") and v.get("render_rel_rmse") is not None}
best = min(analytic, key=analytic.get) if analytic else None
ho = ev.get("holdout", {})
hs = ho.get("synthesized") or ho.get("partial") or {}
ha = ho.get("auto") or {}
# auto against the best single model of any kind (issue 16: at most 1.02).
single = {k: v["render_rel_rmse"] for k, v in m.items() if k != "auto" and v.get("render_rel_rmse") is not None}
auto_rel = m.get("auto", {}).get("render_rel_rmse")
auto_rel = auto_rel / min(single.values()) if auto_rel is not None and single and min(single.values()) > 0 else None
reach = ev.get("lobe_reach") or {}
def d(v):
    return "-" if v is None else f"{v:.2f}"
def rr(k):
    v = m.get(k, {}).get("render_rel_rmse_resolved")
    return "-" if v is None else f"{v:.4f}"
print(f"{name:24} {f(syn.get('ndf_rel_l2_observed')):>8} {f(syn.get('ndf_shape_observed')):>8} "
      f"{f(syn.get('ndf_rel_l2_full')):>8} {f(syn.get('ndf_rel_l2_observed_footprint')):>8} "
      f"{f(syn.get('ndf_rel_l2_full_footprint')):>8} {r('synthesized'):>8} {r('auto'):>8} {(best or '-'):>18} "
      f"{f(analytic.get(best)) if best else '-':>8} {f(ev.get('render_resolution_floor')):>8} "
      f"{rr('synthesized'):>8} {rr('auto'):>8} {f(hs.get('frame_rel_rmse')):>8} {f(ha.get('frame_rel_rmse')):>8} "
      f"{f(hs.get('noise_floor')):>8} {f(auto_rel):>9} {d(reach.get('half_mass_deg')):>6} {d(reach.get('spacing_deg')):>6}")
EOF
}

scan() { # name [capture args...]
  local name="$1"; shift
  local dir="$out/$name"
  if [ "$reeval" = 1 ]; then
    [ -f "$dir/capture.json" ] || { echo "eval-all: --reeval: $dir holds no capture" >&2; return 1; }
  else
    rm -rf "$dir"
    "$bin/capture" --quality "$quality" --no-daemon --out "$dir" "${rig[@]}" "$@" >/dev/null 2>"$out/$name.log"
  fi
  "$bin/refl" eval "$dir" --json --px 64 "${subpixels[@]}" >"$dir/eval.json" 2>>"$out/$name.log"
  row "$name" "$dir"
}

if [ "$no_geometry" = 1 ] && [ "$reeval" = 0 ]; then
  "$bin/capture" --calibrate white --quality "$quality" --no-daemon "${rig[@]}" >/dev/null 2>"$out/calibrate.log"
fi

printf '%-24s %8s %8s %8s %8s %8s %8s %8s %18s %8s %8s %8s %8s %8s %8s %8s %9s %6s %6s\n' sample ndf_obs shape ndf_full obs_fp full_fp synth auto best_analytic best res_flr synth_rs auto_rs ho_synth ho_auto floor auto/best lobe hv_sp
for s in $("$bin/capture" --list-samples | awk '{print $1}'); do
  scan "$s" --sample "$s"
done
if [ -d "$rgl_dir" ]; then
  for f in "$rgl_dir"/*.bsdf; do
    name="$(basename "$f" .bsdf)"
    if [ "$reeval" = 0 ]; then
      rm -rf "$out/mat-$name"
      "$bin/refl" import-rgl "$f" --out "$out/mat-$name" >/dev/null 2>"$out/$name.import.log"
    fi
    scan "$name" --sample "$name" --sim-material "$out/mat-$name"
  done
else
  echo "eval-all: $rgl_dir is absent; the measured RGL materials were not scored" >&2
fi
echo "eval-all: per-sample eval JSON under $out" >&2
