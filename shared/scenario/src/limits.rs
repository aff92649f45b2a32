//! The bounds on every number of a scenario: what drives the cost of the
//! design (list lengths, grid sizes) and what no physical set-up reaches.
//! `scenarios/README.md` lists them beside the fields.

/// `loop.rate_hz`: at least 1 Hz; above 100 kHz the tick grid is below 10 µs.
pub const RATE_HZ: (f64, f64) = (1.0, 100_000.0);
/// `loop.duration_s`, `reference.start_s`, `reference.repeat_s`: one day
/// (0 runs until stopped).
pub const DURATION_S_MAX: f64 = 86_400.0;
/// `plant.mass_kg`.
pub const MASS_KG: (f64, f64) = (1e-6, 1e6);
/// `plant.input_limit` in N (or A).
pub const INPUT_LIMIT_MAX: f64 = 1e6;
/// `plant.force_noise`: σ of the force disturbance in N.
pub const FORCE_NOISE_MAX: f64 = 1e3;
/// `plant.sensor_noise`, `plant.reference_noise`: σ in m (or rad).
pub const SENSOR_NOISE_MAX: f64 = 1.0;
/// `observer.q_nu`.
pub const Q_NU_MAX: f64 = 1e12;
/// `observer.bandpass_q`.
pub const BANDPASS_Q_MAX: f64 = 1e3;
/// `observer.observer_damping`, `observer.feedback_damping`.
pub const POLE_DAMPING_MAX: f64 = 10.0;
/// `observer.scheduling_step` in node units: at most 141 grid points over
/// the chain, each a Kalman design and two closed-loop checks in every
/// process's start-up.
pub const SCHEDULING_STEP: (f64, f64) = (0.05, 7.0);
/// `controller.notches_hz`: each notch is two states of the controller.
pub const NOTCHES_MAX: usize = 8;
/// `[controller.feedforward]` gains, in absolute value.
pub const FEEDFORWARD_GAIN_MAX: f64 = 1e6;
/// `reference.amplitude` in m (or rad).
pub const AMPLITUDE_MAX: f64 = 10.0;
/// `reference.direction` entries, in absolute value.
pub const DIRECTION_MAX: f64 = 1e3;
/// `realtime.timer_slack_ns`: 1 ms, ten ticks at 10 kHz.
pub const TIMER_SLACK_NS_MAX: u64 = 1_000_000;
/// `realtime.<process>.cpu`: the kernel's CPU set size.
pub const CPU_MAX: usize = 1023;
/// `supervision.command_watchdog_ticks`, `supervision.estimate_watchdog_ticks`,
/// `supervision.silent_ticks`.
pub const WATCHDOG_TICKS_MAX: u32 = 100_000;
/// `supervision.max_restarts`.
pub const MAX_RESTARTS_MAX: u32 = 1_000_000;
/// `supervision.restart_backoff_ms`.
pub const RESTART_BACKOFF_MS_MAX: u64 = 60_000;
/// `name`: it names the run directory.
pub const NAME_BYTES_MAX: usize = 100;
/// `plant.stiffness_n_per_m` and lumped springs in N/m, dampers in N s/m.
pub const STIFFNESS_MAX: f64 = 1e15;
pub const DAMPER_MAX: f64 = 1e12;
/// `plant.masses_kg`, lumped springs, dampers, forces and positions: list
/// lengths (each mass is two states of the plant emulator; the loop carries
/// at most 128 observer states).
pub const LUMPED_MASSES_MAX: usize = 64;
pub const LUMPED_ELEMENTS_MAX: usize = 1024;
/// `plant.rayleigh` α (1/s) and β (s).
pub const RAYLEIGH_MAX: f64 = 1e6;
