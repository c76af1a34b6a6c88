#!/bin/bash
# The capture daemon under systemd, in scripts/vm-systemd-test.sh's guest (a
# small Debian root booted with systemd as PID 1). It follows
# udev/README.md's steps 1 and 6 as written, on the simulated rig (no rig
# file; its calibration was made on the host, under the name the daemon
# looks for). Then: the service is ready by sd_notify and its watchdog
# pinged, an operator (alice) in the service's group captures through the socket,
# a user outside it is refused, `systemctl stop` mid-capture is honoured
# within the unit's TimeoutStopSec and leaves a resumable capture, the
# restarted service resumes it, and the web page switched on as the guide's
# section says keeps its token to the group. Prints "vm: systemd exit=N"
# and powers off.
set -u
src=/root/reflectometer
caps=/var/lib/reflectometer/captures
say() { echo "vm: systemd: $*"; }
finish() {
  echo "vm: systemd exit=$1"
  systemctl --no-block poweroff
  exit "$1"
}
fail() {
  say "FAILED: $*"
  journalctl -u reflectometer --no-pager -o short-monotonic | tail -40
  finish 1
}
prop() { systemctl show -p "$1" --value reflectometer; }
uptime_s() { cut -d' ' -f1 /proc/uptime; }
# A small fast capture of the white sample as user $1 (in their home
# directory), with the further arguments (--out, --steps).
capture_as() {
  user=$1
  shift
  (cd "/home/$user" && runuser -u "$user" -- capture --sample white --quality fast --grid 8 --camera-px 48 \
    --no-fit "$@")
}
say "booted by $(readlink -f /proc/1/exe) at $(uptime_s) s"

# udev/README.md step 1: the binaries.
install -m 755 "$src/refl" "$src/capture" /usr/local/bin/ || fail "installing the binaries"
# Step 6: the service's user, an operator (alice) in its group, a user outside it (bob), the unit.
useradd --system --groups dialout,video reflectometer || fail "useradd reflectometer"
useradd --create-home --groups reflectometer alice || fail "useradd alice"
useradd --create-home bob || fail "useradd bob"
install -m 644 "$src/reflectometer.service" /etc/systemd/system/ || fail "installing the unit"
# The simulated rig's calibration, where the service's data directory keeps it.
install -d -o reflectometer -g reflectometer -m 755 /var/lib/reflectometer "$caps"
cp -r "$src/calibration" /var/lib/reflectometer/ && chown -R reflectometer:reflectometer /var/lib/reflectometer \
  || fail "installing the calibration"
systemctl daemon-reload || fail "daemon-reload"
# Type=notify: this returns once the daemon has sent READY=1.
systemctl enable --now reflectometer || fail "systemctl enable --now reflectometer"
started=$(uptime_s)
[ "$(prop ActiveState)" = active ] || fail "the service is $(prop ActiveState) after start"
[ "$(prop StatusText)" = idle ] || fail "the service's status is '$(prop StatusText)', not idle"
say "active at $started s, status '$(prop StatusText)', watchdog $(prop WatchdogUSec), stop timeout $(prop TimeoutStopUSec)"
pid0=$(prop MainPID)
wd0=$(prop WatchdogTimestampMonotonic)
[ "$(stat -c '%U %G %a' /run/reflectometer)" = "reflectometer reflectometer 750" ] \
  || fail "runtime directory: $(stat -c '%U %G %a' /run/reflectometer)"
[ "$(stat -c '%U %G %a' /run/reflectometer/daemon.sock)" = "reflectometer reflectometer 660" ] \
  || fail "socket: $(stat -c '%U %G %a' /run/reflectometer/daemon.sock)"

# The operator's capture goes through the service (and is written by it).
capture_as alice --out "$caps/op-1" --steps 4 >/tmp/op-1.log 2>&1
rc=$?
cat /tmp/op-1.log
[ "$rc" = 0 ] || fail "the operator's capture exited $rc"
grep -q "handing the job to the daemon on /run/reflectometer/daemon.sock" /tmp/op-1.log \
  || fail "the operator's capture did not go through the service"
[ "$(stat -c %U "$caps/op-1/manifest.jsonl")" = reflectometer ] || fail "op-1 was not written by the service"
say "operator's capture through the socket: exit 0, $(wc -l <"$caps/op-1/manifest.jsonl") frames"
runuser -u alice -- refl daemon --status >/tmp/status.json 2>&1 || fail "refl daemon --status: $(cat /tmp/status.json)"
grep -q '"busy":null' /tmp/status.json || fail "status after the capture: $(cat /tmp/status.json)"

# A directory the service may not write (the operator's home) is refused
# before anything is taken, and so is the default, beside the operator.
capture_as alice --steps 4 --out /home/alice/mine >/tmp/home.log 2>&1
rc=$?
cat /tmp/home.log
[ "$rc" = 2 ] || fail "a capture into the operator's home exited $rc, not 2 (refused)"
grep -q "the capture daemon writes the capture as reflectometer" /tmp/home.log \
  || fail "the refusal of the operator's home does not say why"
[ ! -e /home/alice/mine ] || fail "the refused capture left /home/alice/mine"
capture_as alice --steps 4 >/tmp/default.log 2>&1
rc=$?
cat /tmp/default.log
[ "$rc" = 2 ] && grep -q -- "--out DIR" /tmp/default.log || fail "a capture without --out: exit $rc"
say "into the operator's home, and with no --out: refused (exit 2), saying why"

