#!/bin/sh
# Runs inside the vm-test guest (busybox sh), after guest-capture.sh: the
# rig PC's serial path on real kernel drivers. udevd runs with the shipped
# udev/70-reflectometer.rules; a USB gadget (the kernel's g_serial on the
# dummy_hcd controller, enumerating with the rig's vendor and product ids)
# is the microcontroller's USB serial port: the emulated MCU answers on its
# device side (/dev/ttyGS0), and the host side is a real /dev/ttyACM* made
# by the CDC-ACM driver, which the rule links as /dev/reflectometer/mcu.
# `capture` runs with a hardware rig file that names only the udev links,
# once cleanly and once with the gadget unplugged mid-capture and plugged
# in again. Prints the unplug's timeline and "vm: usb exit=N" last.
set -u
fail() {
  echo "vm: usb check failed: $*"
  echo "vm: usb exit=1"
  exit 1
}
# The ids the shipped rule matches for the MCU (its tty rule's first line).
ids=$(grep -A1 '^SUBSYSTEM=="tty"' /etc/udev/rules.d/70-reflectometer.rules \
  | sed -n 's/.*ATTRS{idVendor}=="\([0-9a-f]*\)", ATTRS{idProduct}=="\([0-9a-f]*\)".*/\1 \2/p' | head -1)
