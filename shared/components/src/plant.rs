//! The plant emulator: the model, the held input and the tick bookkeeping.
//!
//! Timing convention (one sample of loop delay): at tick k the plant applies
//! u_c(k−1), the command computed from y(k−1), over [t_k, t_k+1), publishes
//! y(k), then advances its model to x(k+1). A command that is not there by
//! its tick is a miss: the plant holds its last input.
//!
//! With an extra sample of loop delay (a scenario setting, to show what a
//! slower pipeline costs), an on-time command waits one more tick in a delay
//! line; the deadline for the command stays one sample.
//!
//! With a command deadline τ_d (`loop.command_deadline_us`, docs/deadline.md)
//! u_c(k−1) acts from t_{k−1} + τ_d if it was sent by then: the sample
//! [t_{k−1}, t_k) is integrated in two pieces, exactly, without a second
//! wake-up. The model runs in the delayed-input form (state z = x − G_new
//! u_a, input u_a(k) = the input present at t_k), so the decision at tick k
//! (on time: u_c(k−1); late: hold) is all the two pieces need. A command
//! sent after its deadline is a miss and is dropped, not applied a sample
//! later: it was computed for an input that by then has acted for a whole
//! sample, and the next command, computed from a y that saw the hold, is
//! the one that fits.

use crate::noise::Gaussian;
use flexloop_control::excitation::{InjectionPoint, ScheduledExcitation};
use flexloop_control::lti::LtiRunner;
use flexloop_design::LoopDesign;
use flexloop_design::reference::Reference;
use flexloop_design::sensor_scan::SensorScan;
use flexloop_protocol::{Activation, Command, MAX_INPUTS, MAX_OUTPUTS, Measurement, NO_SEQ, flags};
use flexloop_runtime::latency::PlantLatencies;
use flexloop_scenario::schema::SafeAction;

/// What the plant did with one command it received.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandVerdict {
    /// The command for this tick, on time: it will be applied.
    Accepted,
    /// The right sequence, published after the tick it was due for.
    Late,
    /// An older sequence than the one due (it arrived after its tick passed).
    Stale,
    /// From an instance that is not the active one.
    WrongGeneration,
    /// Non-finite values: rejected, the plant holds its input.
    NonFinite,
    /// For a tick the plant has not reached (cannot happen in a healthy loop).
    Early,
    /// The standby controller's command for this tick, kept for the safe action.
    Standby,
}

/// Counters the plant reports in every measurement.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PlantCounters {
    pub ticks: u64,
    pub misses: u64,
    pub late_commands: u64,
    pub stalled_ticks: u64,
    pub stall_misses: u64,
    pub wrong_generation: u64,
    pub non_finite: u64,
    pub clamped: u64,
    /// Ticks under the safe action.
    pub fallback_ticks: u64,
    /// Fallback ticks that applied the standby controller's command.
    pub standby_ticks: u64,
}

/// A sensor the structure scans past: the output row follows the reference.
struct ScannedSensor {
    scan: SensorScan,
    reference: Reference,
    ts: f64,
    /// The output row at this tick's position.
    row: Vec<f64>,
}

pub struct PlantCore {
    model: LtiRunner,
    scanned: Option<ScannedSensor>,
    n_outputs: usize,
    n_inputs: usize,
    input_limit: f64,
    force_sigma: f64,
    sensor_sigma: f64,
    reference_sigma: f64,
    extra_delay: bool,
    /// With a command deadline: T − τ_d [ns], how long before its tick a
    /// command is due (the command due at tick k must be sent by t_{k−1} + τ_d).
    deadline_before_tick_ns: Option<u64>,
    /// With extra delay: the input for [t_k+1, t_k+2), already accepted.
    pending: [f64; MAX_INPUTS],
    pending_seq: u64,
    noise: Gaussian,
    /// Which controller generation owns which commands.
    activation: Activation,
    /// Consecutive ticks without an accepted command, and the watchdog.
    silent_ticks: u32,
    watchdog_ticks: u32,
    safe_action: SafeAction,
    /// Input applied over the current interval.
    held: [f64; MAX_INPUTS],
    /// The on-time command for the next tick, once accepted.
    next: Option<(u64, [f64; MAX_INPUTS])>,
    /// Whether that command was computed without a fresh estimate.
    next_without_observer: bool,
    /// Whether the last command applied was.
    without_observer: bool,
    /// A role fell silent at this tick: the supervisor is to be woken.
    alarm: bool,
    /// The standby controller's command for the next tick, if any.
    standby_next: Option<(u64, [f64; MAX_INPUTS])>,
    /// [u; w] as the model's input vector.
    model_input: [f64; 2 * MAX_INPUTS],
    y_true: [f64; MAX_OUTPUTS],
    previous_tick_stalled: bool,
    /// The active controller's command for the due sample came after its
    /// time since the last tick (flagged `ANSWERED_LATE` on the next one).
    answered_late: bool,
    applied_seq: u64,
    /// An excitation for a frequency-response measurement (docs/control.md
    /// §14), where it is added, and its value this tick.
    excitation: Option<ScheduledExcitation>,
    excitation_now: f64,
    pub counters: PlantCounters,
    pub latencies: PlantLatencies,
}

