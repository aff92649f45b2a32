//! Modal models of flexible structures: from the nodal form (M, K, modal
//! damping, actuator and sensor selection) to the mass-normalised modal form,
//! the continuous "type 1" state space, truncation with compliance (T_DC)
//! compensation, and position-dependent sensor rows (docs/control.md §1.1, §2).
//!
//! Conventions, fixed here so that every model is reproducible:
//! * modes are sorted by frequency, rigid modes (ω = 0) first;
//! * mode shapes are mass-normalised, Φᵀ M Φ = I;
//! * sign: each mode is scaled so that its gain at the first actuator, φ_a,1,
//!   is positive; where that gain is negligible (< 1e-9 of the mode's largest
//!   entry) the node entry of largest magnitude is made positive instead;
//! * state order x = col(η1, η̇1, η2, η̇2, …) (type 1, docs/control.md (2.9)).

use crate::continuous::ContinuousStateSpace;
use crate::linalg::block_diag;
use crate::matrix_error::MatrixError;
use nalgebra::{DMatrix, DVector, SymmetricEigen};
use std::fmt;

/// Why a model could not be built.
#[derive(Debug, Clone, PartialEq)]
pub enum ModelError {
    /// A matrix or parameter does not fit or is not finite.
    Matrix(MatrixError),
    /// The mass matrix is not symmetric positive definite (singular or
    /// indefinite), so the modes are not defined.
    MassNotPositiveDefinite,
    /// M or K is not symmetric.
    NotSymmetric(&'static str),
    /// K has a clearly negative eigenvalue (unstable structure).
    NegativeStiffness(f64),
    /// A modal damping ratio outside [0, 1) or of the wrong count.
    InvalidDamping(String),
    /// A mode index, count or position is out of range.
    OutOfRange(String),
    /// The symmetric eigen-solver did not converge.
    EigenFailed,
    /// Position-dependent outputs need the nodal mode shapes.
    NoModeShapes,
}

impl fmt::Display for ModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Matrix(e) => write!(f, "{e}"),
            Self::MassNotPositiveDefinite => {
                write!(f, "mass matrix is not symmetric positive definite")
            }
            Self::NotSymmetric(what) => write!(f, "{what} is not symmetric"),
            Self::NegativeStiffness(l) => {
                write!(f, "stiffness has a negative modal eigenvalue {l}")
            }
            Self::InvalidDamping(s) => write!(f, "invalid modal damping: {s}"),
            Self::OutOfRange(s) => write!(f, "out of range: {s}"),
            Self::EigenFailed => write!(f, "symmetric eigen-decomposition did not converge"),
            Self::NoModeShapes => write!(f, "model has no nodal mode shapes"),
        }
    }
}

impl std::error::Error for ModelError {}

/// Modal damping of the flexible modes (rigid modes always get ζ = 0).
#[derive(Debug, Clone, PartialEq)]
pub enum ModalDamping {
    /// The same ζ for every flexible mode (the thesis chain: 0.005).
    Uniform(f64),
    /// One ζ per flexible mode, in frequency order.
    PerFlexibleMode(Vec<f64>),
    /// Stiffness-proportional damping D = β K, i.e. ζ_i = β ω_i / 2
    /// (a chain with equal dampers b along equal springs k has β = b/k).
    StiffnessProportional(f64),
    /// Rayleigh damping D = α M + β K, i.e. ζ_i = α/(2ω_i) + β ω_i/2. The
    /// α M term damps rigid-body motion too (a damper to ground), so α must
    /// be 0 on a model with rigid modes.
    Rayleigh { alpha: f64, beta: f64 },
}

/// Nodal form M q̈ + D q̇ + K q = S_a f, y = S_s q (docs/control.md (2.1)).
#[derive(Debug, Clone, PartialEq)]
pub struct NodalModel {
    /// Symmetric positive definite mass matrix (n × n).
    pub mass: DMatrix<f64>,
    /// Symmetric positive semi-definite stiffness matrix (n × n).
    pub stiffness: DMatrix<f64>,
    pub damping: ModalDamping,
    /// S_a: how each actuator force is distributed over the nodes (n × n_act).
    pub actuators: DMatrix<f64>,
    /// S_s: which node combinations are measured (n_sens × n).
    pub sensors: DMatrix<f64>,
}