set -- $ids
[ $# = 2 ] || fail "no USB ids for the MCU in 70-reflectometer.rules"
vendor=$1
product=$2
gadget_ids="idVendor=0x$vendor idProduct=0x$product iProduct=reflectometer-mcu"
mkdir -p /run/udev
/lib/systemd/systemd-udevd --daemon || fail "udevd did not start"
udevadm trigger --action=add
udevadm settle --timeout=60
for m in /modules-usb/*.ko; do
  case "$m" in
    *g_serial.ko) insmod "$m" $gadget_ids ;;
    *) insmod "$m" ;;
  esac || fail "insmod $m"
done
udevadm settle --timeout=60
i=0
while [ ! -e /dev/reflectometer/mcu ]; do
  i=$((i + 1))
  [ $i -lt 100 ] || fail "no /dev/reflectometer/mcu: $(ls -l /dev/ttyACM* /dev/ttyGS* /dev/reflectometer 2>&1)"
  sleep 0.1
done
mcu=$(readlink -f /dev/reflectometer/mcu)
case "$mcu" in /dev/ttyACM*) ;; *) fail "/dev/reflectometer/mcu points at $mcu, not a CDC-ACM tty" ;; esac
[ "$(cat /sys/class/tty/${mcu#/dev/}/device/../idVendor)" = "$vendor" ] || fail "$mcu is not the gadget"
[ "$(stat -c '%G %a' "$mcu")" = "dialout 660" ] || fail "$mcu is $(stat -c '%G %a' "$mcu"), not dialout 660"
cam=$(readlink -f /dev/reflectometer/camera)
[ "$cam" = /dev/video0 ] || fail "/dev/reflectometer/camera points at $cam"
[ "$(stat -c '%G %a' "$cam")" = "video 660" ] || fail "$cam is $(stat -c '%G %a' "$cam"), not video 660"
echo "vm: udev linked /dev/reflectometer/mcu -> $mcu ($vendor:$product, group dialout, 0660) and /dev/reflectometer/camera -> $cam"
refl sim-mcu --device /dev/ttyGS0 >/tmp/usb-mcu.log 2>&1 &
sim=$!
rig=/etc/usb-rig.toml
calib=/etc/vivid-calib
settings="--quality fast --steps 8 --led-stride 10 --grid 8"
capture --rig $rig --calib-dir $calib --sample vivid-bars --out /tmp/usbcap $settings \
  || fail "capture through /dev/reflectometer/mcu exited $?"
info=/tmp/usbcap/capture.json
grep -q '"status": *"complete"' $info || fail "capture.json is not complete: $(head -c 600 $info)"
shots() { ls "$1/frames" | grep '^s' | sort; }
n=$(shots /tmp/usbcap | wc -l)
[ "$n" = 32 ] || fail "expected 32 shot frames, found $n"
link() { tr -d ' \n' <"$1/report.json" | grep -o '"link":{[^}]*}'; }
echo "vm: capture through the kernel's USB serial driver stored $n shots; $(link /tmp/usbcap)"

# A real unplug mid-capture: the gadget's module is removed (the host's
# /dev/ttyACM* vanishes as on a pulled cable, the board loses power) and
# loaded again 3 s later; the capture must recover through the udev link
# and end with the clean run's frames.
t() { cut -d' ' -f1 /proc/uptime; }
gadget=$(ls /modules-usb/*g_serial.ko)
# start_capture NAME: a capture into /tmp/NAME in the background ($cap),
# returning once it has stored 8 shots.
start_capture() {
  capture --rig $rig --calib-dir $calib --sample vivid-bars --out "/tmp/$1" $settings >"/tmp/$1.log" 2>&1 &
  cap=$!
  local i=0
  while [ "$(shots "/tmp/$1" 2>/dev/null | wc -l)" -lt 8 ]; do
    i=$((i + 1))
    [ $i -lt 600 ] || fail "the capture into /tmp/$1 took no frames: $(tail -5 "/tmp/$1.log")"
    sleep 0.1
  done
}
# plug: load the gadget again and wait for its udev link.
plug() {
  insmod "$gadget" $gadget_ids || fail "insmod g_serial again"
  local i=0
  while [ ! -e /dev/reflectometer/mcu ]; do
    i=$((i + 1))
    [ $i -lt 200 ] || fail "/dev/reflectometer/mcu did not come back"
    sleep 0.05
  done
}
start_capture unplug
echo "vm: unplug at $(t) s, after $(shots /tmp/unplug | wc -l) shots: rmmod g_serial"
rmmod g_serial || fail "rmmod g_serial"
while [ -e /dev/reflectometer/mcu ]; do sleep 0.05; done
echo "vm: node gone at $(t) s ($(ls /dev/ttyACM* 2>/dev/null | tr '\n' ' '))"
sleep 3
echo "vm: replugged at $(t) s"
plug
echo "vm: node back at $(t) s: /dev/reflectometer/mcu -> $(readlink -f /dev/reflectometer/mcu)"
wait $cap
rc=$?
echo "vm: capture ended at $(t) s, exit $rc"
grep -iE "lost|reconnect|unplug|retak|hom|recover" /tmp/unplug.log | sed 's/^/vm: capture log: /'
[ $rc = 0 ] || fail "the unplugged capture exited $rc: $(tail -10 /tmp/unplug.log)"
grep -q '"status": *"complete"' /tmp/unplug/capture.json || fail "the unplugged capture is not complete"
[ "$(shots /tmp/unplug)" = "$(shots /tmp/usbcap)" ] || fail "the unplugged capture's frames differ from the clean run's"
echo "vm: the unplugged capture recovered with the clean run's $n frames; $(link /tmp/unplug);" \
  "$(tr -d '\n' </tmp/unplug/report.json | grep -o '"recoveries": *\[[^]]*\]' | tr -s ' ')"

# An unplug that never ends: the capture gives up after the driver's
# reconnect time (15 s, PROTOCOL.md), says why, and leaves a capture that
# `--resume` finishes once the rig is back.
start_capture gone
t0=$(t)
rmmod g_serial || fail "rmmod g_serial"
echo "vm: unplugged for good at $t0 s"
wait $cap
rc=$?
echo "vm: the capture gave up at $(t) s, exit $rc: $(grep -i "disappeared" /tmp/gone.log | tail -1)"
[ $rc != 0 ] || fail "a capture whose rig never came back succeeded"
grep -q "did not come back within 15 s" /tmp/gone.log || fail "no clear message: $(tail -5 /tmp/gone.log)"
grep -q '"status": *"interrupted"' /tmp/gone/capture.json || fail "the abandoned capture is not resumable: $(head -c 300 /tmp/gone/capture.json)"
plug
capture --resume /tmp/gone --rig $rig --calib-dir $calib >/tmp/resume.log 2>&1 || fail "resume exited $?: $(tail -5 /tmp/resume.log)"
[ "$(shots /tmp/gone)" = "$(shots /tmp/usbcap)" ] || fail "the resumed capture's frames differ from the clean run's"
echo "vm: resumed once the rig was back: the clean run's $n frames"
kill $sim
echo "vm: usb exit=0"
