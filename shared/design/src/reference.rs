//! Set-point profiles: r and its first four derivatives at any time.
//!
//! Evaluated once per sample by the controller, so [`Reference::sample`] is
//! closed-form and allocation-free.

use flexloop_control::setpoint::{Setpoint, SetpointParams};
use flexloop_scenario::{Scenario, ScenarioError};
use std::f64::consts::PI;

const SWITCH_NUDGE_S: f64 = 1e-12;

/// r, ṙ, r̈, r⃛ and the snap, in that order.
pub type Derivatives = [f64; 5];

#[derive(Debug, Clone, PartialEq)]
pub enum Reference {
    /// r = 0.
    Hold,
    /// A step of `amplitude` at `start_s` (derivatives are zero: a step has no
    /// feedforward).
    Step { amplitude: f64, start_s: f64 },
    /// amplitude · sin(ω (t − start)) from `start_s` on.
    Sine {
        amplitude: f64,
        omega: f64,
        start_s: f64,
    },
    /// The thesis' snap-limited scan (Table 3.6), shifted to start at
    /// `start_s`; with `repeat_s` > 0 it scans back and forth (a meander),
    /// one scan every `repeat_s` seconds.
    Scan {
        /// Boxed: the profile's segment table would make every variant large.
        setpoint: Box<Setpoint>,
        start_s: f64,
        repeat_s: f64,
        /// The profile times this (1: the thesis' 0.17 m stroke), with the
        /// same timing: a shorter stroke at a proportionally lower speed.
        scale: f64,
    },
}

impl Reference {
    pub fn sample(&self, t: f64) -> Derivatives {
        match *self {
            Reference::Hold => [0.0; 5],
            Reference::Step { amplitude, start_s } => [
                if t >= start_s { amplitude } else { 0.0 },
                0.0,
                0.0,
                0.0,
                0.0,
            ],
            Reference::Sine {
                amplitude,
                omega,
                start_s,
            } => {
                if t < start_s {
                    return [0.0; 5];
                }
                let phase = omega * (t - start_s);
                let (s, c) = phase.sin_cos();
                let a = amplitude;
                [
                    a * s,
                    a * omega * c,
                    -a * omega.powi(2) * s,
                    -a * omega.powi(3) * c,
                    a * omega.powi(4) * s,
                ]
            }
            Reference::Scan {
                ref setpoint,
                start_s,
                repeat_s,
                scale,
            } => {
                // Ticks fall exactly on the profile's switching times (every
                // 5 ms); 1 ps forward makes each one resolve to the segment that
                // starts there, whatever the rounding of t (a tick on the wrong
                // side costs one sample of a 13 N snap feedforward step).
                let (index, local) = scan_index(t - start_s + SWITCH_NUDGE_S, repeat_s);
                let p = setpoint.evaluate(local);
                let d = if index % 2 == 0 {
                    [p.r, p.v, p.a, p.j, p.s]
                } else {
                    // Back: from the end position to the start.
                    let end = setpoint.evaluate(setpoint.duration()).r;
                    [end - p.r, -p.v, -p.a, -p.j, -p.s]
                };
                if scale == 1.0 {
                    d
                } else {
                    d.map(|v| scale * v)
                }
            }
        }
    }

    /// The windows over which tracking is judged, up to `until_s`: the scan
    /// phase of each scan (docs/control.md §8). Empty for other shapes.
    pub fn scan_windows(&self, until_s: f64) -> Vec<(f64, f64)> {
        match self {
            Reference::Scan {
                setpoint,
                start_s,
                repeat_s,
                ..
            } => {
                let (a, b) = setpoint.scan_window();
                let mut windows = Vec::new();
                let mut offset = *start_s;
                while offset + b <= until_s + 1e-12 {
                    windows.push((offset + a, offset + b));
                    if *repeat_s <= 0.0 {
                        break;
                    }
                    offset += repeat_s;
                }
                windows
            }
            _ => Vec::new(),
        }
    }

    /// When a profile that repeats starts doing so, and its period: a
    /// meander's forth and back. None for one that does not repeat.
    pub fn repetition(&self) -> Option<(f64, f64)> {
        match self {
            Reference::Scan {
                start_s, repeat_s, ..
            } if *repeat_s > 0.0 => Some((*start_s, 2.0 * repeat_s)),
            _ => None,
        }
    }

    /// When the motion is over (None: it never ends).
    pub fn end_s(&self) -> Option<f64> {
        match self {
            Reference::Hold => Some(0.0),
            Reference::Step { start_s, .. } => Some(*start_s),
            Reference::Sine { .. } => None,
            Reference::Scan {
                setpoint,
                start_s,
                repeat_s,
                ..
            } => (*repeat_s <= 0.0).then(|| start_s + setpoint.duration()),
        }
    }
}

