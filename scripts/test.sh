#!/usr/bin/env bash
# The whole test suite, from a fresh clone: system packages, the workspace's
# tests (end-to-end runs of the binaries included), the binaries' processor
# check, the firmware protocol's no_std build, the Python examples, the
# exported formats in their tools, the daemon's web page in a real
# browser, the V4L2 backend against the kernel's vivid driver in a QEMU
# guest, the daemon's systemd unit, and the fit spread over a Slurm cluster.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export CARGO_TERM_COLOR=never
# Proves firmware-protocol is no_std and allocation-free (see PROTOCOL.md).
cargo build --quiet --manifest-path firmware-protocol/nostd-check/Cargo.toml
cargo test --workspace --no-fail-fast
# The binaries refuse a processor without the instructions they were
# compiled for, saying so (.cargo/config.toml).
bash scripts/cpu-check.sh
# The Python examples in a fresh virtual environment, against refl.
bash scripts/python-test.sh
# The glTF and EXR files through the Khronos validator and oiiotool.
bash scripts/formats-test.sh
# The daemon's web page in headless chromium.
bash scripts/web-test.sh
# The V4L2 tests (not a `cargo test` target: this kernel has no V4L2) in a QEMU guest.
bash scripts/vm-test.sh
# The daemon under systemd (the shipped unit) in a QEMU guest booted with systemd.
bash scripts/vm-systemd-test.sh
# The fit in tiles on a real Slurm controller and node on loopback, and the
# Kubernetes manifests that do the same.
bash scripts/slurm-test.sh
# (PyYAML: Debian's python3-yaml, from setup.sh, where the python3 first on
# PATH is another without it.)
py=python3
python3 -c "import yaml" 2>/dev/null || py=/usr/bin/python3
"$py" tests/deploy/check_k8s.py
# The shipped systemd unit, checked against the freshly built daemon.
cargo build --quiet --bin refl
if command -v systemd-analyze >/dev/null 2>&1; then
  unit_dir="$(mktemp -d)"
  sed "s#^ExecStart=.*#ExecStart=$PWD/target/debug/refl daemon#" udev/reflectometer.service >"$unit_dir/reflectometer.service"
  systemd-analyze verify "$unit_dir/reflectometer.service"
  rm -rf "$unit_dir"
  echo "test: udev/reflectometer.service verified" >&2
else
  echo "test: systemd-analyze is not installed here; the unit file was not verified" >&2
fi
