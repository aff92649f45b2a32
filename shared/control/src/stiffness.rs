//! Active-stiffness gains on estimated modal positions (docs/control.md §5.2,
//! Table 3.1 case c; thesis (3.42)–(3.43)).
//!
//! Feeding back u_s = K_s η̂ (ADDED to the plant input, as u_d in
//! [`crate::damping`]) changes mode i to η̈ = (−ω² + φ_aᵀ K_s) η − 2ζω η̇ + …,
//! so ω_new² = ω² − φ_aᵀ K_s (3.42). For a frequency ratio ρ = ω_new/ω:
//! K_s,i = −(φ_a,iᵀ)† ω_i² (ρ_i² − 1); ρ = 1.5 gives the thesis' −1.25 ω²/φ_aᵀ
//! (3.43). The velocity term is untouched, so the relative damping falls to
//! ζ/ρ: one reason the thesis does not recommend active stiffness (high gain,
//! less damping, observability); it can still move a mode onto a zero of the
//! MA sinc (Remark 3.3.3). Only increases are allowed (Remark 3.3.1).
//!
//! Gains on the targeted modes change only those modes' columns of A + B K,
//! so the closed loop is block-triangular: untargeted modes keep frequency
//! and damping, on the reduced and on the full model alike, and the targeted
//! modes are the eigenvalues of their own block. For ONE targeted mode the
//! per-mode formula is then exact. For several, the per-mode gains couple
//! through B (on the thesis chain, +20 % on modes 1–3 gives +9.8 %, +11.0 %
//! and +24.9 %); [`StiffnessMethod::Placed`] solves the coupled problem
//! instead: with one actuator, the targeted undamped stiffness
//! Ω_T² − φ_T kᵀ has the requested eigenvalues when
//! k_i φ_i = Π_j (ω_i² − t_j) / Π_{l≠i} (ω_i² − ω_l²) (residues of the
//! characteristic polynomial), which is exact without damping and off by
//! O(ζ²) with it.

use crate::design_error::DesignError;
use crate::linalg::pinv;
use crate::lti::DiscreteStateSpace;
use crate::matrix_error::MatrixError;
use crate::modal::ModalModel;
use nalgebra::{DMatrix, DVector};

/// How the per-mode position gains are chosen (as for damping, §5.2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StiffnessMethod {
    /// Each mode on its own: K_s,i = −(φ_a,iᵀ)† ω_i² (ρ_i² − 1).
    Automated,
    /// Minimum-norm K with Φ_at K = −diag(ω_i² (ρ_i² − 1)) over ALL retained
    /// modes (rigid ones with 0): limits interaction when there are several
    /// actuators.
    MinimalInteraction,
    /// Single actuator: the targeted frequencies are assigned jointly on the
    /// undamped modal stiffness (module doc), so coupling is accounted for.
    Placed,
}

/// An active-stiffness design on a modal model.
#[derive(Debug, Clone, PartialEq)]
pub struct ActiveStiffness {
    /// Position gains, one column per mode (n_u × n_modes); zero for rigid
    /// and untouched modes.
    pub gains: DMatrix<f64>,
    /// Mode frequencies [rad/s] of the design model.
    pub omega: Vec<f64>,
}

