//! The controller process's work: u(k) from y(k) and the estimate for tick k.
//!
//! u_c(k) = u_fb + u_ff + u_d, where
//! - ŷ_flex and u_d are the observer block's outputs at tick k: the estimate's
//!   free response plus its direct gain times [y(k); u_a(k)] (and u_pending(k)
//!   with an extra sample of loop delay);
//! - u_fb is the feedback filter on e_meas = r(k) − (y(k) − ŷ_flex(k));
//! - u_ff is the feedforward for the tick the command will be applied at,
//!   advanced by the loop delay so that the delay does not cost tracking.

use crate::control_law::{ControlLaw, ControllerSetup, SetupError, stamp_command};
use crate::handover::{Fingerprint, bumpless_shift};
use flexloop_control::lti::LtiRunner;
use flexloop_design::LoopDesign;
use flexloop_design::reference::{Derivatives, Reference};
use flexloop_protocol::{
    Command, Estimate, Handover, MAX_HANDOVER_STATES, MAX_INPUTS, MAX_OBSERVER_INPUTS,
    MAX_OBSERVER_OUTPUTS, MAX_OUTPUTS, Measurement, NO_SEQ, flags,
};
use nalgebra::DMatrix;

pub struct ControllerCore {
    feedback: Option<LtiRunner>,
    feedforward: [Derivatives; MAX_INPUTS],
    /// Appendix A's block on [u0; r], or None (u_ff = u0).
    modified_feedforward: Option<LtiRunner>,
    /// [u0; r] for the modified block.
    feedforward_input: [f64; MAX_INPUTS + MAX_OUTPUTS],
    reference: Reference,
    /// Output i follows direction[i] · r (1 for a SISO loop: r itself).
    direction: [f64; MAX_OUTPUTS],
    ts: f64,
    loop_delay_samples: u32,
    command_deadline_s: Option<f64>,
    n_outputs: usize,
    n_inputs: usize,
    /// Inputs of the observer block: [y; u_a] or [y; u_a; u_pending].
    n_block_inputs: usize,
    input_limit: f64,
    generation: u32,
    observer_input: [f64; MAX_OBSERVER_INPUTS],
    observer_output: [f64; MAX_OBSERVER_OUTPUTS],
    error: [f64; MAX_OUTPUTS],
    design_hash: u64,
    /// Feedback state shift per unit of output change (bumpless transfer).
    bumpless_shift: DMatrix<f64>,
    /// How many ticks old an estimate may be before the observer is dropped.
    estimate_watchdog: u32,
    /// The sample whose feedforward the modified block computes next.
    feedforward_next_seq: u64,
    /// Fingerprint of the feedforward alone (see [`Handover::carried_hash`]).
    feedforward_hash: u64,
    /// T_s / T_t of the anti-windup (0: none).
    anti_windup_gain: f64,
    /// The commands sent last, by sequence number modulo [`SENT`]: what the
    /// plant should have applied, to compare with what it did.
    sent: [(u64, [f64; MAX_INPUTS]); SENT],
}

/// Commands remembered for the anti-windup: more than the loop delay.
const SENT: usize = 4;

/// Skipped samples the step catches the feedforward block up on; a longer
/// gap (a joining instance) is closed by [`ControllerCore::fast_forward`].
const MAX_FEEDFORWARD_CATCH_UP: u64 = 64;

