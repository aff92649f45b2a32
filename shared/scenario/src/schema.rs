//! The scenario file format.
//!
//! Every table refuses unknown fields, so a typo is an error rather than a
//! silently ignored setting. Defaults are the values a control engineer would
//! pick for the model at hand; `scenarios/README.md` documents each field.

use crate::ScenarioError;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// How the plant paces the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// Absolute 100 µs (1/rate) clock; late commands are dropped and counted.
    Realtime,
    /// The plant waits for u(k) before advancing: deterministic, bit-reproducible.
    Lockstep,
}

impl Mode {
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Realtime => "realtime",
            Mode::Lockstep => "lockstep",
        }
    }

    pub fn parse(text: &str) -> Option<Self> {
        match text {
            "realtime" => Some(Mode::Realtime),
            "lockstep" => Some(Mode::Lockstep),
            _ => None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    pub name: String,
    #[serde(default)]
    pub description: String,
    #[serde(rename = "loop")]
    pub timing: LoopSection,
    pub plant: PlantSection,
    pub observer: ObserverSection,
    #[serde(default)]
    pub controller: ControllerSection,
    #[serde(default)]
    pub reference: ReferenceSection,
    #[serde(default)]
    pub realtime: RealtimeSection,
    #[serde(default)]
    pub logger: LoggerSection,
    #[serde(default)]
    pub supervision: SupervisionSection,
    /// The file it was read from (not part of the format).
    #[serde(skip)]
    pub source: PathBuf,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoopSection {
    #[serde(default = "default_rate")]
    pub rate_hz: f64,
    #[serde(default = "default_mode")]
    pub mode: Mode,
    /// Seconds of loop time; 0 runs until stopped.
    #[serde(default = "default_duration")]
    pub duration_s: f64,
}

fn default_rate() -> f64 {
    10_000.0
}
fn default_mode() -> Mode {
    Mode::Realtime
}
fn default_duration() -> f64 {
    10.0
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantSection {
    /// Built-in model: `double-integrator`, `thesis-chain`, `mimo-example`,
    /// `oat-like` or `two-inertia` (see [`MODELS`]).
    pub model: String,
    /// Mass of the double integrator.
    #[serde(default = "one")]
    pub mass_kg: f64,
    /// Thesis chain: the measured mass y1..y7 (control.md §1.3; y5 in the
    /// thesis runs). Two-inertia setup: 1 = θ1 (the load), 2 = θ2 (the
    /// motor side); absent: 1. The other models measure every sensor.
    #[serde(default = "default_output")]
    pub output: usize,
    /// Uniform chain (the model-size stand-in of `bench --sweep`): its number
    /// of equal masses, 2..=64 (2·nodes states).
    pub nodes: Option<usize>,
    /// OAT-like model: which three of the four out-of-plane encoders
    /// (1..=4) are read, the thesis' "position" (control.md §1.8).
    pub encoders: Option<Vec<usize>>,
    /// Thesis chain: a world-fixed sensor at this position along the
    /// structure in node units, 0 = ma, 1 = m1 … 7 = m7; between nodes the
    /// mass-normalised mode-shape rows are interpolated linearly (control.md
    /// §1.4). Replaces `output`: an integer position is the same sensor.
    pub sensor_position: Option<f64>,
    /// Thesis chain: a world-fixed sensor that the structure scans past:
    /// at the first position (node units) when the scan's reference is at
    /// its start, at the second when it is at its end, linearly in between
    /// (control.md §1.4). Plant and observer follow it every tick; the
    /// observer schedules its Kalman gain (`observer.scheduling`).
    pub sensor_scan: Option<[f64; 2]>,
    /// Whether the file named `output` (not part of the format): `output`
    /// has a default, so only the text tells a given one from the default.
    #[serde(skip)]
    pub output_given: bool,
    /// |u| limit in N; commands beyond it are clamped and counted.
    #[serde(default = "default_limit")]
    pub input_limit: f64,
    /// Seed of the disturbance generator (runs are reproducible).
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// σ of the force disturbance w in N (0: off).
    #[serde(default)]
    pub force_noise: f64,
    /// σ of the sensor noise d in m (0: off).
    #[serde(default)]
    pub sensor_noise: f64,
    /// σ of the sensor reference noise v in m (0: off); y_meas = y − v + d.
    #[serde(default)]
    pub reference_noise: f64,
}

/// The last node of the thesis chain (m7), in sensor-position units.
pub const SENSOR_POSITION_MAX: f64 = 7.0;

/// The built-in plant models.
pub const MODELS: [&str; 6] = [
    "double-integrator",
    "thesis-chain",
    "mimo-example",
    "oat-like",
    "two-inertia",
    "uniform-chain",
];

/// OAT-like model: the encoders read when the file names none.
pub const DEFAULT_ENCODERS: [usize; 3] = [1, 2, 3];

impl PlantSection {
    /// The thesis chain's sensor in node units: `sensor_position`, or the
    /// node of `output` (y_i sits on node i).
    pub fn sensor_node(&self) -> f64 {
        self.sensor_position.unwrap_or(self.output as f64)
    }

    /// Two-inertia setup: the measured angle, 1 (θ1, the load) unless the
    /// file names one.
    pub fn two_inertia_output(&self) -> usize {
        if self.output_given { self.output } else { 1 }
    }

    /// OAT-like model: the three encoders read (1..=4).
    pub fn oat_encoders(&self) -> Vec<usize> {
        self.encoders
            .clone()
            .unwrap_or_else(|| DEFAULT_ENCODERS.to_vec())
    }
}

fn default_output() -> usize {
    5
}
fn one() -> f64 {
    1.0
}
fn default_limit() -> f64 {
    1_000.0
}
fn default_seed() -> u64 {
    1
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObserverSection {
    /// `state-feedback`: predictor observer with state feedback u = -L x̂(k+1|k)
    /// (the lecture's double integrator). `kalman`: steady-state Kalman
    /// predictor on the reduced modal model with T_DC, driving MC and AD.
    /// `none`: no observer (the thesis' original loop).
    pub design: String,
    /// Observer poles: continuous natural frequency and damping, mapped by e^{sT}.
    #[serde(default = "default_observer_hz")]
    pub observer_bandwidth_hz: f64,
    #[serde(default = "default_damping")]
    pub observer_damping: f64,
    /// State-feedback poles, likewise.
    #[serde(default = "default_feedback_hz")]
    pub feedback_bandwidth_hz: f64,
    #[serde(default = "default_damping")]
    pub feedback_damping: f64,
    /// Measurement compensation: the controller sees y − ŷ_flex.
    #[serde(default)]
    pub mc: bool,
    /// Active damping: u_d from the estimated modal velocities.
    #[serde(default)]
    pub ad: bool,
    /// Noise-model weight Q_ν (U = B_t) when MC is on; absent: 10³ with AD,
    /// 0.03 without (control.md §10.1); 0: no noise model.
    pub q_nu: Option<f64>,
    /// Increase of modal damping AD aims for on each retained flexible mode.
    #[serde(default = "default_damping_increase")]
    pub damping_increase: f64,
    /// The modal damping AD aims for on every retained flexible mode; when
    /// given, it replaces `damping_increase` (each mode gets the increase
    /// from its own open-loop damping, none if it is already damped more).
    pub damping_target: Option<f64>,
    /// Flexible modes the observer's reduced model keeps (the rest enter as
    /// T_DC); absent: the model's default (thesis chain 3, MIMO example 2,
    /// OAT-like 8, two-inertia 1). The thesis chain's mode 7 stays unknown.
    pub flexible_modes: Option<usize>,
    /// Q of the per-mode band-pass filters of AD; 0: no band-pass.
    #[serde(default = "default_bandpass_q")]
    pub bandpass_q: f64,
    /// With `plant.sensor_scan`: `interpolated` (steady-state Kalman gains on
    /// a position grid, interpolated) or `time-varying` (the Riccati
    /// recursion every tick).
    #[serde(default = "default_scheduling")]
    pub scheduling: String,
    /// With `plant.sensor_scan`: the largest spacing of the interpolation
    /// grid in node units (0.25: the thesis' 29 points over the chain).
    #[serde(default = "default_scheduling_step")]
    pub scheduling_step: f64,
}

fn default_scheduling() -> String {
    "interpolated".into()
}
fn default_scheduling_step() -> f64 {
    0.25
}

fn default_damping_increase() -> f64 {
    0.035
}
fn default_bandpass_q() -> f64 {
    2.0
}
fn default_observer_hz() -> f64 {
    200.0
}
fn default_feedback_hz() -> f64 {
    20.0
}
fn default_damping() -> f64 {
    0.7
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerSection {
    /// Feedback on e_meas: `pid` (PID + low-pass, Table 3.3 tuning) or `none`.
    #[serde(default = "default_feedback")]
    pub feedback: String,
    /// The PID's single tuning parameter f_bw in Hz (crossover ≈ 1.05 f_bw).
    #[serde(default = "default_pid_bandwidth")]
    pub bandwidth_hz: f64,
    /// Notch frequencies in Hz (control.md §6), empty: none.
    #[serde(default)]
    pub notches_hz: Vec<f64>,
    /// Extra samples of loop delay to emulate (0: the one sample the loop has).
    #[serde(default)]
    pub extra_delay_samples: u32,
    /// Four-gain feedforward on the set-point derivatives; absent: the model's
    /// mass on the acceleration.
    pub feedforward: Option<FeedforwardSection>,
    /// `plain`: u_ff is the four-gain filter. `modified`: Appendix A's
    /// u_ff = u0 − û_d − C_fb ŷ_f with a copy of the observer and of the
    /// feedback driven by the reference, so that MC and AD do not react to it.
    #[serde(default = "default_feedforward_form")]
    pub feedforward_form: String,
}

fn default_feedforward_form() -> String {
    "plain".into()
}

impl Default for ControllerSection {
    fn default() -> Self {
        Self {
            feedback: default_feedback(),
            bandwidth_hz: default_pid_bandwidth(),
            notches_hz: Vec::new(),
            extra_delay_samples: 0,
            feedforward: None,
            feedforward_form: default_feedforward_form(),
        }
    }
}

fn default_feedback() -> String {
    "none".into()
}
fn default_pid_bandwidth() -> f64 {
    35.5
}

/// u_ff = snap·r⁗ + jerk·r⃛ + acc·r̈ + vel·ṙ (control.md (A.1)).
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FeedforwardSection {
    #[serde(default)]
    pub snap: f64,
    #[serde(default)]
    pub jerk: f64,
    #[serde(default)]
    pub acc: f64,
    #[serde(default)]
    pub vel: f64,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceSection {
    /// `hold` (r = 0), `step`, `sine` or `scan` (the thesis' snap-limited
    /// scan of Table 3.6, starting at `start_s`).
    #[serde(default = "default_shape")]
    pub shape: String,
    /// Step height or sine amplitude in m.
    #[serde(default)]
    pub amplitude: f64,
    #[serde(default = "default_frequency")]
    pub frequency_hz: f64,
    /// Scan only: start a scan every so many seconds, alternately back and
    /// forth (0: one scan).
    #[serde(default)]
    pub repeat_s: f64,
    /// Time the step, sine or scan starts in s (a scan needs at least one
    /// sample of rest first: its feedforward is issued ahead of the motion).
    #[serde(default)]
    pub start_s: f64,
    /// How the profile drives the outputs: r_i = direction_i · r. Absent:
    /// the profile on the first output, every other output held at 0.
    pub direction: Option<Vec<f64>>,
}

impl Default for ReferenceSection {
    fn default() -> Self {
        Self {
            shape: default_shape(),
            amplitude: 0.0,
            frequency_hz: default_frequency(),
            repeat_s: 0.0,
            start_s: 0.0,
            direction: None,
        }
    }
}

fn default_shape() -> String {
    "hold".into()
}
fn default_frequency() -> f64 {
    1.0
}

/// Scheduling of one process.
#[derive(Debug, Clone, Default, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProcessRealtime {
    /// SCHED_FIFO priority 1..=99; absent: SCHED_OTHER.
    pub priority: Option<u8>,
    pub cpu: Option<usize>,
}

/// How the loop's processes share the machine's CPUs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Profile {
    /// Event wake-ups: the processes sleep between samples and may share a
    /// CPU (the chain pinned to one, as on a 2-CPU machine).
    #[default]
    SharedCores,
    /// Plant, observer and controller each spin on a CPU of their own (the
    /// clock and their inputs, no wake-up): for machines with isolated cores.
    DedicatedCores,
}

impl Profile {
    pub fn as_str(self) -> &'static str {
        match self {
            Profile::SharedCores => "shared-cores",
            Profile::DedicatedCores => "dedicated-cores",
        }
    }
}

/// CPUs a spinning profile needs: one per loop process, one for the logger
/// and the rest of the system.
pub const DEDICATED_CORES_MIN_CPUS: usize = 4;

#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RealtimeSection {
    #[serde(default)]
    pub profile: Profile,
    #[serde(default = "yes")]
    pub lock_memory: bool,
    #[serde(default = "default_slack")]
    pub timer_slack_ns: u64,
    #[serde(default = "yes")]
    pub hold_cpu_dma_latency: bool,
    #[serde(default)]
    pub plant: ProcessRealtime,
    #[serde(default)]
    pub observer: ProcessRealtime,
    #[serde(default)]
    pub controller: ProcessRealtime,
    #[serde(default)]
    pub logger: ProcessRealtime,
}

fn yes() -> bool {
    true
}
fn default_slack() -> u64 {
    1
}

impl Default for RealtimeSection {
    fn default() -> Self {
        Self {
            profile: Profile::default(),
            lock_memory: true,
            timer_slack_ns: default_slack(),
            hold_cpu_dma_latency: true,
            plant: ProcessRealtime::default(),
            observer: ProcessRealtime::default(),
            controller: ProcessRealtime::default(),
            logger: ProcessRealtime::default(),
        }
    }
}

/// What the plant applies once the active controller has been silent for
/// `command_watchdog_ticks`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SafeAction {
    /// Keep the last accepted input.
    Hold,
    /// Apply zero input.
    Zero,
    /// Apply the command of a standby controller: a second instance of the
    /// controller that follows the active one's state every sample and
    /// publishes what it would send; it is promoted when the active one dies.
    Standby,
}

/// When the supervisor restarts a component that died.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RestartPolicy {
    OnCrash,
    Never,
}