/// Joint assignment of the targeted undamped frequencies with one actuator
/// (module doc): k_i = r_i / φ_i with r_i the residues of
/// Π_j (λ − t_j) / Π_i (λ − ω_i²) over the targeted set.
fn placed_gains(model: &ModalModel, ratio: &[f64]) -> Result<DMatrix<f64>, DesignError> {
    let nr = model.n_rigid;
    if model.inputs() != 1 {
        return Err(DesignError::InvalidParameter(format!(
            "the placed stiffness design needs one actuator, the model has {}; \
             use MinimalInteraction, which decouples with enough actuators",
            model.inputs()
        )));
    }
    let targeted: Vec<usize> = (0..ratio.len())
        .filter(|&i| ratio[i] != 1.0)
        .map(|i| nr + i)
        .collect();
    let d: Vec<f64> = targeted.iter().map(|&i| model.omega[i].powi(2)).collect();
    let t: Vec<f64> = targeted
        .iter()
        .map(|&i| (model.omega[i] * ratio[i - nr]).powi(2))
        .collect();
    let mut k = DMatrix::zeros(1, model.modes());
    for (a, &i) in targeted.iter().enumerate() {
        let phi = model.phi_a[(i, 0)];
        if phi.abs() <= 1e-12 * model.phi_a.amax() {
            return Err(DesignError::InvalidParameter(format!(
                "mode {i} is not controllable from the actuator"
            )));
        }
        let mut r = t.iter().map(|tj| d[a] - tj).product::<f64>();
        for (b, db) in d.iter().enumerate() {
            if b != a {
                let gap = d[a] - db;
                if gap.abs() <= 1e-12 * d[a] {
                    return Err(DesignError::InvalidParameter(format!(
                        "modes {i} and {} have the same frequency; one actuator cannot \
                         set them apart",
                        targeted[b]
                    )));
                }
                r /= gap;
            }
        }
        k[(0, i)] = r / phi;
    }
    Ok(k)
}

