//! Active-damping gain design on estimated modal velocities (docs/control.md
//! §5.2): the "automated manual" gains (3.31), the minimal-interaction gains
//! (3.32), and the dynamic gain K(s) with per-mode band-pass filters
//! (3.34)/(4.17), compiled to a discrete map x̂ → u_d.
//!
//! Sign convention: u_d is ADDED to the plant input, so a damping gain is
//! negative: 2ζ*ω = 2ζω − φ_aᵀ K_d, K_d = −(φ_aᵀ)† 2 Δζ ω. Δζ is the
//! INCREASE of damping (0.035 to go from 0.005 to 0.04).

use crate::continuous::ContinuousStateSpace;
use crate::design_error::DesignError;
use crate::discretise::tustin;
use crate::linalg::{block_diag, pinv};
use crate::lti::DiscreteStateSpace;
use crate::matrix_error::MatrixError;
use crate::modal::ModalModel;
use nalgebra::DMatrix;

/// How the per-mode velocity gains are chosen.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DampingMethod {
    /// (3.31): each mode on its own, K_di = −(φ_aiᵀ)† 2 Δζ_i ω_i.
    Automated,
    /// (3.32): minimum-norm K with Φ_at K = −diag(Z_des) over ALL retained
    /// modes (rigid ones with Z_des = 0), which limits interaction.
    MinimalInteraction,
}

/// An active-damping design on a modal model.
#[derive(Debug, Clone, PartialEq)]
pub struct ActiveDamping {
    /// Velocity gains, one column per mode of the model (n_u × n_modes);
    /// zero for rigid and undamped modes.
    pub gains: DMatrix<f64>,
    /// Mode frequencies [rad/s] (for the band-pass filters).
    pub omega: Vec<f64>,
    /// Band-pass quality factor (thesis: 2), or None for static gains.
    pub bandpass_q: Option<f64>,
}