/// Watchdogs and restarts.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SupervisionSection {
    /// Ticks without an accepted command before the plant's safe action.
    #[serde(default = "two")]
    pub command_watchdog_ticks: u32,
    #[serde(default = "default_safe_action")]
    pub safe_action: SafeAction,
    /// Ticks without a fresh estimate before the controller drops the
    /// observer's contribution (ŷ_flex and u_d) and runs on feedback alone.
    #[serde(default = "two")]
    pub estimate_watchdog_ticks: u32,
    #[serde(default = "default_restart")]
    pub restart: RestartPolicy,
    /// Restarts per component before the supervisor stops the run.
    #[serde(default = "default_max_restarts")]
    pub max_restarts: u32,
    /// Wait before the first restart; doubled for each further one.
    #[serde(default = "default_backoff")]
    pub restart_backoff_ms: u64,
    /// Keeps an idle instance of the controller and of the observer with
    /// every port open, so that a swap starts and stops no process: a port
    /// that appears or goes costs the running loop a connection update
    /// (about 0.1 ms, a missed sample at 10 kHz). The replaced instance
    /// becomes the next spare.
    #[serde(default = "yes")]
    pub warm_spares: bool,
}

fn two() -> u32 {
    2
}
fn default_safe_action() -> SafeAction {
    SafeAction::Hold
}
fn default_restart() -> RestartPolicy {
    RestartPolicy::OnCrash
}
fn default_max_restarts() -> u32 {
    5
}
fn default_backoff() -> u64 {
    100
}