/// Mass-normalised modal model, modes sorted with rigid modes first.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalModel {
    /// Natural frequencies ω_i [rad/s]; exactly 0 for rigid modes.
    pub omega: Vec<f64>,
    /// Relative damping ζ_i; 0 for rigid modes.
    pub zeta: Vec<f64>,
    /// Row i is φ_a,iᵀ (modal input gains of mode i), n_modes × n_act.
    pub phi_a: DMatrix<f64>,
    /// Column i is φ_s,i (sensor gains of mode i), n_sens × n_modes.
    pub phi_s: DMatrix<f64>,
    /// Nodal mode shapes Φ (n_nodes × n_modes) when built from a nodal model;
    /// used for position-dependent sensor rows.
    pub shapes: Option<DMatrix<f64>>,
    /// Number of rigid modes (the first `n_rigid` entries).
    pub n_rigid: usize,
}

/// Truncated model plus the static compliance of chosen discarded modes.
#[derive(Debug, Clone, PartialEq)]
pub struct ReducedModel {
    /// The retained modes.
    pub modal: ModalModel,
    /// T_DC = Σ φ_s φ_aᵀ / ω² over the compensated discarded modes (n_sens × n_act).
    pub t_dc: DMatrix<f64>,
}

fn check_finite(m: &DMatrix<f64>, what: &'static str) -> Result<(), ModelError> {
    if m.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(ModelError::Matrix(MatrixError::NonFinite(what)))
    }
}

fn check_symmetric(m: &DMatrix<f64>, what: &'static str) -> Result<(), ModelError> {
    let scale = m.amax().max(f64::MIN_POSITIVE);
    if (m - m.transpose()).amax() > 1e-12 * scale {
        return Err(ModelError::NotSymmetric(what));
    }
    Ok(())
}

impl ModalModel {
    /// Builds a modal model directly from modal data (for structures given in
    /// modal form, e.g. invented mode shapes). Modes must be sorted rigid
    /// first, then by non-decreasing frequency.
    pub fn new(
        omega: Vec<f64>,
        zeta: Vec<f64>,
        phi_a: DMatrix<f64>,
        phi_s: DMatrix<f64>,
    ) -> Result<Self, ModelError> {
        let n = omega.len();
        if zeta.len() != n {
            return Err(ModelError::InvalidDamping(format!(
                "{} damping ratios for {n} modes",
                zeta.len()
            )));
        }
        if phi_a.nrows() != n {
            return Err(ModelError::Matrix(MatrixError::DimensionMismatch {
                what: "phi_a",
                expected: (n, phi_a.ncols()),
                found: phi_a.shape(),
            }));
        }
        if phi_s.ncols() != n {
            return Err(ModelError::Matrix(MatrixError::DimensionMismatch {
                what: "phi_s",
                expected: (phi_s.nrows(), n),
                found: phi_s.shape(),
            }));
        }
        check_finite(&phi_a, "phi_a")?;
        check_finite(&phi_s, "phi_s")?;
        if omega.iter().chain(zeta.iter()).any(|v| !v.is_finite()) {
            return Err(ModelError::Matrix(MatrixError::NonFinite("omega/zeta")));
        }
        if omega.iter().any(|w| *w < 0.0) || omega.windows(2).any(|w| w[1] < w[0]) {
            return Err(ModelError::OutOfRange(
                "frequencies must be non-negative and sorted".into(),
            ));
        }
        if zeta.iter().any(|z| !(0.0..1.0).contains(z)) {
            return Err(ModelError::InvalidDamping("ζ must lie in [0, 1)".into()));
        }
        let n_rigid = omega.iter().take_while(|w| **w == 0.0).count();
        Ok(Self {
            omega,
            zeta,
            phi_a,
            phi_s,
            shapes: None,
            n_rigid,
        })
    }

