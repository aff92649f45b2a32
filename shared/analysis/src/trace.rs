//! A run as columns per tick, aligned by sequence number: the first output
//! and first input in [`TickRow`] (the SISO loops the thesis studies), and
//! e_true and u of every axis beside them (MIMO loops).
//!
//! Row k holds y(k) as the plant published it, u(k) as the controller
//! computed it from y(k), and the estimate the controller used at tick k
//! (x̂(k|k−1)). A tick whose messages are missing from a log is left out and
//! counted, never filled in. The timing of every tick the plant logged,
//! complete or not, is kept apart in [`RunTrace::timing`].

use flexloop_components::InProcessLoop;
use flexloop_protocol::{Command, Estimate, Measurement, flags};
use flexloop_recording::LogReader;
use std::collections::BTreeMap;

/// One tick of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TickRow {
    pub seq: u64,
    /// Set-point r(k).
    pub r: f64,
    /// True output y(k) (no sensor noise).
    pub y_true: f64,
    /// Measured output.
    pub y: f64,
    /// Input applied over [t_k, t_k+1).
    pub u_applied: f64,
    /// Command computed from y(k), and its parts.
    pub u: f64,
    pub u_fb: f64,
    pub u_ff: f64,
    pub u_d: f64,
    pub e_meas: f64,
    /// Innovation of y(k) (from the estimate for tick k+1; NaN where unknown).
    pub innovation: f64,
    /// The plant held its input at this tick (command missing).
    pub held: bool,
    /// The controller used an older estimate than the one due.
    pub stale_estimate: bool,
}

impl TickRow {
    /// e_true(k) = r(k) − y(k): the error the machine actually makes.
    pub fn e_true(&self) -> f64 {
        self.r - self.y_true
    }
}

/// How one tick went, as the plant and the controller stamped it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TickTiming {
    pub seq: u64,
    /// Plant awake minus the scheduled tick, ns.
    pub lateness_ns: u64,
    /// u(k) published minus the scheduled tick k, ns (None when u(k) is not
    /// in the log): the one-sample budget applies to it.
    pub command_ns: Option<u64>,
    /// The plant held its input: the command due was missing (a loop miss,
    /// or a miss after a stall).
    pub held: bool,
    /// The plant itself woke too late for this tick.
    pub stalled: bool,
    /// The plant applied its safe action (controller silent).
    pub fallback: bool,
    /// The controller ran without the observer's contribution.
    pub observer_fallback: bool,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunTrace {
    /// Sample period in s; tick k is at t = k·ts.
    pub ts: f64,
    pub rows: Vec<TickRow>,
    /// x̂(k|k−1) per row, `n_states` values each.
    pub x_hat: Vec<f64>,
    pub n_states: usize,
    /// e_true = r − y_true of every output per row, `n_outputs` values each.
    pub e_true_axes: Vec<f64>,
    pub n_outputs: usize,
    /// The command u of every input per row, `n_inputs` values each.
    pub u_axes: Vec<f64>,
    pub n_inputs: usize,
    /// Ticks with a measurement but no command or estimate in the log.
    pub incomplete_ticks: u64,
    /// Every logged measurement's timing, by sequence number (empty for a
    /// simulated run, which has no clock).
    pub timing: Vec<TickTiming>,
    /// The plant's own counters at the end of the run.
    pub misses: u64,
    pub stalled_ticks: u64,
    pub stall_misses: u64,
    pub late_commands: u64,
}

impl RunTrace {
    pub fn new(ts: f64) -> Self {
        Self {
            ts,
            ..Self::default()
        }
    }

    pub fn time(&self, row: &TickRow) -> f64 {
        row.seq as f64 * self.ts
    }

    /// x̂ of row `i`.
    pub fn x_hat(&self, i: usize) -> &[f64] {
        &self.x_hat[i * self.n_states..(i + 1) * self.n_states]
    }