/// Which scan a time falls in, and the time within it.
fn scan_index(t: f64, repeat_s: f64) -> (u64, f64) {
    if repeat_s <= 0.0 || t < 0.0 {
        return (0, t);
    }
    let index = (t / repeat_s).floor();
    (index as u64, t - index * repeat_s)
}

impl Reference {
    /// The profile of `s.reference` (a scan checked for its lead-in and repeat).
    /// With a command deadline τ_d the profile starts τ_d later: each
    /// command acts from t_k + τ_d, and so the profile's switching instants
    /// (the snap's steps, on the sample grid from `start_s`) fall on that
    /// actuation grid; evaluated at t_k + τ_d the feedforward then switches
    /// exactly when the profile does, rather than τ_d late (docs/deadline.md).
    pub fn from_scenario(s: &Scenario) -> Result<Self, ScenarioError> {
        let r = &s.reference;
        let start_s = r.start_s + s.command_deadline_s().unwrap_or(0.0);
        Ok(match r.shape.as_str() {
            "hold" => Reference::Hold,
            "step" => Reference::Step {
                amplitude: r.amplitude,
                start_s,
            },
            "sine" => Reference::Sine {
                amplitude: r.amplitude,
                omega: 2.0 * PI * r.frequency_hz,
                start_s,
            },
            "scan" => {
                let ts = 1.0 / s.timing.rate_hz;
                if r.start_s < ts {
                    return Err(ScenarioError::new(
                        &s.source,
                        Some("reference.start_s"),
                        format!(
                            "a scan must start at least one sample ({ts} s) after the run, \
                             so that its feedforward can be issued ahead of the motion; got {}",
                            r.start_s
                        ),
                    ));
                }
                let setpoint = Setpoint::new(&SetpointParams::thesis()).map_err(|e| {
                    ScenarioError::new(&s.source, Some("reference"), format!("set-point: {e}"))
                })?;
                if r.repeat_s > 0.0 && r.repeat_s < setpoint.duration() {
                    return Err(ScenarioError::new(
                        &s.source,
                        Some("reference.repeat_s"),
                        format!(
                            "a scan lasts {} s; it cannot repeat every {} s",
                            setpoint.duration(),
                            r.repeat_s
                        ),
                    ));
                }
                // `amplitude` 0: the thesis' stroke, as the profile has it.
                let stroke = setpoint.evaluate(setpoint.duration()).r;
                let scale = if r.amplitude == 0.0 {
                    1.0
                } else {
                    r.amplitude / stroke
                };
                Reference::Scan {
                    setpoint: Box::new(setpoint),
                    start_s,
                    repeat_s: r.repeat_s,
                    scale,
                }
            }
            other => {
                return Err(ScenarioError::new(
                    &s.source,
                    Some("reference.shape"),
                    format!("unknown shape `{other}` (expected hold, step, sine or scan)"),
                ));
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sine_derivatives_match_finite_differences() {
        let r = Reference::Sine {
            amplitude: 2.0,
            omega: 3.0,
            start_s: 0.0,
        };
        let h = 1e-6;
        let t = 0.4;
        for i in 0..4 {
            let numeric = (r.sample(t + h)[i] - r.sample(t - h)[i]) / (2.0 * h);
            let exact = r.sample(t)[i + 1];
            assert!((numeric - exact).abs() < 1e-4 * exact.abs().max(1.0), "{i}");
        }
    }

    #[test]
    fn meander_scans_back_and_forth_continuously() {
        let setpoint =
            Setpoint::new(&flexloop_control::setpoint::SetpointParams::thesis()).unwrap();
        let r = Reference::Scan {
            setpoint: Box::new(setpoint),
            start_s: 0.01,
            repeat_s: 0.25,
            scale: 1.0,
        };
        let end = r.sample(0.01 + 0.2)[0];
        assert!((end - 0.17).abs() < 1e-9, "{end}");
        // Back at the start after the second scan, and continuous at the turn.
        assert!(r.sample(0.01 + 0.25 + 0.2)[0].abs() < 1e-9);
        let before = r.sample(0.01 + 0.25 - 1e-6);
        let after = r.sample(0.01 + 0.25 + 1e-6);
        assert!((before[0] - after[0]).abs() < 1e-9);
        assert!(after[1] <= 0.0);
        assert_eq!(r.scan_windows(0.6), vec![(0.05, 0.18), (0.3, 0.43)],);
    }

    #[test]
    fn step_switches_at_its_time() {
        let r = Reference::Step {
            amplitude: 1.0,
            start_s: 0.5,
        };
        assert_eq!(r.sample(0.49)[0], 0.0);
        assert_eq!(r.sample(0.5)[0], 1.0);
    }
}