# A user outside the group is refused, and nothing runs in-process.
capture_as bob --out "$caps/out-1" --steps 4 >/tmp/out-1.log 2>&1
rc=$?
cat /tmp/out-1.log
[ "$rc" != 0 ] || fail "the outsider's capture was not refused"
grep -q "not open to you" /tmp/out-1.log || fail "the outsider's refusal does not say why"
[ ! -e "$caps/out-1" ] || fail "the outsider's refused capture left $caps/out-1"
say "outsider (bob) refused: exit $rc"

# The watchdog: systemd saw pings (the daemon pings at half of WatchdogSec)
# and did not restart the service. Wait for two ping periods.
period=$(($(prop WatchdogUSec | sed 's/s$//') + 2))
now=$(uptime_s)
wait_s=$(awk -v s="$started" -v n="$now" -v p="$period" 'BEGIN { w = s + p - n; print (w > 0 ? int(w) + 1 : 0) }')
sleep "$wait_s"
wd1=$(prop WatchdogTimestampMonotonic)
[ "$(prop ActiveState)" = active ] || fail "the service is $(prop ActiveState) after $period s"
[ "$(prop MainPID)" = "$pid0" ] && [ "$(prop NRestarts)" = 0 ] || fail "the service was restarted (pid $pid0 -> $(prop MainPID))"
[ "$wd1" -gt "$wd0" ] || fail "no watchdog ping seen by systemd ($wd0 -> $wd1)"
say "watchdog: last ping at $((wd1 / 1000000)) s (first $((wd0 / 1000000)) s), pid $pid0, no restart"

# systemctl stop mid-capture: honoured within TimeoutStopSec, the capture
# left interrupted and resumable.
capture_as alice --out "$caps/op-2" --steps 16 >/tmp/op-2.log 2>&1 &
client=$!
i=0
while [ "$(cat "$caps/op-2/manifest.jsonl" 2>/dev/null | wc -l)" -lt 20 ]; do
  i=$((i + 1))
  [ "$i" -lt 600 ] || fail "op-2 stored no frames in 60 s: $(cat /tmp/op-2.log)"
  sleep 0.1
done
t_stop=$(uptime_s)
systemctl stop reflectometer
t_stopped=$(uptime_s)
wait "$client"
rc=$?
cat /tmp/op-2.log
took=$(awk -v a="$t_stop" -v b="$t_stopped" 'BEGIN { printf "%.1f", b - a }')
limit=$(prop TimeoutStopUSec | sed 's/s$//')
[ "$(prop Result)" = success ] || fail "systemctl stop: result $(prop Result)"
awk -v t="$took" -v l="$limit" 'BEGIN { exit !(t < l) }' || fail "stopping took $took s, the unit allows $limit s"
grep -q '"status": *"interrupted"' "$caps/op-2/capture.json" || fail "op-2 is not marked interrupted"
frames=$(wc -l <"$caps/op-2/manifest.jsonl")
say "systemctl stop at $t_stop s mid-capture ($frames frames): stopped in $took s (limit $limit s), result success, client exit $rc, capture interrupted"

# The service back, the operator resumes the capture through it.
systemctl start reflectometer || fail "systemctl start"
runuser -u alice -- capture --resume "$caps/op-2" >/tmp/op-2r.log 2>&1
rc=$?
tail -5 /tmp/op-2r.log
[ "$rc" = 0 ] || fail "the resumed capture exited $rc"
grep -q '"status": *"complete"' "$caps/op-2/capture.json" || fail "op-2 is not complete after the resume"
say "resumed through the restarted service: $(wc -l <"$caps/op-2/manifest.jsonl") frames, complete"

# The guide's web page, step 2: `--http` by a drop-in that clears
# ExecStart (what `systemctl edit` writes), and a restart.
mkdir -p /etc/systemd/system/reflectometer.service.d
printf '[Service]\nExecStart=\nExecStart=/usr/local/bin/refl daemon --http\n' \
  >/etc/systemd/system/reflectometer.service.d/override.conf
systemctl daemon-reload && systemctl restart reflectometer || fail "restarting with --http"
token_file=/run/reflectometer/http-token
[ "$(stat -c '%U %G %a' "$token_file")" = "reflectometer reflectometer 640" ] \
  || fail "the page's token file: $(stat -c '%U %G %a' "$token_file")"
token=$(runuser -u alice -- cat "$token_file") || fail "the operator cannot read the page's token"
runuser -u bob -- cat "$token_file" >/dev/null 2>&1 && fail "the outsider can read the page's token"
journalctl -u reflectometer --no-pager | grep -q "$token" || fail "the page's token is not in the journal"
# http METHOD PATH [TOKEN]: the page's answer's status code.
http() {
  local auth=""
  [ -n "${3:-}" ] && auth="Authorization: Bearer $3"$'\r\n'
  exec 3<>/dev/tcp/127.0.0.1/8470 || return 1
  printf '%s %s HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\nContent-Length: 0\r\n%s\r\n' "$1" "$2" "$auth" >&3
  head -1 <&3 | cut -d' ' -f2
  exec 3<&-
}
[ "$(http GET /api/state)" = 200 ] || fail "GET /api/state: $(http GET /api/state)"
[ "$(http POST /api/cancel)" = 401 ] || fail "cancel without the token: $(http POST /api/cancel)"
[ "$(http POST /api/cancel not-the-token)" = 403 ] || fail "cancel with a wrong token: $(http POST /api/cancel not-the-token)"
[ "$(http POST /api/cancel "$token")" = 200 ] || fail "cancel with the token: $(http POST /api/cancel "$token")"
say "web page on 127.0.0.1:8470: state 200; cancel 401 without the token, 403 with a wrong one, 200 with the group's"
finish 0
