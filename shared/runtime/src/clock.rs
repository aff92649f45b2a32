//! The plant's tick grid: absolute wake-ups on CLOCK_MONOTONIC.
//!
//! Absolute deadlines do not drift when one tick runs long, and
//! `clock_nanosleep` is hrtimer-based (iceoryx2's WaitSet timers round to
//! whole milliseconds, so they cannot drive 10 kHz).

use crate::monotonic_ns;
use crate::wait::WaitMode;

/// Waits for `deadline_ns`: sleeping ([`WaitMode::Events`]) or spinning on
/// the clock ([`WaitMode::Spin`], a CPU of its own, no wake-up latency).
pub fn wait_until(mode: WaitMode, deadline_ns: u64) {
    match mode {
        WaitMode::Events => sleep_until(deadline_ns),
        WaitMode::Spin => {
            while monotonic_ns() < deadline_ns {
                std::hint::spin_loop();
            }
        }
    }
}

/// Sleeps until `deadline_ns` on CLOCK_MONOTONIC; returns at once if it passed.
///
/// Retries on EINTR so that a signal (the shutdown handler) does not shorten a
/// tick; the caller checks its shutdown flag once per tick.
pub fn sleep_until(deadline_ns: u64) {
    let ts = libc::timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as libc::time_t,
        tv_nsec: (deadline_ns % 1_000_000_000) as libc::c_long,
    };
    // Bounded: each EINTR needs a delivered signal, and after a handful the
    // deadline has usually passed and the call returns at once.
    for _ in 0..64 {
        // SAFETY: `ts` is a valid timespec; a null remainder is allowed with TIMER_ABSTIME.
        let rc = unsafe {
            libc::clock_nanosleep(
                libc::CLOCK_MONOTONIC,
                libc::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if rc != libc::EINTR {
            return;
        }
    }
}

/// The grid t_k = start + k · period.
#[derive(Debug, Clone, Copy)]
pub struct TickGrid {
    start_ns: u64,
    period_ns: u64,
}

impl TickGrid {
    /// A grid whose tick 0 is `lead_ns` from now (time to get everyone ready).
    pub fn starting_in(period_ns: u64, lead_ns: u64) -> Self {
        Self {
            start_ns: monotonic_ns() + lead_ns,
            period_ns,
        }
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    pub fn tick_ns(&self, k: u64) -> u64 {
        self.start_ns + k * self.period_ns
    }

    /// The first tick whose time has not passed yet at `now_ns`.
    pub fn next_tick_after(&self, now_ns: u64) -> u64 {
        if now_ns < self.start_ns {
            0
        } else {
            (now_ns - self.start_ns) / self.period_ns + 1
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_is_absolute() {
        let g = TickGrid {
            start_ns: 1_000,
            period_ns: 100,
        };
        assert_eq!(g.tick_ns(0), 1_000);
        assert_eq!(g.tick_ns(7), 1_700);
        assert_eq!(g.next_tick_after(999), 0);
        assert_eq!(g.next_tick_after(1_000), 1);
        assert_eq!(g.next_tick_after(1_250), 3);
    }

    #[test]
    fn sleep_until_does_not_return_early() {
        let deadline = monotonic_ns() + 2_000_000;
        sleep_until(deadline);
        assert!(monotonic_ns() >= deadline);
        // A deadline in the past returns at once.
        sleep_until(0);
    }
}
