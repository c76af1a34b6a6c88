#!/usr/bin/env bash
# The fit spread over a real Slurm cluster: a controller (slurmctld) and one
# node (slurmd) on loopback, authenticated by their own munged, all started
# here as root with their state under target/slurm-test. A simulated
# capture is fitted whole (`refl fit`) and through deploy/slurm/submit.sh
# (an array of N tile tasks, then the merge once they succeed); the two
# materials must be the same, every file byte for byte but material.json's
# timings (scripts/same-material.py). Then the split is timed with 1 and 2
# tasks.
#
#   bash scripts/slurm-test.sh [--release] [--quality Q] [--keep]
#
# --release uses the release build (the figures in the README) instead of
# the debug build the test suite builds; --quality the capture's preset
# (default fast, a 48 x 48 grid); --keep leaves the daemons running and
# target/slurm-test in place. Needs root, or password-less sudo.
set -euo pipefail
cd "$(dirname "$0")/.."
profile=debug
quality=fast
keep=0
while [ $# -gt 0 ]; do
  case "$1" in
    --release) profile=release; shift ;;
    --quality) quality="$2"; shift 2 ;;
    --keep) keep=1; shift ;;
    *) sed -n 2,16p "$0" >&2; exit 2 ;;
  esac
done
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null || {
    echo "slurm-test: needs root (or password-less sudo) to run slurmctld, slurmd and munged" >&2; exit 1; }
  exec sudo -n --preserve-env=PATH,CARGO_HOME,RUSTUP_HOME bash "$0" "$@"
fi
for t in slurmctld slurmd munged sbatch squeue sinfo; do
  command -v "$t" >/dev/null 2>&1 || { echo "slurm-test: $t not found: run scripts/setup.sh" >&2; exit 1; }
done
if [ "$profile" = release ]; then
  cargo build --release --quiet -p reflectometer-cli --bin capture --bin refl
else
  cargo build --quiet -p reflectometer-cli --bin capture --bin refl
fi
bin="$PWD/target/$profile"
root="$PWD/target/slurm-test"
# A previous run's daemons, if --keep left them (their pid files say).
for d in slurmd slurmctld munged; do
  [ -f "$root/$d.pid" ] && kill "$(cat "$root/$d.pid")" 2>/dev/null || true
