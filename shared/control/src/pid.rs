//! The thesis feedback controller (docs/control.md §6): PID with a second-order
//! low-pass, the Table 3.3 single-parameter tuning, optional notches, and
//! its Tustin discretisation into a [`DiscreteStateSpace`] (input e, output
//! u_fb).
//!
//! C_fb(s) = K_p (s + ω_i)/s · (s/ω_d + 1) · ω_lp² / (s² + 2 z_lp ω_lp s + ω_lp²)
//!           · Π N(s, ω_n),  N(s, ω) = (s² + 0.002 ω s + ω²)/(s² + 0.2 ω s + ω²).

use crate::continuous::ContinuousStateSpace;
use crate::design_error::DesignError;
use crate::discretise::tustin;
use crate::lti::DiscreteStateSpace;
use nalgebra::DMatrix;
use std::f64::consts::PI;

/// PID + low-pass parameters (angular frequencies in rad/s).
#[derive(Debug, Clone, PartialEq)]
pub struct PidTuning {
    pub kp: f64,
    pub wi: f64,
    pub wd: f64,
    pub wlp: f64,
    pub zlp: f64,
    /// Notch frequencies [rad/s] (empty: no notches).
    pub notches: Vec<f64>,
}

impl PidTuning {
    /// Table 3.3: K_p = m ω_bw²/3, ω_i = ω_bw/9, ω_d = ω_bw/3, ω_lp = 3 ω_bw,
    /// z_lp = 0.7, with ω_bw = 2π f_bw. The resulting 0 dB crossover on
    /// 1/(m s²) is 1.0498 f_bw.
    pub fn single_parameter(mass: f64, f_bw: f64) -> Result<Self, DesignError> {
        if !(mass.is_finite() && mass > 0.0 && f_bw.is_finite() && f_bw > 0.0) {
            return Err(DesignError::InvalidParameter(format!(
                "mass {mass} kg and f_bw {f_bw} Hz must be positive"
            )));
        }
        let w = 2.0 * PI * f_bw;
        Ok(Self {
            kp: mass * w * w / 3.0,
            wi: w / 9.0,
            wd: w / 3.0,
            wlp: 3.0 * w,
            zlp: 0.7,
            notches: Vec::new(),
        })
    }

    /// Adds notches N(s, ω) at the given continuous frequencies [rad/s]. For
    /// a discrete notch exactly at ω, give [`crate::freq::prewarped_notch`]
    /// of it: what the running controller (flexloop-design's `feedback`)
    /// and the bandwidth searches do.
    pub fn with_notches(mut self, notches: &[f64]) -> Self {
        self.notches = notches.to_vec();
        self
    }

    fn check(&self) -> Result<(), DesignError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        let all_ok = ok(self.kp)
            && ok(self.wi)
            && ok(self.wd)
            && ok(self.wlp)
            && ok(self.zlp)
            && self.notches.iter().all(|w| ok(*w));
        if !all_ok {
            return Err(DesignError::InvalidParameter(format!(
                "PID parameters must be positive and finite: {self:?}"
            )));
        }
        Ok(())
    }

    /// Continuous controller as a series of low-order sections (keeps the
    /// realisation well conditioned with notches at kHz).
    pub fn continuous(&self) -> Result<ContinuousStateSpace, DesignError> {
        self.check()?;
        let pi = ContinuousStateSpace::from_transfer_function(
            &[self.kp, self.kp * self.wi],
            &[1.0, 0.0],
        )?;
        let w2 = self.wlp * self.wlp;
        let lead_lp = ContinuousStateSpace::from_transfer_function(
            &[w2 / self.wd, w2],
            &[1.0, 2.0 * self.zlp * self.wlp, w2],
        )?;
        let mut c = pi.series(&lead_lp)?;
        for &w in &self.notches {
            let n = ContinuousStateSpace::from_transfer_function(
                &[1.0, 0.002 * w, w * w],
                &[1.0, 0.2 * w, w * w],
            )?;
            c = c.series(&n)?;
        }
        Ok(c)
    }

    /// Tustin discretisation (no pre-warping, as in docs/control.md §10.1).
    pub fn discrete(&self, ts: f64) -> Result<DiscreteStateSpace, DesignError> {
        Ok(tustin(&self.continuous()?, ts, None)?)
    }
}

/// Convenience: the thesis PID for the 12.5 kg chain at `f_bw`, discretised.
pub fn thesis_pid(f_bw: f64, ts: f64) -> Result<DiscreteStateSpace, DesignError> {
    PidTuning::single_parameter(crate::models::CHAIN_MASS, f_bw)?.discrete(ts)
}

/// A static error-to-force gain (no controller), e.g. for open-loop tests.
pub fn zero_controller(ts: f64) -> Result<DiscreteStateSpace, DesignError> {
    Ok(DiscreteStateSpace::gain(DMatrix::zeros(1, 1), ts)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::freq::{freq_response_continuous, freq_response_discrete};

    #[test]
    fn table_3_3_tuning_and_crossover() {
        let t = PidTuning::single_parameter(12.5, 35.5).unwrap();
        let w = 2.0 * PI * 35.5;
        assert!((t.kp - 12.5 * w * w / 3.0).abs() < 1e-9);
        assert!((t.wi - w / 9.0).abs() < 1e-12 && (t.wlp - 3.0 * w).abs() < 1e-12);
        let c = t.continuous().unwrap();
        // |L(jω_bw)| = 1.056 on 1/(m s²).
        let l = freq_response_continuous(&c, w).unwrap()[(0, 0)] / (12.5 * w * w);
        assert!((l.norm() - 1.056).abs() < 0.001, "{}", l.norm());
        // Crossover at 1.0498 f_bw: |L| = 1 there.
        let wc = w * 1.0498;
        let lc = freq_response_continuous(&c, wc).unwrap()[(0, 0)] / (12.5 * wc * wc);
        assert!((lc.norm() - 1.0).abs() < 0.001, "{}", lc.norm());
        // Tustin keeps the low-frequency response.
        let d = t.discrete(1e-4).unwrap();
        let hd = freq_response_discrete(&d, w).unwrap()[(0, 0)];
        let hc = freq_response_continuous(&c, w).unwrap()[(0, 0)];
        assert!((hd - hc).norm() < 2e-3 * hc.norm());
        assert!(PidTuning::single_parameter(0.0, 35.5).is_err());
        // Notch: deep at its frequency.
        let wn = 2.0 * PI * 470.06;
        let tn = t.clone().with_notches(&[wn]);
        let cn = tn.continuous().unwrap();
        let ratio = freq_response_continuous(&cn, wn).unwrap()[(0, 0)].norm()
            / freq_response_continuous(&c, wn).unwrap()[(0, 0)].norm();
        assert!((ratio - 0.01).abs() < 1e-6);
    }
}