    /// Mass-normalised generalised eigen-decomposition K Φ = M Φ Ω² via the
    /// Cholesky factor of M and the symmetric eigenproblem of L⁻¹ K L⁻ᵀ.
    pub fn from_nodal(nodal: &NodalModel) -> Result<Self, ModelError> {
        let n = nodal.mass.nrows();
        let sq = |m: &DMatrix<f64>, what| {
            if m.shape() != (n, n) {
                Err(ModelError::Matrix(MatrixError::DimensionMismatch {
                    what,
                    expected: (n, n),
                    found: m.shape(),
                }))
            } else {
                Ok(())
            }
        };
        sq(&nodal.mass, "mass")?;
        sq(&nodal.stiffness, "stiffness")?;
        if nodal.actuators.nrows() != n {
            return Err(ModelError::Matrix(MatrixError::DimensionMismatch {
                what: "actuator selection S_a",
                expected: (n, nodal.actuators.ncols()),
                found: nodal.actuators.shape(),
            }));
        }
        if nodal.sensors.ncols() != n {
            return Err(ModelError::Matrix(MatrixError::DimensionMismatch {
                what: "sensor selection S_s",
                expected: (nodal.sensors.nrows(), n),
                found: nodal.sensors.shape(),
            }));
        }
        check_finite(&nodal.mass, "mass")?;
        check_finite(&nodal.stiffness, "stiffness")?;
        check_finite(&nodal.actuators, "S_a")?;
        check_finite(&nodal.sensors, "S_s")?;
        check_symmetric(&nodal.mass, "mass")?;
        check_symmetric(&nodal.stiffness, "stiffness")?;
        if n == 0 {
            return Err(ModelError::OutOfRange("model has no nodes".into()));
        }
        let chol = nodal
            .mass
            .clone()
            .cholesky()
            .ok_or(ModelError::MassNotPositiveDefinite)?;
        let l = chol.l();
        let l_inv = l
            .clone()
            .try_inverse()
            .ok_or(ModelError::MassNotPositiveDefinite)?;
        let kt = &l_inv * &nodal.stiffness * l_inv.transpose();
        let kt = (&kt + kt.transpose()) * 0.5;
        let eig =
            SymmetricEigen::try_new(kt, f64::EPSILON, 1000 * n).ok_or(ModelError::EigenFailed)?;
        let lam_max = eig.eigenvalues.amax();
        let rigid_tol = 1e-9 * lam_max.max(f64::MIN_POSITIVE);
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let phi_all = l_inv.transpose() * &eig.eigenvectors;
        let mut shapes = DMatrix::zeros(n, n);
        let mut omega = Vec::with_capacity(n);
        for (col, &i) in order.iter().enumerate() {
            let lam = eig.eigenvalues[i];
            if lam < -rigid_tol {
                return Err(ModelError::NegativeStiffness(lam));
            }
            omega.push(if lam <= rigid_tol { 0.0 } else { lam.sqrt() });
            let mut v: DVector<f64> = phi_all.column(i).into_owned();
            // Deterministic sign (see module doc).
            let gain = if nodal.actuators.ncols() > 0 {
                (nodal.actuators.column(0).transpose() * &v)[(0, 0)]
            } else {
                0.0
            };
            let vmax = v.amax();
            let sign_ref = if gain.abs() > 1e-9 * vmax {
                gain
            } else {
                let k = v.iamax();
                v[k]
            };
            if sign_ref < 0.0 {
                v = -v;
            }
            shapes.set_column(col, &v);
        }
        let n_rigid = omega.iter().take_while(|w| **w == 0.0).count();
        let n_flex = n - n_rigid;
        let mut zeta = vec![0.0; n];
        match &nodal.damping {
            ModalDamping::Uniform(z) => zeta[n_rigid..].fill(*z),
            ModalDamping::PerFlexibleMode(v) => {
                if v.len() != n_flex {
                    return Err(ModelError::InvalidDamping(format!(
                        "{} ratios for {n_flex} flexible modes",
                        v.len()
                    )));
                }
                zeta[n_rigid..].copy_from_slice(v);
            }
            ModalDamping::StiffnessProportional(beta) => {
                for i in n_rigid..n {
                    zeta[i] = beta * omega[i] / 2.0;
                }
            }
            ModalDamping::Rayleigh { alpha, beta } => {
                if !(alpha.is_finite() && beta.is_finite()) {
                    return Err(ModelError::Matrix(MatrixError::NonFinite(
                        "Rayleigh alpha/beta",
                    )));
                }
                if *alpha != 0.0 && n_rigid > 0 {
                    return Err(ModelError::InvalidDamping(format!(
                        "Rayleigh α = {alpha} damps the {n_rigid} rigid-body mode(s) (α M is a \
                         damper to ground): use α = 0 (β K only) or modal ζ"
                    )));
                }
                for i in n_rigid..n {
                    zeta[i] = alpha / (2.0 * omega[i]) + beta * omega[i] / 2.0;
                }
            }
        }
        let phi_a = shapes.transpose() * &nodal.actuators;
        let phi_s = &nodal.sensors * &shapes;
        let mut m = Self::new(omega, zeta, phi_a, phi_s)?;
        m.shapes = Some(shapes);
        Ok(m)
    }

