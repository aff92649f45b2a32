//! What a run's figures are worth: whether the plant kept its grid, and
//! whether a scan's rms is the design's or the machine's.
//!
//! - The grid: a tick is *stalled* when the plant woke more than half a
//!   period late for it. Above [`STALL_SHARE_LIMIT`] of the ticks the loop
//!   did not run at its rate at all (one loop per CPU at 100 kHz: every tick
//!   stalled), whatever the miss counter says: `up`, `status` and `run` fail.
//! - The figures: the control metrics are the design's only if every tick
//!   they depend on ran as designed. A tick where the plant held its input
//!   (the command was late or missing), applied its safe action, or where
//!   the controller ran without the observer, or a tick whose measurement,
//!   command or estimate the log lacks, anywhere from the start of a scan's
//!   motion to the end of its scan window (the whole run for other
//!   references) makes them another loop's.
//!   Stale estimates (one or two ticks old) are reported, not judged: the
//!   controller uses them as designed.

/// Share of stalled ticks above which the plant did not keep its grid.
pub const STALL_SHARE_LIMIT: f64 = 0.10;

/// The plant's counts of a run or of a running loop.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GridCounts {
    pub ticks: u64,
    pub stalled_ticks: u64,
    pub late_commands: u64,
    pub misses: u64,
    pub stall_misses: u64,
}

impl GridCounts {
    /// Stalled ticks as a share of all ticks (0 before the first).
    pub fn stall_share(&self) -> f64 {
        if self.ticks == 0 {
            0.0
        } else {
            self.stalled_ticks as f64 / self.ticks as f64
        }
    }

    /// Whether stalls dominate: the loop did not run at its rate.
    pub fn stalls_dominate(&self) -> bool {
        self.stall_share() > STALL_SHARE_LIMIT
    }

    /// Which component was late, in words: the controller, whose commands
    /// came after their tick or not at all outside stalls (the plant held
    /// its input), and the observer, whose estimates came after the
    /// controller's half-period wait (it used one a tick old). A component
    /// slower than the period, a user's program included, shows here.
    pub fn late_components(&self, stale_estimates: u64) -> String {
        let mut late = Vec::new();
        if self.late_commands + self.misses > 0 {
            late.push(format!(
                "controller ({} commands after their tick, {} ticks without one outside stalls: the plant held its input)",
                self.late_commands, self.misses
            ));
        }
        if stale_estimates > 0 {
            late.push(format!(
                "observer ({stale_estimates} estimates after the controller's half-period wait: it used the one a tick old)"
            ));
        }
        if late.is_empty() {
            "no component was late".into()
        } else {
            format!("late: {}", late.join("; "))
        }
    }

    /// One line: the verdict and the counts behind it.
    pub fn verdict(&self) -> String {
        let counts = format!(
            "{} of {} ticks stalled ({:.1} %), {} late commands, {} misses ({} more after stalls)",
            self.stalled_ticks,
            self.ticks,
            100.0 * self.stall_share(),
            self.late_commands,
            self.misses,
            self.stall_misses
        );
        if self.stalls_dominate() {
            format!(
                "FAILED: the plant did not keep its grid: {counts}; more than {:.0} % of ticks stalled, the loop did not run at its rate (a busy or shared CPU, or a rate this machine cannot keep)",
                100.0 * STALL_SHARE_LIMIT
            )
        } else {
            format!("the plant kept its grid: {counts}")
        }
    }
}

/// What the control figures depend on that did not run as designed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FigureFaults {
    /// Ticks judged (those the figures depend on).
    pub judged_ticks: u64,
    /// The plant held its input: the command was late or missing.
    pub held: u64,
    /// The plant applied its safe action (the controller was silent).
    pub safe_action: u64,
    /// The controller ran without the observer's contribution.
    pub observer_dropped: u64,
    /// Ticks the log lacks (or lacks their command or estimate).
    pub missing: u64,
    /// The plant woke late (reported; judged over the run by [`GridCounts`]).
    pub stalled: u64,
}

