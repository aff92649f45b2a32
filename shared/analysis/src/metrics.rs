//! The control engineer's numbers of a run (docs/control.md §8): tracking error
//! over each scan window (rms, peak, moving average MA and moving standard
//! deviation MSD over the exposure time), control effort split into its
//! parts, and innovation statistics.

use crate::trace::RunTrace;
use serde::Serialize;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MetricsOptions {
    /// Exposure time T of MA and MSD (docs/control.md §8: T = slit / scan speed;
    /// the thesis does not give the slit, so this is a choice).
    pub exposure_s: f64,
}

impl Default for MetricsOptions {
    fn default() -> Self {
        // A 5 mm slit at the 1 m/s scan speed of Table 3.6.
        Self { exposure_s: 0.005 }
    }
}

/// Tracking over one scan window.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScanMetrics {
    pub start_s: f64,
    pub end_s: f64,
    pub samples: usize,
    /// rms of e_true = r − y over the window (the thesis' Table 3.7 measure).
    pub rms_e_true: f64,
    pub peak_e_true: f64,
    /// Largest |MA| and largest MSD over the window's valid part.
    pub max_abs_ma: f64,
    pub max_msd: f64,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct SignalStats {
    pub mean: f64,
    pub rms: f64,
    pub peak: f64,
}