impl ControllerCore {
    pub fn new(design: &LoopDesign, generation: u32) -> Self {
        let mut feedforward = [[0.0; 5]; MAX_INPUTS];
        for (dst, src) in feedforward.iter_mut().zip(&design.feedforward) {
            *dst = *src;
        }
        let mut fingerprint = Fingerprint::default().number(design.ts);
        if let Some(fb) = &design.feedback {
            fingerprint = fingerprint.system(fb);
        }
        if let Some(block) = &design.modified_feedforward {
            fingerprint = fingerprint.system(block);
        }
        for gains in &design.feedforward {
            fingerprint = gains.iter().fold(fingerprint, |f, g| f.number(*g));
        }
        let mut direction = [0.0; MAX_OUTPUTS];
        for (dst, src) in direction.iter_mut().zip(&design.reference_direction) {
            *dst = *src;
        }
        fingerprint = design
            .reference_direction
            .iter()
            .fold(fingerprint, |f, d| f.number(*d));
        let mut feedforward_fingerprint = Fingerprint::default()
            .number(design.ts)
            .number(f64::from(design.loop_delay_samples))
            // Debug prints every parameter exactly (shortest round-trip floats).
            .bytes(format!("{:?}", design.reference).as_bytes());
        if let Some(block) = &design.modified_feedforward {
            feedforward_fingerprint = feedforward_fingerprint.system(block);
        }
        for gains in &design.feedforward {
            feedforward_fingerprint = gains
                .iter()
                .fold(feedforward_fingerprint, |f, g| f.number(*g));
        }
        // The modified block's reference input is direction · r.
        feedforward_fingerprint = design
            .reference_direction
            .iter()
            .fold(feedforward_fingerprint, |f, d| f.number(*d));
        let bumpless_shift = design
            .feedback
            .as_ref()
            .map_or_else(|| DMatrix::zeros(0, 0), bumpless_shift);
        Self {
            design_hash: fingerprint.value(),
            feedforward_hash: feedforward_fingerprint.value(),
            bumpless_shift,
            estimate_watchdog: u32::MAX,
            feedforward_next_seq: 0,
            anti_windup_gain: if design.anti_windup_s > 0.0 {
                (design.ts / design.anti_windup_s).min(1.0)
            } else {
                0.0
            },
            sent: [(NO_SEQ, [0.0; MAX_INPUTS]); SENT],
            feedback: design.feedback.clone().map(LtiRunner::new),
            modified_feedforward: design.modified_feedforward.clone().map(LtiRunner::new),
            feedforward_input: [0.0; MAX_INPUTS + MAX_OUTPUTS],
            feedforward,
            reference: design.reference.clone(),
            direction,
            ts: design.ts,
            loop_delay_samples: design.loop_delay_samples,
            command_deadline_s: design.command_deadline_s,
            n_outputs: design.n_outputs,
            n_inputs: design.n_inputs,
            n_block_inputs: design.observer.system.inputs(),
            input_limit: design.input_limit,
            generation,
            observer_input: [0.0; MAX_OBSERVER_INPUTS],
            observer_output: [0.0; MAX_OBSERVER_OUTPUTS],
            error: [0.0; MAX_OUTPUTS],
        }
    }

    /// With an estimate more than `ticks` ticks old the observer counts as
    /// silent: its contribution (ŷ_flex, u_d) is dropped until a fresh
    /// estimate arrives.
    pub fn set_estimate_watchdog(&mut self, ticks: u32) {
        self.estimate_watchdog = ticks.max(1);
    }

    /// Fingerprint of the controller design (feedback, feedforward).
    pub fn design_hash(&self) -> u64 {
        self.design_hash
    }

    fn state_len(&self) -> usize {
        self.feedback.as_ref().map_or(0, |f| f.state().len())
            + self
                .modified_feedforward
                .as_ref()
                .map_or(0, |f| f.state().len())
    }

    /// Writes the filter states into `out` (a design too large to hand over
    /// writes none, and no replacement will take it).
    pub fn save(&self, out: &mut Handover) {
        let n = self.state_len();
        out.design_hash = self.design_hash;
        if n > MAX_HANDOVER_STATES {
            out.n_states = 0;
            out.design_hash = 0;
            out.carried_hash = 0;
            return;
        }
        out.n_states = n as u32;
        out.n_inputs = self.n_inputs as u32;
        out.carried_hash = self.feedforward_hash;
        out.carried_at = self.feedback.as_ref().map_or(0, |f| f.state().len()) as u32;
        out.carried_len = self
            .modified_feedforward
            .as_ref()
            .map_or(0, |f| f.state().len()) as u32;
        let mut at = 0;
        for runner in [&self.feedback, &self.modified_feedforward]
            .into_iter()
            .flatten()
        {
            let x = runner.state();
            out.state[at..at + x.len()].copy_from_slice(x);
            at += x.len();
        }
    }

    /// Takes over the states of an identical design; false (and nothing
    /// changed) otherwise.
    pub fn load(&mut self, from: &Handover) -> bool {
        let n = self.state_len();
        if from.design_hash != self.design_hash
            || from.n_states as usize != n
            || n > MAX_HANDOVER_STATES
            || from.state[..n].iter().any(|v| !v.is_finite())
        {
            return false;
        }
        let mut at = 0;
        for runner in [&mut self.feedback, &mut self.modified_feedforward]
            .into_iter()
            .flatten()
        {
            let len = runner.state().len();
            runner.set_state(&from.state[at..at + len]);
            at += len;
        }
        self.feedforward_next_seq = from.seq + 1;
        true
    }

    /// Takes over the feedforward block's state from an instance with the
    /// same feedforward (a retuned feedback, say): what a joining instance
    /// would otherwise replay from sample 0, a cost that grows with the run
    /// (an hour at 10 kHz is 36 million block steps). False (and nothing
    /// changed) if the feedforward differs or there is no block.
    pub fn load_feedforward(&mut self, from: &Handover) -> bool {
        let Some(block) = &mut self.modified_feedforward else {
            return false;
        };
        let (at, len) = (from.carried_at as usize, from.carried_len as usize);
        if from.carried_hash != self.feedforward_hash
            || len != block.state().len()
            || at + len > MAX_HANDOVER_STATES
            || from.state[at..at + len].iter().any(|v| !v.is_finite())
        {
            return false;
        }
        block.set_state(&from.state[at..at + len]);
        self.feedforward_next_seq = from.seq + 1;
        true
    }