impl FigureFaults {
    /// The faults of a run over `spans` (s, inclusive; the whole run when
    /// empty). `timing` holds every logged measurement's flags (sorted by
    /// sequence number), `row_seqs` the sequence numbers with a complete row.
    pub fn of(
        timing: &[crate::trace::TickTiming],
        row_seqs: &[u64],
        ts: f64,
        spans: &[(f64, f64)],
    ) -> Self {
        let eps = 1e-9 * ts;
        let last_seq = timing.last().map_or(0, |t| t.seq);
        let judged = |seq: u64| {
            let t = seq as f64 * ts;
            spans.is_empty() || spans.iter().any(|&(a, b)| t >= a - eps && t <= b + eps)
        };
        let mut faults = Self::default();
        let judged_ticks = (0..=last_seq).filter(|&s| judged(s)).count() as u64;
        faults.judged_ticks = if timing.is_empty() { 0 } else { judged_ticks };
        for t in timing.iter().filter(|t| judged(t.seq)) {
            faults.held += u64::from(t.held);
            faults.safe_action += u64::from(t.fallback);
            faults.observer_dropped += u64::from(t.observer_fallback);
            faults.stalled += u64::from(t.stalled);
        }
        let complete = row_seqs.iter().filter(|&&s| judged(s)).count() as u64;
        faults.missing = faults.judged_ticks.saturating_sub(complete);
        faults
    }
}

/// Why a run's control figures are not the design's; empty when they are.
pub fn invalid_reasons(faults: &FigureFaults, grid: &GridCounts) -> Vec<String> {
    let mut reasons = Vec::new();
    let of = faults.judged_ticks;
    let mut say = |n: u64, what: &str| {
        if n > 0 {
            reasons.push(format!("{n} of {of} ticks the figures rest on {what}"));
        }
    };
    say(
        faults.held,
        "held the input (the command was late or missing)",
    );
    say(
        faults.safe_action,
        "applied the safe action (the controller was silent)",
    );
    say(
        faults.observer_dropped,
        "ran without the observer (its estimate was too old)",
    );
    say(
        faults.missing,
        "lack their measurement, command or estimate in the log",
    );
    if grid.stalls_dominate() {
        reasons.push(format!(
            "the plant did not keep its grid: {} of {} ticks stalled ({:.1} %, more than {:.0} %)",
            grid.stalled_ticks,
            grid.ticks,
            100.0 * grid.stall_share(),
            100.0 * STALL_SHARE_LIMIT
        ));
    }
    reasons
}

/// The spans a scan's figures rest on: each scan window from the start of
/// its scan's motion (`lead_s` before the window: a held input while the
/// stage accelerates still moves the error inside the window).
pub fn judged_spans(windows: &[(f64, f64)], lead_s: f64) -> Vec<(f64, f64)> {
    windows.iter().map(|&(a, b)| (a - lead_s, b)).collect()
}

#[cfg(test)]
mod tests {

    #[test]
    fn the_late_component_is_named_by_what_it_was_late_with() {
        let on_time = GridCounts {
            ticks: 1_000,
            ..GridCounts::default()
        };
        assert_eq!(on_time.late_components(0), "no component was late");
        let slow_controller = GridCounts {
            late_commands: 3,
            misses: 5,
            ..on_time
        };
        let said = slow_controller.late_components(0);
        assert!(
            said.starts_with("late: controller (3 commands") && !said.contains("observer"),
            "{said}"
        );
        let said = on_time.late_components(7);
        assert!(said.starts_with("late: observer (7 estimates"), "{said}");
    }

    use super::*;
    use crate::trace::TickTiming;

    fn timing(n: u64) -> Vec<TickTiming> {
        (0..n)
            .map(|seq| TickTiming {
                seq,
                ..TickTiming::default()
            })
            .collect()
    }