impl SignalStats {
    /// Mean, rms and peak of the finite values. Summed relative to the
    /// peak, so that values near f64's range (a program's 1e300 N command)
    /// give their finite rms, not an overflow to infinity.
    pub fn of(values: impl Iterator<Item = f64>) -> Self {
        let finite: Vec<f64> = values.filter(|v| v.is_finite()).collect();
        let peak = finite.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if finite.is_empty() {
            return Self::default();
        }
        if peak == 0.0 {
            return Self {
                mean: 0.0,
                rms: 0.0,
                peak,
            };
        }
        let n = finite.len() as f64;
        let (sum, sq) = finite.iter().fold((0.0, 0.0), |(sum, sq), v| {
            let scaled = v / peak;
            (sum + scaled, sq + scaled * scaled)
        });
        Self {
            mean: peak * (sum / n),
            rms: peak * (sq / n).sqrt(),
            peak,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct InnovationStats {
    pub mean: f64,
    pub std: f64,
    /// Normalised autocorrelation at lag 1: near 0 for a well-tuned Kalman
    /// filter (white innovation), near 1 when it lags the plant.
    pub lag1_autocorrelation: f64,
}

/// Tracking of one output (MIMO loops: one per axis).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AxisMetrics {
    /// rms of e_true over all scan windows (None without a scan).
    pub rms_e_true_scan: Option<f64>,
    /// Over the whole run.
    pub e_true: SignalStats,
    /// Largest |e_true| over the last tenth of the run: what is left once
    /// the motion has settled.
    pub settled_peak_e_true: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ControlMetrics {
    pub ticks: usize,
    pub scans: Vec<ScanMetrics>,
    /// rms of e_true over all scan windows together (None without a scan).
    pub rms_e_true_scan: Option<f64>,
    /// Over the whole run.
    pub e_true: SignalStats,
    pub u: SignalStats,
    pub u_fb: SignalStats,
    pub u_ff: SignalStats,
    pub u_d: SignalStats,
    pub innovation: InnovationStats,
    /// Ticks on which the plant held its input: every recorded tick, with
    /// its command or without (a silent controller's ticks have none).
    pub held_ticks: usize,
    pub stale_estimates: usize,
    /// Every output (the first is the one above), and the command of every
    /// input; empty when the trace has no per-axis columns.
    pub axes: Vec<AxisMetrics>,
    pub inputs: Vec<SignalStats>,
}

impl ControlMetrics {
    /// `windows`: the scan windows in s (from the scenario's reference).
    pub fn compute(trace: &RunTrace, windows: &[(f64, f64)], options: &MetricsOptions) -> Self {
        let rows = &trace.rows;
        let eps = 1e-9 * trace.ts;
        let mut scans = Vec::new();
        let (mut total_sq, mut total_n) = (0.0, 0usize);
        for &(a, b) in windows {
            let e: Vec<f64> = rows
                .iter()
                .filter(|r| {
                    let t = trace.time(r);
                    t >= a - eps && t <= b + eps
                })
                .map(|r| r.e_true())
                .collect();
            if e.is_empty() {
                continue;
            }
            let sq: f64 = e.iter().map(|v| v * v).sum();
            total_sq += sq;
            total_n += e.len();
            let (max_abs_ma, max_msd) = moving_stats(&e, trace.ts, options.exposure_s);
            scans.push(ScanMetrics {
                start_s: a,
                end_s: b,
                samples: e.len(),
                rms_e_true: (sq / e.len() as f64).sqrt(),
                peak_e_true: e.iter().fold(0.0f64, |m, v| m.max(v.abs())),
                max_abs_ma,
                max_msd,
            });
        }
        let (axes, inputs) = axis_metrics(trace, windows);
        Self {
            axes,
            inputs,
            ticks: rows.len(),
            scans,
            rms_e_true_scan: (total_n > 0).then(|| (total_sq / total_n as f64).sqrt()),
            e_true: SignalStats::of(rows.iter().map(|r| r.e_true())),
            u: SignalStats::of(rows.iter().map(|r| r.u)),
            u_fb: SignalStats::of(rows.iter().map(|r| r.u_fb)),
            u_ff: SignalStats::of(rows.iter().map(|r| r.u_ff)),
            u_d: SignalStats::of(rows.iter().map(|r| r.u_d)),
            innovation: innovation_stats(rows.iter().map(|r| r.innovation)),
            held_ticks: held_ticks(trace),
            stale_estimates: rows.iter().filter(|r| r.stale_estimate).count(),
        }
    }
}

/// The held ticks among every tick the log holds (a trace simulated in
/// process has rows only: every tick has its command there).
fn held_ticks(trace: &RunTrace) -> usize {
    if trace.timing.is_empty() {
        trace.rows.iter().filter(|r| r.held).count()
    } else {
        trace.timing.iter().filter(|t| t.held).count()
    }
}

/// Per-output tracking and per-input effort from the trace's axis columns.
fn axis_metrics(trace: &RunTrace, windows: &[(f64, f64)]) -> (Vec<AxisMetrics>, Vec<SignalStats>) {
    let rows = &trace.rows;
    let (ny, nu) = (trace.n_outputs, trace.n_inputs);
    if ny == 0
        || trace.e_true_axes.len() != rows.len() * ny
        || trace.u_axes.len() != rows.len() * nu
    {
        return (Vec::new(), Vec::new());
    }
    let eps = 1e-9 * trace.ts;
    let in_scan = |t: f64| windows.iter().any(|&(a, b)| t >= a - eps && t <= b + eps);
    let settled_from = rows.len() - rows.len().div_ceil(10);
    let axes = (0..ny)
        .map(|j| {
            let e = |i: usize| trace.e_true_axes[i * ny + j];
            let (mut sq, mut n) = (0.0, 0usize);
            for (i, r) in rows.iter().enumerate() {
                if in_scan(trace.time(r)) {
                    sq += e(i) * e(i);
                    n += 1;
                }
            }
            AxisMetrics {
                rms_e_true_scan: (n > 0).then(|| (sq / n as f64).sqrt()),
                e_true: SignalStats::of((0..rows.len()).map(e)),
                settled_peak_e_true: (settled_from..rows.len())
                    .map(|i| e(i).abs())
                    .fold(0.0, f64::max),
            }
        })
        .collect();
    let inputs = (0..nu)
        .map(|j| SignalStats::of((0..rows.len()).map(|i| trace.u_axes[i * nu + j])))
        .collect();
    (axes, inputs)
}

/// Largest |MA| and MSD over windows of `exposure_s` that fit inside `e`
/// (docs/control.md (1.1)–(1.2): valid only where the whole window is inside).
fn moving_stats(e: &[f64], ts: f64, exposure_s: f64) -> (f64, f64) {
    let w = ((exposure_s / ts).round() as usize).max(1);
    if e.len() < w {
        return (f64::NAN, f64::NAN);
    }
    let (mut sum, mut sq) = (0.0, 0.0);
    let (mut max_ma, mut max_msd) = (0.0f64, 0.0f64);
    for (i, v) in e.iter().enumerate() {
        sum += v;
        sq += v * v;
        if i >= w {
            sum -= e[i - w];
            sq -= e[i - w] * e[i - w];
        }
        if i + 1 >= w {
            let ma = sum / w as f64;
            let var = (sq / w as f64 - ma * ma).max(0.0);
            max_ma = max_ma.max(ma.abs());
            max_msd = max_msd.max(var.sqrt());
        }
    }
    (max_ma, max_msd)
}

fn innovation_stats(values: impl Iterator<Item = f64>) -> InnovationStats {
    let v: Vec<f64> = values.filter(|v| v.is_finite()).collect();
    if v.len() < 2 {
        return InnovationStats::default();
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    let lag1 = if var > 0.0 {
        v.windows(2)
            .map(|p| (p[0] - mean) * (p[1] - mean))
            .sum::<f64>()
            / (n * var)
    } else {
        0.0
    };
    InnovationStats {
        mean,
        std: var.sqrt(),
        lag1_autocorrelation: lag1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::{TickRow, TickTiming};

    fn trace_of(e: &[f64]) -> RunTrace {
        let mut t = RunTrace::new(1e-3);
        t.rows = e
            .iter()
            .enumerate()
            .map(|(k, v)| TickRow {
                seq: k as u64,
                r: *v,
                innovation: if k % 2 == 0 { 1.0 } else { -1.0 },
                ..TickRow::default()
            })
            .collect();
        t
    }

    #[test]
    fn signal_stats_of_values_near_the_range_of_f64_stay_finite() {
        let s = SignalStats::of([1e300, -1e300, 1e300, -1e300, f64::NAN].into_iter());
        assert_eq!(s.peak, 1e300);
        assert!((s.rms / 1e300 - 1.0).abs() < 1e-12, "{s:?}");
        assert_eq!(s.mean, 0.0);
        let small = SignalStats::of([3.0, 4.0].into_iter());
        assert!((small.rms - 12.5f64.sqrt()).abs() < 1e-12);
        assert_eq!(small.mean, 3.5);
        assert_eq!(SignalStats::of([0.0, 0.0].into_iter()).rms, 0.0);
    }

    #[test]
    fn held_ticks_count_the_ticks_without_a_command_too() {
        let mut t = trace_of(&[0.0; 4]);
        t.rows[1].held = true;
        assert_eq!(held_ticks(&t), 1, "rows only: a simulated trace");
        // From a log: 10 ticks, 6 held, 5 of them without any command row.
        t.timing = (0..10)
            .map(|k| TickTiming {
                seq: k,
                held: k >= 4,
                ..TickTiming::default()
            })
            .collect();
        assert_eq!(held_ticks(&t), 6);
    }

    #[test]
    fn rms_over_the_window_only() {
        // 1 inside [0.010, 0.019], 100 outside.
        let e: Vec<f64> = (0..40)
            .map(|k| if (10..20).contains(&k) { 1.0 } else { 100.0 })
            .collect();
        let m = ControlMetrics::compute(
            &trace_of(&e),
            &[(0.010, 0.019)],
            &MetricsOptions { exposure_s: 0.005 },
        );
        assert_eq!(m.scans[0].samples, 10);
        assert!((m.rms_e_true_scan.unwrap() - 1.0).abs() < 1e-12);
        // A constant error is all MA, no MSD.
        assert!((m.scans[0].max_abs_ma - 1.0).abs() < 1e-12);
        assert!(m.scans[0].max_msd < 1e-6);
        assert_eq!(m.e_true.peak, 100.0);
        // Alternating innovation: perfectly anti-correlated at lag 1.
        assert!((m.innovation.lag1_autocorrelation + 1.0).abs() < 0.05);
    }

    #[test]
    fn no_window_no_scan_rms() {
        let m = ControlMetrics::compute(&trace_of(&[1.0; 5]), &[], &MetricsOptions::default());
        assert!(m.rms_e_true_scan.is_none());
        assert!(m.scans.is_empty());
    }
}
