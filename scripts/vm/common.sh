# Sourced by the QEMU tiers (scripts/vm-test.sh, scripts/vm-systemd-test.sh)
# after they set `me` (their name, for messages), `root` (the checkout) and
# `vm` (target/vm, created here).
mkdir -p "$vm"

# vm_need TOOL...: each tool is on PATH (sbin included), or say what to run.
vm_need() {
  local tool
  for tool in "$@"; do
    command -v "$tool" >/dev/null 2>&1 || PATH="$PATH:/usr/sbin:/sbin"
    command -v "$tool" >/dev/null 2>&1 || { echo "$me: $tool is missing; run scripts/setup.sh" >&2; return 1; }
  done
}

# vm_kernel: unpack Debian's current kernel package into $vm once (not
# installed) and set `pkg` (the package), `kroot` (its root), `kver` (its
# release) and `kernel` (the image to boot).
vm_kernel() {
  pkg=$(apt-cache depends linux-image-amd64 2>/dev/null | awk '/Depends: linux-image-[0-9]/ && !found {print $2; found = 1}')
  if [ -z "$pkg" ]; then
    echo "$me: apt does not know linux-image-amd64; run 'apt-get update' (scripts/setup.sh does)" >&2
    return 1
  fi
  kroot="$vm/$pkg"
  if [ ! -d "$kroot/boot" ]; then
    rm -rf "$kroot.tmp" && mkdir -p "$kroot.tmp"
    (cd "$kroot.tmp" && apt-get download "$pkg" >/dev/null 2>&1) || {
      echo "$me: could not download $pkg" >&2; return 1; }
    dpkg-deb -x "$kroot.tmp"/*.deb "$kroot.tmp/root"
    mv "$kroot.tmp/root" "$kroot" && rm -rf "$kroot.tmp"
  fi
  kver=$(ls "$kroot/lib/modules")
  [ -f "$kroot/lib/modules/$kver/modules.dep" ] || depmod -b "$kroot" "$kver"
  kernel="$kroot/boot/vmlinuz-$kver"
}

# vm_boot INITRD APPEND LOG: boot $kernel with INITRD under TCG (no KVM
# here), its console in LOG, until the guest powers off (at most 15
# minutes); sets `qemu_rc`.
vm_boot() {
  set +e
  timeout 900 qemu-system-x86_64 -accel tcg -cpu max -m 2048 -smp 1 -nographic -no-reboot -nic none \
    -kernel "$kernel" -initrd "$1" -append "console=ttyS0 panic=-1 quiet loglevel=4 $2" >"$3" 2>&1
  qemu_rc=$?
  set -e
}

# vm_guest_part LOG NAME WHAT: the guest script NAME printed
# "vm: NAME exit=0" in LOG; otherwise say so with the log's tail and fail.
vm_guest_part() {
  local status
  status=$(sed -n "s/.*vm: $2 exit=\([0-9]*\).*/\1/p" "$1" | tr -d '\r' | tail -1)
  if [ "$status" != 0 ]; then
    echo "$me: FAILED: $3 failed in the guest (exit ${status:-none}); see $1" >&2
    tail -40 "$1" >&2
    exit 1
  fi
  echo "$me: $3 passed" >&2
}
