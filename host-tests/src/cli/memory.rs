//! The process's allocator policy for the host tools' large working sets.
//!
//! glibc's malloc hands a freed block of more than its mmap threshold back to the kernel, and
//! trims the top of its heap once more than the trim threshold is free; the next vector of the
//! same size then comes as fresh pages, each zeroed by the kernel on its first touch. `explain`
//! on a million-row recording builds and drops hundreds of such vectors (a column is 8 MB):
//! measured on `bench_explain --large`, ≈ 550,000 page faults and 1.6 s of system time of
//! 8.5 s CPU. Keeping freed memory in the process for the next vector (mmap only beyond
//! 32 MiB, the largest threshold glibc accepts; no trimming) cut that to ≈ 390,000 faults and
//! 1.2 s, with a peak RSS ≈ 5 % higher (BENCHMARKS.md, "Explain"). Nothing computed changes.

/// Keep freed memory in the process for reuse instead of returning it to the kernel (glibc on
/// Linux; elsewhere nothing). Call once at the start of `main`, before threads start.
pub fn reuse_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets malloc's tuning parameters; both values are in the ranges
    // glibc documents (mmap threshold ≤ HEAP_MAX_SIZE/2 = 32 MiB on 64-bit), and an
    // out-of-range value is refused (returns 0) without effect.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, libc::c_int::MAX);
    }
}