impl ActiveStiffness {
    /// Gains raising the frequency of each flexible mode i of `model` by the
    /// factor `ratio[i − n_rigid]` (1 leaves a mode alone; 1.5 is +50 %).
    pub fn design(
        model: &ModalModel,
        ratio: &[f64],
        method: StiffnessMethod,
    ) -> Result<Self, DesignError> {
        let n = model.modes();
        let nr = model.n_rigid;
        if ratio.len() != n - nr {
            return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                what: "frequency ratio per flexible mode",
                expected: (n - nr, 1),
                found: (ratio.len(), 1),
            }));
        }
        if let Some(r) = ratio.iter().find(|r| !r.is_finite()) {
            return Err(DesignError::Matrix(MatrixError::NonFinite(if r.is_nan() {
                "frequency ratio (NaN)"
            } else {
                "frequency ratio (infinite)"
            })));
        }
        if let Some(r) = ratio.iter().find(|r| **r < 1.0) {
            return Err(DesignError::InvalidParameter(format!(
                "frequency ratio {r} < 1: only stiffness increases are allowed (Remark 3.3.1)"
            )));
        }
        let nu = model.inputs();
        let mut target = vec![0.0; n];
        for (i, r) in ratio.iter().enumerate() {
            let w = model.omega[nr + i];
            target[nr + i] = w * w * (r * r - 1.0);
        }
        let gains = match method {
            StiffnessMethod::Automated => {
                let mut k = DMatrix::zeros(nu, n);
                for (i, &t) in target.iter().enumerate().skip(nr) {
                    if t == 0.0 {
                        continue;
                    }
                    let row = model.phi_a.rows(i, 1).into_owned();
                    if row.amax() == 0.0 {
                        return Err(DesignError::InvalidParameter(format!(
                            "mode {i} is not controllable from the actuators"
                        )));
                    }
                    let col = pinv(&row)? * (-t);
                    k.column_mut(i).copy_from(&col.column(0));
                }
                k
            }
            StiffnessMethod::MinimalInteraction => {
                -pinv(&model.phi_a)? * DMatrix::from_diagonal(&DVector::from_vec(target))
            }
            StiffnessMethod::Placed => placed_gains(model, ratio)?,
        };
        Ok(Self {
            gains,
            omega: model.omega.clone(),
        })
    }

    /// Static gain on the type-1 state x = col(η, η̇) (n_u × 2 n_modes):
    /// position columns only.
    pub fn state_gain(&self) -> DMatrix<f64> {
        let (nu, n) = self.gains.shape();
        let mut k = DMatrix::zeros(nu, 2 * n);
        for i in 0..n {
            k.column_mut(2 * i).copy_from(&self.gains.column(i));
        }
        k
    }

    /// (3.42) per mode of `model`, ignoring coupling between modes:
    /// ω_new,i = √(ω_i² − φ_a,iᵀ K_s,i) [rad/s].
    pub fn predicted_frequencies(&self, model: &ModalModel) -> Result<Vec<f64>, DesignError> {
        if model.modes() != self.gains.ncols() || model.inputs() != self.gains.nrows() {
            return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                what: "model for the stiffness gains (inputs x modes)",
                expected: self.gains.shape(),
                found: (model.inputs(), model.modes()),
            }));
        }
        Ok((0..model.modes())
            .map(|i| {
                let pk = (model.phi_a.row(i) * self.gains.column(i))[(0, 0)];
                (model.omega[i] * model.omega[i] - pk).max(0.0).sqrt()
            })
            .collect())
    }

    /// Discrete static map from the observer state (n_obs ≥ 2 n_modes; extra
    /// states get zero gain) to u_s, usable as the K(z) of an observer block.
    /// No band-pass: the +2 low-frequency slope needs a 4th-order one
    /// (Remark 4.3.5), which is not provided here.
    pub fn to_discrete(&self, n_obs: usize, ts: f64) -> Result<DiscreteStateSpace, DesignError> {
        let (nu, n) = self.gains.shape();
        if n_obs < 2 * n {
            return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                what: "observer states for the stiffness gain",
                expected: (2 * n, 1),
                found: (n_obs, 1),
            }));
        }
        let mut k = DMatrix::zeros(nu, n_obs);
        k.view_mut((0, 0), (nu, 2 * n))
            .copy_from(&self.state_gain());
        Ok(DiscreteStateSpace::gain(k, ts)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::eigenvalues;
    use crate::models::{thesis_plant, thesis_reduced};

    /// Closed-loop (frequency [rad/s], damping) of A + B K nearest to each
    /// wanted frequency.
    fn nearest(a: &DMatrix<f64>, wanted: &[f64]) -> Vec<(f64, f64)> {
        let ev = eigenvalues(a).unwrap();
        wanted
            .iter()
            .map(|w| {
                let p = ev
                    .iter()
                    .filter(|s| s.im > 0.0)
                    .min_by(|x, y| (x.norm() - w).abs().total_cmp(&(y.norm() - w).abs()))
                    .unwrap();
                (p.norm(), -p.re / p.norm())
            })
            .collect()
    }

    #[test]
    fn plus_50_percent_on_mode_1_is_exact_on_the_thesis_chain() {
        // Design on the observer model (rigid + 3 flexible), apply to the full
        // 8-mode chain at y5 with the gain on the (ideally estimated) retained
        // modal positions; the continuous closed loop A + B K.
        let red = thesis_reduced(5).unwrap().modal;
        let st =
            ActiveStiffness::design(&red, &[1.5, 1.0, 1.0], StiffnessMethod::Automated).unwrap();
        // (3.43): K_s1 = −1.25 ω1²/φ_a1.
        let w1 = red.omega[1];
        let k1 = -1.25 * w1 * w1 / red.phi_a[(1, 0)];
        assert!((st.gains[(0, 1)] - k1).abs() < 1e-9 * k1.abs());
        assert_eq!(st.gains[(0, 0)], 0.0);
        let full = thesis_plant(5).unwrap();
        let ss = full.state_space();
        let mut k = DMatrix::zeros(1, 16);
        k.view_mut((0, 0), (1, 8)).copy_from(&st.state_gain());
        let a = &ss.a + &ss.b * &k;
        let got = nearest(&a, &[1.5 * w1]);
        let (w_new, zeta_new) = got[0];
        // 470.06 Hz → 705.09 Hz, ζ 0.005 → 0.005/1.5.
        assert!((w_new / w1 - 1.5).abs() < 1e-9, "ratio {}", w_new / w1);
        assert!((zeta_new - 0.005 / 1.5).abs() < 1e-9, "ζ {zeta_new}");
        // Every other mode keeps its frequency and damping.
        let others: Vec<f64> = full.omega[2..].to_vec();
        for ((w, z), w0) in nearest(&a, &others).iter().zip(&others) {
            assert!((w / w0 - 1.0).abs() < 1e-9 && (z - 0.005).abs() < 1e-9);
        }
        let pred = st.predicted_frequencies(&red).unwrap();
        assert!((pred[1] / w1 - 1.5).abs() < 1e-12);
    }

    #[test]
    fn several_modes_at_once_per_mode_couples_placed_does_not() {
        // +20 % on the three retained flexible modes of the thesis chain (y5).
        let red = thesis_reduced(5).unwrap().modal;
        let ss = red.state_space();
        let targets: Vec<f64> = red.omega[1..].iter().map(|w| 1.2 * w).collect();
        let achieved = |method| {
            let st = ActiveStiffness::design(&red, &[1.2; 3], method).unwrap();
            let a = &ss.a + &ss.b * st.state_gain();
            nearest(&a, &targets)
        };
        // Per-mode gains (3.31-style) couple: +9.8 %, +11.0 %, +24.9 %.
        let auto = achieved(StiffnessMethod::Automated);
        let ratios: Vec<f64> = auto
            .iter()
            .zip(&red.omega[1..])
            .map(|(g, w)| g.0 / w)
            .collect();
        for (r, want) in ratios.iter().zip([1.098, 1.110, 1.249]) {
            assert!((r - want).abs() < 0.002, "{ratios:?}");
        }
        // The joint design reaches every target; with ζ = 0.005 the error is
        // O(ζ²) (measured: 0.6, 1.1 and −1.7 ppm).
        let placed = achieved(StiffnessMethod::Placed);
        for ((w, zeta), t) in placed.iter().zip(&targets) {
            eprintln!(
                "placed: achieved/target − 1 = {:.2e}, ζ {zeta:.5}",
                w / t - 1.0
            );
            assert!((w / t - 1.0).abs() < 1e-5, "{w} vs {t}");
            assert!(*zeta > 0.0);
        }
        // And it keeps the unretained modes of the full chain where they were.
        let full = thesis_plant(5).unwrap();
        let st = ActiveStiffness::design(&red, &[1.2; 3], StiffnessMethod::Placed).unwrap();
        let fs = full.state_space();
        let mut k = DMatrix::zeros(1, 16);
        k.view_mut((0, 0), (1, 8)).copy_from(&st.state_gain());
        let a = &fs.a + &fs.b * &k;
        let rest: Vec<f64> = full.omega[4..].to_vec();
        for ((w, _), w0) in nearest(&a, &rest).iter().zip(&rest) {
            assert!((w / w0 - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn refuses_decreases_and_bad_sizes() {
        let red = thesis_reduced(5).unwrap().modal;
        assert!(matches!(
            ActiveStiffness::design(&red, &[0.9, 1.0, 1.0], StiffnessMethod::Automated),
            Err(DesignError::InvalidParameter(s)) if s.contains("only stiffness increases")
        ));
        assert!(matches!(
            ActiveStiffness::design(&red, &[1.5, 1.0], StiffnessMethod::Automated),
            Err(DesignError::Matrix(MatrixError::DimensionMismatch { .. }))
        ));
        assert!(matches!(
            ActiveStiffness::design(&red, &[f64::NAN, 1.0, 1.0], StiffnessMethod::Automated),
            Err(DesignError::Matrix(MatrixError::NonFinite(_)))
        ));
        let st =
            ActiveStiffness::design(&red, &[1.5, 1.0, 1.0], StiffnessMethod::MinimalInteraction)
                .unwrap();
        let mimo = crate::models::mimo_example().unwrap();
        assert!(matches!(
            ActiveStiffness::design(&mimo, &[1.1; 3], StiffnessMethod::Placed),
            Err(DesignError::InvalidParameter(s)) if s.contains("one actuator")
        ));
        assert!(st.to_discrete(7, 1e-4).is_err());
        let k = st.to_discrete(9, 1e-4).unwrap();
        assert_eq!((k.inputs(), k.outputs(), k.states()), (9, 1, 0));
    }
}
