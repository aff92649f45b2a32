//! Scales and their ticks.
//!
//! A scale maps a data value to a position along the axis (the affine map to
//! pixels comes after): the value itself, its base-10 logarithm, or for
//! HdrHistogram's percentile plots the number of nines of a quantile,
//! log10(1/(1−q)), so that 90 %, 99 %, 99.9 % ... sit one decade apart.

/// How data values are placed along an axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scale {
    Linear,
    /// Positive values, a decade per unit.
    Log10,
    /// Quantiles q in [0, 1) at log10(1/(1−q)).
    PercentileLog,
}

impl Scale {
    /// Position of `value` along the axis; None where the scale cannot show
    /// it (non-finite, ≤ 0 on a log axis, outside [0, 1) on a percentile axis).
    pub fn position(self, value: f64) -> Option<f64> {
        if !value.is_finite() {
            return None;
        }
        match self {
            Scale::Linear => Some(value),
            Scale::Log10 => (value > 0.0).then(|| value.log10()),
            Scale::PercentileLog => (0.0..1.0).contains(&value).then(|| -(1.0 - value).log10()),
        }
    }

    /// The value at `position` (inverse of [`position`](Self::position)).
    pub fn value(self, position: f64) -> f64 {
        match self {
            Scale::Linear => position,
            Scale::Log10 => 10f64.powf(position),
            Scale::PercentileLog => 1.0 - 10f64.powf(-position),
        }
    }
}

/// One axis of a figure.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    /// With its unit, e.g. "time [s]".
    pub label: String,
    pub scale: Scale,
    /// Fixed data range; None: from the data, widened to ticks.
    pub range: Option<(f64, f64)>,
}

impl Axis {
    pub fn linear(label: &str) -> Self {
        Self::new(label, Scale::Linear)
    }

    pub fn log10(label: &str) -> Self {
        Self::new(label, Scale::Log10)
    }

    pub fn percentile(label: &str) -> Self {
        Self::new(label, Scale::PercentileLog)
    }

    fn new(label: &str, scale: Scale) -> Self {
        Self {
            label: label.to_string(),
            scale,
            range: None,
        }
    }

    /// Fixes the data range (in data values, not positions).
    pub fn with_range(mut self, lo: f64, hi: f64) -> Self {
        self.range = Some((lo, hi));
        self
    }
}

/// A labelled tick.
#[derive(Debug, Clone, PartialEq)]
pub struct Tick {
    /// Position along the axis (see [`Scale::position`]).
    pub position: f64,
    pub label: String,
}

/// Positions within this of a whole step count as on it (0.3 / 0.05 is
/// 5.999...).
const ROUNDING: f64 = 1e-9;

/// 1, 2 or 5 times a power of ten, at least `raw`.
pub fn nice_step(raw: f64) -> f64 {
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let magnitude = 10f64.powf(raw.log10().floor());
    let normalised = raw / magnitude;
    let factor = if normalised <= 1.0 + 1e-9 {
        1.0
    } else if normalised <= 2.0 + 1e-9 {
        2.0
    } else if normalised <= 5.0 + 1e-9 {
        5.0
    } else {
        10.0
    };
    factor * magnitude
}

/// The 1-2-5 step whose ticks inside `lo..=hi` come closest to `target`
/// intervals (the larger step on a tie), so that a range widened to whole
/// steps keeps the step it was widened with.
fn linear_step(lo: f64, hi: f64, target: usize) -> f64 {
    let target = target.max(1) as f64;
    let base = nice_step((hi - lo) / target);
    let count = |step: f64| (hi / step + ROUNDING).floor() - (lo / step - ROUNDING).ceil() + 1.0;
    [base / 2.5, base / 2.0, base, base * 2.0, base * 2.5]
        .into_iter()
        .map(nice_step)
        .fold((base, f64::INFINITY), |(best, miss), step| {
            let m = (count(step) - (target + 1.0)).abs();
            if m < miss || (m == miss && step > best) {
                (step, m)
            } else {
                (best, miss)
            }
        })
        .0
}