    pub fn modes(&self) -> usize {
        self.omega.len()
    }
    pub fn inputs(&self) -> usize {
        self.phi_a.ncols()
    }
    pub fn outputs(&self) -> usize {
        self.phi_s.nrows()
    }

    /// Natural frequencies in Hz.
    pub fn frequencies_hz(&self) -> Vec<f64> {
        self.omega
            .iter()
            .map(|w| w / (2.0 * std::f64::consts::PI))
            .collect()
    }

    /// Continuous type-1 state space (position outputs, D = 0), docs/control.md (2.9).
    pub fn state_space(&self) -> ContinuousStateSpace {
        let n = self.modes();
        let blocks: Vec<DMatrix<f64>> = (0..n)
            .map(|i| {
                let w = self.omega[i];
                DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -w * w, -2.0 * self.zeta[i] * w])
            })
            .collect();
        let refs: Vec<&DMatrix<f64>> = blocks.iter().collect();
        let a = block_diag(&refs);
        let mut b = DMatrix::zeros(2 * n, self.inputs());
        let mut c = DMatrix::zeros(self.outputs(), 2 * n);
        for i in 0..n {
            b.row_mut(2 * i + 1).copy_from(&self.phi_a.row(i));
            c.column_mut(2 * i).copy_from(&self.phi_s.column(i));
        }
        ContinuousStateSpace {
            a,
            b,
            c,
            d: DMatrix::zeros(self.outputs(), self.inputs()),
        }
    }

    /// Static compliance T_DC = Σ φ_s,i φ_a,iᵀ / ω_i² over the given modes
    /// (docs/control.md (2.13)). Rigid modes have no static compliance.
    pub fn compliance(&self, modes: &[usize]) -> Result<DMatrix<f64>, ModelError> {
        let mut t = DMatrix::zeros(self.outputs(), self.inputs());
        for &i in modes {
            if i >= self.modes() {
                return Err(ModelError::OutOfRange(format!("mode {i}")));
            }
            if i < self.n_rigid {
                return Err(ModelError::OutOfRange(format!(
                    "mode {i} is rigid and has no compliance"
                )));
            }
            let w2 = self.omega[i] * self.omega[i];
            t += self.phi_s.column(i) * self.phi_a.row(i) / w2;
        }
        Ok(t)
    }

    /// The first `keep` modes plus T_DC over `compensate` (indices of
    /// discarded modes, e.g. 4..=6 for the thesis chain; the rest are
    /// ignored as "unknown").
    pub fn truncate(&self, keep: usize, compensate: &[usize]) -> Result<ReducedModel, ModelError> {
        if keep == 0 || keep > self.modes() {
            return Err(ModelError::OutOfRange(format!(
                "keep {keep} of {} modes",
                self.modes()
            )));
        }
        if let Some(i) = compensate.iter().find(|&&i| i < keep) {
            return Err(ModelError::OutOfRange(format!(
                "mode {i} is retained and cannot be compensated"
            )));
        }
        let t_dc = self.compliance(compensate)?;
        let modal = self.select_modes(&(0..keep).collect::<Vec<_>>())?;
        Ok(ReducedModel { modal, t_dc })
    }

    /// A model with only the given modes (in the given order).
    pub fn select_modes(&self, modes: &[usize]) -> Result<Self, ModelError> {
        if let Some(i) = modes.iter().find(|&&i| i >= self.modes()) {
            return Err(ModelError::OutOfRange(format!("mode {i}")));
        }
        let omega = modes.iter().map(|&i| self.omega[i]).collect();
        let zeta = modes.iter().map(|&i| self.zeta[i]).collect();
        let phi_a = self.phi_a.select_rows(modes);
        let phi_s = self.phi_s.select_columns(modes);
        let mut m = Self::new(omega, zeta, phi_a, phi_s)?;
        m.shapes = self.shapes.as_ref().map(|s| s.select_columns(modes));
        Ok(m)
    }

    /// A model with only the given sensors (rows of Φ_s).
    pub fn select_outputs(&self, outputs: &[usize]) -> Result<Self, ModelError> {
        if let Some(i) = outputs.iter().find(|&&i| i >= self.outputs()) {
            return Err(ModelError::OutOfRange(format!("output {i}")));
        }
        let mut m = self.clone();
        m.phi_s = self.phi_s.select_rows(outputs);
        Ok(m)
    }

    /// Sensor row (1 × n_modes) of a sensor at a fractional node index:
    /// linear interpolation of the mass-normalised mode-shape rows between the
    /// neighbouring nodes (docs/control.md §1.4; the thesis gives no mapping).
    /// Position 0.0 is node 0, 1.5 halfway between nodes 1 and 2.
    pub fn sensor_row_at(&self, position: f64) -> Result<DMatrix<f64>, ModelError> {
        let shapes = self.shapes.as_ref().ok_or(ModelError::NoModeShapes)?;
        let last = (shapes.nrows() - 1) as f64;
        if !(position.is_finite() && (0.0..=last).contains(&position)) {
            return Err(ModelError::OutOfRange(format!(
                "sensor position {position} outside [0, {last}]"
            )));
        }
        let i0 = (position.floor() as usize).min(shapes.nrows().saturating_sub(2));
        let frac = position - i0 as f64;
        let row = if shapes.nrows() == 1 {
            shapes.row(0).into_owned()
        } else {
            shapes.row(i0) * (1.0 - frac) + shapes.row(i0 + 1) * frac
        };
        Ok(DMatrix::from_row_slice(1, row.ncols(), row.as_slice()))
    }

    /// The same structure measured by sensors at the given fractional node
    /// positions (output position dependency: B unchanged, C and T_DC change).
    pub fn with_sensor_positions(&self, positions: &[f64]) -> Result<Self, ModelError> {
        let mut phi_s = DMatrix::zeros(positions.len(), self.modes());
        for (r, &p) in positions.iter().enumerate() {
            phi_s.row_mut(r).copy_from(&self.sensor_row_at(p)?);
        }
        let mut m = self.clone();
        m.phi_s = phi_s;
        Ok(m)
    }
}