impl Default for SupervisionSection {
    fn default() -> Self {
        Self {
            command_watchdog_ticks: two(),
            safe_action: default_safe_action(),
            estimate_watchdog_ticks: two(),
            restart: default_restart(),
            max_restarts: default_max_restarts(),
            restart_backoff_ms: default_backoff(),
            warm_spares: true,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LoggerSection {
    #[serde(default = "yes")]
    pub enabled: bool,
}

impl Default for LoggerSection {
    fn default() -> Self {
        Self { enabled: true }
    }
}

/// Command-line settings that take precedence over the file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Overrides {
    pub rate_hz: Option<f64>,
    pub duration_s: Option<f64>,
    pub mode: Option<Mode>,
    /// Drop all SCHED_FIFO priorities (e.g. in tests on a shared machine).
    pub no_realtime: bool,
}

impl Scenario {
    /// Reads, parses, applies `overrides` and validates `path`.
    pub fn load(path: &Path, overrides: &Overrides) -> Result<Self, ScenarioError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| ScenarioError::new(path, None, format!("cannot read: {e}")))?;
        let mut scenario = Self::parse(path, &text)?;
        scenario.apply(overrides);
        scenario.validate()?;
        Ok(scenario)
    }

    /// Parses `text` as if read from `path` (no validation).
    pub fn parse(path: &Path, text: &str) -> Result<Self, ScenarioError> {
        let mut scenario: Scenario = toml::from_str(text).map_err(|e| {
            let (line, col) = e
                .span()
                .map(|span| line_col(text, span.start))
                .unwrap_or((0, 0));
            let field = field_in_message(e.message())
                .or_else(|| e.span().and_then(|span| key_at(text, span.start)));
            ScenarioError::new(
                path,
                field.as_deref(),
                format!("{} (line {line}, column {col})", e.message().trim()),
            )
        })?;
        scenario.source = path.to_path_buf();
        scenario.plant.output_given = toml::from_str::<toml::Table>(text)
            .ok()
            .and_then(|t| t.get("plant")?.as_table()?.get("output").cloned())
            .is_some();
        Ok(scenario)
    }