    fn grid(ticks: u64, stalled: u64) -> GridCounts {
        GridCounts {
            ticks,
            stalled_ticks: stalled,
            ..GridCounts::default()
        }
    }

    #[test]
    fn stalls_dominate_above_a_tenth_of_the_ticks() {
        assert!(!grid(0, 0).stalls_dominate());
        assert!(!grid(1_000, 100).stalls_dominate());
        assert!(grid(1_000, 101).stalls_dominate());
        // --rate 100000 on a 2-CPU VM: every tick stalled, no "miss".
        let all = GridCounts {
            ticks: 100_000,
            stalled_ticks: 100_000,
            late_commands: 99_999,
            misses: 0,
            stall_misses: 99_999,
        };
        assert!(all.stalls_dominate());
        let line = all.verdict();
        assert!(
            line.starts_with("FAILED") && line.contains("100000 of 100000 ticks stalled (100.0 %)"),
            "{line}"
        );
        assert!(
            grid(1_000, 3)
                .verdict()
                .starts_with("the plant kept its grid")
        );
    }

    #[test]
    fn a_clean_run_is_valid() {
        let t = timing(100);
        let rows: Vec<u64> = (0..100).collect();
        let faults = FigureFaults::of(&t, &rows, 1e-3, &[(0.02, 0.05)]);
        assert_eq!(faults.judged_ticks, 31);
        assert!(invalid_reasons(&faults, &grid(100, 0)).is_empty());
    }

    #[test]
    fn faults_inside_the_spans_invalidate_and_outside_they_do_not() {
        let mut t = timing(100);
        let rows: Vec<u64> = (0..100).filter(|s| *s != 40).collect();
        t[10].held = true; // before the span
        t[30].held = true;
        t[31].held = true;
        t[32].fallback = true;
        t[33].observer_fallback = true;
        t[34].stalled = true; // reported, judged over the run
        t[90].fallback = true; // after it
        let faults = FigureFaults::of(&t, &rows, 1e-3, &[(0.02, 0.05)]);
        assert_eq!(
            faults,
            FigureFaults {
                judged_ticks: 31,
                held: 2,
                safe_action: 1,
                observer_dropped: 1,
                missing: 1,
                stalled: 1,
            }
        );
        let reasons = invalid_reasons(&faults, &grid(100, 1));
        assert_eq!(reasons.len(), 4, "{reasons:?}");
        assert!(reasons[0].starts_with("2 of 31 ticks") && reasons[0].contains("held the input"));
        assert!(reasons[3].contains("lack their measurement, command or estimate"));
    }

    #[test]
    fn ticks_the_logger_never_got_count_as_missing() {
        // Measurements 20..=29 never reached the log at all.
        let t: Vec<TickTiming> = timing(50)
            .into_iter()
            .filter(|t| !(20..30).contains(&t.seq))
            .collect();
        let rows: Vec<u64> = t.iter().map(|t| t.seq).collect();
        let faults = FigureFaults::of(&t, &rows, 1e-3, &[]);
        assert_eq!((faults.judged_ticks, faults.missing), (50, 10));
    }

    #[test]
    fn dominating_stalls_invalidate_even_a_run_without_a_held_input() {
        let t = timing(100);
        let rows: Vec<u64> = (0..100).collect();
        let faults = FigureFaults::of(&t, &rows, 1e-3, &[]);
        let reasons = invalid_reasons(&faults, &grid(100, 60));
        assert_eq!(reasons.len(), 1);
        assert!(
            reasons[0].contains("60 of 100 ticks stalled"),
            "{reasons:?}"
        );
    }

    #[test]
    fn a_scan_is_judged_from_the_start_of_its_motion() {
        assert_eq!(
            judged_spans(&[(0.5, 1.75), (3.0, 4.25)], 0.25),
            vec![(0.25, 1.75), (2.75, 4.25)]
        );
    }
}
