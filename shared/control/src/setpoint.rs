//! The 4th-order (snap-limited) scan set-point of Table 3.6 (docs/control.md §7):
//! accelerate, settle, scan at constant velocity, decelerate, rest.
//! Evaluation at a time t is allocation-free and branch-bounded (at most 16
//! piecewise-polynomial segments), so it can run in the loop.

use std::fmt;

/// Why a set-point was refused.
#[derive(Debug, Clone, PartialEq)]
pub enum SetpointError {
    /// A limit or duration is not positive and finite.
    InvalidParameter(&'static str),
    /// The limits are inconsistent (e.g. A_max reached before J_max phase
    /// can end: A/J < J/S, or V/A shorter than the jerk phases).
    InconsistentLimits(String),
}

impl fmt::Display for SetpointError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::InvalidParameter(w) => {
                write!(f, "set-point parameter {w} must be positive and finite")
            }
            Self::InconsistentLimits(s) => write!(f, "inconsistent set-point limits: {s}"),
        }
    }
}

impl std::error::Error for SetpointError {}

/// Table 3.6 parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetpointParams {
    /// Snap limit [m/s⁴].
    pub s_max: f64,
    /// Jerk limit [m/s³].
    pub j_max: f64,
    /// Acceleration limit [m/s²].
    pub a_max: f64,
    /// Scan velocity [m/s].
    pub v_max: f64,
    /// Duration of the constant-velocity phase [s] (settle + scan).
    pub t_vel: f64,
    /// Settling time at the start of the constant-velocity phase [s].
    pub t_settle: f64,
}

impl SetpointParams {
    /// Table 3.6: S 4e6, J 2e4, A 100, V 1, T_vel 0.15, T_settle 0.02.
    pub fn thesis() -> Self {
        Self {
            s_max: 4e6,
            j_max: 2e4,
            a_max: 100.0,
            v_max: 1.0,
            t_vel: 0.15,
            t_settle: 0.02,
        }
    }
}

/// Phase of the scan at a time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    Accelerate,
    Settle,
    Scan,
    Decelerate,
    Rest,
}

/// Reference and its derivatives at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SetpointSample {
    pub r: f64,
    pub v: f64,
    pub a: f64,
    pub j: f64,
    pub s: f64,
    pub phase: Phase,
}

#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Segment {
    t0: f64,
    snap: f64,
    r0: f64,
    v0: f64,
    a0: f64,
    j0: f64,
}

impl Segment {
    fn eval(&self, t: f64) -> (f64, f64, f64, f64) {
        let tau = t - self.t0;
        let (s, j0, a0, v0) = (self.snap, self.j0, self.a0, self.v0);
        let j = j0 + s * tau;
        let a = a0 + tau * (j0 + tau * s / 2.0);
        let v = v0 + tau * (a0 + tau * (j0 / 2.0 + tau * s / 6.0));
        let r = self.r0 + tau * (v0 + tau * (a0 / 2.0 + tau * (j0 / 6.0 + tau * s / 24.0)));
        (r, v, a, j)
    }
}

const MAX_SEGMENTS: usize = 16;

/// A precomputed scan profile.
#[derive(Debug, Clone, PartialEq)]
pub struct Setpoint {
    segs: [Segment; MAX_SEGMENTS],
    n: usize,
    t_acc: f64,
    t_settle: f64,
    t_vel: f64,
    t_end: f64,
    end: (f64, f64, f64, f64),
}