impl PlantCore {
    pub fn new(design: &LoopDesign) -> Self {
        let scanned = design.sensor_scan.clone().map(|scan| ScannedSensor {
            row: vec![0.0; design.plant.states()],
            scan,
            reference: design.reference.clone(),
            ts: design.ts,
        });
        Self {
            model: LtiRunner::new(design.plant.clone()),
            scanned,
            n_outputs: design.n_outputs,
            n_inputs: design.n_inputs,
            input_limit: design.input_limit,
            force_sigma: design.force_noise,
            sensor_sigma: design.sensor_noise,
            reference_sigma: design.reference_noise,
            extra_delay: design.loop_delay_samples > 1,
            deadline_before_tick_ns: design
                .command_deadline_s
                .map(|tau| ((design.ts - tau) * 1e9).round() as u64),
            pending: [0.0; MAX_INPUTS],
            pending_seq: NO_SEQ,
            noise: Gaussian::new(design.seed),
            activation: Activation::INITIAL,
            silent_ticks: 0,
            watchdog_ticks: 2,
            safe_action: SafeAction::Hold,
            held: [0.0; MAX_INPUTS],
            next: None,
            next_without_observer: false,
            without_observer: false,
            alarm: false,
            standby_next: None,
            model_input: [0.0; 2 * MAX_INPUTS],
            y_true: [0.0; MAX_OUTPUTS],
            previous_tick_stalled: false,
            answered_late: false,
            applied_seq: NO_SEQ,
            excitation: design.measurement.as_ref().map(ScheduledExcitation::new),
            excitation_now: 0.0,
            counters: PlantCounters::default(),
            latencies: PlantLatencies::default(),
        }
    }

    /// Replaces the design's measurement, if any, by `excitation` (None: no
    /// excitation). At the plant input the recorded `u_applied` stays the
    /// command and the plant's input is both; at the sensor the recorded `y`
    /// is the measurement with it, `y_true` without.
    pub fn set_excitation(&mut self, excitation: Option<ScheduledExcitation>) {
        self.excitation = excitation;
        self.excitation_now = 0.0;
    }

    /// The excitation added at the last tick (0 without).
    pub fn excitation(&self) -> f64 {
        self.excitation_now
    }

    /// The excitation at the plant input this tick (0 at the sensor or without).
    fn input_excitation(&self) -> f64 {
        match &self.excitation {
            Some(e) if e.point() == InjectionPoint::PlantInput => self.excitation_now,
            _ => 0.0,
        }
    }

    /// Which controller generation's commands are accepted, by sequence.
    pub fn set_activation(&mut self, activation: &Activation) {
        self.activation = *activation;
    }

    /// After `ticks` ticks without an accepted command, apply `action`.
    pub fn set_watchdog(&mut self, ticks: u32, action: SafeAction) {
        self.watchdog_ticks = ticks.max(1);
        self.safe_action = action;
    }

    /// Judges a command received before tick `k`, whose scheduled time is
    /// `tick_ns`. In lockstep mode pass `tick_ns = u64::MAX` (nothing is late).
    /// Due by `tick_ns`, or with a command deadline by t_{k−1} + τ_d.
    pub fn offer(&mut self, cmd: &Command, k: u64, tick_ns: u64) -> CommandVerdict {
        let due = k.wrapping_sub(1);
        let due_by_ns = tick_ns.saturating_sub(self.deadline_before_tick_ns.unwrap_or(0));
        if cmd.flags & flags::STANDBY != 0
            && cmd.generation != self.activation.controller_for(cmd.seq)
        {
            return self.offer_standby(cmd, due, due_by_ns);
        }
        if cmd.generation != self.activation.controller_for(cmd.seq) {
            self.counters.wrong_generation += 1;
            return CommandVerdict::WrongGeneration;
        }
        // Every command of the active instance, late ones included (as the
        // logger counts them); a rogue or a standby is not the loop's.
        self.latencies.observe_command(cmd);
        if k == 0 || cmd.seq < due {
            self.counters.late_commands += 1;
            CommandVerdict::Stale
        } else if cmd.seq > due {
            CommandVerdict::Early
        } else if cmd.published_ns > due_by_ns {
            self.counters.late_commands += 1;
            self.answered_late = true;
            CommandVerdict::Late
        } else if cmd.u[..self.n_inputs].iter().any(|v| !v.is_finite()) {
            self.counters.non_finite += 1;
            CommandVerdict::NonFinite
        } else {
            let mut u = [0.0; MAX_INPUTS];
            for (dst, src) in u.iter_mut().zip(&cmd.u[..self.n_inputs]) {
                let clamped = src.clamp(-self.input_limit, self.input_limit);
                if clamped != *src {
                    self.counters.clamped += 1;
                }
                *dst = clamped;
            }
            self.next = Some((cmd.seq, u));
            self.next_without_observer = cmd.flags & flags::OBSERVER_FALLBACK != 0;
            CommandVerdict::Accepted
        }
    }

