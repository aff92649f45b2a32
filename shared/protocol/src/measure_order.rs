//! A measurement ordered on a running loop (`flexloop measure --running`):
//! the supervisor checks the `[measure]` fields against the loop's scenario
//! and sends them with the sample to start at; the plant designs the
//! excitation off its loop thread and adds it from that sample
//! (docs/control.md, "Measuring the loop").

use iceoryx2::prelude::*;

/// `point`: a force beside the first input's command.
pub const AT_PLANT_INPUT: u32 = 0;
/// `point`: added to the first measured output.
pub const AT_SENSOR: u32 = 1;
/// `point`: added by the controller to the first output's reference.
pub const AT_REFERENCE: u32 = 2;
/// `phases`: Schroeder's.
pub const SCHROEDER: u32 = 0;
/// `phases`: random, from `seed`.
pub const RANDOM: u32 = 1;
/// `signal`: a multisine, every line at once.
pub const MULTISINE: u32 = 0;
/// `signal`: a periodic logarithmic sweep.
pub const SWEPT_SINE: u32 = 1;
/// `signal`: one line at a time.
pub const STEPPED_SINE: u32 = 2;

/// The `[measure]` fields (scenarios/README.md) and where it starts.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("flexloop.MeasureOrder.v2")]
pub struct MeasureOrder {
    pub published_ns: u64,
    /// The sample the excitation starts at (its fade-in's first).
    pub start_seq: u64,
    pub seed: u64,
    pub f_min_hz: f64,
    pub f_max_hz: f64,
    pub amplitude: f64,
    pub lines: u32,
    pub period_samples: u32,
    pub transient_periods: u32,
    pub periods: u32,
    /// [`AT_PLANT_INPUT`], [`AT_SENSOR`] or [`AT_REFERENCE`].
    pub point: u32,
    /// [`SCHROEDER`] or [`RANDOM`].
    pub phases: u32,
    /// [`MULTISINE`], [`SWEPT_SINE`] or [`STEPPED_SINE`].
    pub signal: u32,
    pub _reserved: u32,
}
