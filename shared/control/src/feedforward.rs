//! The 4-gain feedforward C_ff(s) = Θ_snap s⁴ + Θ_jerk s³ + Θ_acc s² + Θ_vel s
//! on the set-point derivatives (docs/control.md §7, (A.1)), and least-squares
//! fitting of the four gains from recorded data.

use crate::setpoint::SetpointSample;
use nalgebra::{DMatrix, DVector};
use std::fmt;

/// Why a fit failed.
#[derive(Debug, Clone, PartialEq)]
pub enum FitError {
    /// Regressor rows and targets differ in number, or there are fewer than 4.
    BadLength { rows: usize, targets: usize },
    /// Data hold NaN or infinity.
    NonFinite,
    /// A regressor column is identically zero or the columns are dependent.
    RankDeficient,
    /// There is no closed-loop model to fit through.
    NoClosedLoop,
}

impl fmt::Display for FitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::BadLength { rows, targets } => {
                write!(
                    f,
                    "fit needs ≥ 4 equal-length rows: {rows} regressors, {targets} targets"
                )
            }
            Self::NonFinite => write!(f, "fit data hold a non-finite number"),
            Self::RankDeficient => write!(f, "fit regressors are rank deficient"),
            Self::NoClosedLoop => write!(f, "no closed-loop model to fit the gains through"),
        }
    }
}

impl std::error::Error for FitError {}

/// Feedforward gains; u_ff = Θ_snap s + Θ_jerk j + Θ_acc a + Θ_vel v.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FeedforwardGains {
    pub snap: f64,
    pub jerk: f64,
    pub acc: f64,
    pub vel: f64,
}

impl FeedforwardGains {
    /// Pure mass feedforward Θ_acc = m.
    pub fn mass(m: f64) -> Self {
        Self {
            acc: m,
            ..Self::default()
        }
    }

    /// u_ff for one set-point sample (allocation-free). To absorb a known
    /// loop delay of d samples, evaluate the set-point at t + d·Ts (§10.1).
    pub fn apply(&self, s: &SetpointSample) -> f64 {
        self.snap * s.s + self.jerk * s.j + self.acc * s.a + self.vel * s.v
    }

    /// The regressor row [s, j, a, v] of a sample, in gain order.
    pub fn regressor(s: &SetpointSample) -> [f64; 4] {
        [s.s, s.j, s.a, s.v]
    }
}

