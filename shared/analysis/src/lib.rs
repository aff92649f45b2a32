//! flexloop-analysis: what a run did, in control terms.
//!
//! - [`trace`]: a run as columns per tick, from a recorded log or from the
//!   in-process loop, aligned by sequence number.
//! - [`metrics`]: tracking error over the scan windows (rms, peak, MA, MSD),
//!   control effort and its parts, innovation statistics.
//! - [`flexible`]: the observer's flexible output against the plant's own,
//!   rebuilt from the logged input.
//! - [`latency_log`]: the logger's HdrHistogram interval log, merged per
//!   histogram, and its percentile distribution.
//! - [`run_log`]: a run's sample files across logger generations, joined
//!   in order, the samples no logger recorded, and the summary rebuilt.
//! - [`modal_damping`]: the damping the loop achieves on each flexible mode,
//!   from the closed-loop model and identified from the run's ring-down.
//! - [`loop_report`]: the design report of any scenario's loop (modes,
//!   observer poles, stability, per-output sensitivity peaks).
//! - [`fault_recovery`]: what a killed process cost the loop (ticks on the
//!   safe action, samples the recording lacks).
//! - [`feedforward_fit`]: least-squares feedforward gains from a recorded run.
//! - [`positions`]: Table 4.1, the scan with the sensor at positions along
//!   the chain (min / mean / max rms of e_true).
//! - [`scheduling_comparison`]: time-varying Kalman filter against
//!   interpolated steady-state gains on a sensor the chain scans past.
//! - [`thesis_design`]: the thesis' design study, the largest PID bandwidth
//!   of every observer case under the 6 dB rule (docs/control.md §9, §10.1).
//! - [`verdict`]: whether the plant kept its grid, and whether a run's
//!   control figures are the design's.
//!
//! Offline code: it allocates freely and never runs inside the loop.

pub mod fault_recovery;
pub mod feedforward_fit;
pub mod flexible;
pub mod latency_log;
pub mod loop_measurement;
pub mod loop_report;
pub mod metrics;
pub mod modal_damping;
pub mod positions;
pub mod run_log;
pub mod scheduling_comparison;
pub mod thesis_design;
pub mod trace;
pub mod verdict;

pub use metrics::{ControlMetrics, MetricsOptions};
pub use trace::RunTrace;
