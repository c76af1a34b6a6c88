# Sourced by the QEMU tiers (scripts/vm-test.sh, scripts/vm-systemd-test.sh):
# `vm_kernel DIR` unpacks Debian's current kernel package into DIR once (not
# installed) and sets `pkg` (the package), `kroot` (its root), `kver` (its
# release) and `kernel` (the image to boot).
vm_kernel() {
  local vm="$1"
  pkg=$(apt-cache depends linux-image-amd64 2>/dev/null | awk '/Depends: linux-image-[0-9]/ && !found {print $2; found = 1}')
  if [ -z "$pkg" ]; then
    echo "vm: apt does not know linux-image-amd64; run 'apt-get update' (scripts/setup.sh does)" >&2
    return 1
  fi
  kroot="$vm/$pkg"
  if [ ! -d "$kroot/boot" ]; then
    rm -rf "$kroot.tmp" && mkdir -p "$kroot.tmp"
    (cd "$kroot.tmp" && apt-get download "$pkg" >/dev/null 2>&1) || {
      echo "vm: could not download $pkg" >&2; return 1; }
    dpkg-deb -x "$kroot.tmp"/*.deb "$kroot.tmp/root"
    mv "$kroot.tmp/root" "$kroot" && rm -rf "$kroot.tmp"
  fi
  kver=$(ls "$kroot/lib/modules")
  [ -f "$kroot/lib/modules/$kver/modules.dep" ] || depmod -b "$kroot" "$kver"
  kernel="$kroot/boot/vmlinuz-$kver"
}
