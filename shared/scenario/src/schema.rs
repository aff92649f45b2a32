//! The scenario file format.
//!
//! Every table refuses unknown fields, so a typo is an error rather than a
//! silently ignored setting. Defaults are the values a control engineer would
//! pick for the model at hand; `scenarios/README.md` documents each field.

pub use crate::plant_description::{Attachment, Damper, ModalZeta, OWN_MODELS, Rayleigh, Spring};
use serde::{Deserialize, Deserializer};
use std::collections::BTreeSet;
use std::path::PathBuf;

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
    /// A frequency-response measurement while the loop runs
    /// (docs/control.md, "Measuring the loop").
    #[serde(default)]
    pub measure: Option<MeasureSection>,
    /// The file it was read from (not part of the format).
    #[serde(skip)]
    pub source: PathBuf,
    /// The dotted fields the file wrote (`plant.mass_kg`), defaults aside:
    /// a field given where it does not act is refused (not part of the format).
    #[serde(skip)]
    pub given: BTreeSet<String>,
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
    /// The command deadline τ_d [µs]: each command u_c(k), computed from
    /// y(k), acts from t_k + τ_d if it was sent by then, and the design
    /// counts on that (docs/deadline.md). None: one whole sample of loop
    /// delay, u_c(k) acting from t_{k+1}.
    pub command_deadline_us: Option<f64>,
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
    /// Thesis chain: the measured mass y1..y7 (docs/control.md §1.3; y5 in the
    /// thesis runs). Two-inertia setup: 1 = θ1 (the load), 2 = θ2 (the
    /// motor side); absent: 1. The other models measure every sensor.
    #[serde(default = "default_output")]
    pub output: usize,
    /// Uniform chain (the model-size stand-in of `bench --sweep`): its number
    /// of equal masses, 2..=64 (2·nodes states).
    pub nodes: Option<usize>,
    /// OAT-like model: which three of the four out-of-plane encoders
    /// (1..=4) are read, the thesis' "position" (docs/control.md §1.8).
    pub encoders: Option<Vec<usize>>,
    /// Thesis chain: a world-fixed sensor at this position along the
    /// structure in node units, 0 = ma, 1 = m1 … 7 = m7; between nodes the
    /// mass-normalised mode-shape rows are interpolated linearly (docs/control.md
    /// §1.4). Replaces `output`: an integer position is the same sensor.
    pub sensor_position: Option<f64>,
    /// Thesis chain: a world-fixed sensor that the structure scans past:
    /// at the first position (node units) when the scan's reference is at
    /// its start, at the second when it is at its end, linearly in between
    /// (docs/control.md §1.4). Plant and observer follow it every tick; the
    /// observer schedules its Kalman gain (`observer.scheduling`). Exactly
    /// two positions: a third is an error, not dropped.
    #[serde(default, deserialize_with = "two_positions")]
    pub sensor_scan: Option<[f64; 2]>,
    /// Thesis chain: the node masses [ma, m1, …, m7] in kg (Table 3.2 by
    /// default). `lumped`: the masses of the network, numbered from 0.
    pub masses_kg: Option<Vec<f64>>,
    /// Thesis chain: the seven springs between consecutive nodes in N/m,
    /// ma–m1 first (Table 3.2 by default).
    pub stiffness_n_per_m: Option<Vec<f64>>,
    /// Thesis chain: the node the force acts on (0 = ma, the default).
    pub actuator_node: Option<usize>,
    /// Modal damping of the flexible modes: one ζ, or one per flexible mode
    /// in frequency order (thesis chain and uniform chain: 0.005 by
    /// default; `lumped` and `second-order` without D: one of `zeta`,
    /// `rayleigh` or dampers is required).
    pub zeta: Option<ModalZeta>,
    /// `lumped`, `second-order` without D: Rayleigh damping D = α M + β K.
    pub rayleigh: Option<Rayleigh>,
    /// `lumped`: springs `{ between = [i, j], stiffness = N/m }`, or
    /// `{ at = i, … }` to the ground.
    #[serde(default)]
    pub springs: Vec<Spring>,
    /// `lumped`: dampers `{ between = [i, j], damping = N s/m }` or to the
    /// ground; the modal model keeps their diagonal (docs/own-plant.md).
    #[serde(default)]
    pub dampers: Vec<Damper>,
    /// `lumped`: the inputs, one per entry: a force on a mass `{ at = i }`
    /// or a force pair between two `{ between = [i, j] }` (+f on j, −f on i).
    #[serde(default)]
    pub forces: Vec<Attachment>,
    /// `lumped`: the outputs, one per entry: a mass's position `{ at = i }`
    /// or a relative one `{ between = [i, j] }` (q_j − q_i).
    #[serde(default)]
    pub positions: Vec<Attachment>,
    /// `second-order`, `state-space`: the file holding the arrays (.npz or
    /// .mat level 5), relative to the scenario's directory.
    pub file: Option<PathBuf>,
    /// `second-order`, `state-space`: the arrays inline, instead of a file
    /// (rows as arrays of numbers).
    pub arrays: Option<toml::Table>,
    /// A `state-space` plant file (.npz or .mat) the observer and the
    /// controller are designed on, instead of the plant emulated (a model
    /// fitted to a measurement: docs/control.md §14); relative to the
    /// scenario's directory. The plant process runs `model` as before.
    pub design_file: Option<PathBuf>,
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
pub const MODELS: [&str; 9] = [
    "double-integrator",
    "thesis-chain",
    "mimo-example",
    "oat-like",
    "two-inertia",
    "uniform-chain",
    "lumped",
    "second-order",
    "state-space",
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

/// `[from, to]`, refusing any other length (a fixed-size array would
/// silently drop a third value).
fn two_positions<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
    let positions = Vec::<f64>::deserialize(d)?;
    match positions[..] {
        [from, to] => Ok(Some([from, to])),
        _ => Err(serde::de::Error::invalid_length(
            positions.len(),
            &"two positions [from, to]",
        )),
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
    /// `io`: the input–output observer (docs/control.md §12.2): the same
    /// reduced model run on u and corrected by a filter K(z) of the
    /// innovation, from `correction` or `correction_file`/`correction_arrays`.
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
    /// 0.03 without (docs/control.md §10.1); 0: no noise model.
    pub q_nu: Option<f64>,
    /// Increase of modal damping AD aims for on each retained flexible mode.
    #[serde(default = "default_damping_increase")]
    pub damping_increase: f64,
    /// The modal damping AD aims for on every retained flexible mode; when
    /// given, it replaces `damping_increase` (each mode gets the increase
    /// from its own open-loop damping, none if it is already damped more).
    pub damping_target: Option<f64>,
    /// Kalman weights: σ of the process noise w on every input (N, per
    /// sample, entering as the force does); absent: `plant.force_noise`,
    /// or the model's own (the thesis' 10 mN) when the plant has none.
    pub process_noise: Option<f64>,
    /// Kalman weights: σ of the measurement noise on every output (m);
    /// absent: √(sensor_noise² + reference_noise²) of the plant, or the
    /// model's own (the thesis' √2 nm) when the plant has none.
    pub measurement_noise: Option<f64>,
    /// Kalman weights given whole: Q (inputs × inputs, per sample, w
    /// entering as the force does) and R (outputs × outputs), rows as arrays.
    pub kalman_q: Option<Vec<Vec<f64>>>,
    pub kalman_r: Option<Vec<Vec<f64>>>,
    /// Own models (`lumped`, `second-order`, `state-space`): the reduced
    /// model keeps the flexible modes up to this frequency (Hz); absent:
    /// 0.15 of the sample rate (docs/own-plant.md). The discarded
    /// modes enter as T_DC.
    pub max_mode_hz: Option<f64>,
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
    /// `io`: the correction filter K(z) built from the scenario:
    /// `observer-based` is the Kalman predictor gain as a static K
    /// correcting the state (E = I), which is the `kalman` observer.
    pub correction: Option<String>,
    /// `io`: a file (.npz or .mat, relative to the scenario's directory)
    /// holding K(z) as A_K, B_K, C_K, D_K (innovation in, input correction
    /// out, E = B), discrete with `ts` (the loop's period) or continuous
    /// without it (Tustin).
    pub correction_file: Option<PathBuf>,
    /// `io`: the same arrays inline, instead of a file (rows as arrays).
    pub correction_arrays: Option<toml::Table>,
    /// A program that serves the observer role in place of the built-in
    /// one, as `controller.exec` does for the controller (docs/components.md).
    pub exec: Option<Vec<String>>,
    /// The program's working directory; only with `exec`.
    pub workdir: Option<PathBuf>,
    /// The program's own tunables; only with `exec`.
    pub params: Option<toml::Table>,
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
    /// The PID's single tuning parameter f_bw in Hz (crossover ≈ 1.05 f_bw),
    /// or `"auto"`: the largest f_bw meeting the 6 dB rule with a stable loop,
    /// which the design resolves (flexloop-design's `pid_bandwidth`).
    #[serde(default = "default_pid_bandwidth")]
    pub bandwidth_hz: PidBandwidth,
    /// Notch frequencies in Hz (docs/control.md §6), empty: none.
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
    /// A program that serves the controller role in place of the built-in
    /// one: `[program, args…]` (docs/components.md). The program with a `/`
    /// is relative to the scenario's directory, a bare name is found on PATH.
    pub exec: Option<Vec<String>>,
    /// The program's working directory (relative to the scenario's
    /// directory); absent: the scenario's directory. Only with `exec`.
    pub workdir: Option<PathBuf>,
    /// The program's own tunables, handed to its law as they are written
    /// (docs/components.md). Only with `exec`.
    pub params: Option<toml::Table>,
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
            exec: None,
            workdir: None,
            params: None,
        }
    }
}

