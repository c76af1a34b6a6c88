#!/usr/bin/env bash
# Install what building and testing the reflectometer needs on a Debian or
# Ubuntu machine that already has Rust (cargo). Safe to run repeatedly: it
# installs only what is missing.
set -euo pipefail

need_pkgs=()
have() { dpkg -s "$1" >/dev/null 2>&1; }
# C toolchain pieces for -sys crates. (The V4L2 camera backend and its
# QEMU test tier are not built yet; they will add libclang-dev and QEMU.)
for p in build-essential pkg-config; do
  have "$p" || need_pkgs+=("$p")
done

if [ "${#need_pkgs[@]}" -gt 0 ]; then
  echo "setup: installing ${need_pkgs[*]}" >&2
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
      echo "setup: need root (or sudo) to install: ${need_pkgs[*]}" >&2; exit 1
    fi
  fi
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${need_pkgs[@]}" >/dev/null
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo not found. Install Rust (https://rustup.rs) and run this again." >&2
  exit 1
fi
