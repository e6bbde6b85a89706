//! Which SIMD paths this CPU runs, decided once per process. `MOTES_SIMD=sse` keeps every path at the
//! x86-64 baseline and `MOTES_SIMD=avx2` stops at AVX2, for tests and side-by-side comparisons
//! (`crate::options`).

#[cfg(target_arch = "x86_64")]
use crate::options::SimdCap;

/// Whether this CPU runs the grid's AVX2 + FMA walk (`crate::space::grid`: eight spheres per pre-test
/// instead of four), unless `MOTES_SIMD=sse`.
#[inline]
pub fn wide_simd() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static WIDE: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *WIDE.get_or_init(|| crate::options::simd_cap() != SimdCap::Sse && cpu_has_wide())
    }
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// Whether the lockstep paths run in AVX-512 (a packet's free flights through the continuous field,
/// its phase functions, a beam's rays against one particle): the CPU has AVX-512 F, DQ and VL, which
/// their 64-bit lanes need (multiplies and conversions), and the wide walk is on. No with
/// `MOTES_SIMD=sse` or `MOTES_SIMD=avx2`.
#[inline]
pub(crate) fn lockstep_simd() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static ON: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *ON.get_or_init(|| {
            wide_simd() && crate::options::simd_cap() == SimdCap::Widest && cpu_has_lockstep()
        })
    }
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// Whether the CPU has AVX2 and FMA, whatever `MOTES_SIMD` says (tests compare the wide paths with the
/// narrow ones wherever they can run).
#[cfg(target_arch = "x86_64")]
pub(crate) fn cpu_has_wide() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// Whether the CPU has AVX-512 F, DQ and VL, whatever `MOTES_SIMD` says.
#[cfg(target_arch = "x86_64")]
pub(crate) fn cpu_has_lockstep() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512dq")
        && std::arch::is_x86_feature_detected!("avx512vl")
}

/// Says, past the test harness's capture of the output (so that a passing test's log shows it), that
/// `test` ran without its SIMD half here: `why` names what this CPU, or `MOTES_SIMD`, lacks.
#[cfg(test)]
pub(crate) fn say_simd_half_not_run(test: &str, why: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{test}: {why}; SIMD half not run");
}
