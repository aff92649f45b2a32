//! The damping the loop achieves on each flexible mode, two ways:
//!
//! - from the closed-loop model the run used (its eigenvalues near each
//!   structural mode, leaving out the observer's own error dynamics);
//! - identified from the run: after the motion stops, each mode rings down in
//!   the true output as e^{−ζωt}. Demodulating y_true at the mode's frequency
//!   and averaging over a few periods isolates that mode's envelope (the
//!   neighbours are hundreds of Hz away); the slope of its logarithm is −ζω.
//!   This is what shows whether the damping force is applied with the right
//!   timing across the real processes (docs/control.md §10.1). The estimate x̂ is
//!   not used: it carries the observer's own error dynamics, which ring near
//!   the same frequencies.

use crate::thesis_design::least_damped_near;
use crate::trace::RunTrace;
use flexloop_control::closed_loop::closed_loop_modes;
use flexloop_design::LoopDesign;
use serde::Serialize;
use std::f64::consts::PI;

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ModeDamping {
    /// Open-loop frequency in Hz.
    pub frequency_hz: f64,
    pub open_loop: f64,
    /// Least-damped closed-loop pole within 5 % of the mode, observer error
    /// poles left out (None if none).
    pub closed_loop_model: Option<f64>,
    /// Identified from the run's ring-down (None when the mode is not
    /// estimated, or did not ring above the numerical floor).
    pub identified: Option<f64>,
}

/// Damping per flexible mode; modes the observer estimates are identified
/// from `trace` over [from_s, to_s].
pub fn modal_damping(
    design: &LoopDesign,
    trace: Option<&RunTrace>,
    from_s: f64,
    to_s: f64,
) -> Vec<ModeDamping> {
    let closed = design
        .closed_loop
        .as_ref()
        .and_then(|cl| closed_loop_modes(cl).ok())
        .unwrap_or_default();
    let frequencies: Vec<f64> = design.flexible_modes.iter().map(|(f, _)| *f).collect();
    let closed_loop = least_damped_near(&closed, &frequencies, &design.observer_modes);
    design
        .flexible_modes
        .iter()
        .zip(closed_loop)
        .map(|(&(f, zeta), closed_loop_model)| {
            // The closest other mode (or the rigid body at 0 Hz) sets how long
            // the demodulation window must be to separate them.
            let spacing = design
                .flexible_modes
                .iter()
                .map(|(g, _)| (g - f).abs())
                .filter(|d| *d > 0.0)
                .fold(f, f64::min);
            let identified = trace.and_then(|t| identify(t, f, spacing, from_s, to_s));
            ModeDamping {
                frequency_hz: f,
                open_loop: zeta,
                closed_loop_model,
                identified,
            }
        })
        .collect()
}

/// ζ of the mode at `f_hz` from the ring-down of y_true over [from_s, to_s];
/// `spacing_hz` is the distance to the nearest other mode.
fn identify(trace: &RunTrace, f_hz: f64, spacing_hz: f64, from_s: f64, to_s: f64) -> Option<f64> {
    let omega = 2.0 * PI * f_hz;
    let samples: Vec<(f64, f64)> = trace
        .rows
        .iter()
        .map(|r| (trace.time(r), r.y_true))
        .filter(|(t, _)| *t >= from_s && *t <= to_s)
        .collect();
    // A Hann-weighted demodulation: its main lobe (±2/T) must stay clear of
    // the nearest other mode, and its low side lobes keep a lightly damped
    // neighbour from leaking into a heavily damped mode's envelope. A long
    // window does not bias the slope: an exponential convolved with any
    // window is the same exponential.
    let window_s = (4.0 / f_hz).max(3.0 / spacing_hz);
    let width = (window_s / trace.ts).round() as usize;
    if width < 8 || samples.len() < 3 * width {
        return None;
    }
    let weights: Vec<f64> = (0..width)
        .map(|i| 0.5 - 0.5 * (2.0 * PI * (i as f64 + 0.5) / width as f64).cos())
        .collect();
    let weight_sum: f64 = weights.iter().sum();
    let envelope: Vec<(f64, f64)> = samples
        .windows(width)
        .map(|window| {
            // Remove the window's weighted mean first: the rigid-body
            // position is many orders of magnitude larger than the ringing.
            let mean = window
                .iter()
                .zip(&weights)
                .map(|(p, w)| p.1 * w)
                .sum::<f64>()
                / weight_sum;
            let (mut re, mut im) = (0.0, 0.0);
            for ((t, y), w) in window.iter().zip(&weights) {
                let (s, c) = (omega * t).sin_cos();
                re += w * (y - mean) * c;
                im += w * (y - mean) * s;
            }
            let t_mid = 0.5 * (window[0].0 + window[width - 1].0);
            (t_mid, 2.0 * (re * re + im * im).sqrt() / weight_sum)
        })
        .collect();
    let t0 = envelope.first()?.0;
    if envelope[0].1.is_nan() || envelope[0].1 <= 0.0 {
        return None;
    }
    // Fit ln(envelope) over two time constants of the current estimate,
    // starting from eight periods: long enough to average the ripple, short
    // enough to stay above the other modes' leakage and the numerical floor.
    let mut span = (8.0 / f_hz).max(window_s);
    let mut zeta = None;
    for _ in 0..4 {
        let fit: Vec<(f64, f64)> = envelope
            .iter()
            .filter(|(t, a)| *t <= t0 + span && *a > 0.0)
            .map(|(t, a)| (*t, a.ln()))
            .collect();
        if fit.len() < width {
            break;
        }
        let n = fit.len() as f64;
        let mt = fit.iter().map(|p| p.0).sum::<f64>() / n;
        let ma = fit.iter().map(|p| p.1).sum::<f64>() / n;
        let sxy: f64 = fit.iter().map(|(t, a)| (t - mt) * (a - ma)).sum();
        let sxx: f64 = fit.iter().map(|(t, _)| (t - mt).powi(2)).sum();
        let z = -(sxy / sxx) / omega;
        if !z.is_finite() {
            return None;
        }
        zeta = Some(z);
        if z <= 0.0 {
            break;
        }
        span = (2.0 / (z * omega)).clamp((8.0 / f_hz).max(window_s), to_s - t0);
    }
    zeta
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trace::TickRow;

    #[test]
    fn ring_down_of_one_mode_among_others_gives_its_damping() {
        // Modes at 470 Hz (ζ 0.05) and 940 Hz (ζ 0.005) on a large offset,
        // sampled at 10 kHz: each is identified apart from the other.
        let ts = 1e-4;
        let mode = |f: f64, zeta: f64, t: f64| {
            let w = 2.0 * PI * f;
            (-zeta * w * t).exp() * (w * (1.0 - zeta * zeta).sqrt() * t).cos()
        };
        let mut trace = RunTrace::new(ts);
        for k in 0..2000u64 {
            let t = k as f64 * ts;
            trace.rows.push(TickRow {
                seq: k,
                y_true: 0.17 + 1e-8 * mode(470.0, 0.05, t) + 2e-9 * mode(940.0, 0.005, t),
                ..TickRow::default()
            });
        }
        let z1 = identify(&trace, 470.0, 470.0, 0.0, 0.2).unwrap();
        assert!((z1 - 0.05).abs() < 0.002, "{z1}");
        let z2 = identify(&trace, 940.0, 470.0, 0.0, 0.2).unwrap();
        assert!((z2 - 0.005).abs() < 0.001, "{z2}");
    }
}
