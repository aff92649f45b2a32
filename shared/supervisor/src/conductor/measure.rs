//! What the conductor measures of the running loop: its pace, and the
//! command's step at a switch.

use flexloop_protocol::{MAX_INPUTS, NO_SEQ};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Samples kept for measuring the step at a switch.
const APPLIED_HISTORY: usize = 4096;
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

/// What the plant applied over its recent samples, from its measurements:
/// the step at a switch is the one the actuator saw. (Not from the commands:
/// their channel holds 16 samples, and a supervisor starved for longer on a
/// loaded machine guessed steps from the ones it still had.)
#[derive(Debug)]
pub struct AppliedHistory {
    recent: VecDeque<Applied>,
    n_inputs: usize,
}

/// One sample as the plant published it.
#[derive(Debug, Clone, Copy)]
struct Applied {
    seq: u64,
    /// The command applied over the sample ([`NO_SEQ`] before the first).
    command_seq: u64,
    u: [f64; MAX_INPUTS],
}

/// The input's step where a switch took effect and the largest ordinary
/// steps before and after it (|u(k) − u(k−1)|, the largest over the
/// inputs; NaN where the samples are not known).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Steps {
    pub at_switch: f64,
    pub before: f64,
    pub after: f64,
}

impl AppliedHistory {
    pub fn new(n_inputs: usize) -> Self {
        Self {
            recent: VecDeque::with_capacity(APPLIED_HISTORY),
            n_inputs,
        }
    }

    pub fn push(&mut self, seq: u64, command_seq: u64, u: [f64; MAX_INPUTS]) {
        if self.recent.len() == APPLIED_HISTORY {
            self.recent.pop_front();
        }
        self.recent.push_back(Applied {
            seq,
            command_seq,
            u,
        });
    }

    fn applied(&self, seq: u64) -> Option<&Applied> {
        self.recent.iter().rev().find(|a| a.seq == seq)
    }

    /// |u(seq) − u(seq − 1)|, if the plant's samples of both were seen.
    fn step(&self, seq: u64) -> Option<f64> {
        let (a, b) = (self.applied(seq.checked_sub(1)?)?, self.applied(seq)?);
        Some(
            (0..self.n_inputs)
                .map(|i| (b.u[i] - a.u[i]).abs())
                .fold(0.0, f64::max),
        )
    }

    /// The steps around the first sample on which a command of `from_seq`
    /// or later acts (the switch's first command; a held input until then
    /// is the safe action's, counted before it).
    /// The first tick that applied a command for `from_seq` or later: the
    /// switch as the plant saw it (a restart after a hold may come ticks
    /// after its boundary).
    pub fn first_applied_from(&self, from_seq: u64) -> Option<u64> {
        self.recent
            .iter()
            .find(|a| a.command_seq != NO_SEQ && a.command_seq >= from_seq)
            .map(|a| a.seq)
    }

    pub fn steps_at(&self, from_seq: u64) -> Steps {
        let largest = |range: std::ops::Range<u64>| {
            let known: Vec<f64> = range.filter_map(|s| self.step(s)).collect();
            if known.is_empty() {
                f64::NAN
            } else {
                known.into_iter().fold(0.0, f64::max)
            }
        };
        let Some(first) = self.first_applied_from(from_seq) else {
            return Steps {
                at_switch: f64::NAN,
                before: f64::NAN,
                after: f64::NAN,
            };
        };
        Steps {
            at_switch: self.step(first).unwrap_or(f64::NAN),
            before: largest(first.saturating_sub(BEFORE_SWITCH)..first),
            after: largest(first + 1..first + 1 + BEFORE_SWITCH),
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
    fn the_step_is_where_the_first_new_command_acts() {
        let mut history = AppliedHistory::new(1);
        assert!(history.steps_at(0).at_switch.is_nan());
        // Commands 0..=8 act one sample later; 9 and 10 are held (the safe
        // action), then command 10 (the new owner's first) acts at 11.
        for seq in 1..10 {
            history.push(seq, seq - 1, u(seq as f64));
        }
        history.push(10, 8, u(9.0));
        history.push(11, 10, u(12.0));
        history.push(12, 11, u(12.5));
        let steps = history.steps_at(10);
        assert_eq!(steps.at_switch, 3.0);
        assert_eq!(steps.before, 1.0);
        assert_eq!(steps.after, 0.5);
        // A sample not seen leaves its steps unknown, not guessed.
        history.push(14, 13, u(13.0));
        assert!(history.steps_at(13).at_switch.is_nan());
        assert!(history.steps_at(20).at_switch.is_nan());
    }
}
