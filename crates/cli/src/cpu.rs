//! Whether this processor runs what the build was compiled for.
//!
//! On x86-64 the workspace is compiled for the `x86-64-v3` level less FMA
//! (`.cargo/config.toml`): AVX2 among others, on Intel processors from
//! Haswell (2013) and AMD's from Excavator (2015). The simulated camera's
//! and the fitter's eight-wide arithmetic (`wide`'s `f32x8`) then runs as
//! one AVX instruction instead of two SSE ones. FMA is left out because
//! `wide` fuses its multiply-adds where it may (its polynomial `exp` and
//! `ln`), which rounds once instead of twice: a few pixels in a capture
//! would then read one DN apart from the baseline build's.
//!
//! On a processor without those instructions, such a binary would die of
//! an illegal instruction at whatever first used one. [`check`], the first
//! thing each binary does, reads the processor's features with `cpuid`
//! and, where one the build uses is missing, says which and how to build
//! for the processor instead. Its test is in assembly and its message
//! spelled out feature by feature, so that it runs on any x86-64
//! processor; `scripts/cpu-check.sh` reads the machine code of everything
//! that runs before the check has answered.
#![cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]

/// One instruction-set extension of the `x86-64-v3` level: its name,
/// where `cpuid` reports it, and whether this build was compiled to use it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Feature {
    pub name: &'static str,
    at: Bit,
    pub compiled: bool,
}

/// A feature bit's place in the `cpuid` report.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Bit {
    /// Leaf 1, register ECX.
    Leaf1Ecx(u32),
    /// Leaf 7 sub-leaf 0, register EBX.
    Leaf7Ebx(u32),
    /// Leaf 0x8000_0001, register ECX.
    ExtEcx(u32),
    /// The operating system saves the AVX registers (XCR0's SSE and AVX
    /// state bits), without which AVX faults even on a processor that has
    /// it.
    OsAvxState,
}

impl Bit {
    /// A report with this feature's bits set and no other: the one place
    /// that says which register holds which feature.
    #[inline(always)]
    const fn mask(self) -> CpuReport {
        let mut r = CpuReport { leaf1_ecx: 0, leaf7_ebx: 0, ext_ecx: 0, xcr0: 0 };
        match self {
            Bit::Leaf1Ecx(b) => r.leaf1_ecx = 1 << b,
            Bit::Leaf7Ebx(b) => r.leaf7_ebx = 1 << b,
            Bit::ExtEcx(b) => r.ext_ecx = 1 << b,
            // XMM (bit 1) and YMM (bit 2) state.
            Bit::OsAvxState => r.xcr0 = 0b110,
        }
        r
    }
}

/// What `x86-64-v3` adds to `x86-64-v2` (the psABI's list; a processor
/// with these has v2's SSE4.2 and POPCNT too), with their `cpuid` bits
/// (Intel's Software Developer's Manual, volume 2A; AMD's `cpuid`
/// specification for LZCNT). The workspace's setting leaves FMA out
/// (`.cargo/config.toml`).
pub const FEATURES: [Feature; 10] = [
    Feature { name: "avx", at: Bit::Leaf1Ecx(28), compiled: cfg!(target_feature = "avx") },
    Feature { name: "os-avx-state", at: Bit::OsAvxState, compiled: cfg!(target_feature = "avx") },
    Feature { name: "avx2", at: Bit::Leaf7Ebx(5), compiled: cfg!(target_feature = "avx2") },
    Feature { name: "fma", at: Bit::Leaf1Ecx(12), compiled: cfg!(target_feature = "fma") },
    Feature { name: "f16c", at: Bit::Leaf1Ecx(29), compiled: cfg!(target_feature = "f16c") },
    Feature { name: "movbe", at: Bit::Leaf1Ecx(22), compiled: cfg!(target_feature = "movbe") },
    Feature { name: "xsave", at: Bit::Leaf1Ecx(26), compiled: cfg!(target_feature = "xsave") },
    Feature { name: "bmi1", at: Bit::Leaf7Ebx(3), compiled: cfg!(target_feature = "bmi1") },
    Feature { name: "bmi2", at: Bit::Leaf7Ebx(8), compiled: cfg!(target_feature = "bmi2") },
    Feature { name: "lzcnt", at: Bit::ExtEcx(5), compiled: cfg!(target_feature = "lzcnt") },
];

