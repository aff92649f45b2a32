//! Waiting on event file descriptors with a precise timeout.
//!
//! iceoryx2's `Listener::timed_wait` uses SO_RCVTIMEO (jiffies, 4-9 ms here);
//! `ppoll` with a timespec uses hrtimers, so a wait can end at a tick deadline.

use std::os::fd::RawFd;

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
