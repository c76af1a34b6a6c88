#!/usr/bin/env bash
# Install what building and testing the reflectometer needs on a Debian or
# Ubuntu machine that already has Rust (cargo). Safe to run repeatedly: it
# installs only what is missing.
set -euo pipefail

need_pkgs=()
have() { dpkg -s "$1" >/dev/null 2>&1; }
# C toolchain pieces for -sys crates; libclang for the bindgen step of the
# `v4l` crate (the V4L2 camera backend).
# The V4L2 test tier (scripts/vm-test.sh): QEMU, a static busybox for the
# guest, cpio for its initramfs, kmod to order the kernel's modules, xz in
# case they are compressed.
# The formats tier (scripts/formats-test.sh): OpenImageIO's oiiotool, and
# node with npm for the Khronos glTF validator.
# The browser tier (scripts/web-test.sh): Debian's chromium.
# The systemd tier (scripts/vm-systemd-test.sh): mmdebstrap for its guest's root.
# The processor check (scripts/cpu-check.sh): qemu-user, to run the
# binaries as an older and a newer processor (objdump is build-essential's).
# The cluster tier (scripts/slurm-test.sh): Slurm's controller, node daemon
# and client, and munge; PyYAML for the Kubernetes manifests' check.
for p in build-essential pkg-config libclang-dev qemu-system-x86 qemu-user busybox-static cpio kmod xz-utils openimageio-tools chromium mmdebstrap slurmctld slurmd slurm-client munge python3-yaml; do
  have "$p" || need_pkgs+=("$p")
done
if ! command -v npm >/dev/null 2>&1; then
  need_pkgs+=(npm)
fi
# The Python examples' tier (scripts/python-test.sh) makes a virtual
# environment: Debian's python3 needs python3-venv for that.
if ! python3 -m venv --help >/dev/null 2>&1 || ! python3 -c "import ensurepip" >/dev/null 2>&1; then
  need_pkgs+=(python3-venv)
fi
# The guest's kernel is Debian's linux-image-amd64, downloaded (not
# installed) by vm-test.sh: apt must know the package.
kernel_known() { apt-cache depends linux-image-amd64 2>/dev/null | grep "Depends: linux-image-[0-9]" >/dev/null; }

if [ "${#need_pkgs[@]}" -gt 0 ] || ! kernel_known; then
  echo "setup: installing ${need_pkgs[*]:-nothing, refreshing the package lists}" >&2
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
      echo "setup: need root (or sudo) to install: ${need_pkgs[*]}" >&2; exit 1
    fi
  fi
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  if [ "${#need_pkgs[@]}" -gt 0 ]; then
    $SUDO apt-get install -y -qq --no-install-recommends "${need_pkgs[@]}" >/dev/null
  fi
fi

if ! command -v cargo >/dev/null 2>&1; then
  echo "setup: cargo not found. Install Rust (https://rustup.rs) and run this again." >&2
  exit 1
fi
