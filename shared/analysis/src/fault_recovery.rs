//! What a fault cost the loop, read from the plant's recorded samples: the
//! ticks it ran on its safe action after a process was killed, and the
//! samples the recording lacks. `flexloop chaos` reports these per kill.

/// One recorded tick, as far as recovery is concerned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tick {
    pub seq: u64,
    /// Scheduled time of the tick (CLOCK_MONOTONIC ns).
    pub tick_ns: u64,
    /// The loop ran on a safe action over this tick: the plant's (no
    /// command from the active controller in time) or the controller's (a
    /// command computed without a fresh estimate).
    pub safe_action: bool,
    /// The plant woke late for it (the machine's stall: on a kernel
    /// without preemption, the killed process's memory freed on the loop's
    /// CPU is one).
    pub stalled: bool,
}

/// The loop counts as recovered at the first run of this many commanded
/// ticks: a replacement catching up may answer one tick and miss the next,
/// and those misses belong to the fault.
pub const RECOVERED_AFTER: usize = 10;

/// The ticks on the safe action from the first tick scheduled at or after
/// `kill_ns` until the loop is recovered ([`RECOVERED_AFTER`] commanded
/// ticks in a row). `ticks` in sequence order; ticks missing from the
/// recording are not counted (see [`missing_ticks`]). `None` if the
/// recording does not reach a recovery after the kill.
pub fn held_ticks(ticks: &[Tick], kill_ns: u64) -> Option<u64> {
    held_span(ticks, kill_ns).map(|held| held.len() as u64)
}

/// Of the [`held_ticks`], those the plant marked stalled: the machine's
/// part of what the fault cost, the rest is the hand-over's.
pub fn held_stalled_ticks(ticks: &[Tick], kill_ns: u64) -> Option<u64> {
    held_span(ticks, kill_ns).map(|held| held.iter().filter(|t| t.stalled).count() as u64)
}

/// The ticks on the safe action from the kill to the recovery.
fn held_span(ticks: &[Tick], kill_ns: u64) -> Option<Vec<&Tick>> {
    let first = ticks.partition_point(|t| t.tick_ns < kill_ns);
    let mut held = Vec::new();
    let mut commanded_in_a_row = 0;
    for tick in &ticks[first..] {
        if tick.safe_action {
            held.push(tick);
            commanded_in_a_row = 0;
        } else {
            commanded_in_a_row += 1;
            if commanded_in_a_row == RECOVERED_AFTER {
                return Some(held);
            }
        }
    }
    None
}

/// Sequence numbers between the first and the last recorded tick that the
/// recording lacks (`ticks` in sequence order, no duplicates).
pub fn missing_ticks(ticks: &[Tick]) -> u64 {
    match (ticks.first(), ticks.last()) {
        (Some(first), Some(last)) => (last.seq - first.seq + 1) - ticks.len() as u64,
        _ => 0,
    }
}

/// The ticks the recording lacks from the first tick at or after `kill_ns`
/// until `within` ticks after it (or the recording's end): what a logger's
/// death cost the recording.
pub fn missing_after(ticks: &[Tick], kill_ns: u64, within: u64) -> u64 {
    let first = ticks.partition_point(|t| t.tick_ns < kill_ns);
    let Some(start) = first.checked_sub(1).map(|i| ticks[i].seq) else {
        return 0;
    };
    // Not past the recording's end: the run may end within the window.
    let end = (start + within).min(ticks.last().map_or(start, |t| t.seq));
    let recorded = ticks[first..].iter().take_while(|t| t.seq <= end).count() as u64;
    (end - start).saturating_sub(recorded)
}

/// The p-th percentile (0–100) of `values` by nearest rank; 0 when empty.
pub fn percentile(values: &[u64], p: f64) -> u64 {
    if values.is_empty() {
        return 0;
    }
    let mut sorted = values.to_vec();
    sorted.sort_unstable();
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ticks 1 ms apart from seq 0; `held` marks which are on the safe action.
    fn ticks(held: &[bool]) -> Vec<Tick> {
        held.iter()
            .enumerate()
            .map(|(i, &h)| Tick {
                seq: i as u64,
                tick_ns: i as u64 * 1_000_000,
                safe_action: h,
                stalled: false,
            })
            .collect()
    }

    #[test]
    fn held_ticks_run_from_the_kill_to_ten_commanded_ticks() {
        let mut held = vec![false; 40];
        // A miss before the kill does not count; 3 held, one answered, 2 held.
        held[2] = true;
        for i in [6, 7, 8, 10, 11] {
            held[i] = true;
        }
        let ticks = ticks(&held);
        assert_eq!(held_ticks(&ticks, 5_000_000), Some(5));
        // A kill that cost nothing.
        assert_eq!(held_ticks(&ticks, 20_000_000), Some(0));
        // No recovery recorded after the kill.
        assert_eq!(held_ticks(&ticks, 35_000_000), None);
    }

    #[test]
    fn the_stalled_among_the_held_ticks_are_counted_apart() {
        let mut held = vec![false; 40];
        for i in [6, 7, 8, 10, 11] {
            held[i] = true;
        }
        let mut ticks = ticks(&held);
        // The plant woke late for ticks 6 and 7 (held) and 9 (answered).
        for i in [6, 7, 9] {
            ticks[i].stalled = true;
        }
        assert_eq!(held_ticks(&ticks, 5_000_000), Some(5));
        assert_eq!(held_stalled_ticks(&ticks, 5_000_000), Some(2));
        assert_eq!(held_stalled_ticks(&ticks, 35_000_000), None);
    }

    #[test]
    fn missing_ticks_are_the_holes_between_first_and_last() {
        let mut t = ticks(&[false; 10]);
        t.retain(|t| !(3..6).contains(&t.seq));
        assert_eq!(missing_ticks(&t), 3);
        assert_eq!(missing_after(&t, 3_000_000, 5), 3);
        assert_eq!(missing_after(&t, 7_000_000, 2), 0);
        // A window past the recording's end counts only up to it.
        assert_eq!(missing_after(&t, 7_000_000, 100), 0);
        assert_eq!(missing_ticks(&[]), 0);
    }

    #[test]
    fn percentiles_by_nearest_rank() {
        let v: Vec<u64> = (1..=100).collect();
        assert_eq!(percentile(&v, 50.0), 50);
        assert_eq!(percentile(&v, 99.0), 99);
        assert_eq!(percentile(&v, 100.0), 100);
        assert_eq!(percentile(&[7], 99.0), 7);
        assert_eq!(percentile(&[], 50.0), 0);
    }
}