impl ActiveDamping {
    /// Designs velocity gains raising the damping of each flexible mode i of
    /// `model` by `increase[i − n_rigid]` (use 0 to leave a mode alone).
    pub fn design(
        model: &ModalModel,
        increase: &[f64],
        method: DampingMethod,
        bandpass_q: Option<f64>,
    ) -> Result<Self, DesignError> {
        let n = model.modes();
        let nr = model.n_rigid;
        if increase.len() != n - nr {
            return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                what: "damping increase per flexible mode",
                expected: (n - nr, 1),
                found: (increase.len(), 1),
            }));
        }
        if increase.iter().any(|z| !z.is_finite() || *z < 0.0) {
            return Err(DesignError::InvalidParameter(
                "damping increase must be finite and ≥ 0 (only increases, Remark 3.3.1)".into(),
            ));
        }
        if let Some(q) = bandpass_q
            && !(q.is_finite() && q > 0.0)
        {
            return Err(DesignError::InvalidParameter(format!("band-pass Q {q}")));
        }
        let nu = model.inputs();
        let mut z_des = vec![0.0; n];
        for (i, dz) in increase.iter().enumerate() {
            z_des[nr + i] = 2.0 * dz * model.omega[nr + i];
        }
        let gains = match method {
            DampingMethod::Automated => {
                let mut k = DMatrix::zeros(nu, n);
                for (i, &zd) in z_des.iter().enumerate().skip(nr) {
                    if zd == 0.0 {
                        continue;
                    }
                    let row = model.phi_a.rows(i, 1).into_owned();
                    if row.amax() == 0.0 {
                        return Err(DesignError::InvalidParameter(format!(
                            "mode {i} is not controllable from the actuators"
                        )));
                    }
                    let col = pinv(&row)? * (-zd);
                    k.column_mut(i).copy_from(&col.column(0));
                }
                k
            }
            DampingMethod::MinimalInteraction => {
                let zd = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(z_des));
                -pinv(&model.phi_a)? * zd
            }
        };
        Ok(Self {
            gains,
            omega: model.omega.clone(),
            bandpass_q,
        })
    }

    /// Static gain matrix on the type-1 state x = col(η, η̇) (n_u × 2 n_modes).
    pub fn state_gain(&self) -> DMatrix<f64> {
        let (nu, n) = self.gains.shape();
        let mut k = DMatrix::zeros(nu, 2 * n);
        for i in 0..n {
            k.column_mut(2 * i + 1).copy_from(&self.gains.column(i));
        }
        k
    }

    fn damped_modes(&self) -> Vec<usize> {
        (0..self.gains.ncols())
            .filter(|&i| self.gains.column(i).amax() > 0.0 && self.omega[i] > 0.0)
            .collect()
    }

    fn check_observer_states(&self, n_obs: usize) -> Result<(), DesignError> {
        let n = self.gains.ncols();
        if n_obs < 2 * n {
            return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                what: "observer states for the damping gain",
                expected: (2 * n, 1),
                found: (n_obs, 1),
            }));
        }
        Ok(())
    }

    /// The static gain padded to the observer state (n_u × n_obs).
    fn padded_gain(&self, n_obs: usize) -> DMatrix<f64> {
        let (nu, n) = self.gains.shape();
        let mut kfull = DMatrix::zeros(nu, n_obs);
        kfull
            .view_mut((0, 0), (nu, 2 * n))
            .copy_from(&self.state_gain());
        kfull
    }

    /// The continuous band-pass of each damped mode.
    fn bandpass_filters(&self, q: f64) -> Result<Vec<(usize, ContinuousStateSpace)>, DesignError> {
        self.damped_modes()
            .into_iter()
            .map(|i| {
                let w = self.omega[i];
                let bp = ContinuousStateSpace::from_transfer_function(
                    &[w / q, 0.0],
                    &[1.0, w / q, w * w],
                )?;
                Ok((i, bp))
            })
            .collect()
    }

    /// Stacks per-mode SISO filters (a, b, c, d) on η̇̂_i into one map
    /// x̂ (n_obs) → u_d.
    fn stack_filters(&self, n_obs: usize, filters: &[(usize, [&DMatrix<f64>; 4])]) -> Abcd {
        let nu = self.gains.nrows();
        let a_refs: Vec<&DMatrix<f64>> = filters.iter().map(|(_, f)| f[0]).collect();
        let a = block_diag(&a_refs);
        let nf = a.nrows();
        let mut b = DMatrix::zeros(nf, n_obs);
        let mut c = DMatrix::zeros(nu, nf);
        let mut d = DMatrix::zeros(nu, n_obs);
        let mut off = 0;
        for (i, [fa, fb, fc, fd]) in filters {
            let ns = fa.nrows();
            let vel = 2 * i + 1;
            b.view_mut((off, vel), (ns, 1)).copy_from(*fb);
            let kcol = self.gains.column(*i);
            c.view_mut((0, off), (nu, ns)).copy_from(&(kcol * *fc));
            let dcol = kcol * fd[(0, 0)];
            let mut dv = d.column_mut(vel);
            dv += dcol;
            off += ns;
        }
        (a, b, c, d)
    }

    /// Discrete map from the observer state (n_obs ≥ 2 n_modes; extra states
    /// such as noise-model states get zero gain) to u_d. Static gains, or per
    /// damped mode the band-pass (ω/Q)s/(s² + (ω/Q)s + ω²) on η̇̂_i, Tustin
    /// pre-warped at ω_i so it has unit gain and zero phase there.
    pub fn to_discrete(&self, n_obs: usize, ts: f64) -> Result<DiscreteStateSpace, DesignError> {
        self.check_observer_states(n_obs)?;
        let Some(q) = self.bandpass_q else {
            return Ok(DiscreteStateSpace::gain(self.padded_gain(n_obs), ts)?);
        };
        let mut filters = Vec::new();
        for (i, bp) in self.bandpass_filters(q)? {
            filters.push((i, tustin(&bp, ts, Some(self.omega[i]))?));
        }
        let refs: Vec<(usize, [&DMatrix<f64>; 4])> = filters
            .iter()
            .map(|(i, f)| (*i, [&f.a, &f.b, &f.c, &f.d]))
            .collect();
        let (a, b, c, d) = self.stack_filters(n_obs, &refs);
        Ok(DiscreteStateSpace::new(a, b, c, d, ts)?)
    }

    /// Continuous map from the observer state (n_obs ≥ 2 n_modes) to u_d:
    /// the static gains, or K_i H_BP,i(s) on η̇̂_i per damped mode (3.34),
    /// for the continuous design checks of docs/control.md §9.
    pub fn to_continuous(&self, n_obs: usize) -> Result<ContinuousStateSpace, DesignError> {
        self.check_observer_states(n_obs)?;
        let Some(q) = self.bandpass_q else {
            return Ok(ContinuousStateSpace::gain(self.padded_gain(n_obs)));
        };
        let filters = self.bandpass_filters(q)?;
        let refs: Vec<(usize, [&DMatrix<f64>; 4])> = filters
            .iter()
            .map(|(i, f)| (*i, [&f.a, &f.b, &f.c, &f.d]))
            .collect();
        let (a, b, c, d) = self.stack_filters(n_obs, &refs);
        Ok(ContinuousStateSpace::new(a, b, c, d)?)
    }
}

