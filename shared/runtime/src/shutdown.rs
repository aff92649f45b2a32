//! SIGINT/SIGTERM become a flag; the loops check it once per sample.
//!
//! The handler only stores to an atomic (async-signal-safe); all the work of
//! stopping happens in the loop, which drains, writes its files and exits.

use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);
static SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(sig: libc::c_int) {
    SIGNAL.store(sig, Ordering::Relaxed);
    REQUESTED.store(true, Ordering::Release);
}

/// Installs the handler for SIGINT, SIGTERM and SIGHUP.
pub fn install() -> std::io::Result<()> {
    for sig in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
        // SAFETY: a zeroed sigaction with a plain handler and an empty mask is
        // valid; the handler only touches atomics.
        unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = on_signal as *const () as usize;
            libc::sigemptyset(&mut action.sa_mask);
            // No SA_RESTART: a blocking wait returns EINTR and the loop sees the flag.
            action.sa_flags = 0;
            if libc::sigaction(sig, &action, std::ptr::null_mut()) != 0 {
                return Err(std::io::Error::last_os_error());
            }
        }
    }
    Ok(())
}

/// True once a termination signal arrived (or [`request`] was called).
pub fn requested() -> bool {
    REQUESTED.load(Ordering::Acquire)
}

/// Asks the loops of this process to stop, as a signal would.
pub fn request() {
    REQUESTED.store(true, Ordering::Release);
}

/// The last signal received, 0 if none.
pub fn signal() -> i32 {
    SIGNAL.load(Ordering::Relaxed)
}
