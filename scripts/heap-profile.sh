#!/usr/bin/env bash
# Where a fit's memory goes at its peak: runs `refl bench fit ARGS...` under
# heaptrack, prints the process's peak heap, and sums what each call site
# held at that moment by the last two workspace functions on the site's
# stack, largest first.
#
#   bash scripts/heap-profile.sh [--bin DIR] OUT [BENCH ARGS...]
#   e.g. bash scripts/heap-profile.sh /tmp/heap --preset balanced --points 128
#
# --bin names the directory holding another build's `refl` (default: this
# tree's release build, built first).
#
# Needs heaptrack (Debian: apt install heaptrack); the test suite does not,
# so scripts/setup.sh does not install it. The benchmark's times under
# heaptrack are not its times.
set -euo pipefail
cd "$(dirname "$0")/.."
bin=""
if [ "${1:-}" = --bin ]; then
  bin="$(cd "$2" && pwd)"
  shift 2
fi
[ $# -ge 1 ] || { sed -n 2,15p "$0" >&2; exit 2; }
command -v heaptrack >/dev/null || { echo "heap-profile: needs heaptrack (apt install heaptrack)" >&2; exit 2; }
. scripts/common.sh
release_bins
out="$(absolute_dir "$1")"
shift
heaptrack -o "$out/heap" "$bin/refl" bench fit "$@" | tee "$out/bench.log"
heaptrack_print -f "$out/heap.zst" --print-peaks 0 --print-allocators 0 --print-temporary 0 --print-leaks 0 | grep "peak heap memory consumption"
heaptrack_print -f "$out/heap.zst" --print-flamegraph "$out/peak-stacks.txt" --flamegraph-cost-type peak >/dev/null
files="$(git ls-files 'crates/*.rs' | xargs -n1 basename | grep -vx 'mod.rs\|lib.rs' | sort -u | tr '\n' ' ')"
python3 - "$out/peak-stacks.txt" "$files" <<'PY'
import collections, sys
# Frames read "function (file.rs)", the file without its directory: a
# frame is the workspace's when its file name is one of the workspace's
# (mod.rs and lib.rs, which the standard library has too, left out).
ours = set(sys.argv[2].split())
by = collections.Counter()
for line in open(sys.argv[1]):
    stack, _, cost = line.rstrip().rpartition(" ")
    named = [f for f in stack.split(";") if f.endswith(")") and f.rsplit("(", 1)[-1][:-1] in ours and not f.startswith("{closure")]
    # In heaptrack's order (where functions were inlined into one another
    # it names the callee first).
    by["; ".join(named[-2:]) if named else "(no workspace function on the stack)"] += int(cost)
print("held at the peak, by the last two workspace functions on the stack:")
for name, cost in by.most_common(15):
    print(f"  {cost / 1e6:9.1f} MB  {name}")
PY