/// The registers [`FEATURES`] are read from, as the processor reports them
/// (0 for a leaf it does not have).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CpuReport {
    pub leaf1_ecx: u32,
    pub leaf7_ebx: u32,
    pub ext_ecx: u32,
    /// XCR0's low word, 0 where the OS has not enabled `xgetbv` (leaf 1
    /// ECX bit 27, OSXSAVE).
    pub xcr0: u32,
}

impl CpuReport {
    /// Whether the processor (and its OS) provides `f`. Inlined always:
    /// [`refuse`] runs it where the build's instructions may be missing.
    #[inline(always)]
    pub fn has(&self, f: Feature) -> bool {
        let m = f.at.mask();
        self.leaf1_ecx & m.leaf1_ecx == m.leaf1_ecx
            && self.leaf7_ebx & m.leaf7_ebx == m.leaf7_ebx
            && self.ext_ecx & m.ext_ecx == m.ext_ecx
            && self.xcr0 & m.xcr0 == m.xcr0
    }

    /// This processor's report ([`registers`]).
    #[cfg(target_arch = "x86_64")]
    pub fn read() -> Self {
        let (leaf1_ecx, leaf7_ebx, ext_ecx, xcr0) = registers();
        CpuReport { leaf1_ecx, leaf7_ebx, ext_ecx, xcr0 }
    }
}

/// The bits of each register that the build's compiled features need.
const REQUIRED: CpuReport = {
    let mut r = CpuReport { leaf1_ecx: 0, leaf7_ebx: 0, ext_ecx: 0, xcr0: 0 };
    let mut k = 0;
    while k < FEATURES.len() {
        if FEATURES[k].compiled {
            let m = FEATURES[k].at.mask();
            r.leaf1_ecx |= m.leaf1_ecx;
            r.leaf7_ebx |= m.leaf7_ebx;
            r.ext_ecx |= m.ext_ecx;
            r.xcr0 |= m.xcr0;
        }
        k += 1;
    }
    r
};

// What runs before the processor is known to have the build's features is
// written in assembly: compiled Rust, however plain, may use them (the
// compiler turned a first version of this check's loop into AVX
// instructions, and chooses BMI's forms of plain bit operations).

/// Leaf 1's ECX, leaf 7's EBX, leaf 0x8000_0001's ECX and XCR0's low word,
/// as [`CpuReport`] holds them, in general registers throughout.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn registers() -> (u32, u32, u32, u32) {
    let (leaf1, leaf7, ext, xcr0): (u32, u32, u32, u32);
    // SAFETY: `cpuid` exists on every x86-64 processor and is asked no leaf
    // above the largest it reports (leaf 0's and 0x8000_0000's answers);
    // `xgetbv` only where `cpuid` reports the OS has enabled it (leaf 1
    // ECX bit 27, OSXSAVE). RBX, which `cpuid` writes and the compiler
    // reserves, is kept in R10 and restored; no operand is given it. No
    // memory is touched.
    unsafe {
        std::arch::asm!(
            "mov r10, rbx",
            "xor eax, eax",
            "xor ecx, ecx",
            "cpuid",
            "mov r11d, eax",
            "mov eax, 1",
            "xor ecx, ecx",
            "cpuid",
            "mov esi, ecx",
            "xor edi, edi",
            "cmp r11d, 7",
            "jb 2f",
            "mov eax, 7",
            "xor ecx, ecx",
            "cpuid",
            "mov edi, ebx",
            "2:",
            "mov eax, 0x80000000",
            "xor ecx, ecx",
            "cpuid",
            "mov r11d, eax",
            "xor r8d, r8d",
            "cmp r11d, 0x80000001",
            "jb 3f",
            "mov eax, 0x80000001",
            "xor ecx, ecx",
            "cpuid",
            "mov r8d, ecx",
            "3:",
            "xor r9d, r9d",
            "bt esi, 27",
            "jnc 4f",
            "xor ecx, ecx",
            "xgetbv",
            "mov r9d, eax",
            "4:",
            "mov rbx, r10",
            // Named registers: a `reg` operand may be given RBX, which
            // `cpuid` overwrites (a first version lost leaf 1 so).
            out("r10") _,
            out("r11") _,
            out("esi") leaf1,
            out("edi") leaf7,
            out("r8d") ext,
            out("r9d") xcr0,
            out("eax") _,
            out("ecx") _,
            out("edx") _,
            options(nomem, nostack),
        );
    }
    (leaf1, leaf7, ext, xcr0)
}

