//! The allocator setting of a diagnosis: speed only, no number changes.
//!
//! A diagnosis allocates and frees many large matrices: the kernel CV's kernels, shifted
//! systems and factors (35 MB each at 2,080 poses) and every round's candidate Jacobian. Above
//! glibc's mmap threshold (at most 32 MB by default) each one is a fresh mapping whose
//! pages the kernel faults in and zeroes, and which is unmapped again on free. Keeping freed
//! blocks in the heap for reuse cuts the system time of a 2,080-pose diagnosis (real UR10
//! Series C: 1.9–2.4 → 0.5–0.7 s system, peak memory +60–110 MB; `docs/findings.md`).

/// Raise glibc's mmap and trim thresholds (to 1 GiB; 32 MiB where glibc refuses that) so
/// that freed large blocks stay in the heap. Process-wide, set once; nothing off glibc.
pub fn keep_large_blocks() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        static ONCE: std::sync::Once = std::sync::Once::new();
        ONCE.call_once(|| {
            // SAFETY: `mallopt` only changes allocator parameters; it is thread-safe and
            // takes no pointers.
            let ok = unsafe { libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 30) } == 1
                || unsafe { libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20) } == 1;
            // SAFETY: as above.
            let trim = unsafe { libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX) } == 1;
            tracing::debug!("allocator: large blocks kept in the heap ({ok}, trim {trim})");
        });
    }
}