impl ModalModel {
    /// Rigid-body decoupling (docs/control.md (4.12)): Γ = [φ_a,rigᵀ]⁻¹ and
    /// Υ = [φ_s,rig]⁻¹, returned with the decoupled model (φ_a Γ, Υ φ_s), in
    /// which the rigid part is the identity times 1/s². Needs as many
    /// actuators and sensors as rigid modes.
    pub fn rigid_body_decoupled(&self) -> Result<(Self, DMatrix<f64>, DMatrix<f64>), ModelError> {
        let r = self.n_rigid;
        if r == 0 || self.inputs() != r || self.outputs() != r {
            return Err(ModelError::Matrix(MatrixError::DimensionMismatch {
                what: "rigid-body decoupling (actuators x sensors)",
                expected: (r, r),
                found: (self.inputs(), self.outputs()),
            }));
        }
        let pa = self.phi_a.rows(0, r).into_owned();
        let ps = self.phi_s.columns(0, r).into_owned();
        let gamma = pa.try_inverse().ok_or(ModelError::OutOfRange(
            "rigid actuator gains are singular".into(),
        ))?;
        let upsilon = ps.try_inverse().ok_or(ModelError::OutOfRange(
            "rigid sensor gains are singular".into(),
        ))?;
        let mut m = self.clone();
        m.phi_a = &self.phi_a * &gamma;
        m.phi_s = &upsilon * &self.phi_s;
        m.shapes = None;
        Ok((m, gamma, upsilon))
    }
}

