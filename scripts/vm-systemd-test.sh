#!/usr/bin/env bash
# The shipped systemd unit run for real: a QEMU guest (TCG, Debian's stock
# kernel as in scripts/vm-test.sh) boots a small Debian root made by
# mmdebstrap (this machine's release, minbase and systemd; built once into
# target/vm) with systemd as PID 1, installs the freshly built binaries and
# udev/reflectometer.service as udev/README.md says, and runs
# scripts/vm/guest-systemd.sh: sd_notify readiness and watchdog as systemd
# sees them, a capture by a user in the service's group through its socket,
# a user outside it refused, `systemctl stop` mid-capture within the unit's
# TimeoutStopSec leaving a resumable capture, the resume, and the web page
# switched on as the guide says (its token readable by the group only).
#
# Usage: bash scripts/vm-systemd-test.sh
# Needs: root or password-less sudo (the guest's files keep their owners),
# qemu-system-x86, mmdebstrap, cpio (scripts/setup.sh), and Debian's mirror
# the first time.
set -euo pipefail
cd "$(dirname "$0")/.."
me=vm-systemd-test root="$PWD" vm="$PWD/target/vm"
. "$root/scripts/vm/common.sh"
t0=$(date +%s)
vm_need qemu-system-x86_64 cpio mmdebstrap strip
# Building the guest's root needs root (its files keep their owners): as
# root, or through sudo without a password.
SUDO=""
if [ "$(id -u)" != 0 ]; then
  if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then SUDO="sudo -n"; else
    echo "vm-systemd-test: needs root (or sudo) to build the guest's root file system" >&2; exit 1
  fi
fi

# 1. The kernel.
vm_kernel

# 2. The guest's Debian root, once: this machine's release (so that the
#    binaries built here find the same C library), minbase plus systemd as
#    init, without documentation. Kept as an initramfs archive.
suite=$(. /etc/os-release && echo "${VERSION_CODENAME:-}")
[ -n "$suite" ] || { echo "vm-systemd-test: /etc/os-release names no release" >&2; exit 1; }
base="$vm/systemd-root-$suite.cpio.gz"
if [ ! -s "$base" ]; then
  tmp="$vm/systemd-root.tmp"
  $SUDO rm -rf "$tmp"
  echo "vm-systemd-test: building the guest's Debian $suite root with mmdebstrap (once)" >&2
  $SUDO mmdebstrap --quiet --variant=minbase --include=systemd-sysv,passwd \
    --dpkgopt='path-exclude=/usr/share/doc/*' --dpkgopt='path-exclude=/usr/share/man/*' \
    --dpkgopt='path-exclude=/usr/share/locale/*' "$suite" "$tmp" >"$vm/mmdebstrap.log" 2>&1 || {
    echo "vm-systemd-test: mmdebstrap failed:" >&2; tail -20 "$vm/mmdebstrap.log" >&2; exit 1; }
  (cd "$tmp" && $SUDO sh -c 'find . | cpio -o -H newc --quiet' | gzip -1) >"$base.tmp"
  mv "$base.tmp" "$base"
  $SUDO rm -rf "$tmp"
fi

# 3. What the test adds: the binaries (debug information stripped), the
#    unit, the simulated rig's calibration made here under the name the
#    service will look for, the guest script and the unit that runs it once
#    the system is up.
cargo build --quiet -p reflectometer-cli --bin capture --bin refl
ov="$vm/systemd-overlay"
rm -rf "$ov"
src="$ov/root/reflectometer"
mkdir -p "$src" "$ov/tests" "$ov/etc/systemd/system/multi-user.target.wants"
for b in refl capture; do strip --strip-debug -o "$src/$b" "$root/target/debug/$b"; done
cp "$root/udev/reflectometer.service" "$src/"
data="$vm/systemd-data"
rm -rf "$data"
REFLECTOMETER_DATA="$data" "$root/target/debug/capture" --no-daemon --calibrate all >"$vm/systemd-calib.log" 2>&1 \
  || { echo "vm-systemd-test: the simulated rig's calibration failed:" >&2; tail -20 "$vm/systemd-calib.log" >&2; exit 1; }
cp -r "$data/calibration" "$src/"
cp "$root/scripts/vm/guest-systemd.sh" "$ov/tests/systemd.sh"
cat >"$ov/etc/systemd/system/refl-vm-test.service" <<'EOF'
[Unit]
Description=reflectometer service test (scripts/vm/guest-systemd.sh)
After=multi-user.target

[Service]
Type=oneshot
ExecStart=/bin/bash /tests/systemd.sh
StandardOutput=journal+console
StandardError=journal+console
EOF
ln -s ../refl-vm-test.service "$ov/etc/systemd/system/multi-user.target.wants/refl-vm-test.service"
# The kernel unpacks concatenated archives in order, the later over the
# earlier; every file of this one is root's, whoever runs the script.
(cd "$ov" && find . -mindepth 1 | cpio -o -H newc -R 0:0 --quiet | gzip -1) | cat "$base" - >"$vm/systemd-initrd.gz"
t1=$(date +%s)

# 4. Boot it. The guest powers off when its script ends.
log="$vm/systemd-console.log"
echo "vm-systemd-test: booting Debian $suite with systemd under QEMU (TCG); console in $log" >&2
vm_boot "$vm/systemd-initrd.gz" "rdinit=/sbin/init systemd.show_status=0 systemd.mask=serial-getty@ttyS0.service" "$log"
t2=$(date +%s)
grep -a "vm: " "$log" | sed 's/\r$//' >&2 || true
echo "vm-systemd-test: prepared in $((t1 - t0)) s, guest ran $((t2 - t1)) s (qemu exit $qemu_rc)" >&2
vm_guest_part "$log" systemd "the daemon under systemd"
