#!/bin/sh
# Runs inside the vm-test guest (busybox sh), after the vivid tests: the
# hardware capture path end to end with real device drivers. The emulated
# microcontroller answers on a pseudo-terminal as a rig's would on its USB
# serial port, the camera is vivid's /dev/video0, and `capture` runs with a
# hardware rig file (/etc/vivid-rig.toml) exactly as on a rig PC: dark scan,
# then a small capture and its fit. vivid's picture does not respond to the
# LEDs, so this checks the plumbing (protocol, V4L2 streaming and controls,
# frame timing, storage, fitting of what arrives), not reflectance. The
# white calibration comes from the simulated rig with the same geometry
# (vm-test.sh makes it on the host).
# Prints "vm: capture exit=N" last.
set -u
fail() {
  echo "vm: capture check failed: $*"
  echo "vm: capture exit=1"
  exit 1
}
refl sim-mcu --link /tmp/mcu >/tmp/mcu.log 2>&1 &
mcu=$!
i=0
while [ ! -e /tmp/mcu ]; do
  i=$((i + 1))
  [ $i -lt 100 ] || fail "the emulated MCU did not start: $(cat /tmp/mcu.log)"
  sleep 0.1
done
rig=/etc/vivid-rig.toml
calib=/etc/vivid-calib
# No lens cap on vivid: its colour bars must be reported as a light leak.
capture --rig $rig --calib-dir $calib --calibrate dark >/tmp/dark.log 2>&1 || fail "capture --calibrate dark exited $?: $(tail -5 /tmp/dark.log)"
cat /tmp/dark.log
grep -q "dark frames are not uniform" /tmp/dark.log || fail "a picture was taken for dark frames without a warning"
# The geometric scan on the hardware path as far as vivid allows: it
# connects, homes, sets the camera to the scan's exposure, and then needs
# an operator to place the target; with no terminal it must refuse, saying
# so, and save nothing.
saved=$(find $calib -name '*.json' | wc -l)
capture --rig $rig --calib-dir $calib --calibrate geometry </dev/null >/tmp/geometry.log 2>&1 \
  && fail "the geometric scan ran with no operator: $(tail -5 /tmp/geometry.log)"
grep -q "needs an operator at the rig" /tmp/geometry.log \
  || fail "the geometric scan did not say it needs an operator: $(tail -5 /tmp/geometry.log)"
[ "$(find $calib -name '*.json' | wc -l)" = "$saved" ] || fail "a refused geometric scan saved a calibration"
echo "vm: the geometric scan refused without an operator, nothing saved"
capture --rig $rig --calib-dir $calib --sample vivid-bars --out /tmp/cap \
  --quality fast --steps 4 --led-stride 10 --grid 8 || fail "capture exited $?"
kill $mcu
info=/tmp/cap/capture.json
[ -f $info ] || fail "no capture.json"
grep -q '"status": *"complete"' $info || fail "capture.json is not complete: $(head -c 600 $info)"
grep -q '"format": *"Y16"' $info || fail "the camera did not stream Y16: $(grep -A3 '"camera"' $info)"
grep -q '"bit_depth": *16' $info || fail "the sensor is not recorded as 16-bit"
grep -q '"e_per_dn": *0.5' $info || fail "e_per_dn is not the rig file's"
! grep -q '"simulated": *{' $info || fail "a hardware capture is recorded as simulated"
# 4 steps x 4 LEDs and the fast preset's dark frames.
shots=$(ls /tmp/cap/frames | grep -c '^s')
[ "$shots" = 16 ] || fail "expected 16 shot frames, found $shots: $(ls /tmp/cap/frames | head)"
[ -d /tmp/cap/material ] || fail "no material was fitted"
grep -q '"simulated": *false' /tmp/cap/report.json || fail "report.json does not say hardware"
echo "vm: capture stored $shots shots from /dev/video0 and fitted them"
echo "vm: capture exit=0"