type Abcd = (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>, DMatrix<f64>);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::eigenvalues;
    use crate::models::thesis_reduced;

    /// Damping of the closed-loop modes of A_t + B_t K near each flexible ω.
    fn achieved(model: &ModalModel, ad: &ActiveDamping) -> Vec<f64> {
        let ss = model.state_space();
        let a = &ss.a + &ss.b * ad.state_gain();
        let ev = eigenvalues(&a).unwrap();
        (model.n_rigid..model.modes())
            .map(|i| {
                let p = ev
                    .iter()
                    .filter(|s| s.im > 0.0)
                    .min_by(|x, y| {
                        (x.norm() - model.omega[i])
                            .abs()
                            .total_cmp(&(y.norm() - model.omega[i]).abs())
                    })
                    .unwrap();
                -p.re / p.norm()
            })
            .collect()
    }

    #[test]
    fn table_3_4() {
        let m = thesis_reduced(5).unwrap().modal;
        let inc = [0.035; 3];
        let auto = ActiveDamping::design(&m, &inc, DampingMethod::Automated, None).unwrap();
        let z = achieved(&m, &auto);
        // Coupled eigenvalues 0.0400 / 0.0403 / 0.0399.
        for (g, w) in z.iter().zip([0.0400, 0.0403, 0.0399]) {
            assert!((g - w).abs() < 0.0002, "(3.31): {z:?}");
        }
        let mi = ActiveDamping::design(&m, &inc, DampingMethod::MinimalInteraction, None).unwrap();
        let z = achieved(&m, &mi);
        for (g, w) in z.iter().zip([0.0184, 0.0136, 0.0100]) {
            assert!((g - w).abs() < 0.00006, "(3.32): {z:?}");
        }
        // Rigid mode gets no gain from (3.31).
        assert_eq!(auto.gains[(0, 0)], 0.0);
        assert!(ActiveDamping::design(&m, &[0.035; 2], DampingMethod::Automated, None).is_err());
        assert!(ActiveDamping::design(&m, &inc, DampingMethod::Automated, Some(-1.0)).is_err());
    }

    #[test]
    fn continuous_gain_matches_the_static_gain_and_the_band_pass() {
        let m = thesis_reduced(5).unwrap().modal;
        let stat = ActiveDamping::design(&m, &[0.035; 3], DampingMethod::Automated, None).unwrap();
        let k = stat.to_continuous(9).unwrap();
        assert_eq!(k.states(), 0);
        assert_eq!(k.d.view((0, 0), (1, 8)), stat.state_gain());
        assert_eq!(k.d[(0, 8)], 0.0);
        let bp =
            ActiveDamping::design(&m, &[0.035; 3], DampingMethod::Automated, Some(2.0)).unwrap();
        let kb = bp.to_continuous(8).unwrap();
        assert_eq!(kb.states(), 6);
        for i in 1..4 {
            let w = m.omega[i];
            let h = crate::freq::freq_response_continuous(&kb, w).unwrap()[(0, 2 * i + 1)];
            let want = bp.gains[(0, i)];
            assert!((h.re - want).abs() < 1e-9 * want.abs() && h.im.abs() < 1e-9 * want.abs());
            // Q = 2: half-power points at ω(√(1 + 1/16) ± 1/4).
            let wl = w * ((1.0f64 + 1.0 / 16.0).sqrt() - 0.25);
            let hl = crate::freq::freq_response_continuous(&kb, wl).unwrap()[(0, 2 * i + 1)];
            assert!(
                (hl.norm() / want.abs() - 0.5f64.sqrt()).abs() < 0.02,
                "{}",
                hl.norm()
            );
        }
        assert!(bp.to_continuous(7).is_err());
    }

    #[test]
    fn bandpass_gain_equals_static_gain_at_the_mode() {
        let m = thesis_reduced(5).unwrap().modal;
        let ad =
            ActiveDamping::design(&m, &[0.035; 3], DampingMethod::Automated, Some(2.0)).unwrap();
        let k = ad.to_discrete(8, 1e-4).unwrap();
        assert_eq!(k.states(), 6);
        for i in 1..4 {
            let h = crate::freq::freq_response_discrete(&k, m.omega[i]).unwrap();
            let want = ad.gains[(0, i)];
            let got = h[(0, 2 * i + 1)];
            assert!((got.re - want).abs() < 1e-9 * want.abs() && got.im.abs() < 1e-9 * want.abs());
        }
    }
}
