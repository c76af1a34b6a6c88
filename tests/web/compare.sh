#!/usr/bin/env bash
# compare.sh VIEWER.png RENDER.exr: three.js's drawing of the exported glTF
# (sRGB, 8 bits, from the browser) against `refl render`'s drawing of the
# same fit (linear radiance, times SCALE: the viewer's light's irradiance,
# default 1), in the same view and light. Both are made
# linear and averaged over 8 x 8 blocks of the frame (oiiotool); what is
# compared is each channel's mean over the frame and the blocks' pattern.
#
# The two are not the same renderer: glTF's material (KHR_materials_specular)
# takes the specular lobe's energy out of the diffuse part and uses
# Schlick's Fresnel, where refl's ggx_aniso adds the two and uses the exact
# dielectric Fresnel; the texture is one texel per fitted point, filtered
# by the GPU. Tolerances: each channel's mean within MEAN_TOL (default
# 0.15: the diffuse loss of a dielectric lobe is its directional albedo,
# under 0.1 for the built-in samples, plus Fresnel's and filtering's
# share); the blocks' relative RMS difference within BLOCK_TOL (default
# 0.3), which a patch drawn in the wrong place or turned fails by far.
set -euo pipefail
viewer="$1"
render="$2"
# A pixel at full scale is clipped: its radiance is unknown.
# ("Stats Max: 58 55 48 (of 255)": the channels' maxima, then the scale.)
if oiiotool --stats "$viewer" | grep -E 'Stats Max:' | sed 's/(of 255)//' | grep -qw 255; then
  echo "compare: $viewer has pixels at full scale; dim the viewer's light" >&2
  exit 1
fi
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
blocks() { # blocks OUT IN [OIIOTOOL ARGS]: IN's 8 x 8 linear block means, one "Pixel" line each
  local out="$1"
  shift
  oiiotool "$@" --ch R,G,B -d float --resize 8x8 -o "$tmp/b.exr"
  oiiotool --dumpdata "$tmp/b.exr" | grep -E '^ *Pixel' >"$out"
}
blocks "$tmp/viewer.txt" "$viewer" --colorconvert sRGB linear
blocks "$tmp/render.txt" "$render" --mulc "${SCALE:-1}"
MEAN_TOL="${MEAN_TOL:-0.15}" BLOCK_TOL="${BLOCK_TOL:-0.3}" python3 - "$tmp/viewer.txt" "$tmp/render.txt" <<'PY'
import os, re, sys
def load(path):
    px = []
    for line in open(path):
        v = [float(x) for x in re.findall(r"-?\d+\.\d+(?:e-?\d+)?", line.split(":", 1)[1])]
        px.append(v[:3])
    assert len(px) == 64, f"{path}: {len(px)} blocks"
    return px
v, r = load(sys.argv[1]), load(sys.argv[2])
mean_tol, block_tol = float(os.environ["MEAN_TOL"]), float(os.environ["BLOCK_TOL"])
ok = True
for c, name in enumerate("RGB"):
    mv = sum(p[c] for p in v) / 64
    mr = sum(p[c] for p in r) / 64
    rel = abs(mv - mr) / mr
    print(f"compare: {name} mean viewer {mv:.5f} render {mr:.5f} relative difference {rel:.3f} (tolerance {mean_tol})")
    ok &= rel <= mean_tol
lum = lambda p: 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]
num = sum((lum(a) - lum(b)) ** 2 for a, b in zip(v, r))
den = sum(lum(b) ** 2 for b in r)
block = (num / den) ** 0.5
print(f"compare: 8x8 blocks' relative RMS difference {block:.3f} (tolerance {block_tol})")
ok &= block <= block_tol
sys.exit(0 if ok else 1)
PY