    /// e_true of every output at row `i`.
    pub fn e_true_of(&self, i: usize) -> &[f64] {
        &self.e_true_axes[i * self.n_outputs..(i + 1) * self.n_outputs]
    }

    /// u of every input at row `i`.
    pub fn u_of(&self, i: usize) -> &[f64] {
        &self.u_axes[i * self.n_inputs..(i + 1) * self.n_inputs]
    }

    /// Appends the messages of one tick.
    pub fn push(&mut self, m: &Measurement, c: &Command, used: &Estimate, next: Option<&Estimate>) {
        let n = used.n_states as usize;
        if self.rows.is_empty() {
            self.n_states = n;
            self.n_outputs = (m.n_outputs as usize).clamp(1, m.y.len());
            self.n_inputs = (c.n_inputs as usize).clamp(1, c.u.len());
        }
        for i in 0..self.n_outputs {
            self.e_true_axes.push(c.r[i] - m.y_true[i]);
        }
        self.u_axes.extend_from_slice(&c.u[..self.n_inputs]);
        self.rows.push(TickRow {
            seq: m.seq,
            r: c.r[0],
            y_true: m.y_true[0],
            y: m.y[0],
            u_applied: m.u_applied[0],
            u: c.u[0],
            u_fb: c.u_fb[0],
            u_ff: c.u_ff[0],
            u_d: c.u_d[0],
            e_meas: c.e_meas[0],
            innovation: next.map_or(f64::NAN, |e| e.innovation[0]),
            held: m.flags & flags::HELD_INPUT != 0,
            stale_estimate: c.flags & flags::STALE_ESTIMATE != 0,
        });
        let width = self.n_states.min(used.x_hat.len());
        self.x_hat.extend_from_slice(&used.x_hat[..width]);
        self.x_hat
            .extend(std::iter::repeat_n(0.0, self.n_states - width));
        self.misses = m.misses;
        self.stalled_ticks = m.stalled_ticks;
        self.stall_misses = m.stall_misses;
        self.late_commands = m.late_commands;
    }

    /// Runs the in-process loop for `ticks` and records it.
    pub fn simulate(run: &mut InProcessLoop, ts: f64, ticks: u64) -> Self {
        let mut trace = Self::new(ts);
        for _ in 0..ticks {
            run.tick();
            trace.push(
                &run.measurement,
                &run.command,
                &run.used_estimate,
                Some(&run.estimate),
            );
        }
        trace
    }

    /// Rebuilds the run from a log: every tick that has its measurement, its
    /// command and the estimate the command used.
    pub fn from_log(log: &LogReader, ts: f64) -> Self {
        let estimates: BTreeMap<u64, &Estimate> = log.estimates().map(|e| (e.seq, e)).collect();
        let commands: BTreeMap<u64, &Command> = log.commands().map(|c| (c.seq, c)).collect();
        let mut trace = Self::new(ts);
        let mut measurements: Vec<&Measurement> = log.measurements().collect();
        measurements.sort_by_key(|m| m.seq);
        for m in measurements {
            let command = commands.get(&m.seq);
            trace.timing.push(TickTiming {
                seq: m.seq,
                lateness_ns: m.woke_ns.saturating_sub(m.tick_ns),
                command_ns: command.map(|c| c.published_ns.saturating_sub(m.tick_ns)),
                held: m.flags & flags::HELD_INPUT != 0,
                stalled: m.flags & flags::STALLED_TICK != 0,
                fallback: m.flags & flags::FALLBACK != 0,
                observer_fallback: command.is_some_and(|c| c.flags & flags::OBSERVER_FALLBACK != 0),
            });
            let used = command.and_then(|c| estimates.get(&c.estimate_seq));
            match (command, used) {
                (Some(c), Some(e)) => {
                    let next = estimates.get(&(m.seq + 1)).copied();
                    trace.push(m, c, e, next);
                }
                _ => trace.incomplete_ticks += 1,
            }
        }
        trace
    }
}