/// Nonzero where the registers lack a bit [`REQUIRED`] has.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn lacking(leaf1: u32, leaf7: u32, ext: u32, xcr0: u32) -> u32 {
    let out: u32;
    // SAFETY: arithmetic on registers only.
    unsafe {
        std::arch::asm!(
            "not {a:e}",
            "and {a:e}, {m1}",
            "not {b:e}",
            "and {b:e}, {m7}",
            "not {c:e}",
            "and {c:e}, {me}",
            "not {d:e}",
            "and {d:e}, {mx}",
            "or {a:e}, {b:e}",
            "or {a:e}, {c:e}",
            "or {a:e}, {d:e}",
            a = inout(reg) leaf1 => out,
            b = inout(reg) leaf7 => _,
            c = inout(reg) ext => _,
            d = inout(reg) xcr0 => _,
            m1 = const REQUIRED.leaf1_ecx,
            m7 = const REQUIRED.leaf7_ebx,
            me = const REQUIRED.ext_ecx,
            mx = const REQUIRED.xcr0,
            options(pure, nomem, nostack),
        );
    }
    out
}

/// Exit with a message on standard error, status
/// [`crate::exit::FAILED`], if the build was compiled for a feature this
/// processor lacks; otherwise return at once. The first call of each
/// binary's `main`.
#[inline(never)]
pub fn check() {
    #[cfg(target_arch = "x86_64")]
    {
        let (leaf1, leaf7, ext, xcr0) = registers();
        if lacking(leaf1, leaf7, ext, xcr0) != 0 {
            refuse(leaf1, leaf7, ext, xcr0);
        }
    }
}

/// The message of [`check`], written a piece at a time with each feature's
/// test spelled out (no loop or formatting that the compiler could turn
/// into the missing instructions; `scripts/cpu-check.sh` reads the
/// machine code to make sure), and the exit.
#[cfg(target_arch = "x86_64")]
#[cold]
#[inline(never)]
fn refuse(leaf1: u32, leaf7: u32, ext: u32, xcr0: u32) -> ! {
    let report = CpuReport { leaf1_ecx: leaf1, leaf7_ebx: leaf7, ext_ecx: ext, xcr0 };
    // Each feature a constant, so that its test folds to one bit test.
    #[inline(always)]
    fn name_if_missing(report: &CpuReport, f: Feature) {
        if f.compiled && !report.has(f) {
            say(b" ");
            say(f.name.as_bytes());
        }
    }
    // One line below per feature.
    const _: () = assert!(FEATURES.len() == 10);
    say(b"error: this build of the reflectometer is compiled for x86-64-v3 processors (Intel Haswell, 2013, AMD Excavator, 2015, and later), and this processor lacks:");
    name_if_missing(&report, FEATURES[0]);
    name_if_missing(&report, FEATURES[1]);
    name_if_missing(&report, FEATURES[2]);
    name_if_missing(&report, FEATURES[3]);
    name_if_missing(&report, FEATURES[4]);
    name_if_missing(&report, FEATURES[5]);
    name_if_missing(&report, FEATURES[6]);
    name_if_missing(&report, FEATURES[7]);
    name_if_missing(&report, FEATURES[8]);
    name_if_missing(&report, FEATURES[9]);
    say(b"\nBuild it for this processor instead: RUSTFLAGS=\"-C target-cpu=native\" cargo build --release (README, \"Building for a processor\").\n");
    std::process::exit(crate::exit::FAILED)
}

