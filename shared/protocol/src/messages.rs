//! Fixed-size messages of the loop.
//!
//! Sample k flows plant -> (observer, controller) -> plant:
//! - [`Measurement`] k: y(k) taken at tick k and the input u_a(k) the plant
//!   applies over [t_k, t_k+1).
//! - [`Estimate`] k+1: what the observer knows about tick k+1 after processing
//!   measurement k: the free response of its outputs and its direct gain, so
//!   that the controller can finish the observer's work on y(k+1) with one
//!   multiply-add instead of waiting for another process wake-up.
//! - [`Command`] k: u_c(k), computed from y(k), held by the plant over
//!   [t_k+1, t_k+2). It must be published before t_k+1 (the one-sample budget).
//!
//! Every message carries the scheduled tick time and the time each stage
//! received and published it, so that any process (the logger) can rebuild
//! every latency against the tick schedule without asking the others.

use iceoryx2::prelude::*;

/// Outputs (sensors) a model may have.
pub const MAX_OUTPUTS: usize = 8;
/// Inputs (actuators) a model may have.
pub const MAX_INPUTS: usize = 8;
/// States an observer may report.
pub const MAX_STATES: usize = 128;
/// Observer block outputs: [ŷ_flex; u_d].
pub const MAX_OBSERVER_OUTPUTS: usize = MAX_OUTPUTS + MAX_INPUTS;
/// Observer block inputs: [y; u_a; u_pending] (u_pending only with an extra
/// sample of loop delay).
pub const MAX_OBSERVER_INPUTS: usize = MAX_OUTPUTS + 2 * MAX_INPUTS;

/// Sequence number meaning "none".
pub const NO_SEQ: u64 = u64::MAX;

/// Bits of the `flags` field.
pub mod flags {
    /// The plant ends the run after this sample; everyone drains and exits.
    pub const END_OF_RUN: u32 = 1 << 0;
    /// The plant held its last input at this tick (the command was missing or late).
    pub const HELD_INPUT: u32 = 1 << 1;
    /// The plant woke too late for this tick (a machine stall, not a loop miss).
    pub const STALLED_TICK: u32 = 1 << 2;
    /// The controller used an estimate older than the one due (observer late).
    pub const STALE_ESTIMATE: u32 = 1 << 3;
    /// The run is in lockstep mode (the plant waits for every command).
    pub const LOCKSTEP: u32 = 1 << 4;
    /// The command was clamped to the actuator limits.
    pub const CLAMPED: u32 = 1 << 5;
    /// The plant applied its safe action: the active controller was silent
    /// for the watchdog's number of ticks.
    pub const FALLBACK: u32 = 1 << 6;
    /// The controller ran without the observer's contribution: no fresh
    /// estimate for the watchdog's number of ticks.
    pub const OBSERVER_FALLBACK: u32 = 1 << 7;
    /// Command: from the standby controller, for the plant's safe action
    /// only. Measurement: the safe action applied the standby's command.
    pub const STANDBY: u32 = 1 << 8;
    /// Estimate: from an observer restarted without its predecessor's
    /// continuous state (no state handed on, or a hole in the replayed
    /// measurements), still converging: its corrections (ŷ_flex, u_d) are
    /// not to act yet. Its law says for how many samples.
    pub const CONVERGING: u32 = 1 << 9;
    /// Measurement: a measurement's excitation runs at this tick (from its
    /// fade-in's first sample to its fade-out's last; docs/control.md §14).
    pub const EXCITING: u32 = 1 << 10;
    /// Measurement: the excitation is the controller's: it adds `excitation`
    /// to its reference for the first output at this tick (docs/control.md
    /// §14, the reference point); the plant adds nothing itself.
    pub const EXCITING_REFERENCE: u32 = 1 << 11;
    /// Measurement: since the last tick the active controller's command for
    /// the sample due came after its time (the tick, or its command
    /// deadline) and was not applied: the controller answered, late.
    pub const ANSWERED_LATE: u32 = 1 << 12;
}

