#!/usr/bin/env bash
# The Python examples (examples/python) against refl, as a researcher would
# use them: a fresh virtual environment with their requirements (downloads
# cached in target/), a small simulated capture of `ward`, its samples
# exported, then tests/python/check_examples.py.
set -euo pipefail
cd "$(dirname "$0")/.."
root="$PWD/target/python-examples"
mkdir -p "$root"
rm -rf "$root/venv"
python3 -m venv "$root/venv"
PIP_CACHE_DIR="$root/pip-cache" "$root/venv/bin/pip" install --quiet --disable-pip-version-check \
  -r examples/python/requirements.txt
cargo build --quiet --bin capture --bin refl
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
REFLECTOMETER_DATA="$work/data" target/debug/capture --sample ward --quality fast \
  --grid 24 --camera-px 96 --steps 16 --out "$work/ward" 2>"$work/capture.log" \
  || { cat "$work/capture.log" >&2; exit 1; }
target/debug/refl export-samples "$work/ward" -o "$work/ward.npz"
"$root/venv/bin/python" tests/python/check_examples.py "$work/ward" "$work/ward.npz" target/debug/refl