/// `bytes` to standard error, unbuffered (`libc::write`; a short write or
/// an error is let go: the exit follows).
#[cfg(target_arch = "x86_64")]
#[inline(never)]
fn say(bytes: &[u8]) {
    // SAFETY: writes `bytes.len()` bytes from a live slice.
    unsafe { libc::write(2, bytes.as_ptr().cast(), bytes.len()) };
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A processor reporting nothing lacks every feature; setting each
    /// feature's bit gives it that one and no other.
    #[test]
    fn each_feature_is_read_from_its_own_bit() {
        let none = CpuReport::default();
        assert!(FEATURES.iter().all(|&f| !none.has(f)));
        for f in FEATURES {
            let r = f.at.mask();
            let has: Vec<_> = FEATURES.iter().filter(|&&g| r.has(g)).map(|g| g.name).collect();
            assert_eq!(has, [f.name], "{f:?}");
        }
        // AVX state saved but not the SSE state under it: not usable.
        assert!(!CpuReport { xcr0: 0b100, ..Default::default() }.has(FEATURES[1]));
    }

    /// The assembly's test agrees with [`CpuReport::has`]: a processor
    /// with every bit passes, and one lacking any one compiled feature's
    /// bit (or anything else) fails exactly when the build uses it.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_assembly_finds_what_is_lacking() {
        let full = CpuReport { leaf1_ecx: !0, leaf7_ebx: !0, ext_ecx: !0, xcr0: !0 };
        let lacks = |r: CpuReport| lacking(r.leaf1_ecx, r.leaf7_ebx, r.ext_ecx, r.xcr0) != 0;
        let rust_lacks = |r: CpuReport| FEATURES.iter().any(|&f| f.compiled && !r.has(f));
        assert!(!lacks(full));
        assert_eq!(lacks(CpuReport::default()), FEATURES.iter().any(|f| f.compiled));
        for f in FEATURES {
            let m = f.at.mask();
            let r = CpuReport {
                leaf1_ecx: !m.leaf1_ecx,
                leaf7_ebx: !m.leaf7_ebx,
                ext_ecx: !m.ext_ecx,
                // Of the OS's state bits, the AVX one only (the SSE one
                // under it kept).
                xcr0: !(m.xcr0 & 0b100),
            };
            assert_eq!(lacks(r), f.compiled, "{f:?}");
            assert_eq!(lacks(r), rust_lacks(r), "{f:?}");
        }
        // Bits no feature uses do not matter.
        let mut state = 0x9e37_79b9_u32;
        for _ in 0..1000 {
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                state
            };
            let r = CpuReport { leaf1_ecx: next(), leaf7_ebx: next(), ext_ecx: next(), xcr0: next() };
            assert_eq!(lacks(r), rust_lacks(r), "{r:?}");
        }
    }

    /// The processor running the tests is read as `std` reads it, and has
    /// every feature the build was compiled for.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn this_processor_is_read_as_std_reads_it() {
        let r = CpuReport::read();
        let std_says = [
            ("avx", std::is_x86_feature_detected!("avx")),
            ("avx2", std::is_x86_feature_detected!("avx2")),
            ("fma", std::is_x86_feature_detected!("fma")),
            ("f16c", std::is_x86_feature_detected!("f16c")),
            ("movbe", std::is_x86_feature_detected!("movbe")),
            ("xsave", std::is_x86_feature_detected!("xsave")),
            ("bmi1", std::is_x86_feature_detected!("bmi1")),
            ("bmi2", std::is_x86_feature_detected!("bmi2")),
            ("lzcnt", std::is_x86_feature_detected!("lzcnt")),
        ];
        for (name, has) in std_says {
            let f = *FEATURES.iter().find(|f| f.name == name).unwrap();
            // `std`'s answer for AVX includes the OS's saving of its registers.
            let ours = r.has(f) && (name != "avx" || r.has(FEATURES[1]));
            if f.compiled {
                // `std` answers yes without asking the processor for a
                // feature the build enables; the tests run, so it is here.
                assert!(ours, "{name}: compiled for and running, yet read as missing");
            } else {
                assert_eq!(ours, has, "{name}");
            }
        }
    }
}
