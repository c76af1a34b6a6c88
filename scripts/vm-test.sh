#!/usr/bin/env bash
# The V4L2 tests against a real kernel driver.
#
# This machine's kernel has no V4L2, so the tests run in a QEMU guest under
# software emulation (TCG): Debian's stock kernel (unpacked from its .deb,
# not installed), a busybox initramfs, and the kernel's `vivid` test driver,
# which gives a real /dev/video0 with GREY, Y16, Bayer and YUYV formats,
# error-flagged buffers and disconnects on demand. The guest runs the
# `vivid` test target of crates/rig (`test = false`: not run by `cargo test`),
# then the hardware capture path end to end (scripts/vm/guest-capture.sh:
# `capture` with a hardware rig file, the emulated MCU on a pseudo-terminal,
# vivid as the camera; the geometric scan up to its first prompt), then the
# rig PC's USB serial path (scripts/vm/guest-usb.sh: udevd with the shipped
# rules, a g_serial gadget on dummy_hcd as the microcontroller's port, a
# clean capture, a real unplug and replug mid-capture, and one that never
# comes back), and prints the three exit statuses; anything else, a guest
# that does not boot included, fails this script.
#
# Usage: bash scripts/vm-test.sh [extra test-binary arguments, e.g. a filter]
# Needs: qemu-system-x86, busybox-static, cpio, kmod (scripts/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
me=vm-test root="$PWD" vm="$PWD/target/vm"
. "$root/scripts/vm/common.sh"
t0=$(date +%s)
vm_need qemu-system-x86_64 cpio depmod modprobe
busybox=/bin/busybox
if [ ! -x "$busybox" ] || ldd "$busybox" >/dev/null 2>&1; then
  echo "vm-test: a static busybox is missing (Debian busybox-static); run scripts/setup.sh" >&2; exit 1
fi

# 1. Debian's current kernel package, unpacked once into target/vm.
vm_kernel

# 2. The test binary, built for this machine (the guest runs the same
#    x86_64 code with this machine's shared libraries copied in).
exe=$(cargo test -p rig --test vivid --no-run --message-format=json 2>/dev/null \
  | grep -o '"executable":"[^"]*"' | tail -1 | cut -d'"' -f4)
[ -x "$exe" ] || { echo "vm-test: building the vivid test binary failed:" >&2; cargo test -p rig --test vivid --no-run >&2; exit 1; }
cargo build --quiet -p reflectometer-cli --bin capture --bin refl
bins="$root/target/debug/capture $root/target/debug/refl"

# The guest capture's white calibration, made on the simulated twin of its
# hardware rig file (vivid's picture does not respond to the LEDs).
rigfile="$root/scripts/vm/vivid-rig.toml"
rm -rf "$vm/vivid-calib"
sed 's/^kind = "hardware"/kind = "sim"/' "$rigfile" >"$vm/vivid-sim.toml"
"$root/target/debug/capture" --rig "$vm/vivid-sim.toml" --calib-dir "$vm/vivid-calib" --calibrate white \
  --sim-rig ideal >"$vm/vivid-calib.log" 2>&1 \
  || { echo "vm-test: the simulated calibration failed:" >&2; tail -20 "$vm/vivid-calib.log" >&2; exit 1; }
# A simulated rig keeps its calibrations under its name and which simulated
# rig it is; the hardware rig looks under its name alone.
name=$(sed -n 's/^name *= *"\(.*\)"/\1/p' "$rigfile")
mv "$vm/vivid-calib/$name-ideal" "$vm/vivid-calib/$name"