    /// A standby command is kept only when it is the one due, on time and
    /// finite; it is never counted against the loop (it is not the active
    /// instance's to miss).
    fn offer_standby(&mut self, cmd: &Command, due: u64, due_by_ns: u64) -> CommandVerdict {
        if self.safe_action != SafeAction::Standby {
            self.counters.wrong_generation += 1;
            return CommandVerdict::WrongGeneration;
        }
        if cmd.seq != due || cmd.published_ns > due_by_ns {
            return CommandVerdict::Stale;
        }
        if cmd.u[..self.n_inputs].iter().any(|v| !v.is_finite()) {
            self.counters.non_finite += 1;
            return CommandVerdict::NonFinite;
        }
        let mut u = [0.0; MAX_INPUTS];
        for (dst, src) in u.iter_mut().zip(&cmd.u[..self.n_inputs]) {
            *dst = src.clamp(-self.input_limit, self.input_limit);
        }
        self.standby_next = Some((cmd.seq, u));
        CommandVerdict::Standby
    }

    /// Whether a role fell silent at the last tick (once per silence): the
    /// controller, the tick the watchdog first applied the safe action; the
    /// observer, the first command computed without its estimate. Cleared
    /// by the call.
    pub fn take_alarm(&mut self) -> bool {
        std::mem::take(&mut self.alarm)
    }

    /// Whether the command due for tick `k` has been accepted.
    pub fn has_command_for(&self, k: u64) -> bool {
        matches!(self.next, Some((seq, _)) if seq.wrapping_add(1) == k)
    }

