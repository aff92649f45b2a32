//! What the conductor measures of the running loop: its pace, and the
//! command's step at a switch.

use flexloop_protocol::MAX_INPUTS;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Commands kept for measuring the step at a switch.
const COMMAND_HISTORY: usize = 4096;
/// Ordinary sample-to-sample changes are measured over this many samples
/// before and after the switch.
pub const BEFORE_SWITCH: u64 = 100;
/// The shortest span the loop's pace is measured over.
const PACE_MIN_SPAN: Duration = Duration::from_millis(100);
/// How far back the pace looks.
const PACE_WINDOW: Duration = Duration::from_millis(500);

/// The loop's real pace, from (when, newest sample) points.
#[derive(Debug, Default)]
pub struct Pace {
    points: VecDeque<(Instant, u64)>,
}

impl Pace {
    pub fn push(&mut self, now: Instant, seq: u64) {
        self.points.push_back((now, seq));
        while self
            .points
            .front()
            .is_some_and(|(t, _)| now.duration_since(*t) > PACE_WINDOW)
        {
            self.points.pop_front();
        }
    }

    /// Samples per second, once the points span [`PACE_MIN_SPAN`]: over a
    /// shorter span one poll that drains a backlog reads as a burst (two
    /// polls 70 µs apart at the loop's start once gave 2.3 MHz, and a
    /// boundary 11 s away that the run never reached).
    pub fn observed(&self) -> Option<f64> {
        let ((t0, s0), (t1, s1)) = (self.points.front()?, self.points.back()?);
        let span = t1.checked_duration_since(*t0)?;
        (span >= PACE_MIN_SPAN).then(|| s1.saturating_sub(*s0) as f64 / span.as_secs_f64())
    }
}

/// The recent commands the plant may have applied: (sample, from its owner,
/// u); the owner's, and the standby's, which the plant applies while the
/// owner is silent.
#[derive(Debug)]
pub struct CommandHistory {
    recent: VecDeque<(u64, bool, [f64; MAX_INPUTS])>,
    n_inputs: usize,
}

/// The command's step at a boundary and the largest ordinary steps before
/// and after it (|u(k) − u(k−1)|, the largest over the inputs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Steps {
    pub at_switch: f64,
    pub before: f64,
    pub after: f64,
}

impl CommandHistory {
    pub fn new(n_inputs: usize) -> Self {
        Self {
            recent: VecDeque::with_capacity(COMMAND_HISTORY),
            n_inputs,
        }
    }

    pub fn push(&mut self, seq: u64, from_owner: bool, u: [f64; MAX_INPUTS]) {
        if self.recent.len() == COMMAND_HISTORY {
            self.recent.pop_front();
        }
        self.recent.push_back((seq, from_owner, u));
    }

    /// What the plant applied at `seq`: the owner's command, else the
    /// standby's, else (neither seen: late or lost on a busy machine) the
    /// input it held, if that was the sample before's; older is not known.
    fn applied(&self, seq: u64) -> Option<[f64; MAX_INPUTS]> {
        let of = |owner: bool| {
            self.recent
                .iter()
                .rev()
                .find(|(s, o, _)| *s == seq && *o == owner)
                .map(|(_, _, u)| *u)
        };
        of(true).or_else(|| of(false)).or_else(|| {
            self.recent
                .iter()
                .filter(|(s, _, _)| s.saturating_add(1) == seq)
                .max_by_key(|(s, o, _)| (*s, *o))
                .map(|(_, _, u)| *u)
        })
    }

    fn step(&self, seq: u64) -> Option<f64> {
        let (a, b) = (self.applied(seq.checked_sub(1)?)?, self.applied(seq)?);
        Some(
            (0..self.n_inputs)
                .map(|i| (b[i] - a[i]).abs())
                .fold(0.0, f64::max),
        )
    }

    pub fn steps_at(&self, from_seq: u64) -> Steps {
        let largest =
            |range: std::ops::Range<u64>| range.filter_map(|s| self.step(s)).fold(0.0, f64::max);
        Steps {
            at_switch: self.step(from_seq).unwrap_or(f64::NAN),
            before: largest(from_seq.saturating_sub(BEFORE_SWITCH)..from_seq),
            after: largest(from_seq + 1..from_seq + 1 + BEFORE_SWITCH),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn u(x: f64) -> [f64; MAX_INPUTS] {
        let mut u = [0.0; MAX_INPUTS];
        u[0] = x;
        u
    }

    #[test]
    fn pace_needs_a_long_enough_span() {
        let t0 = Instant::now();
        let mut pace = Pace::default();
        assert_eq!(pace.observed(), None);
        // A backlog drained by two polls 70 µs apart is no pace at all.
        pace.push(t0, 94);
        pace.push(t0 + Duration::from_micros(70), 258);
        assert_eq!(pace.observed(), None);
        let mut steady = Pace::default();
        steady.push(t0, 1000);
        steady.push(t0 + Duration::from_millis(50), 1500);
        steady.push(t0 + Duration::from_millis(200), 3000);
        let pace = steady.observed().unwrap();
        assert!((pace - 10_000.0).abs() < 1e-6, "{pace}");
    }

    #[test]
    fn pace_forgets_what_is_older_than_its_window() {
        let t0 = Instant::now();
        let mut pace = Pace::default();
        // A stall (400 samples in 400 ms), then the loop's own pace.
        pace.push(t0, 0);
        pace.push(t0 + Duration::from_millis(400), 400);
        pace.push(t0 + Duration::from_millis(700), 3400);
        // The stall's start is more than the window ago: no longer counted.
        let observed = pace.observed().unwrap();
        assert!((observed - 10_000.0).abs() < 1e-6, "{observed}");
    }

    #[test]
    fn the_step_is_the_owners_else_the_standbys_else_the_held_input() {
        let mut history = CommandHistory::new(1);
        for seq in 0..10 {
            history.push(seq, true, u(seq as f64));
        }
        // Sample 10: the owner silent, the standby's command applied.
        history.push(10, false, u(12.0));
        history.push(11, true, u(12.5));
        // Sample 12: nothing seen; the plant held sample 11's.
        history.push(13, true, u(13.0));
        let steps = history.steps_at(10);
        assert_eq!(steps.at_switch, 3.0);
        assert_eq!(steps.before, 1.0);
        assert_eq!(steps.after, 0.5);
        assert_eq!(history.steps_at(12).at_switch, 0.0);
        // Before the first command nothing is known.
        assert!(history.steps_at(0).at_switch.is_nan());
    }
}