done
sleep 0.5
rm -rf "$root"
mkdir -p "$root"/{munge,state,spool,work}
chmod 700 "$root/munge"
daemons=()
stop_all() {
  if [ "$keep" = 0 ]; then
    for p in "${daemons[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
  fi
}
trap stop_all EXIT
fail() {
  echo "slurm-test: FAILED: $*" >&2
  for f in "$root"/*.log "$root"/work/*.log; do
    [ -f "$f" ] && { echo "--- $f" >&2; tail -n 30 "$f" >&2; }
  done
  exit 1
}

# munge: a fresh key, a daemon on our own socket (as root, hence --force).
dd if=/dev/urandom of="$root/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$root/munge/munge.key"
munged --force --key-file="$root/munge/munge.key" --socket="$root/munge/munge.socket" \
  --pid-file="$root/munged.pid" --log-file="$root/munged.log" --seed-file="$root/munge/seed" \
  || fail "munged did not start"
daemons+=("$(cat "$root/munged.pid")")

host="$(hostname -s)"
cpus="$(nproc)"
mem_mb="$(awk '/MemTotal/ { print int($2 / 1024 * 0.9) }' /proc/meminfo)"
export SLURM_CONF="$root/slurm.conf"
cat >"$SLURM_CONF" <<EOF
ClusterName=refltest
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=16817
SlurmdPort=16818
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$root/munge/munge.socket
CredType=cred/munge
StateSaveLocation=$root/state
SlurmdSpoolDir=$root/spool
SlurmctldPidFile=$root/slurmctld.pid
SlurmdPidFile=$root/slurmd.pid
SlurmctldLogFile=$root/slurmctld.log
SlurmdLogFile=$root/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/backfill
ReturnToService=2
MpiDefault=none
JobCompType=jobcomp/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
NodeName=refl1 NodeHostname=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=test Nodes=refl1 Default=YES MaxTime=INFINITE State=UP
EOF
slurmctld -c -i || fail "slurmctld did not start"
for _ in $(seq 50); do [ -s "$root/slurmctld.pid" ] && break; sleep 0.2; done
daemons+=("$(cat "$root/slurmctld.pid")")
slurmd -N refl1 || fail "slurmd did not start"
for _ in $(seq 50); do [ -s "$root/slurmd.pid" ] && break; sleep 0.2; done
daemons+=("$(cat "$root/slurmd.pid")")
state=""
for _ in $(seq 100); do
  state="$(sinfo -h -n refl1 -o %t 2>/dev/null || true)"
  [ "$state" = idle ] && break
  sleep 0.3
done
[ "$state" = idle ] || fail "the node is '$state', not idle"
echo "slurm-test: controller and node up (node refl1, $cpus CPUs)" >&2

export REFLECTOMETER_DATA="$root/data" RUST_LOG=warn
cap="$root/capture"
grid=()
[ "$quality" = fast ] && grid=(--grid 48 --camera-px 192 --steps 16)
"$bin/capture" --sample satin --quality "$quality" "${grid[@]}" --no-fit --out "$cap" >"$root/capture.log" 2>&1 \
  || fail "the capture failed"
# A copy of the capture sharing its frames, for each fit.
fresh() {
  rm -rf "$1"
  mkdir -p "$1"
  cp "$cap/capture.json" "$cap/manifest.jsonl" "$1/"
  ln -s "$cap/frames" "$1/frames"
}
fresh "$root/whole"
# Seconds since $1 (from `date +%s%N`), to a tenth.
since() { local ms=$(( ($(date +%s%N) - $1) / 1000000 )); printf '%d.%d' $((ms / 1000)) $((ms % 1000 / 100)); }
t0=$(date +%s%N)
RAYON_NUM_THREADS="$cpus" "$bin/refl" fit "$root/whole" >"$root/whole.log" 2>&1 || fail "the whole fit failed"
whole_s="$(since "$t0")"

# Submit the split of capture copy DIR with N tasks and wait for the
# merge's end; print its state and the wall time.
submit_and_wait() { # DIR N CPUS_PER_TASK
  local dir="$1" jobs merge t0 st
  t0=$(date +%s%N)
  jobs="$(cd "$root/work" && RUST_LOG=info REFL="$bin/refl" bash "$OLDPWD/deploy/slurm/submit.sh" --cpus "$3" --merge-cpus "$cpus" "$dir" "$2")" \
    || fail "submit.sh failed"
  merge="$(echo "$jobs" | awk '/^merge/ { print $2 }')"
  for _ in $(seq 1800); do
    st="$(scontrol show job "$merge" 2>/dev/null | sed -n 's/.*JobState=\([A-Z_]*\).*/\1/p')"
    case "$st" in COMPLETED|FAILED|CANCELLED|TIMEOUT|NODE_FAIL|OUT_OF_MEMORY) break ;; esac
    sleep 0.5
  done
  echo "$st $(since "$t0")"
}
run_split() { # N CPUS_PER_TASK
  local out
  fresh "$root/split$1"
  out="$(submit_and_wait "$root/split$1" "$1" "$2")"
  [ "${out%% *}" = COMPLETED ] || fail "the merge of $1 tiles ended ${out%% *}"
  echo "${out#* }"
}
# A tile that fails (its frames are gone) and the merge never runs: the
# capture gets no material and keeps its frames' manifest.
fresh "$root/broken"
rm "$root/broken/frames"
mkdir "$root/broken/frames"
out="$(submit_and_wait "$root/broken" 2 1)"
[ "${out%% *}" = CANCELLED ] || fail "the merge after failed tiles ended ${out%% *}, not CANCELLED"
[ ! -e "$root/broken/material" ] || fail "a material was written from failed tiles"
cmp -s "$cap/manifest.jsonl" "$root/broken/manifest.jsonl" || fail "the failed fit changed the manifest"
echo "slurm-test: tiles that fail leave the merge cancelled and nothing written" >&2
split2_s="$(run_split 2 1)"
[ ! -e "$root/split2/tiles" ] || fail "the merge left its tiles"
python3 scripts/same-material.py "$root/whole/material" "$root/split2/material" \
  || fail "the material fitted in 2 Slurm tasks differs from the whole fit's"
split1_s="$(run_split 1 "$cpus")"
python3 scripts/same-material.py "$root/whole/material" "$root/split1/material" \
  || fail "the material fitted in 1 Slurm task differs from the whole fit's"
echo "slurm-test: $quality satin ($profile build): whole fit ${whole_s} s; through Slurm with 1 task of $cpus CPUs ${split1_s} s, with 2 tasks of 1 CPU ${split2_s} s (submission to merged material)" >&2
python3 - "$root/whole/report.json" "$root/split2/report.json" <<'PY'
import json, sys
# Seconds by stage (the tiles' slowest for ingest and points), then the
# process's peak memory.
stages = ["ingest", "points", "synthesis", "pool", "analytic", "selection"]
for name, path in zip(["whole fit", "2 tiles + merge"], sys.argv[1:]):
    r = json.load(open(path))
    t = r["timings"]
    cols = [f"{k} {t.get('fit_' + k + '_s', 0):.1f}" for k in stages]
    cols += [f"material_write {t.get('material_write_s', 0):.1f}", f"peak {r.get('peak_memory_mb') or 0:.0f} MB"]
    print(f"slurm-test: {name:16} " + "  ".join(cols), file=sys.stderr)
PY
# Each tile's own time (frames read, its points ingested and fitted) and
# the merge's reading of the tiles, from the jobs' logs.
grep -h -o "tile [0-9]*/2: [0-9]* frames read .*" "$root"/work/refl-tile-*.log | sed 's/^/slurm-test: /' >&2 || true
grep -h -o "2 tiles read in .*" "$root"/work/refl-merge-*.log | sed 's/^/slurm-test: merge: /' >&2 || true
echo "slurm-test: passed" >&2