# udevd for the USB serial part (scripts/vm/guest-usb.sh): Debian's udev
# and the systemd library it links, unpacked once into target/vm.
uroot="$vm/udev-root"
if [ ! -x "$uroot/bin/udevadm" ]; then
  rm -rf "$uroot.tmp" && mkdir -p "$uroot.tmp"
  (cd "$uroot.tmp" && apt-get download udev libsystemd-shared >/dev/null 2>&1) || {
    echo "vm-test: could not download udev" >&2; exit 1; }
  for d in "$uroot.tmp"/*.deb; do dpkg-deb -x "$d" "$uroot.tmp/root"; done
  mv "$uroot.tmp/root" "$uroot" && rm -rf "$uroot.tmp"
fi

# 3. The initramfs: busybox, the test binary, capture and refl and their
#    libraries, the rig file and calibration, vivid and the modules it
#    depends on (in load order), and /init.
ird="$vm/initramfs"
rm -rf "$ird" && mkdir -p "$ird"/{bin,dev,proc,sys,tmp,run,modules,modules-usb,tests,etc/udev/rules.d,lib/udev/rules.d,lib/systemd}
cp "$busybox" "$ird/bin/busybox"
cp "$exe" "$ird/tests/vivid"
cp $bins "$ird/bin/"
cp "$root/scripts/vm/guest-capture.sh" "$ird/tests/capture.sh"
cp "$root/scripts/vm/guest-usb.sh" "$ird/tests/usb.sh"
cp "$rigfile" "$ird/etc/vivid-rig.toml"
# The same rig reached as a rig PC reaches it: through the udev links.
sed -e 's#^path = .*#path = "/dev/reflectometer/mcu"#' -e 's#^device = "/dev/video0"#device = "/dev/reflectometer/camera"#' \
  "$rigfile" >"$ird/etc/usb-rig.toml"
cp -r "$vm/vivid-calib" "$ird/etc/vivid-calib"
# udevd, with the shipped rules, Debian's defaults for ttys, and a rule
# that names vivid (a platform device: no USB ids) as the rig's camera.
cp "$uroot/bin/udevadm" "$ird/bin/udevadm"
ln -s /bin/udevadm "$ird/lib/systemd/systemd-udevd"
ushared=$(ls "$uroot"/usr/lib/x86_64-linux-gnu/systemd/libsystemd-shared-*.so)
mkdir -p "$ird/usr/lib/x86_64-linux-gnu/systemd" && cp "$ushared" "$ird/usr/lib/x86_64-linux-gnu/systemd/"
cp "$uroot"/lib/udev/rules.d/{50-udev-default,60-serial}.rules "$ird/lib/udev/rules.d/"
cp "$root/udev/70-reflectometer.rules" "$ird/etc/udev/rules.d/"
cat >"$ird/etc/udev/rules.d/71-vivid-camera.rules" <<'EOF'
# The test's camera: vivid's capture node, linked as the shipped rule links a USB camera.
SUBSYSTEM=="video4linux", ATTR{name}=="vivid-000-vid-cap", SYMLINK+="reflectometer/camera", GROUP="video", MODE="0660"
EOF
printf 'root:x:0:0:root:/tmp:/bin/sh\n' >"$ird/etc/passwd"
printf 'root:x:0:\ndialout:x:20:\nvideo:x:44:\n' >"$ird/etc/group"
for lib in $(LD_LIBRARY_PATH="$(dirname "$ushared")" ldd "$exe" $bins "$uroot/bin/udevadm" | grep -v ':$' \
  | grep -o '/[^ ]*' | grep -v '/systemd/libsystemd-shared' | sort -u); do
  mkdir -p "$ird$(dirname "$lib")" && cp -L "$lib" "$ird$lib"
done
i=0
modprobe -d "$kroot" -S "$kver" --show-depends vivid | awk '/^insmod/{print $2}' | while read -r ko; do
  i=$((i + 1))
  name=$(basename "$ko")
  case "$ko" in
    *.xz) xz -dc "$ko" >"$ird/modules/$(printf %02d $i)-${name%.xz}" ;;
    *.zst) zstd -dqc "$ko" >"$ird/modules/$(printf %02d $i)-${name%.zst}" ;;
    *) cp "$ko" "$ird/modules/$(printf %02d $i)-$name" ;;
  esac
done
ls "$ird"/modules/*vivid.ko >/dev/null 2>&1 || { echo "vm-test: vivid.ko not found in $pkg" >&2; exit 1; }
# The USB serial link, loaded by guest-usb.sh once udevd runs: the dummy
# host and device controllers, the ACM function and the g_serial gadget
# (the device side, /dev/ttyGS0), and the host's CDC-ACM driver (/dev/ttyACM*).
# usb_f_acm is asked for by name at run time, so it is listed before g_serial.
i=0
for m in dummy_hcd usb_f_acm g_serial cdc_acm; do
  modprobe -d "$kroot" -S "$kver" --show-depends "$m" | awk '/^insmod/{print $2}'
done | awk '!seen[$0]++' | while read -r ko; do
  i=$((i + 1))
  name=$(basename "$ko")
  case "$ko" in
    *.xz) xz -dc "$ko" >"$ird/modules-usb/$(printf %02d $i)-${name%.xz}" ;;
    *.zst) zstd -dqc "$ko" >"$ird/modules-usb/$(printf %02d $i)-${name%.zst}" ;;
    *) cp "$ko" "$ird/modules-usb/$(printf %02d $i)-$name" ;;
  esac
done
ls "$ird"/modules-usb/*g_serial.ko >/dev/null 2>&1 || { echo "vm-test: g_serial.ko not found in $pkg" >&2; exit 1; }
# One capture node, one webcam input: the camera the tests drive.
vivid_opts="n_devs=1 node_types=0x1 num_inputs=1 input_types=0x0"
cat >"$ird/init" <<EOF
#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
mkdir -p /dev/pts && mount -t devpts devpts /dev/pts
mount -t tmpfs tmp /tmp
for m in /modules/*.ko; do
  case "\$m" in *vivid.ko) insmod "\$m" $vivid_opts ;; *) insmod "\$m" ;; esac || echo "vm: insmod \$m failed"
done
echo "vm: booted \$(uname -r); \$(ls /dev/video* 2>/dev/null | tr '\n' ' ')"
export HOME=/tmp RUST_BACKTRACE=1 REFL_VIVID_REPLUG=/bin/vivid-replug
/tests/vivid --test-threads=1 --nocapture $*
echo "vm: vivid tests exit=\$?"
sh /tests/capture.sh
sh /tests/usb.sh
poweroff -f
EOF
cat >"$ird/bin/vivid-replug" <<EOF
#!/bin/sh
# Unplug and plug the vivid camera again (after its Disconnect control).
rmmod vivid || exit 1
insmod /modules/*vivid.ko $vivid_opts
EOF
chmod +x "$ird/init" "$ird/bin/vivid-replug"
(cd "$ird" && find . | cpio -o -H newc --quiet | gzip -1) >"$vm/initramfs.gz"
t1=$(date +%s)

# 4. Boot it. No KVM here: TCG. The guest powers off when the tests end.
log="$vm/console.log"
echo "vm-test: booting $pkg under QEMU (TCG) with vivid; console in $log" >&2
vm_boot "$vm/initramfs.gz" "rdinit=/init" "$log"
t2=$(date +%s)
grep -aE "vm:|^(test |running|test result|failures|----|thread|vivid|applied)|ERROR|WARN" "$log" | sed 's/\r$//' >&2 || true
status=$(sed -n 's/.*vm: vivid tests exit=\([0-9]*\).*/\1/p' "$log" | tr -d '\r' | tail -1)
echo "vm-test: prepared in $((t1 - t0)) s, guest ran $((t2 - t1)) s (qemu exit $qemu_rc)" >&2
if ! grep -aq "vm: booted" "$log"; then
  echo "vm-test: FAILED: the guest did not boot; see $log" >&2
  tail -30 "$log" >&2
  exit 1
fi
if [ -z "$status" ]; then
  echo "vm-test: FAILED: the tests did not finish in the guest; see $log" >&2
  tail -30 "$log" >&2
  exit 1
fi
if [ "$status" != 0 ]; then
  echo "vm-test: FAILED: the vivid tests failed in the guest (exit $status)" >&2
  exit 1
fi
if ! grep -aq "test result: ok" "$log" || grep -aq "test result: ok. 0 passed" "$log"; then
  echo "vm-test: FAILED: no vivid test ran" >&2
  exit 1
fi
echo "vm-test: V4L2 tests passed against vivid" >&2
vm_guest_part "$log" capture "the hardware capture with vivid and the emulated MCU"
vm_guest_part "$log" usb "the capture through udevd's links and the kernel's CDC-ACM driver (USB gadget), unplugged and replugged"
