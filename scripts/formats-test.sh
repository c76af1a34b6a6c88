#!/usr/bin/env bash
# The formats proven by the tools people open them with: the Khronos glTF
# validator (npm gltf-validator, pinned in tests/formats/package.json) on
# every glTF `refl export-gltf` writes, with no error and no warning; and
# OpenImageIO's `oiiotool --info --stats` on every EXR the project writes
# (a material's maps, tables, atlas and models, the renders), each readable
# with no NaN or infinity, the maps' channels named as MATERIAL.md says.
# Downloads are cached in target/.
set -euo pipefail
cd "$(dirname "$0")/.."
root="$PWD/target/formats"
mkdir -p "$root"
cp tests/formats/package.json "$root/package.json"
(cd "$root" && npm_config_cache="$root/npm-cache" npm install --silent --no-audit --no-fund --no-update-notifier)
cargo build --quiet --bin capture --bin refl
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
passed=0
failed=0
check() { # check OK WHAT
  if [ "$1" = 0 ]; then passed=$((passed + 1)); echo "ok   $2"; else failed=$((failed + 1)); echo "FAIL $2"; fi
}
# satin (tabulated and anisotropic models, a model choice) and white (diffuse).
for sample in satin white; do
  REFLECTOMETER_DATA="$work/data" target/debug/capture --sample "$sample" --quality fast \
    --grid 24 --camera-px 96 --steps 16 --out "$work/$sample" 2>"$work/capture.log" \
    || { cat "$work/capture.log" >&2; exit 1; }
  target/debug/refl export-gltf "$work/$sample" -o "$work/gltf-$sample/$sample.gltf" >/dev/null
  set +e
  NODE_PATH="$root/node_modules" node tests/formats/validate-gltf.js "$work/gltf-$sample/$sample.gltf"
  check $? "$sample.gltf: the Khronos validator finds no error or warning"
  set -e
done
target/debug/refl render "$work/satin" --model tabulated --light sky:35,20 --px 64 -o "$work/render.exr" >/dev/null
for f in "$work"/satin/material/*.exr "$work"/white/material/*.exr "$work"/satin/renders/*.exr "$work/render.exr"; do
  name="${f#"$work"/}"
  if ! oiiotool --info -v --stats "$f" >"$work/oiio.txt" 2>&1; then
    check 1 "$name: oiiotool cannot read it: $(head -3 "$work/oiio.txt")"
    continue
  fi
  # Every channel's NaN and infinity counts are 0.
  bad="$(grep -E 'Stats (NanCount|InfCount):' "$work/oiio.txt" | tr -s ' ' '\n' | grep -E '^[0-9]+$' | grep -vc '^0$' || true)"
  check "$bad" "$name: read by oiiotool, no NaN or infinity"
done
oiiotool --info -v "$work/satin/material/maps.exr" >"$work/oiio.txt"
for ch in kd.R kd.G kd.B ks.R ks.G ks.B eta flags choice partial_ks.R partial_eta; do
  if grep -q "channel list:.*\b$ch\b" "$work/oiio.txt"; then ok=0; else ok=1; fi
  check "$ok" "maps.exr names channel $ch as MATERIAL.md does"
done
echo "formats: $passed passed, $failed failed"
[ "$failed" = 0 ]
