//! Waiting for the plant's tick t_k so that y(k) is sampled on it.
//!
//! An absolute `clock_nanosleep` returns 10–20 µs after t_k on this machine
//! kind (timer wake-up, /work/shared/reference/timing.md), so the sampling
//! instant jitters by as much. [`TickWait::SleepThenSpin`] sleeps until
//! t_k − margin and spins on the clock for the rest; the margin follows a
//! high percentile of the sleep's own recent lateness ([`SpinMargin`]), so
//! the spin is as short as this machine allows at the moment. The spin is
//! bounded (it ends at t_k or after margin + [`SPIN_CAP_NS`]) and runs below
//! the observer and the controller in priority, which preempt it
//! (docs/architecture.md, "Waiting for the tick").
//!
//! Per tick: two clock reads (vDSO, no system call) besides the sleep, no
//! allocation, no lock.

use crate::clock::sleep_until;
use crate::monotonic_ns;

/// How the plant waits for its tick under shared cores.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TickWait {
    /// Sleep until t_k.
    Sleep,
    /// Sleep until t_k − margin, then spin until t_k.
    SleepThenSpin,
}

/// Lower bound of the margin: below it a spin saves too little to be worth
/// a wake-up that lands after the tick.
pub const MARGIN_MIN_NS: u64 = 5_000;
/// Upper bound of the margin (never more than half a period either).
pub const MARGIN_MAX_NS: u64 = 60_000;
/// A spin never lasts longer than the margin plus this, whatever the clock
/// says (a sleep cut short by signals): then the tick goes on.
pub const SPIN_CAP_NS: u64 = 50_000;
/// Added to the lateness percentile: the wake-up itself and the first clock
/// read after it.
const GUARD_NS: u64 = 2_000;
/// Recent sleeps the percentile is taken over (0.1 s at 10 kHz).
const WINDOW: usize = 1024;
/// Lateness is counted in whole microseconds, 0..=BUCKETS-1 (the last
/// bucket holds everything later: the margin's bound is below it anyway).
const BUCKETS: usize = 64;
/// The percentile of recent lateness the margin covers, per mille.
const PERCENTILE_PER_MILLE: usize = 990;

/// The spin margin: the p99 of the sleep's lateness over the last
/// [`WINDOW`] wake-ups, plus a guard, within [`MARGIN_MIN_NS`] and the
/// upper bound. A sliding histogram of 1 µs buckets: each wake-up adds one
/// count and removes the one that left the window, and the percentile is
/// a scan of 64 counters.
#[derive(Debug, Clone)]
pub struct SpinMargin {
    ring: [u8; WINDOW],
    counts: [u16; BUCKETS],
    next: usize,
    filled: usize,
    max_ns: u64,
    margin_ns: u64,
    lowest_ns: u64,
    highest_ns: u64,
}

impl SpinMargin {
    /// Starts at the upper bound (safe until the window has samples);
    /// `period_ns` caps it at half a period, so that the plant sleeps for
    /// at least half of every period.
    pub fn new(period_ns: u64) -> Self {
        let max_ns = MARGIN_MAX_NS.min(period_ns / 2).max(MARGIN_MIN_NS);
        Self {
            ring: [0; WINDOW],
            counts: [0; BUCKETS],
            next: 0,
            filled: 0,
            max_ns,
            margin_ns: max_ns,
            lowest_ns: max_ns,
            highest_ns: max_ns,
        }
    }

    /// The margin for the next sleep.
    pub fn current_ns(&self) -> u64 {
        self.margin_ns
    }

    /// The smallest and largest margin used so far.
    pub fn range_ns(&self) -> (u64, u64) {
        (self.lowest_ns, self.highest_ns)
    }

    /// The margin's bounds, `(lower, upper)`.
    pub fn bounds_ns(&self) -> (u64, u64) {
        (MARGIN_MIN_NS, self.max_ns)
    }

    /// One sleep's lateness (wake-up − the time asked for).
    pub fn observe(&mut self, lateness_ns: u64) {
        let bucket = (lateness_ns / 1_000).min(BUCKETS as u64 - 1) as u8;
        if self.filled == WINDOW {
            let old = self.ring[self.next] as usize;
            self.counts[old] -= 1;
        } else {
            self.filled += 1;
        }
        self.ring[self.next] = bucket;
        self.counts[bucket as usize] += 1;
        self.next = (self.next + 1) % WINDOW;
        // The smallest bucket with at least the percentile's share at or
        // below it; its upper edge is the lateness covered.
        let rank = (self.filled * PERCENTILE_PER_MILLE).div_ceil(1000).max(1);
        let mut seen = 0;
        let mut covered_us = BUCKETS as u64;
        for (b, &c) in self.counts.iter().enumerate() {
            seen += c as usize;
            if seen >= rank {
                covered_us = b as u64 + 1;
                break;
            }
        }
        self.margin_ns = (covered_us * 1_000 + GUARD_NS).clamp(MARGIN_MIN_NS, self.max_ns);
        self.lowest_ns = self.lowest_ns.min(self.margin_ns);
        self.highest_ns = self.highest_ns.max(self.margin_ns);
    }
}