    /// Bumpless transfer for a different design: moves the feedback's
    /// integrator so that its output changes by `delta_u` from now on.
    pub fn shift_output(&mut self, delta_u: &[f64]) {
        let Some(feedback) = &mut self.feedback else {
            return;
        };
        let n = feedback.state().len();
        if n == 0 || self.bumpless_shift.nrows() != n {
            return;
        }
        let mut x = [0.0; MAX_HANDOVER_STATES];
        if n > x.len() {
            return;
        }
        x[..n].copy_from_slice(feedback.state());
        for (j, d) in delta_u.iter().enumerate().take(self.bumpless_shift.ncols()) {
            for (i, xi) in x[..n].iter_mut().enumerate() {
                *xi += self.bumpless_shift[(i, j)] * d;
            }
        }
        feedback.set_state(&x[..n]);
    }

    /// Steps the modified feedforward block through samples `from..to`
    /// (their outputs are not needed, only the state they leave).
    fn advance_feedforward(&mut self, from: u64, to: u64) {
        if self.modified_feedforward.is_none() {
            return;
        }
        let n = self.n_inputs + self.n_outputs;
        for seq in from..to {
            self.fill_feedforward_input(seq);
            if let Some(block) = &mut self.modified_feedforward {
                block.advance(&self.feedforward_input[..n]);
            }
        }
    }

    /// [u0; r] at the tick sample `seq`'s command applies; returns r's derivatives there.
    /// With a command deadline τ_d u0 is the feedforward at the instant the
    /// command starts to act, t_seq + τ_d (a snap mistimed by τ_d costs
    /// nanometres, docs/deadline.md), and r the reference at the next tick,
    /// the sample the command is first seen in.
    fn fill_feedforward_input(&mut self, seq: u64) -> [f64; 5] {
        let (ny, nu) = (self.n_outputs, self.n_inputs);
        let t_next_tick = (seq + self.loop_delay_samples as u64) as f64 * self.ts;
        let r_applied = self.reference.sample(t_next_tick);
        let u0_from = match self.command_deadline_s {
            Some(tau) => self.reference.sample(seq as f64 * self.ts + tau),
            None => r_applied,
        };
        for i in 0..nu {
            let gains = &self.feedforward[i];
            self.feedforward_input[i] = gains.iter().zip(&u0_from).map(|(g, r)| g * r).sum();
        }
        for i in 0..ny {
            self.feedforward_input[nu + i] = self.direction[i] * r_applied[0];
        }
        r_applied
    }

    /// A replacement joining at sample `seq` brings its feedforward block to
    /// where a loop running since sample 0 has it (design-time work: one
    /// block step per sample passed).
    /// Returns how many samples it stepped through.
    pub fn fast_forward(&mut self, seq: u64) -> u64 {
        let from = self.feedforward_next_seq;
        self.advance_feedforward(from, seq);
        self.feedforward_next_seq = from.max(seq);
        seq.saturating_sub(from)
    }

    /// Computes u(k) into `out` (all but the receive/publish stamps).
    pub fn step(&mut self, m: &Measurement, estimate: &Estimate, out: &mut Command) {
        self.compute(m, estimate, out);
        stamp_command(
            out,
            m,
            estimate,
            self.generation,
            self.n_inputs,
            self.n_outputs,
        );
    }