/// The axis range (positions) covering data positions `lo..=hi`, widened to
/// whole ticks so that the frame starts and ends on a label.
pub fn auto_range(scale: Scale, lo: f64, hi: f64, target_ticks: usize) -> (f64, f64) {
    let (lo, hi) = if lo.is_finite() && hi.is_finite() && lo <= hi {
        (lo, hi)
    } else {
        (0.0, 1.0)
    };
    match scale {
        Scale::Linear => {
            let (lo, hi) = if hi - lo <= f64::EPSILON * hi.abs().max(1e-300) {
                let pad = if lo == 0.0 { 1.0 } else { lo.abs() * 0.1 };
                (lo - pad, hi + pad)
            } else {
                (lo, hi)
            };
            let step = linear_step(lo, hi, target_ticks);
            (
                (lo / step + ROUNDING).floor() * step,
                (hi / step - ROUNDING).ceil() * step,
            )
        }
        Scale::Log10 => {
            let (lo, hi) = ((lo + ROUNDING).floor(), (hi - ROUNDING).ceil());
            if hi > lo { (lo, hi) } else { (lo, lo + 1.0) }
        }
        // From 0 %, to the next whole number of nines past the data.
        Scale::PercentileLog => (
            (lo.min(0.0) + ROUNDING).floor(),
            (hi - ROUNDING).ceil().max(1.0),
        ),
    }
}

/// Ticks over the range `lo..=hi` of positions.
pub fn ticks(scale: Scale, lo: f64, hi: f64, target: usize) -> Vec<Tick> {
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return Vec::new();
    }
    let inside = |p: f64| p >= lo - 1e-9 * (hi - lo) && p <= hi + 1e-9 * (hi - lo);
    match scale {
        Scale::Linear => {
            let step = linear_step(lo, hi, target);
            let first = (lo / step - ROUNDING).ceil() as i64;
            let last = (hi / step + ROUNDING).floor() as i64;
            (first..=last)
                .map(|i| {
                    let v = i as f64 * step;
                    Tick {
                        position: v,
                        label: format_linear(v, step),
                    }
                })
                .collect()
        }
        Scale::Log10 => {
            // Over few decades, 2 and 5 as well.
            let multiples: &[f64] = if hi - lo <= 2.0 {
                &[1.0, 2.0, 5.0]
            } else {
                &[1.0]
            };
            let mut out = Vec::new();
            for decade in (lo.floor() as i32)..=(hi.ceil() as i32) {
                for m in multiples {
                    let v = m * 10f64.powi(decade);
                    let p = v.log10();
                    if inside(p) {
                        out.push(Tick {
                            position: p,
                            label: format_log(v),
                        });
                    }
                }
            }
            out
        }
        Scale::PercentileLog => {
            let mut out = Vec::new();
            for nines in (lo.ceil().max(0.0) as i32)..=(hi.floor() as i32) {
                out.push(Tick {
                    position: nines as f64,
                    label: percent_label(nines as u32),
                });
                if nines == 0 && inside(2f64.log10()) {
                    out.push(Tick {
                        position: 2f64.log10(),
                        label: "50 %".into(),
                    });
                }
            }
            out
        }
    }
}

/// "0 %", "90 %", "99 %", "99.9 %", ...: the quantile 1 − 10^−nines.
pub fn percent_label(nines: u32) -> String {
    if nines == 0 {
        return "0 %".into();
    }
    let percent = 100.0 * (1.0 - 10f64.powi(-(nines as i32)));
    format!("{percent:.*} %", nines.saturating_sub(2) as usize)
}

/// A linear tick value with as many decimals as its step needs.
pub fn format_linear(v: f64, step: f64) -> String {
    if v.abs() < step * 1e-9 {
        return "0".into();
    }
    if !(1e-4..1e5).contains(&step) {
        let text = format!("{v:e}");
        // 1.5000000000000002e5 -> 1.5e5: ticks are multiples of 1, 2 or 5.
        return match text.split_once('e') {
            Some((mantissa, exp)) => {
                let m: f64 = mantissa.parse().unwrap_or(0.0);
                format!("{}e{exp}", trim_zeros(&format!("{m:.3}")))
            }
            None => text,
        };
    }
    let decimals = (-(step.log10() + 1e-9).floor()).max(0.0) as usize;
    format!("{v:.decimals$}")
}