/// What the spinning wait did over a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SpinCounts {
    /// Ticks whose sleep ended before t_k and that spun the rest.
    pub spun_ticks: u64,
    /// Ticks whose sleep ended at or after t_k (nothing left to spin).
    pub late_wakeups: u64,
    /// Spins that ended by [`SPIN_CAP_NS`] before t_k.
    pub capped_spins: u64,
    /// Time spent spinning, summed.
    pub spin_ns: u64,
}

/// The plant's tick wait: the setting, and for a spinning one its margin
/// and counts.
#[derive(Debug, Clone)]
pub struct TickWaiter {
    wait: TickWait,
    margin: SpinMargin,
    counts: SpinCounts,
}

impl TickWaiter {
    pub fn new(wait: TickWait, period_ns: u64) -> Self {
        Self {
            wait,
            margin: SpinMargin::new(period_ns),
            counts: SpinCounts::default(),
        }
    }

    pub fn setting(&self) -> TickWait {
        self.wait
    }

    pub fn margin(&self) -> &SpinMargin {
        &self.margin
    }

    pub fn counts(&self) -> SpinCounts {
        self.counts
    }

    /// Returns at `tick_ns` or after (sleeping: when the timer wakes the
    /// process; spinning: on the tick, unless the sleep woke after it).
    pub fn wait_for(&mut self, tick_ns: u64) {
        match self.wait {
            TickWait::Sleep => sleep_until(tick_ns),
            TickWait::SleepThenSpin => self.sleep_then_spin(tick_ns),
        }
    }

    fn sleep_then_spin(&mut self, tick_ns: u64) {
        let margin = self.margin.current_ns();
        let target = tick_ns.saturating_sub(margin);
        // Only a real sleep says how late this machine wakes: a plant that
        // is already past its target (a long tick, a stall) would count its
        // own lateness.
        if monotonic_ns() < target {
            sleep_until(target);
            let woke = monotonic_ns();
            self.margin.observe(woke.saturating_sub(target));
        }
        let start = monotonic_ns();
        if start >= tick_ns {
            self.counts.late_wakeups += 1;
            return;
        }
        let stop = tick_ns.min(start.saturating_add(margin + SPIN_CAP_NS));
        let mut now = start;
        while now < stop {
            std::hint::spin_loop();
            now = monotonic_ns();
        }
        self.counts.spun_ticks += 1;
        self.counts.spin_ns += now - start;
        if now < tick_ns {
            self.counts.capped_spins += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_margin_covers_the_p99_of_recent_lateness_within_its_bounds() {
        let mut m = SpinMargin::new(200_000);
        assert_eq!(m.current_ns(), MARGIN_MAX_NS, "starts at the upper bound");
        // Over 99 % wake 12.x µs late, 8 in 1024 40 µs: the p99 is the 12 µs bucket.
        for i in 0..WINDOW {
            m.observe(if i % 128 == 0 { 40_000 } else { 12_400 });
        }
        assert_eq!(m.current_ns(), 13_000 + GUARD_NS);
        // A quiet machine: the lower bound.
        for _ in 0..WINDOW {
            m.observe(300);
        }
        assert_eq!(m.current_ns(), MARGIN_MIN_NS);
        // A wild one: the upper bound, however late.
        for _ in 0..WINDOW {
            m.observe(5_000_000);
        }
        assert_eq!(m.current_ns(), MARGIN_MAX_NS);
        assert_eq!(m.range_ns(), (MARGIN_MIN_NS, MARGIN_MAX_NS));
    }

    #[test]
    fn old_wake_ups_leave_the_window() {
        let mut m = SpinMargin::new(200_000);
        for _ in 0..WINDOW {
            m.observe(30_000);
        }
        assert_eq!(m.current_ns(), 33_000);
        // Once 99 % of the window is newer and earlier, the old ones no
        // longer count.
        for _ in 0..WINDOW - WINDOW / 100 {
            m.observe(8_000);
        }
        assert_eq!(m.current_ns(), 11_000);
        assert_eq!(m.counts.iter().map(|c| *c as usize).sum::<usize>(), WINDOW);
    }

    #[test]
    fn half_a_period_caps_the_margin() {
        // 20 kHz: 50 µs period, margin at most 25 µs.
        let m = SpinMargin::new(50_000);
        assert_eq!(m.bounds_ns(), (MARGIN_MIN_NS, 25_000));
        assert_eq!(m.current_ns(), 25_000);
    }

    #[test]
    fn every_wait_returns_on_or_after_its_tick() {
        for wait in [TickWait::Sleep, TickWait::SleepThenSpin] {
            let mut w = TickWaiter::new(wait, 200_000);
            let start = monotonic_ns() + 1_000_000;
            for k in 0..50 {
                let tick = start + k * 200_000;
                w.wait_for(tick);
                assert!(monotonic_ns() >= tick, "{wait:?} tick {k}");
            }
            let c = w.counts();
            match wait {
                TickWait::Sleep => assert_eq!(c, SpinCounts::default()),
                TickWait::SleepThenSpin => {
                    assert_eq!(c.spun_ticks + c.late_wakeups, 50);
                    assert_eq!(c.capped_spins, 0);
                }
            }
        }
    }
}