    /// u(k) and its parts, without the stamps (the controller process
    /// stamps every law's command itself: [`ControlLaw::step`]).
    fn compute(&mut self, m: &Measurement, estimate: &Estimate, out: &mut Command) {
        let (ny, nu) = (self.n_outputs, self.n_inputs);
        let n_in = self.n_block_inputs;
        let mut command_flags = 0;
        // An estimate a tick or two old (the observer was late) still serves;
        // older than the watchdog's ticks, the observer counts as silent.
        let age = m.seq.saturating_sub(estimate.seq);
        // A restarted observer's estimate still converging (docs/architecture.md,
        // "Restarts") is left out too: its MC and AD act once it settled.
        let observer_dropped =
            age > u64::from(self.estimate_watchdog) || estimate.flags & flags::CONVERGING != 0;
        if observer_dropped {
            command_flags |= flags::OBSERVER_FALLBACK;
        }
        self.observer_input[..ny].copy_from_slice(&m.y[..ny]);
        self.observer_input[ny..ny + nu].copy_from_slice(&m.u_applied[..nu]);
        if n_in > ny + nu {
            self.observer_input[ny + nu..n_in].copy_from_slice(&m.u_pending[..nu]);
        }
        for i in 0..ny + nu {
            let row = &estimate.direct[i * MAX_OBSERVER_INPUTS..i * MAX_OBSERVER_INPUTS + n_in];
            let direct: f64 = row
                .iter()
                .zip(&self.observer_input[..n_in])
                .map(|(d, w)| d * w)
                .sum();
            self.observer_output[i] = if observer_dropped {
                0.0
            } else {
                estimate.free[i] + direct
            };
        }
        let t_now = m.seq as f64 * self.ts;
        let r_now = self.reference.sample(t_now);
        // A measurement at the reference (docs/control.md §14): the plant's
        // excitation enters the first output's set-point of the feedback,
        // not the feedforward's trajectory.
        let r_excitation = if m.flags & flags::EXCITING_REFERENCE != 0 {
            m.excitation
        } else {
            0.0
        };
        // Appendix A's block runs on the set-point alone: samples this
        // instance did not process (misses, a late join) are stepped through
        // so that its state stays on the loop's time base.
        let catch_up_from = self
            .feedforward_next_seq
            .max(m.seq.saturating_sub(MAX_FEEDFORWARD_CATCH_UP));
        self.advance_feedforward(catch_up_from, m.seq);
        self.feedforward_next_seq = m.seq + 1;
        self.fill_feedforward_input(m.seq);
        for i in 0..ny {
            let y_comp = m.y[i] - self.observer_output[i];
            let r = self.direction[i] * r_now[0] + if i == 0 { r_excitation } else { 0.0 };
            out.r[i] = r;
            self.error[i] = r - y_comp;
            out.e_meas[i] = self.error[i];
        }
        let u_fb: &[f64] = match &mut self.feedback {
            Some(filter) => filter.step(&self.error[..ny]),
            None => &[0.0; MAX_INPUTS][..nu],
        };
        let u_ff: &[f64] = match &mut self.modified_feedforward {
            Some(block) => block.step(&self.feedforward_input[..nu + ny]),
            None => &self.feedforward_input[..nu],
        };
        // Tracking anti-windup (back-calculation): the feedback's integrator
        // follows what the actuator did rather than what was asked, with
        // time constant T_t, so that a clamped command, or one the plant
        // did not apply (late: it held the input; silent: its safe action),
        // does not wind the integrator up. First the last sample's: the
        // command due at this tick against the one the plant applies.
        let mut untracked = [0.0; MAX_INPUTS];
        let due = m
            .seq
            .checked_sub(u64::from(self.loop_delay_samples))
            .unwrap_or(NO_SEQ);
        // (Zero when the plant applied this command; the hold, a zero, or
        // the standby's command otherwise.)
        let (sent_seq, sent_u) = self.sent[(due % SENT as u64) as usize];
        if due != NO_SEQ && sent_seq == due {
            for i in 0..nu {
                untracked[i] = m.u_applied[i] - sent_u[i];
            }
        }
        for i in 0..nu {
            let u_d = self.observer_output[ny + i];
            let total = u_fb[i] + u_ff[i] + u_d;
            let limited = total.clamp(-self.input_limit, self.input_limit);
            if limited != total {
                command_flags |= flags::CLAMPED;
                untracked[i] += limited - total;
            }
            out.u_fb[i] = u_fb[i];
            out.u_ff[i] = u_ff[i];
            out.u_d[i] = u_d;
            out.u[i] = limited;
        }
        self.sent[(m.seq % SENT as u64) as usize] = (m.seq, out.u);
        if self.anti_windup_gain > 0.0 && untracked[..nu].iter().any(|d| *d != 0.0) {
            for d in &mut untracked[..nu] {
                *d *= self.anti_windup_gain;
            }
            self.shift_output(&untracked[..nu]);
        }
        out.flags = command_flags;
    }
}

/// The built-in law, on the API a user's law is written against.
impl ControlLaw for ControllerCore {
    fn new(setup: &ControllerSetup<'_>) -> Result<Self, SetupError> {
        let mut core = ControllerCore::new(setup.design, setup.generation);
        core.set_estimate_watchdog(setup.scenario.supervision.estimate_watchdog_ticks);
        Ok(core)
    }

    fn step(&mut self, m: &Measurement, estimate: &Estimate, out: &mut Command) {
        self.compute(m, estimate, out);
    }

    fn save(&self, out: &mut Handover) {
        ControllerCore::save(self, out);
    }

    fn load(&mut self, from: &Handover) -> bool {
        ControllerCore::load(self, from)
    }

    fn shift_output(&mut self, delta_u: &[f64]) {
        ControllerCore::shift_output(self, delta_u);
    }

    fn load_feedforward(&mut self, from: &Handover) -> bool {
        ControllerCore::load_feedforward(self, from)
    }

    fn fast_forward(&mut self, seq: u64) -> u64 {
        ControllerCore::fast_forward(self, seq)
    }
}
