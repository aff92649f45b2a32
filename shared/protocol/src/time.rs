//! The one clock of the loop: CLOCK_MONOTONIC in nanoseconds.
//!
//! All processes stamp messages with it, so that stamps from different
//! processes on one machine can be subtracted directly.

/// Nanoseconds on CLOCK_MONOTONIC (a vDSO call, no syscall on Linux x86_64).
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

#[cfg(test)]
mod tests {
    #[test]
    fn clock_is_monotonic() {
        let a = super::monotonic_ns();
        let b = super::monotonic_ns();
        assert!(a > 0 && b >= a);
    }
}