/// y(k) from the plant, published at tick k.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.Measurement.v4")]
pub struct Measurement {
    pub seq: u64,
    /// Scheduled time of tick k (CLOCK_MONOTONIC ns).
    pub tick_ns: u64,
    /// When the plant woke for tick k.
    pub woke_ns: u64,
    /// When the plant published y(k).
    pub published_ns: u64,
    /// Sequence number of the command applied over [t_k, t_k+1), or NO_SEQ.
    pub command_seq: u64,
    /// Cumulative loop misses (command not there by its tick, tick not stalled).
    pub misses: u64,
    /// Cumulative commands that arrived after their tick and were dropped.
    pub late_commands: u64,
    /// Cumulative ticks the plant itself woke too late for.
    pub stalled_ticks: u64,
    /// Cumulative misses on ticks that were stalled (counted apart from `misses`).
    pub stall_misses: u64,
    /// Cumulative ticks under the safe action (controller silent).
    pub fallback_ticks: u64,
    /// Cumulative commands refused: from an instance that is not the active
    /// one, or with non-finite values.
    pub rejected_commands: u64,
    pub flags: u32,
    /// Generation of the command source the plant accepts.
    pub generation: u32,
    pub n_outputs: u32,
    pub n_inputs: u32,
    /// Measured outputs y(k) (with sensor noise when the scenario has it).
    pub y: [f64; MAX_OUTPUTS],
    /// Noise-free outputs, for the logger only: no controller may use them.
    pub y_true: [f64; MAX_OUTPUTS],
    /// The input the plant applies over [t_k, t_k+1) (with a command
    /// deadline τ_d: the input present at t_k, until t_k + τ_d; docs/deadline.md).
    pub u_applied: [f64; MAX_INPUTS],
    /// The input already accepted for [t_k+1, t_k+2): with an extra sample
    /// of loop delay the observer needs it to predict two samples ahead.
    /// Zero without extra delay.
    pub u_pending: [f64; MAX_INPUTS],
    /// A measurement's excitation added at tick k (docs/control.md,
    /// "Measuring the loop"): at the plant input a force beside
    /// `u_applied`, at the sensor already inside `y`. Zero without one.
    pub excitation: f64,
}

/// The observer's contribution for tick `seq`, computed from measurement `seq - 1`.
///
/// At tick k the observer block outputs are `free + direct · [y(k); u_a(k); u_pending(k)]`
/// (rows: ŷ_flex then u_d). `free` is known one tick ahead; `direct` is the
/// block's feedthrough, constant for a steady-state observer.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.Estimate.v3")]
pub struct Estimate {
    /// The tick this estimate is for (k).
    pub seq: u64,
    /// Tick time of the measurement it was computed from (k-1).
    pub source_tick_ns: u64,
    /// When the plant published that measurement.
    pub source_published_ns: u64,
    /// When the observer received measurement k-1.
    pub received_ns: u64,
    /// When the observer published this estimate.
    pub published_ns: u64,
    pub flags: u32,
    pub generation: u32,
    pub n_outputs: u32,
    pub n_inputs: u32,
    pub n_states: u32,
    pub _reserved: u32,
    /// Free response of [ŷ_flex; u_d] at tick `seq`: C_o s(k).
    pub free: [f64; MAX_OBSERVER_OUTPUTS],
    /// Row-major `direct[i * MAX_OBSERVER_INPUTS + j]`: feedthrough from input j
    /// ([y; u_a; u_pending]) to output i ([ŷ_flex; u_d]).
    pub direct: [f64; MAX_OBSERVER_OUTPUTS * MAX_OBSERVER_INPUTS],
    /// x̂(k|k-1), for the logger and for a hand-over to another observer
    /// (with a command deadline in the observer model's coordinates,
    /// x̂ − G_new u_a(k): docs/deadline.md).
    pub x_hat: [f64; MAX_STATES],
    /// Innovation of measurement k-1: y(k-1) − ŷ(k-1|k-2).
    pub innovation: [f64; MAX_OUTPUTS],
}

