#!/usr/bin/env bash
# The whole test suite, from a fresh clone: system packages, the workspace's
# tests, the firmware protocol's no_std build, and the V4L2 tier in a VM.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export CARGO_TERM_COLOR=never
# Proves firmware-protocol is no_std and allocation-free (see PROTOCOL.md).
cargo build --quiet --manifest-path firmware-protocol/nostd-check/Cargo.toml
cargo test --workspace --no-fail-fast
