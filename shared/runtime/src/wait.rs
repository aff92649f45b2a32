//! Waiting for a loop process's next input: on event file descriptors with
//! a precise timeout, or by spinning on the input itself.
//!
//! iceoryx2's `Listener::timed_wait` uses SO_RCVTIMEO (jiffies, 4-9 ms here);
//! `ppoll` with a timespec uses hrtimers, so a wait can end at a tick deadline.

use crate::monotonic_ns;
use std::os::fd::RawFd;

/// How a loop process waits (the scenario's `realtime.profile`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WaitMode {
    /// Block in the kernel until an event or the deadline (`ppoll`,
    /// `clock_nanosleep`): the loop's processes share CPUs (`shared-cores`).
    Events,
    /// Spin on the input and the clock, without a system call: each loop
    /// process owns an isolated CPU (`dedicated-cores`), so nothing else
    /// needs it and the wake-up's latency is gone.
    Spin,
}

/// Waits until `ready()` holds or, with [`WaitMode::Events`], one of `fds`
/// is readable; at most `timeout_ns`. Spinning reports `Ready(1)`.
pub fn wait_for_input(
    mode: WaitMode,
    fds: &[RawFd],
    timeout_ns: u64,
    mut ready: impl FnMut() -> bool,
) -> std::io::Result<Readiness> {
    match mode {
        WaitMode::Events => wait_readable(fds, timeout_ns),
        WaitMode::Spin => {
            let deadline = monotonic_ns().saturating_add(timeout_ns);
            loop {
                if ready() {
                    return Ok(Readiness::Ready(1));
                }
                if monotonic_ns() >= deadline {
                    return Ok(Readiness::TimedOut);
                }
                std::hint::spin_loop();
            }
        }
    }
}

/// Outcome of [`wait_readable`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Readiness {
    /// At least one descriptor is readable; bit i set for `fds[i]`.
    Ready(u32),
    TimedOut,
    /// A signal arrived; the caller should check its shutdown flag.
    Interrupted,
}

/// Blocks until one of `fds` (at most 4) is readable or `timeout_ns` passed.
pub fn wait_readable(fds: &[RawFd], timeout_ns: u64) -> std::io::Result<Readiness> {
    let mut pollfds = [libc::pollfd {
        fd: -1,
        events: 0,
        revents: 0,
    }; 4];
    let n = fds.len().min(4);
    for (slot, fd) in pollfds.iter_mut().zip(fds) {
        slot.fd = *fd;
        slot.events = libc::POLLIN;
    }
    let ts = libc::timespec {
        tv_sec: (timeout_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (timeout_ns % 1_000_000_000) as libc::c_long,
    };
    // SAFETY: `pollfds` holds `n` initialised entries; `ts` is valid; no sigmask.
    let rc = unsafe {
        libc::ppoll(
            pollfds.as_mut_ptr(),
            n as libc::nfds_t,
            &ts,
            std::ptr::null(),
        )
    };
    if rc < 0 {
        let err = std::io::Error::last_os_error();
        if err.raw_os_error() == Some(libc::EINTR) {
            return Ok(Readiness::Interrupted);
        }
        return Err(err);
    }
    if rc == 0 {
        return Ok(Readiness::TimedOut);
    }
    let mut mask = 0u32;
    for (i, p) in pollfds[..n].iter().enumerate() {
        if p.revents != 0 {
            mask |= 1 << i;
        }
    }
    Ok(Readiness::Ready(mask))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spinning_returns_when_ready_and_times_out_otherwise() {
        let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let setter = flag.clone();
        let t = std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(5));
            setter.store(true, std::sync::atomic::Ordering::Release);
        });
        let ready = || flag.load(std::sync::atomic::Ordering::Acquire);
        // Bounded: 10 s is a failure, never the expected way out.
        assert_eq!(
            wait_for_input(WaitMode::Spin, &[], 10_000_000_000, ready).unwrap(),
            Readiness::Ready(1)
        );
        t.join().unwrap();
        let since = monotonic_ns();
        assert_eq!(
            wait_for_input(WaitMode::Spin, &[], 2_000_000, || false).unwrap(),
            Readiness::TimedOut
        );
        assert!(monotonic_ns() - since >= 2_000_000);
    }

    #[test]
    fn times_out_and_sees_readable_pipe() {
        let mut fds = [0; 2];
        assert_eq!(unsafe { libc::pipe(fds.as_mut_ptr()) }, 0);
        assert_eq!(
            wait_readable(&[fds[0]], 1_000_000).unwrap(),
            Readiness::TimedOut
        );
        assert_eq!(unsafe { libc::write(fds[1], b"x".as_ptr().cast(), 1) }, 1);
        assert_eq!(
            wait_readable(&[fds[1], fds[0]], 1_000_000).unwrap(),
            Readiness::Ready(0b10)
        );
        unsafe {
            libc::close(fds[0]);
            libc::close(fds[1]);
        }
    }
}
