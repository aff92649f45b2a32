//! CPU time used by this process (user + system), for the bench's CPU column.

/// User and system CPU time of this process in nanoseconds.
pub fn process_cpu_ns() -> u64 {
    // SAFETY: zeroed rusage is valid; getrusage only writes it.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut ru) };
    timeval_ns(ru.ru_utime) + timeval_ns(ru.ru_stime)
}

pub fn timeval_ns(tv: libc::timeval) -> u64 {
    tv.tv_sec as u64 * 1_000_000_000 + tv.tv_usec as u64 * 1_000
}