/// Least squares: gains θ minimising Σ_k (target_k − rows_k · θ)², with
/// rows in the order [snap, jerk, acc, vel]. Columns are normalised first,
/// since snap (~10⁶) and velocity (~1) differ by many decades.
///
/// Two uses: rows = set-point derivatives and target = the force the plant
/// needed; or rows = the responses of y to each basis signal fed as u_ff and
/// target = e_true without feedforward (then θ minimises e_true).
pub fn fit_gains(rows: &[[f64; 4]], target: &[f64]) -> Result<FeedforwardGains, FitError> {
    if rows.len() != target.len() || rows.len() < 4 {
        return Err(FitError::BadLength {
            rows: rows.len(),
            targets: target.len(),
        });
    }
    if rows.iter().flatten().chain(target).any(|v| !v.is_finite()) {
        return Err(FitError::NonFinite);
    }
    let n = rows.len();
    let mut a = DMatrix::from_fn(n, 4, |i, j| rows[i][j]);
    let mut scale = [0.0; 4];
    for (j, sc) in scale.iter_mut().enumerate() {
        *sc = a.column(j).norm();
        if *sc == 0.0 {
            return Err(FitError::RankDeficient);
        }
        a.column_mut(j).unscale_mut(*sc);
    }
    let b = DVector::from_column_slice(target);
    let svd = a
        .try_svd(true, true, f64::EPSILON, 10_000)
        .ok_or(FitError::RankDeficient)?;
    let smax = svd.singular_values.max();
    if svd.singular_values.min() < 1e-12 * smax {
        return Err(FitError::RankDeficient);
    }
    let th = svd.solve(&b, 0.0).map_err(|_| FitError::RankDeficient)?;
    Ok(FeedforwardGains {
        snap: th[0] / scale[0],
        jerk: th[1] / scale[1],
        acc: th[2] / scale[2],
        vel: th[3] / scale[3],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::closed_loop::{LoopSpec, assemble_loop};
    use crate::discretise::zoh;
    use crate::lti::{DiscreteStateSpace, LtiRunner};
    use crate::models::{TS_10KHZ, thesis_plant};
    use crate::pid::thesis_pid;
    use crate::setpoint::{Setpoint, SetpointParams};

    /// Runs the closed loop (inputs [r, n, u_ff, w]) and returns (e_true, y).
    fn run(
        cl: &DiscreteStateSpace,
        steps: usize,
        input: impl Fn(usize) -> [f64; 4],
    ) -> (Vec<f64>, Vec<f64>) {
        let mut r = LtiRunner::new(cl.clone());
        let mut e = Vec::with_capacity(steps);
        let mut y = Vec::with_capacity(steps);
        for k in 0..steps {
            let out = r.step(&input(k));
            y.push(out[1]);
            e.push(out[2]);
        }
        (e, y)
    }

    #[test]
    fn fit_recovers_mass_and_reference_scan_rms() {
        // Baseline loop: chain y5, ZOH 10 kHz, PID f_bw 35.5, 1 sample delay;
        // the feedforward is advanced by that sample (§10.1).
        let plant = zoh(&thesis_plant(5).unwrap().state_space(), TS_10KHZ).unwrap();
        let pid = thesis_pid(35.5, TS_10KHZ).unwrap();
        let cl = assemble_loop(&LoopSpec {
            plant: &plant,
            observer: None,
            controller: &pid,
            loop_delay: 1,
        })
        .unwrap();
        let sp = Setpoint::new(&SetpointParams::thesis()).unwrap();
        // Tick 0 is t = −Ts, so that the feedforward for t = 0 is issued one
        // tick before the motion starts.
        let steps = (sp.duration() / TS_10KHZ).round() as usize + 2;
        let t = |k: usize| (k as f64 - 1.0) * TS_10KHZ;
        let (e0, _) = run(&cl, steps, |k| [sp.evaluate(t(k)).r, 0.0, 0.0, 0.0]);
        let mut resp: Vec<Vec<f64>> = Vec::new();
        for i in 0..4 {
            let (_, y) = run(&cl, steps, |k| {
                let reg = FeedforwardGains::regressor(&sp.evaluate(t(k + 1)));
                [0.0, 0.0, reg[i], 0.0]
            });
            resp.push(y);
        }
        let rows: Vec<[f64; 4]> = (0..steps)
            .map(|k| [resp[0][k], resp[1][k], resp[2][k], resp[3][k]])
            .collect();
        let g = fit_gains(&rows, &e0).unwrap();
        // Reference fit: Θ_acc = 12.49996 (= m to 5 digits).
        assert!((g.acc - 12.49996).abs() < 2e-5, "{g:?}");
        // Scan rms of e_true with the fitted gains (§10.1 bold column: 8.46 nm).
        let (e, _) = run(&cl, steps, |k| {
            [
                sp.evaluate(t(k)).r,
                0.0,
                g.apply(&sp.evaluate(t(k + 1))),
                0.0,
            ]
        });
        let (a, b) = sp.scan_window();
        let win: Vec<f64> = (0..steps)
            .filter(|&k| t(k) >= a - 1e-12 && t(k) <= b + 1e-12)
            .map(|k| e[k])
            .collect();
        let rms = (win.iter().map(|v| v * v).sum::<f64>() / win.len() as f64).sqrt();
        assert!((rms * 1e9 - 8.46).abs() < 0.05, "rms {} nm", rms * 1e9);
    }

    #[test]
    fn fit_errors() {
        assert!(matches!(
            fit_gains(&[[1.0; 4]; 3], &[1.0; 3]),
            Err(FitError::BadLength { .. })
        ));
        assert_eq!(
            fit_gains(&[[1.0, 0.0, 1.0, 1.0]; 5], &[1.0; 5]),
            Err(FitError::RankDeficient)
        );
        assert_eq!(
            fit_gains(&[[1.0, f64::NAN, 1.0, 1.0]; 5], &[1.0; 5]),
            Err(FitError::NonFinite)
        );
    }
}