/// u_c(k), computed from y(k), to be held over [t_k+1, t_k+2).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.Command.v1")]
pub struct Command {
    /// k: the measurement this command answers.
    pub seq: u64,
    /// Scheduled time of tick k.
    pub tick_ns: u64,
    /// When the plant published measurement k.
    pub measurement_published_ns: u64,
    /// When the controller received measurement k.
    pub received_ns: u64,
    /// When the controller published this command (the plant holds it from then on).
    pub published_ns: u64,
    /// Sequence of the estimate used (k if fresh).
    pub estimate_seq: u64,
    /// When that estimate was published by the observer.
    pub estimate_published_ns: u64,
    pub flags: u32,
    /// Generation of the controller instance that computed it.
    pub generation: u32,
    pub n_inputs: u32,
    pub n_outputs: u32,
    /// The command u_c(k) = u_fb + u_ff + u_d (after limits).
    pub u: [f64; MAX_INPUTS],
    pub u_fb: [f64; MAX_INPUTS],
    pub u_ff: [f64; MAX_INPUTS],
    pub u_d: [f64; MAX_INPUTS],
    /// Reference r(k) and measured error r(k) - y_comp(k).
    pub r: [f64; MAX_OUTPUTS],
    pub e_meas: [f64; MAX_OUTPUTS],
}

/// Periodic counters of a service, for `flexloop status` and the supervisor.
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.Telemetry.v1")]
pub struct Telemetry {
    pub published_ns: u64,
    /// Last sequence number processed.
    pub seq: u64,
    pub samples: u64,
    pub misses: u64,
    pub late_commands: u64,
    pub stalled_ticks: u64,
    pub stall_misses: u64,
    pub gaps: u64,
    pub stale_estimates: u64,
    /// Latency percentiles in ns, `[p50, p90, p99, p99.9, p99.99, max]` per histogram.
    pub round_trip: [u64; 6],
    pub tick_lateness: [u64; 6],
    pub role: u32,
    pub pid: u32,
}

macro_rules! zeroed_default {
    ($($t:ty),*) => {$(
        impl Default for $t {
            fn default() -> Self {
                // SAFETY: every field is an integer, a float or an array of them,
                // for which all-zero bits are a valid value.
                unsafe { core::mem::zeroed() }
            }
        }
    )*};
}
zeroed_default!(Measurement, Estimate, Command, Telemetry);

/// A loop message's bytes as they travel and as the sample file and the
/// live view carry them (the ROS1 serialisation of its layout,
/// [`crate::layout`]).
pub trait WireBytes {
    fn wire_bytes(&self) -> &[u8];
}

macro_rules! wire_bytes {
    ($($t:ty),*) => {$(
        impl WireBytes for $t {
            fn wire_bytes(&self) -> &[u8] {
                // SAFETY: #[repr(C)] plain data without padding (the layout
                // tables and the size tests below check it), so every byte
                // is initialised.
                unsafe {
                    core::slice::from_raw_parts(
                        (self as *const Self).cast::<u8>(),
                        core::mem::size_of::<Self>(),
                    )
                }
            }
        }
    )*};
}
wire_bytes!(Measurement, Estimate, Command);

impl Estimate {
    pub fn direct_at(&self, output: usize, input: usize) -> f64 {
        self.direct[output * MAX_OBSERVER_INPUTS + input]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_have_fixed_sizes_and_alignment() {
        // Sizes are part of the wire contract: a change must be deliberate
        // (and bump the type name version).
        assert_eq!(
            core::mem::size_of::<Measurement>(),
            11 * 8 + 4 * 4 + 4 * 8 * 8 + 8
        );
        assert_eq!(core::mem::align_of::<Measurement>(), 8);
        assert_eq!(core::mem::size_of::<Command>(), 7 * 8 + 4 * 4 + 6 * 8 * 8);
        assert_eq!(
            core::mem::size_of::<Estimate>(),
            5 * 8 + 6 * 4 + 8 * (16 + 16 * 24 + MAX_STATES + 8)
        );
    }

    #[test]
    fn default_is_all_zero() {
        let m = Measurement::default();
        assert_eq!(m.seq, 0);
        assert!(m.y.iter().all(|v| *v == 0.0));
        let e = Estimate::default();
        assert_eq!(e.direct_at(3, 4), 0.0);
    }
}