    /// Tick k: settles the input for [t_k, t_k+1), computes y(k) and fills `out`
    /// (all but `published_ns`, which the caller stamps at send time).
    pub fn tick(
        &mut self,
        k: u64,
        tick_ns: u64,
        woke_ns: u64,
        stalled: bool,
        out: &mut Measurement,
    ) {
        self.latencies.tick_lateness.record_span(tick_ns, woke_ns);
        let mut tick_flags = 0;
        if std::mem::take(&mut self.answered_late) {
            tick_flags |= flags::ANSWERED_LATE;
        }
        // The value entering the delay line this tick: the on-time command, or
        // on a miss the last value that entered it (hold).
        let mut arriving_seq = if self.extra_delay {
            self.pending_seq
        } else {
            self.applied_seq
        };
        let standby_next = self.standby_next.take();
        let arriving = match self.next.take() {
            Some((seq, u)) if seq.wrapping_add(1) == k => {
                arriving_seq = seq;
                self.silent_ticks = 0;
                // The observer's silence, as the controller saw it first.
                self.alarm |= self.next_without_observer && !self.without_observer;
                self.without_observer = self.next_without_observer;
                u
            }
            _ if k == 0 => [0.0; MAX_INPUTS],
            _ if self.silent_ticks.saturating_add(1) >= self.watchdog_ticks => {
                // The controller has been silent too long: the safe action.
                self.silent_ticks = self.silent_ticks.saturating_add(1);
                self.alarm |= self.silent_ticks == self.watchdog_ticks;
                self.count_miss();
                self.counters.fallback_ticks += 1;
                tick_flags |= flags::HELD_INPUT | flags::FALLBACK;
                let standby = standby_next.filter(|(seq, _)| {
                    seq.wrapping_add(1) == k && self.safe_action == SafeAction::Standby
                });
                match (self.safe_action, standby, self.extra_delay) {
                    (SafeAction::Zero, _, _) => [0.0; MAX_INPUTS],
                    (SafeAction::Standby, Some((seq, u)), _) => {
                        tick_flags |= flags::STANDBY;
                        self.counters.standby_ticks += 1;
                        arriving_seq = seq;
                        u
                    }
                    (_, _, true) => self.pending,
                    (_, _, false) => self.held,
                }
            }
            _ => {
                self.silent_ticks += 1;
                self.count_miss();
                tick_flags |= flags::HELD_INPUT;
                if self.extra_delay {
                    self.pending
                } else {
                    self.held
                }
            }
        };
        if self.extra_delay {
            self.held = self.pending;
            self.applied_seq = self.pending_seq;
            self.pending = arriving;
            self.pending_seq = arriving_seq;
        } else {
            self.held = arriving;
            self.applied_seq = arriving_seq;
        }
        if stalled {
            self.counters.stalled_ticks += 1;
            tick_flags |= flags::STALLED_TICK;
        }
        self.previous_tick_stalled = stalled;
        self.counters.ticks += 1;
        if let Some(excitation) = self.excitation.as_mut() {
            if excitation.runs_at(k) {
                tick_flags |= flags::EXCITING;
                if excitation.point() == InjectionPoint::Reference {
                    tick_flags |= flags::EXCITING_REFERENCE;
                }
            }
            self.excitation_now = excitation.value_at(k);
        }

        match &mut self.scanned {
            // The one output of a scanned sensor: its row at this tick's
            // position (the full model has no feedthrough).
            Some(sensor) => {
                let p = sensor
                    .scan
                    .position_of_tick(&sensor.reference, k, sensor.ts);
                sensor.scan.plant_row(p, &mut sensor.row);
                self.y_true[0] = sensor
                    .row
                    .iter()
                    .zip(self.model.state())
                    .map(|(c, x)| c * x)
                    .sum();
            }
            None => {
                if self.deadline_before_tick_ns.is_some() {
                    // y(k) = C z(k) + C G_new u_a(k): the input present at t_k.
                    self.model_input[..self.n_inputs].copy_from_slice(&self.held[..self.n_inputs]);
                    self.model_input[0] += self.input_excitation();
                }
                let y = self.model.output(&self.model_input);
                self.y_true[..self.n_outputs].copy_from_slice(&y[..self.n_outputs]);
            }
        }

        out.seq = k;
        out.tick_ns = tick_ns;
        out.woke_ns = woke_ns;
        out.command_seq = self.applied_seq;
        out.misses = self.counters.misses;
        out.late_commands = self.counters.late_commands;
        out.stalled_ticks = self.counters.stalled_ticks;
        out.stall_misses = self.counters.stall_misses;
        out.fallback_ticks = self.counters.fallback_ticks;
        out.rejected_commands = self.counters.wrong_generation + self.counters.non_finite;
        out.flags = tick_flags;
        out.generation = self.activation.controller_for(k);
        out.n_outputs = self.n_outputs as u32;
        out.n_inputs = self.n_inputs as u32;
        for i in 0..self.n_outputs {
            let d = if self.sensor_sigma > 0.0 {
                self.sensor_sigma * self.noise.sample()
            } else {
                0.0
            };
            let v = if self.reference_sigma > 0.0 {
                self.reference_sigma * self.noise.sample()
            } else {
                0.0
            };
            out.y_true[i] = self.y_true[i];
            out.y[i] = self.y_true[i] - v + d;
        }
        if self
            .excitation
            .as_ref()
            .is_some_and(|e| e.point() == InjectionPoint::Sensor)
        {
            out.y[0] += self.excitation_now;
        }
        out.excitation = self.excitation_now;
        out.u_applied[..self.n_inputs].copy_from_slice(&self.held[..self.n_inputs]);
        if self.extra_delay {
            out.u_pending[..self.n_inputs].copy_from_slice(&self.pending[..self.n_inputs]);
        }
    }

    /// x(k+1) = A x(k) + B [u_a(k); w(k)]: off the critical path, after publishing.
    pub fn advance(&mut self) {
        let n = self.n_inputs;
        self.model_input[..n].copy_from_slice(&self.held[..n]);
        self.model_input[0] += self.input_excitation();
        for i in 0..n {
            self.model_input[n + i] = if self.force_sigma > 0.0 {
                self.force_sigma * self.noise.sample()
            } else {
                0.0
            };
        }
        self.model.advance(&self.model_input);
    }

    /// A miss on a tick after a stall is the machine's fault, not the loop's.
    fn count_miss(&mut self) {
        if self.previous_tick_stalled {
            self.counters.stall_misses += 1;
        } else {
            self.counters.misses += 1;
        }
    }

    /// The input that will be applied over the current interval (with a
    /// command deadline: until t_k + τ_d, when the next command may take over).
    pub fn held_input(&self) -> &[f64] {
        &self.held[..self.n_inputs]
    }
}