fn default_feedback() -> String {
    "none".into()
}
fn default_pid_bandwidth() -> PidBandwidth {
    PidBandwidth::Hz(35.5)
}

/// `controller.bandwidth_hz`: a number of Hz, or the string `"auto"`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PidBandwidth {
    /// f_bw as given [Hz].
    Hz(f64),
    /// The largest f_bw that meets the 6 dB rule and keeps the loop stable
    /// (docs/control.md §6, §10.1), found by the design.
    Auto,
}

impl PidBandwidth {
    /// The number given, None for `"auto"`.
    pub fn hz(self) -> Option<f64> {
        match self {
            Self::Hz(hz) => Some(hz),
            Self::Auto => None,
        }
    }
}

impl std::fmt::Display for PidBandwidth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Hz(hz) => write!(f, "{hz}"),
            Self::Auto => f.write_str("\"auto\""),
        }
    }
}

impl<'de> Deserialize<'de> for PidBandwidth {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = PidBandwidth;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a number of Hz or \"auto\"")
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Self::Value, E> {
                Ok(PidBandwidth::Hz(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Self::Value, E> {
                Ok(PidBandwidth::Hz(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Self::Value, E> {
                Ok(PidBandwidth::Hz(v as f64))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Self::Value, E> {
                match v {
                    "auto" => Ok(PidBandwidth::Auto),
                    other => Err(E::custom(format!(
                        "expected a number of Hz or \"auto\", got \"{other}\""
                    ))),
                }
            }
        }
        d.deserialize_any(Visitor)
    }
}

/// u_ff = snap·r⁗ + jerk·r⃛ + acc·r̈ + vel·ṙ (docs/control.md (A.1)).
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

/// How the plant waits for tick t_k under the shared-cores profile
/// (docs/architecture.md, "Waiting for the tick").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TickWait {
    /// An absolute `clock_nanosleep` until t_k: y(k) is sampled when the
    /// timer's wake-up comes, 10–20 µs late on a virtual machine.
    Sleep,
    /// Sleep until t_k minus an adaptive margin, then spin on the clock
    /// until t_k (bounded), so that y(k) is sampled on the tick. Needs the
    /// plant below observer and controller in SCHED_FIFO priority, so that
    /// they preempt the spin.
    SleepThenSpin,
}

impl TickWait {
    /// The setting of a scenario that names none. Switching the default is
    /// this one line (docs/benchmarks.md, "Sleep or sleep-then-spin": the lead measures both on a quiet machine).
    pub const DEFAULT: TickWait = TickWait::Sleep;

    fn default_setting() -> Self {
        Self::DEFAULT
    }

    pub fn as_str(self) -> &'static str {
        match self {
            TickWait::Sleep => "sleep",
            TickWait::SleepThenSpin => "sleep-then-spin",
        }
    }
}

impl std::str::FromStr for TickWait {
    type Err = String;
    fn from_str(text: &str) -> Result<Self, String> {
        match text {
            "sleep" => Ok(TickWait::Sleep),
            "sleep-then-spin" => Ok(TickWait::SleepThenSpin),
            _ => Err(format!(
                "unknown tick wait `{text}` (expected sleep or sleep-then-spin)"
            )),
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
    /// How the plant waits for each tick of the grid (realtime mode,
    /// shared-cores profile).
    #[serde(default = "TickWait::default_setting")]
    pub tick: TickWait,
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
            tick: TickWait::default_setting(),
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

/// A measurement's excitation: a periodic multisine, a periodic sweep or a
/// stepped sine added at one point of the running loop (docs/control.md,
/// "Measuring the loop").
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeasureSection {
    /// Where it enters: `"plant-input"` (a force beside the command, N) or
    /// `"sensor"` (added to the first measured output, m).
    pub point: MeasurePoint,
    /// `"multisine"` (every line at once), `"swept-sine"` (a logarithmic
    /// sweep each period) or `"stepped-sine"` (one line at a time).
    #[serde(default)]
    pub signal: MeasureSignal,
    pub f_min_hz: f64,
    pub f_max_hz: f64,
    /// At most this many log-spaced lines (fewer where DFT bins coincide).
    #[serde(default = "default_measure_lines")]
    pub lines: usize,
    /// Samples in one period; by default the loop's rate over `f_min_hz`,
    /// so that the lowest line is the period's first bin.
    pub period_samples: Option<usize>,
    /// The largest |value| the excitation takes (N or m, as the point).
    pub amplitude: f64,
    /// The multisine's phases (Schroeder's by default); a multisine's only.
    pub phases: Option<MeasurePhases>,
    /// The random phases' seed (with `phases = "random"` only).
    pub seed: Option<u64>,
    /// Periods dropped before the measured ones; the first is the fade-in.
    #[serde(default = "default_transient_periods")]
    pub transient_periods: usize,
    /// Periods measured and averaged.
    #[serde(default = "default_measured_periods")]
    pub periods: usize,
    /// Loop time at which the excitation starts (the loop settles first).
    #[serde(default = "default_measure_start")]
    pub start_s: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MeasurePoint {
    PlantInput,
    Sensor,
    Reference,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MeasureSignal {
    #[default]
    Multisine,
    SweptSine,
    SteppedSine,
}

impl MeasureSignal {
    pub fn name(self) -> &'static str {
        match self {
            Self::Multisine => "multisine",
            Self::SweptSine => "swept-sine",
            Self::SteppedSine => "stepped-sine",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MeasurePhases {
    #[default]
    Schroeder,
    Random,
}

fn default_measure_lines() -> usize {
    60
}

fn default_transient_periods() -> usize {
    2
}

fn default_measured_periods() -> usize {
    10
}

fn default_measure_start() -> f64 {
    0.1
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
    /// Wait before a restart that continues a crash loop (a crash within
    /// 250 ms of the role's last restart, or a failed restart); doubled for
    /// each further one in a row. Other crashes are restarted at once.
    #[serde(default = "default_backoff")]
    pub restart_backoff_ms: u64,
    /// Keeps an idle instance of the controller and of the observer with
    /// every port open, so that a swap starts and stops no process: a port
    /// that appears or goes costs the running loop a connection update
    /// (about 0.1 ms, a missed sample at 10 kHz). The replaced instance
    /// becomes the next spare.
    #[serde(default = "yes")]
    pub warm_spares: bool,
    /// Ticks of the loop without a role's output (no fresh command, no
    /// estimate) after which the supervisor judges the live process hung,
    /// stops it and brings the role back as after a crash (with real-time
    /// priority; on a shared machine also not before 0.5 s, in lockstep 3 s:
    /// docs/architecture.md, "Standby, watchdogs and guards").
    #[serde(default = "default_silent_ticks")]
    pub silent_ticks: u32,
}

fn default_silent_ticks() -> u32 {
    200
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
            silent_ticks: default_silent_ticks(),
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
    /// `realtime.tick`, as if the file gave it.
    pub tick: Option<TickWait>,
}

impl Scenario {
    /// `plant.file` resolved against the scenario's directory.
    pub fn plant_file_path(&self) -> Option<PathBuf> {
        self.beside(self.plant.file.as_ref()?)
    }

    /// `plant.design_file` resolved against the scenario's directory.
    pub fn design_file_path(&self) -> Option<PathBuf> {
        self.beside(self.plant.design_file.as_ref()?)
    }

    /// `observer.correction_file` resolved against the scenario's directory.
    pub fn correction_file_path(&self) -> Option<PathBuf> {
        self.beside(self.observer.correction_file.as_ref()?)
    }

    /// `file` as named from the scenario's directory.
    fn beside(&self, file: &std::path::Path) -> Option<PathBuf> {
        Some(match self.source.parent() {
            Some(dir) if file.is_relative() => dir.join(file),
            _ => file.to_path_buf(),
        })
    }

    pub fn period_ns(&self) -> u64 {
        (1e9 / self.timing.rate_hz).round() as u64
    }

    /// The command deadline τ_d in seconds, if the scenario sets one.
    pub fn command_deadline_s(&self) -> Option<f64> {
        self.timing.command_deadline_us.map(|us| us / 1e6)
    }

    /// Ticks to run; `None` runs until stopped.
    pub fn ticks(&self) -> Option<u64> {
        (self.timing.duration_s > 0.0)
            .then(|| (self.timing.duration_s * self.timing.rate_hz).round() as u64)
    }
}