    /// Puts the thesis chain's world-fixed sensor at `position` (node units),
    /// in place of whatever output the file named; `validate` checks the range.
    pub fn set_sensor_position(&mut self, position: f64) {
        self.plant.sensor_position = Some(position);
        self.plant.output_given = false;
    }

    pub fn apply(&mut self, overrides: &Overrides) {
        if let Some(rate) = overrides.rate_hz {
            self.timing.rate_hz = rate;
        }
        if let Some(duration) = overrides.duration_s {
            self.timing.duration_s = duration;
        }
        if let Some(mode) = overrides.mode {
            self.timing.mode = mode;
        }
        if overrides.no_realtime {
            for p in [
                &mut self.realtime.plant,
                &mut self.realtime.observer,
                &mut self.realtime.controller,
                &mut self.realtime.logger,
            ] {
                p.priority = None;
            }
            self.realtime.hold_cpu_dma_latency = false;
            self.realtime.lock_memory = false;
        }
    }

    fn err(&self, field: &str, reason: impl Into<String>) -> ScenarioError {
        ScenarioError::new(&self.source, Some(field), reason)
    }

    /// Checks ranges and consistency; the design step checks the maths.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let positive = |field: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(self.err(field, format!("must be a positive finite number, got {v}")))
            }
        };
        let non_negative = |field: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(self.err(field, format!("must be zero or positive, got {v}")))
            }
        };
        positive("loop.rate_hz", self.timing.rate_hz)?;
        if self.timing.rate_hz > 100_000.0 {
            return Err(self.err("loop.rate_hz", "above 100 kHz the tick grid is below 10 µs"));
        }
        non_negative("loop.duration_s", self.timing.duration_s)?;
        positive("plant.mass_kg", self.plant.mass_kg)?;
        positive("plant.input_limit", self.plant.input_limit)?;
        non_negative("plant.force_noise", self.plant.force_noise)?;
        non_negative("plant.sensor_noise", self.plant.sensor_noise)?;
        non_negative("plant.reference_noise", self.plant.reference_noise)?;
        for (field, ticks) in [
            (
                "supervision.command_watchdog_ticks",
                self.supervision.command_watchdog_ticks,
            ),
            (
                "supervision.estimate_watchdog_ticks",
                self.supervision.estimate_watchdog_ticks,
            ),
        ] {
            if ticks == 0 {
                return Err(self.err(field, "must be at least 1 tick"));
            }
        }
        if !MODELS.contains(&self.plant.model.as_str()) {
            return Err(self.err(
                "plant.model",
                format!(
                    "unknown model `{}` (expected one of {})",
                    self.plant.model,
                    MODELS.join(", ")
                ),
            ));
        }
        self.validate_outputs()?;
        if let Some(p) = self.plant.sensor_position {
            let field = "plant.sensor_position";
            if self.plant.model != "thesis-chain" {
                return Err(self.err(
                    field,
                    format!(
                        "only the thesis chain has a sensor position, not `{}`",
                        self.plant.model
                    ),
                ));
            }
            if self.plant.output_given {
                return Err(self.err(
                    field,
                    "give either plant.output or plant.sensor_position, not both \
                     (position 5.0 is output 5)",
                ));
            }
            if !(p.is_finite() && (0.0..=SENSOR_POSITION_MAX).contains(&p)) {
                return Err(self.err(
                    field,
                    format!(
                        "must lie in [0, {SENSOR_POSITION_MAX}] (0 = ma, 1..7 = m1..m7), got {p}"
                    ),
                ));
            }
        }
        if let Some(q) = self.observer.q_nu {
            non_negative("observer.q_nu", q)?;
        }
        self.validate_sensor_scan()?;
        self.validate_profile()?;
        non_negative("observer.damping_increase", self.observer.damping_increase)?;
        if let Some(z) = self.observer.damping_target
            && !(z.is_finite() && z > 0.0 && z < 1.0)
        {
            return Err(self.err(
                "observer.damping_target",
                format!("a modal damping ratio must lie in (0, 1), got {z}"),
            ));
        }
        non_negative("observer.bandpass_q", self.observer.bandpass_q)?;
        positive("controller.bandwidth_hz", self.controller.bandwidth_hz)?;
        for (i, hz) in self.controller.notches_hz.iter().enumerate() {
            positive(&format!("controller.notches_hz[{i}]"), *hz)?;
        }
        if let Some(ff) = &self.controller.feedforward {
            for (field, v) in [
                ("controller.feedforward.snap", ff.snap),
                ("controller.feedforward.jerk", ff.jerk),
                ("controller.feedforward.acc", ff.acc),
                ("controller.feedforward.vel", ff.vel),
            ] {
                if !v.is_finite() {
                    return Err(self.err(field, format!("must be finite, got {v}")));
                }
            }
        }
        positive(
            "observer.observer_bandwidth_hz",
            self.observer.observer_bandwidth_hz,
        )?;
        positive(
            "observer.feedback_bandwidth_hz",
            self.observer.feedback_bandwidth_hz,
        )?;
        positive("observer.observer_damping", self.observer.observer_damping)?;
        positive("observer.feedback_damping", self.observer.feedback_damping)?;
        let nyquist = self.timing.rate_hz / 2.0;
        let notches = self
            .controller
            .notches_hz
            .iter()
            .map(|hz| ("controller.notches_hz", *hz));
        for (field, hz) in [
            (
                "observer.observer_bandwidth_hz",
                self.observer.observer_bandwidth_hz,
            ),
            (
                "observer.feedback_bandwidth_hz",
                self.observer.feedback_bandwidth_hz,
            ),
            ("controller.bandwidth_hz", self.controller.bandwidth_hz),
        ]
        .into_iter()
        .chain(notches)
        {
            if hz >= nyquist {
                return Err(self.err(
                    field,
                    format!("{hz} Hz is not below the Nyquist frequency {nyquist} Hz"),
                ));
            }
        }
        if self.controller.extra_delay_samples > 1 {
            return Err(self.err("controller.extra_delay_samples", "must be 0 or 1"));
        }
        non_negative("reference.amplitude", self.reference.amplitude.abs())?;
        positive("reference.frequency_hz", self.reference.frequency_hz)?;
        non_negative("reference.start_s", self.reference.start_s)?;
        non_negative("reference.repeat_s", self.reference.repeat_s)?;
        if let Some(direction) = &self.reference.direction {
            if let Some((i, v)) = direction.iter().enumerate().find(|(_, v)| !v.is_finite()) {
                return Err(self.err(
                    &format!("reference.direction[{i}]"),
                    format!("must be finite, got {v}"),
                ));
            }
            if direction.iter().all(|v| *v == 0.0) {
                return Err(self.err(
                    "reference.direction",
                    "needs at least one non-zero entry (the profile drives no output)",
                ));
            }
        }
        for (field, p) in [
            ("realtime.plant.priority", &self.realtime.plant),
            ("realtime.observer.priority", &self.realtime.observer),
            ("realtime.controller.priority", &self.realtime.controller),
            ("realtime.logger.priority", &self.realtime.logger),
        ] {
            if let Some(prio) = p.priority
                && !(1..=99).contains(&prio)
            {
                return Err(self.err(
                    field,
                    format!("SCHED_FIFO priority must be 1..=99, got {prio}"),
                ));
            }
        }
        Ok(())
    }

    /// A spinning profile needs a CPU of its own for each loop process.
    fn validate_profile(&self) -> Result<(), ScenarioError> {
        let rt = &self.realtime;
        if rt.profile != Profile::DedicatedCores {
            return Ok(());
        }
        let mut taken: Vec<(usize, &str)> = Vec::new();
        for (field, p) in [
            ("realtime.plant.cpu", &rt.plant),
            ("realtime.observer.cpu", &rt.observer),
            ("realtime.controller.cpu", &rt.controller),
        ] {
            let Some(cpu) = p.cpu else {
                return Err(self.err(
                    field,
                    "dedicated-cores spins each loop process on a CPU of its own: name it",
                ));
            };
            if let Some((_, other)) = taken.iter().find(|(c, _)| *c == cpu) {
                return Err(self.err(
                    field,
                    format!("dedicated-cores needs a CPU of its own; {cpu} is also {other}"),
                ));
            }
            taken.push((cpu, field));
        }
        if let Some(cpu) = rt.logger.cpu
            && let Some((_, other)) = taken.iter().find(|(c, _)| *c == cpu)
        {
            return Err(self.err(
                "realtime.logger.cpu",
                format!("CPU {cpu} spins for {other} under dedicated-cores"),
            ));
        }
        Ok(())
    }

    /// Whether this machine can run the scenario's profile: a spinning one
    /// is refused below [`DEDICATED_CORES_MIN_CPUS`] CPUs (three spinning
    /// processes would starve everything else, the logger and the kernel's
    /// own threads included) and on CPUs it does not have.
    pub fn check_machine(&self, online_cpus: usize) -> Result<(), ScenarioError> {
        if self.realtime.profile != Profile::DedicatedCores {
            return Ok(());
        }
        if online_cpus < DEDICATED_CORES_MIN_CPUS {
            return Err(self.err(
                "realtime.profile",
                format!(
                    "dedicated-cores spins plant, observer and controller each on a CPU of its \
                     own and needs at least {DEDICATED_CORES_MIN_CPUS} CPUs; this machine has \
                     {online_cpus}: use shared-cores"
                ),
            ));
        }
        let rt = &self.realtime;
        for (field, p) in [
            ("realtime.plant.cpu", &rt.plant),
            ("realtime.observer.cpu", &rt.observer),
            ("realtime.controller.cpu", &rt.controller),
            ("realtime.logger.cpu", &rt.logger),
        ] {
            if let Some(cpu) = p.cpu.filter(|c| *c >= online_cpus) {
                return Err(self.err(
                    field,
                    format!("CPU {cpu} does not exist here (CPUs 0..{online_cpus})"),
                ));
            }
        }
        Ok(())
    }

    /// A sensor the structure scans past: the thesis chain, a scan, two
    /// positions on it, no other way of placing the sensor.
    fn validate_sensor_scan(&self) -> Result<(), ScenarioError> {
        let o = &self.observer;
        if !matches!(o.scheduling.as_str(), "interpolated" | "time-varying") {
            return Err(self.err(
                "observer.scheduling",
                format!(
                    "unknown scheduling `{}` (expected interpolated or time-varying)",
                    o.scheduling
                ),
            ));
        }
        if !(o.scheduling_step.is_finite() && o.scheduling_step > 0.0 && o.scheduling_step <= 7.0) {
            return Err(self.err(
                "observer.scheduling_step",
                format!("must lie in (0, 7] node units, got {}", o.scheduling_step),
            ));
        }
        let Some([from, to]) = self.plant.sensor_scan else {
            return Ok(());
        };
        let field = "plant.sensor_scan";
        if self.plant.model != "thesis-chain" {
            return Err(self.err(
                field,
                format!(
                    "only the thesis chain has a sensor to scan past, not `{}`",
                    self.plant.model
                ),
            ));
        }
        if self.plant.output_given || self.plant.sensor_position.is_some() {
            return Err(self.err(
                field,
                "give one of plant.output, plant.sensor_position and plant.sensor_scan",
            ));
        }
        for p in [from, to] {
            if !(p.is_finite() && (0.0..=SENSOR_POSITION_MAX).contains(&p)) {
                return Err(self.err(
                    field,
                    format!(
                        "positions must lie in [0, {SENSOR_POSITION_MAX}] (0 = ma, 1..7 = m1..m7), got {p}"
                    ),
                ));
            }
        }
        if from == to {
            return Err(self.err(
                field,
                format!("the sensor does not move ({from} to {to}): use plant.sensor_position"),
            ));
        }
        if self.reference.shape != "scan" {
            return Err(self.err(
                field,
                format!(
                    "the sensor follows a scan; reference.shape is `{}`",
                    self.reference.shape
                ),
            ));
        }
        if self.controller.feedforward_form == "modified" {
            return Err(self.err(
                "controller.feedforward_form",
                "the modified feedforward copies a fixed observer; with plant.sensor_scan \
                 use `plain`",
            ));
        }
        Ok(())
    }

    /// Which sensors the model reads: `output`, `sensor_position` and
    /// `encoders` each belong to one model.
    fn validate_outputs(&self) -> Result<(), ScenarioError> {
        let model = self.plant.model.as_str();
        let output = self.plant.output;
        match model {
            "two-inertia" => {
                if !(1..=2).contains(&output) {
                    return Err(self.err(
                        "plant.output",
                        format!("the two-inertia setup measures θ1 (1) or θ2 (2), got {output}"),
                    ));
                }
            }
            "uniform-chain" => {
                if self.plant.output_given {
                    return Err(self.err(
                        "plant.output",
                        "the uniform chain has one sensor, at 5/7 of its length",
                    ));
                }
            }
            "mimo-example" | "oat-like" => {
                if self.plant.output_given {
                    return Err(self.err(
                        "plant.output",
                        format!(
                            "`{model}` measures all its sensors; reference.direction says \
                             which outputs the reference moves"
                        ),
                    ));
                }
            }
            _ => {
                if !(1..=7).contains(&output) {
                    return Err(self.err(
                        "plant.output",
                        format!("the chain has outputs 1..=7, got {output}"),
                    ));
                }
            }
        }
        let nodes_range = flexloop_control::models::UNIFORM_CHAIN_NODES;
        match (model, self.plant.nodes) {
            ("uniform-chain", None) => {
                return Err(self.err(
                    "plant.nodes",
                    format!(
                        "the uniform chain needs its number of masses ({} to {})",
                        nodes_range.start(),
                        nodes_range.end()
                    ),
                ));
            }
            ("uniform-chain", Some(n)) if !nodes_range.contains(&n) => {
                return Err(self.err(
                    "plant.nodes",
                    format!(
                        "must lie in {}..={} (2·nodes states; the loop carries at most {} \
                         observer states), got {n}",
                        nodes_range.start(),
                        nodes_range.end(),
                        flexloop_protocol::MAX_STATES
                    ),
                ));
            }
            ("uniform-chain", Some(_)) | (_, None) => {}
            (_, Some(_)) => {
                return Err(self.err(
                    "plant.nodes",
                    format!("only the uniform chain has a number of nodes, not `{model}`"),
                ));
            }
        }
        if let Some(encoders) = &self.plant.encoders {
            let field = "plant.encoders";
            if model != "oat-like" {
                return Err(self.err(
                    field,
                    format!("only the OAT-like model selects encoders, not `{model}`"),
                ));
            }
            let mut sorted = encoders.clone();
            sorted.sort_unstable();
            sorted.dedup();
            if encoders.len() != 3
                || sorted.len() != 3
                || sorted.iter().any(|e| !(1..=4).contains(e))
            {
                return Err(self.err(
                    field,
                    format!("three different encoders of 1..=4, got {encoders:?}"),
                ));
            }
        }
        Ok(())
    }

    pub fn period_ns(&self) -> u64 {
        (1e9 / self.timing.rate_hz).round() as u64
    }

    /// Ticks to run; `None` runs until stopped.
    pub fn ticks(&self) -> Option<u64> {
        (self.timing.duration_s > 0.0)
            .then(|| (self.timing.duration_s * self.timing.rate_hz).round() as u64)
    }
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.len() - before.rfind('\n').map(|i| i + 1).unwrap_or(0) + 1;
    (line, col)
}

/// The key of the `key = value` line holding byte `at` (for a bad value,
/// where serde's message names the value, not the field).
fn key_at(text: &str, at: usize) -> Option<String> {
    let line_start = text[..at.min(text.len())].rfind('\n').map_or(0, |i| i + 1);
    let line = text[line_start..].lines().next()?;
    let (key, _) = line.split_once('=')?;
    let key = key.trim();
    (!key.is_empty() && !key.starts_with('[')).then(|| key.to_string())
}

/// Pulls the field name out of serde's "unknown field `x`" / "missing field `x`".
fn field_in_message(message: &str) -> Option<String> {
    if !message.contains("field `") {
        return None;
    }
    let start = message.find("field `")? + "field `".len();
    let end = start + message[start..].find('`')?;
    Some(message[start..end].to_string())
}