fn format_log(v: f64) -> String {
    if (1e-3..1e6).contains(&v) {
        let decimals = (-(v.log10() + 1e-9).floor()).max(0.0) as usize;
        format!("{v:.decimals$}")
    } else {
        format!("1e{}", v.log10().round() as i32)
    }
}

fn trim_zeros(s: &str) -> &str {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_steps_are_one_two_five() {
        assert_eq!(nice_step(0.7), 1.0);
        assert_eq!(nice_step(1.3), 2.0);
        assert_eq!(nice_step(3.0), 5.0);
        assert_eq!(nice_step(7.0), 10.0);
        assert!((nice_step(0.00023) - 0.0005).abs() < 1e-15);
        assert_eq!(nice_step(2000.0), 2000.0);
    }

    #[test]
    fn linear_ticks_cover_the_range_on_round_values() {
        let (lo, hi) = auto_range(Scale::Linear, -3.2, 41.0, 5);
        assert_eq!((lo, hi), (-10.0, 50.0));
        let t = ticks(Scale::Linear, lo, hi, 5);
        let labels: Vec<&str> = t.iter().map(|t| t.label.as_str()).collect();
        assert_eq!(labels, ["-10", "0", "10", "20", "30", "40", "50"]);
        let t = ticks(Scale::Linear, 0.0, 0.3, 6);
        let labels: Vec<&str> = t.iter().map(|t| t.label.as_str()).collect();
        assert_eq!(
            labels,
            ["0", "0.05", "0.10", "0.15", "0.20", "0.25", "0.30"]
        );
    }

    #[test]
    fn a_flat_series_still_gets_a_range() {
        let (lo, hi) = auto_range(Scale::Linear, 5.0, 5.0, 5);
        assert!(lo < 5.0 && hi > 5.0);
        let (lo, hi) = auto_range(Scale::Linear, 0.0, 0.0, 5);
        assert!(lo < 0.0 && hi > 0.0);
    }

    #[test]
    fn large_and_small_values_use_exponents() {
        assert_eq!(format_linear(150_000.0, 50_000.0 * 2.0), "1.5e5");
        assert_eq!(format_linear(2e-5, 1e-5), "2e-5");
        assert_eq!(format_linear(-0.0, 1.0), "0");
    }

    #[test]
    fn log_percentile_axis_puts_each_nine_one_decade_on() {
        let s = Scale::PercentileLog;
        assert_eq!(s.position(0.0), Some(0.0));
        assert!((s.position(0.9).unwrap() - 1.0).abs() < 1e-12);
        assert!((s.position(0.999).unwrap() - 3.0).abs() < 1e-9);
        assert!((s.position(0.5).unwrap() - 2f64.log10()).abs() < 1e-12);
        assert_eq!(s.position(1.0), None, "100 % is infinitely far");
        assert_eq!(s.position(-0.1), None);
        assert!((s.value(4.0) - 0.9999).abs() < 1e-12);
        // 100 000 samples: the last quantile below 1 is 1 − 1e-5.
        let (lo, hi) = auto_range(s, 0.0, s.position(1.0 - 1e-5).unwrap(), 5);
        assert_eq!((lo, hi), (0.0, 5.0));
        let labels: Vec<String> = ticks(s, lo, hi, 5).into_iter().map(|t| t.label).collect();
        assert_eq!(
            labels,
            [
                "0 %", "50 %", "90 %", "99 %", "99.9 %", "99.99 %", "99.999 %"
            ]
        );
    }

    #[test]
    fn log10_ticks_are_decades_or_one_two_five() {
        let labels = |lo, hi| -> Vec<String> {
            ticks(Scale::Log10, lo, hi, 5)
                .into_iter()
                .map(|t| t.label)
                .collect()
        };
        assert_eq!(labels(0.0, 4.0), ["1", "10", "100", "1000", "10000"]);
        assert_eq!(labels(0.0, 2.0), ["1", "2", "5", "10", "20", "50", "100"]);
        assert_eq!(labels(-2.0, -1.0), ["0.01", "0.02", "0.05", "0.1"]);
        assert_eq!(Scale::Log10.position(0.0), None);
    }
}