impl ReducedModel {
    /// Continuous reduced model ẋ = A_t x + B_t f, y = C_t x + T_DC f (2.14).
    pub fn state_space(&self) -> ContinuousStateSpace {
        let mut s = self.modal.state_space();
        s.d = self.t_dc.clone();
        s
    }

    /// State indices of the flexible modal velocities (η̇ of modes ≥ n_rigid).
    pub fn flexible_velocity_states(&self) -> Vec<usize> {
        (self.modal.n_rigid..self.modal.modes())
            .map(|i| 2 * i + 1)
            .collect()
    }

    /// C_f: C_t with the rigid-mode columns zeroed (MC output, docs/control.md §5.1).
    pub fn flexible_output_matrix(&self) -> DMatrix<f64> {
        let mut c = self.modal.state_space().c;
        for j in 0..2 * self.modal.n_rigid {
            c.column_mut(j).fill(0.0);
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_mass() -> NodalModel {
        NodalModel {
            mass: DMatrix::from_diagonal(&DVector::from_vec(vec![1.0, 2.0])),
            stiffness: DMatrix::from_row_slice(2, 2, &[100.0, -100.0, -100.0, 100.0]),
            damping: ModalDamping::Uniform(0.01),
            actuators: DMatrix::from_column_slice(2, 1, &[1.0, 0.0]),
            sensors: DMatrix::identity(2, 2),
        }
    }

    #[test]
    fn two_mass_modes_are_mass_normalised() {
        let nodal = two_mass();
        let m = ModalModel::from_nodal(&nodal).unwrap();
        assert_eq!(m.n_rigid, 1);
        // ω² = k (1/m1 + 1/m2) = 150.
        assert!((m.omega[1] - 150f64.sqrt()).abs() < 1e-12);
        let phi = m.shapes.as_ref().unwrap();
        let ortho = phi.transpose() * &nodal.mass * phi;
        assert!((ortho - DMatrix::identity(2, 2)).amax() < 1e-12);
        assert!(m.phi_a[(0, 0)] > 0.0 && m.phi_a[(1, 0)] > 0.0);
        assert_eq!(m.zeta, vec![0.0, 0.01]);
        // Rigid gain 1/(m_total s²): φ_a φ_s = 1/3.
        assert!((m.phi_a[(0, 0)] * m.phi_s[(1, 0)] - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn rejects_bad_input() {
        let mut n = two_mass();
        n.mass[(1, 1)] = 0.0;
        assert_eq!(
            ModalModel::from_nodal(&n),
            Err(ModelError::MassNotPositiveDefinite)
        );
        let mut n = two_mass();
        n.stiffness[(0, 1)] = f64::NAN;
        assert!(matches!(
            ModalModel::from_nodal(&n),
            Err(ModelError::Matrix(MatrixError::NonFinite(_)))
        ));
        let mut n = two_mass();
        n.sensors = DMatrix::identity(3, 3);
        assert!(matches!(
            ModalModel::from_nodal(&n),
            Err(ModelError::Matrix(MatrixError::DimensionMismatch { .. }))
        ));
        let m = ModalModel::from_nodal(&two_mass()).unwrap();
        assert!(m.truncate(1, &[0]).is_err());
        assert!(m.sensor_row_at(1.5).is_err());
    }

    #[test]
    fn interpolated_sensor_rows() {
        let m = ModalModel::from_nodal(&two_mass()).unwrap();
        let mid = m.sensor_row_at(0.25).unwrap();
        let want = m.phi_s.row(0) * 0.75 + m.phi_s.row(1) * 0.25;
        assert!((mid - want).amax() < 1e-15);
        let end = m.sensor_row_at(1.0).unwrap();
        assert!((end - m.phi_s.row(1)).amax() < 1e-15);
    }
}
