#!/usr/bin/env bash
# The rig's web page in a real browser: `refl daemon --http` on loopback,
# Debian's chromium (headless, software WebGL) driven by playwright-core
# (pinned in tests/web/package.json). The page loads, refuses a wrong
# token, starts a simulated capture whose progress and camera view
# advance, shows its evaluation, renders and 3D viewer, and cancels a
# second capture, leaving it resumable. The viewer's drawing of the
# exported glTF is then compared with `refl render` of the same view and
# light (tests/web/compare.sh states the tolerance). Downloads are cached
# in target/.
set -euo pipefail
cd "$(dirname "$0")/.."
root="$PWD/target/web-test"
mkdir -p "$root"
cp tests/web/package.json tests/web/package-lock.json "$root/"
export npm_config_cache="$PWD/target/npm-cache"
(cd "$root" && npm ci --silent --no-audit --no-fund --no-update-notifier)
# three.js for the page's viewer, where the daemon looks for it.
(cd web && npm ci --silent --no-audit --no-fund --no-update-notifier)
cargo build --quiet --bin refl
work="$(mktemp -d)"
daemon_pid=""
cleanup() {
  if [ -n "$daemon_pid" ]; then kill "$daemon_pid" 2>/dev/null || true; wait "$daemon_pid" 2>/dev/null || true; fi
  rm -rf "$work"
}
trap cleanup EXIT
export REFLECTOMETER_DATA="$work/data"
RUST_LOG=info NO_COLOR=1 target/debug/refl daemon --socket "$work/run/daemon.sock" --http 127.0.0.1:0 \
  >"$work/daemon.log" 2>&1 &
daemon_pid=$!
for _ in $(seq 300); do
  grep -q "web page on http://" "$work/daemon.log" && break
  kill -0 "$daemon_pid" 2>/dev/null || { cat "$work/daemon.log" >&2; exit 1; }
  sleep 0.1
done
addr="$(grep -o 'web page on http://[0-9.:]*' "$work/daemon.log" | sed 's#.*http://##')"
token="$(cat "$work/run/http-token")"
# The viewer is compared with refl render in two scenes: lit from the side
# (mostly diffuse) and in the mirror direction, the highlight at the
# centre (the light dimmed so that 8-bit sRGB does not clip it).
scenes='[{"name":"side","camera":[40,90],"light":[60,200],"intensity":1},
         {"name":"highlight","camera":[40,90],"light":[50,270],"intensity":0.5}]'
mkdir -p "$work/shots"
if ! NODE_PATH="$root/node_modules" node tests/web/browser-test.js "http://$addr/" "$token" "$work/shots" \
  "$scenes" >"$work/seen.json"; then
  echo "--- daemon log" >&2; cat "$work/daemon.log" >&2; exit 1
fi
cat "$work/seen.json"
field() { python3 -c "import json,sys; print(json.load(open(sys.argv[1]))[sys.argv[2]])" "$work/seen.json" "$1"; }
passed=0
failed=0
expect() { # expect WHAT COMMAND...: run COMMAND, count its outcome
  local what="$1"
  shift
  if "$@"; then passed=$((passed + 1)); echo "ok   $what"; else failed=$((failed + 1)); echo "FAIL $what"; fi
}
expect "the page ran without script errors" [ "$(field problems)" = "[]" ]
expect "the daemon logged the wrong token" grep -q "web page: capture refused: wrong token" "$work/daemon.log"
first="$(field first)"
cancelled="$(field cancelled)"
expect "the capture started from the page wrote its material" test -f "$first/material/maps.exr"
expect "the cancelled capture is another" [ "$first" != "$cancelled" ]
expect "the cancelled capture is left resumable" grep -q '"status": *"interrupted"' "$cancelled/capture.json"
for scene in "side 40,90 60,200 1" "highlight 40,90 50,270 0.5"; do
  read -r name camera light scale <<<"$scene"
  target/debug/refl render "$first" --model ggx_aniso --light "directional:$light" --camera "$camera" --px 256 \
    -o "$work/shots/render-$name.exr" >/dev/null
  expect "three.js draws the glTF as refl render draws its fit ($name)" \
    env SCALE="$scale" bash tests/web/compare.sh "$work/shots/viewer-$name.png" "$work/shots/render-$name.exr"
done
if [ -n "${WEB_TEST_KEEP:-}" ]; then mkdir -p "$WEB_TEST_KEEP" && cp "$work"/shots/* "$WEB_TEST_KEEP"/; fi
echo "web: $passed passed, $failed failed"
[ "$failed" = 0 ]