impl Setpoint {
    pub fn new(p: &SetpointParams) -> Result<Self, SetpointError> {
        let pos = |v: f64, w| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(SetpointError::InvalidParameter(w))
            }
        };
        pos(p.s_max, "s_max")?;
        pos(p.j_max, "j_max")?;
        pos(p.a_max, "a_max")?;
        pos(p.v_max, "v_max")?;
        pos(p.t_vel, "t_vel")?;
        if !(p.t_settle.is_finite() && p.t_settle >= 0.0 && p.t_settle <= p.t_vel) {
            return Err(SetpointError::InvalidParameter("t_settle"));
        }
        let ts = p.j_max / p.s_max;
        let mut tj = p.a_max / p.j_max - ts;
        let mut ta = p.v_max / p.a_max - 2.0 * ts - tj;
        // Round-off in e.g. 100/2e4 − 5e-3 must not count as inconsistent.
        let eps = 1e-12 * (ts + p.v_max / p.a_max);
        if tj < -eps || ta < -eps {
            return Err(SetpointError::InconsistentLimits(format!(
                "constant-jerk time {tj} s, constant-acceleration time {ta} s"
            )));
        }
        tj = tj.max(0.0);
        ta = ta.max(0.0);
        let s = p.s_max;
        let accel = [
            (s, ts),
            (0.0, tj),
            (-s, ts),
            (0.0, ta),
            (-s, ts),
            (0.0, tj),
            (s, ts),
        ];
        let mut plan: Vec<(f64, f64)> = Vec::with_capacity(MAX_SEGMENTS);
        plan.extend(accel.iter().copied());
        plan.push((0.0, p.t_vel));
        plan.extend(accel.iter().map(|&(sn, d)| (-sn, d)));
        let mut segs = [Segment::default(); MAX_SEGMENTS];
        let (mut t, mut st) = (0.0, (0.0, 0.0, 0.0, 0.0));
        let mut n = 0;
        for &(snap, dur) in &plan {
            if dur <= 0.0 {
                continue;
            }
            let seg = Segment {
                t0: t,
                snap,
                r0: st.0,
                v0: st.1,
                a0: st.2,
                j0: st.3,
            };
            t += dur;
            st = seg.eval(t);
            segs[n] = seg;
            n += 1;
        }
        let t_acc = 4.0 * ts + 2.0 * tj + ta;
        Ok(Self {
            segs,
            n,
            t_acc,
            t_settle: p.t_settle,
            t_vel: p.t_vel,
            t_end: t,
            // Exact rest values: velocity and below are zero by construction.
            end: (st.0, 0.0, 0.0, 0.0),
        })
    }

    /// Total duration of the motion [s] (0.19 s for Table 3.6).
    pub fn duration(&self) -> f64 {
        self.t_end
    }

    /// Start and end of the scan window [s] ([0.04, 0.17] for Table 3.6).
    pub fn scan_window(&self) -> (f64, f64) {
        (self.t_acc + self.t_settle, self.t_acc + self.t_vel)
    }

    /// The set-point at time t [s]; before 0 and after the end it is at rest.
    pub fn evaluate(&self, t: f64) -> SetpointSample {
        if t.is_nan() || t < 0.0 {
            return SetpointSample {
                r: 0.0,
                v: 0.0,
                a: 0.0,
                j: 0.0,
                s: 0.0,
                phase: Phase::Rest,
            };
        }
        if t >= self.t_end {
            let (r, v, a, j) = self.end;
            return SetpointSample {
                r,
                v,
                a,
                j,
                s: 0.0,
                phase: Phase::Rest,
            };
        }
        let mut k = 0;
        while k + 1 < self.n && t >= self.segs[k + 1].t0 {
            k += 1;
        }
        let seg = &self.segs[k];
        let (r, v, a, j) = seg.eval(t);
        let phase = if t < self.t_acc {
            Phase::Accelerate
        } else if t < self.t_acc + self.t_settle {
            Phase::Settle
        } else if t < self.t_acc + self.t_vel {
            Phase::Scan
        } else {
            Phase::Decelerate
        };
        SetpointSample {
            r,
            v,
            a,
            j,
            s: seg.snap,
            phase,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_3_6_timeline() {
        let sp = Setpoint::new(&SetpointParams::thesis()).unwrap();
        assert!((sp.duration() - 0.19).abs() < 1e-12);
        let (a, b) = sp.scan_window();
        assert!((a - 0.04).abs() < 1e-12 && (b - 0.17).abs() < 1e-12);
        let at = |t: f64| sp.evaluate(t);
        let s = at(0.02);
        assert!((s.r - 0.01).abs() < 1e-12 && (s.v - 1.0).abs() < 1e-12 && s.a.abs() < 1e-9);
        assert_eq!(s.phase, Phase::Settle);
        assert!((at(0.04).r - 0.03).abs() < 1e-12);
        assert_eq!(at(0.1).phase, Phase::Scan);
        assert!((at(0.17).r - 0.16).abs() < 1e-12);
        assert_eq!(at(0.18).phase, Phase::Decelerate);
        let e = at(0.19);
        assert!((e.r - 0.17).abs() < 1e-12 && e.v == 0.0 && e.phase == Phase::Rest);
        let m = at(0.01);
        assert!((m.a - 100.0).abs() < 1e-9 && m.phase == Phase::Accelerate);
        assert!((at(0.005).j - 2e4).abs() < 1e-6);
        assert_eq!(at(0.001).s, 4e6);
        assert_eq!(at(0.012).s, -4e6);
        assert_eq!(at(-1.0).phase, Phase::Rest);
        let mut bad = SetpointParams::thesis();
        bad.a_max = 50.0; // A/J = 2.5 ms < J/S = 5 ms
        assert!(matches!(
            Setpoint::new(&bad),
            Err(SetpointError::InconsistentLimits(_))
        ));
        bad.a_max = f64::NAN;
        assert!(Setpoint::new(&bad).is_err());
    }
}
