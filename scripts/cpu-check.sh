#!/usr/bin/env bash
# Check that the binaries refuse, saying why, to run on a processor without
# the instructions the build was compiled for (.cargo/config.toml,
# crates/cli/src/cpu.rs), rather than dying of an illegal instruction.
#
#   bash scripts/cpu-check.sh [BINARY...]   (default: target/debug/refl and capture)
#
# 1. The machine code that runs before the check has answered (the C `main`,
#    the standard library's start-up closure and the binary's `main`, up to
#    the call of the check) and the check itself (`cli::cpu::check` and
#    every function of `cli::cpu` it calls) must be x86-64 baseline
#    instructions only: the listed ones, with no VEX-encoded (AVX) or BMI
#    forms. The compiler chooses those freely in any Rust it compiles for
#    x86-64-v3, so this reads the disassembly (objdump) rather than
#    trusting the source.
# 2. Run under QEMU's user-mode emulation as a Nehalem (x86-64-v2, no AVX),
#    `refl --version` must exit 1 with the message naming AVX2; as a
#    Haswell (x86-64-v3) it must print its version. QEMU does not fault on
#    every instruction its model lacks, which is why (1) reads the code.
# Needs objdump (binutils) and qemu-user (scripts/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
[ "$(uname -m)" = x86_64 ] || { echo "cpu-check: not x86-64; nothing to check" >&2; exit 0; }
if [ $# -eq 0 ]; then
  cargo build --quiet -p reflectometer-cli --bin refl --bin capture
  set -- target/debug/refl target/debug/capture
fi
for b in "$@"; do
  python3 - "$b" <<'EOF'
import re, subprocess, sys
binary = sys.argv[1]
name = binary.rsplit("/", 1)[-1]
# Function symbols: demangled name -> [(address, size)].
syms = {}
for line in subprocess.run(["nm", "-S", "-C", "--defined-only", binary], capture_output=True, text=True, check=True).stdout.splitlines():
    f = line.split(maxsplit=3)
    if len(f) == 4 and f[2] in "tT":
        syms.setdefault(f[3], []).append((int(f[0], 16), int(f[1], 16)))

def find(pattern):
    hits = [(d, a) for d, at in syms.items() if re.fullmatch(pattern, d) for a in at]
    if len(hits) != 1:
        sys.exit(f"cpu-check: {binary}: {len(hits)} functions named like {pattern}: {[h[0] for h in hits][:5]}")
    return hits[0]

def code(fn):
    start, size = fn[1]
    out = subprocess.run(["objdump", "-d", "--no-show-raw-insn", f"--start-address={start}", f"--stop-address={start + size}", binary],
                         capture_output=True, text=True, check=True).stdout
    rows = []
    for line in out.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s+(\S+)\s*(.*)", line)
        if m:
            rows.append((int(m.group(1), 16), m.group(2), m.group(3)))
    return rows

# Baseline x86-64 (SSE2 at most, which start-up code may use for moves),
# by mnemonic as objdump prints it (AT&T, with size suffixes).
allowed = re.compile(r"(push|pop|mov|movabs|movz[bw]|movs[bwl]|lea|call|jmp|j[a-z]+|ret|int3|nop|endbr64|xor|and|or|not|add|sub|cmp|test|bt|set[a-z]+|cmov[a-z]+|cpuid|xgetbv|xchg|inc|dec|neg|shl|shr|sar|cltq|cqto|cltd|ud2|movaps|movups|movq|movd|movdqa|movdqu|xorps|pxor)[lqwb]?")
checked = []
def inspect(fn, to_first_call=False):
    for addr, op, args in code(fn):
        if to_first_call and op.startswith("call"):
            break
        if not allowed.fullmatch(op):
            sys.exit(f"cpu-check: {binary}: {fn[0]} at {addr:#x}: '{op} {args}' is not a baseline x86-64 instruction, and it runs before or in the processor check")
    checked.append(fn[0])

def by_address(addr):
    hits = [(d, a) for d, at in syms.items() for a in at if a[0] == addr]
    if len(hits) != 1:
        sys.exit(f"cpu-check: {binary}: no single function at {addr:#x}")
    return hits[0]

def direct_calls(fn):
    return [int(m.group(1), 16) for _, op, args in code(fn) if op.startswith("call") for m in [re.match(r"([0-9a-f]+) <", args)] if m]

inspect(find("main"))
closure = find(r"std::rt::lang_start::\{\{closure\}\}")
inspect(closure)
# The closure calls `__rust_begin_short_backtrace`, which calls `main`
# through a register.
for target in direct_calls(closure):
    inspect(by_address(target))
# The binary's `main`: to its first call (the check, through the GOT).
inspect(find(rf"{name}::main"), to_first_call=True)
# The check, and every function of `cli::cpu` it calls, however deep (a
# closure or a helper the compiler kept apart; calls into the standard
# library's compiled code and libc are not followed).
seen = set()
todo = [find(r"cli::cpu::check")]
while todo:
    fn = todo.pop()
    if fn[1][0] in seen:
        continue
    seen.add(fn[1][0])
    inspect(fn)
    for target in direct_calls(fn):
        callee = by_address(target)
        if callee[0].startswith("cli::cpu::"):
            todo.append(callee)
print(f"cpu-check: {binary}: baseline instructions only in {len(checked)} functions ({', '.join(sorted(set(checked)))})", file=sys.stderr)
EOF
  out=$(qemu-x86_64 -cpu Nehalem "$b" --version 2>&1) && rc=0 || rc=$?
  if [ "$rc" -eq 0 ] && grep -q "0\." <<<"$out"; then
    echo "cpu-check: $b runs on a Nehalem: it was built for the x86-64 baseline (RUSTFLAGS?), not this workspace's x86-64-v3; nothing to refuse" >&2
    continue
  fi
  if [ "$rc" -ne 1 ] || ! grep -q "this processor lacks: avx" <<<"$out" || ! grep -q "avx2" <<<"$out"; then
    echo "cpu-check: $b as a Nehalem: exit $rc, expected 1 and the message naming avx2; it printed:" >&2
    echo "$out" >&2
    exit 1
  fi
  qemu-x86_64 -cpu Haswell "$b" --version 2>/dev/null | grep -q "0\." || { echo "cpu-check: $b as a Haswell did not print its version" >&2; exit 1; }
  echo "cpu-check: $b refuses a Nehalem with: $(head -1 <<<"$out" | cut -c1-60)... and runs on a Haswell" >&2
done
