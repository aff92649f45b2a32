//! The one error type of the user-model conversions ([`crate::second_order`],
//! [`crate::lumped_network`], [`crate::real_modal_form`],
//! [`crate::zoh_inverse`]): which array of the user's model is wrong and why,
//! so that the caller can prefix the file name ("plant.npz: K: …").

use crate::modal::ModelError;
use std::fmt;

/// A user's plant model refused: `array` names the array or field as the user
/// wrote it (`"M"`, `"K"`, `"D"`, `"A"`, `"B"`, `"C"`, `"damping"`,
/// `"masses"`, `"springs"`, `"dampers"`, `"forces"`, `"positions"`, `"ts"`).
#[derive(Debug, Clone, PartialEq)]
pub struct PlantModelError {
    pub array: &'static str,
    pub reason: PlantModelReason,
}

/// Why a user's plant model was refused.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum PlantModelReason {
    /// The array has the wrong shape.
    Shape {
        expected: (usize, usize),
        found: (usize, usize),
    },
    /// The array holds NaN or infinity.
    NonFinite,
    /// M or K is not symmetric.
    NotSymmetric,
    /// M is singular: a degree of freedom without mass.
    SingularMass,
    /// M has a negative eigenvalue.
    IndefiniteMass,
    /// K has a clearly negative modal eigenvalue ω².
    NegativeStiffness(f64),
    /// Neither a damping matrix D nor modal damping was given.
    DampingMissing,
    /// Both a damping matrix D and modal damping were given.
    DampingTwice,
    /// D damps a rigid-body mode (a damper to ground).
    RigidModeDamped { mode: usize },
    /// D couples two modes: the modal model keeps diagonal damping only.
    NonProportionalDamping {
        modes: (usize, usize),
        coupling: f64,
    },
    /// A damping ratio outside [0, 1).
    DampingOutOfRange { mode: usize, zeta: f64 },
    /// Other invalid modal damping (count, Rayleigh α with rigid modes, …).
    InvalidDamping(String),
    /// An index, count or value out of its range (lumped networks).
    OutOfRange(String),
    /// A real nonzero eigenvalue: first-order dynamics or an overdamped mode.
    RealEigenvalue(f64),
    /// An eigenvalue in the right half plane (σ + iω).
    Unstable { re: f64, im: f64 },
    /// A zero eigenvalue without its Jordan partner (a single integrator),
    /// or a Jordan chain at zero longer than two (a triple integrator).
    NotRigidBodyIntegrator {
        zero_eigenvalues: usize,
        kernel_dim: usize,
    },
    /// A repeated complex eigenvalue with a Jordan block (not a mode).
    DefectiveEigenvalue { frequency_hz: f64 },
    /// An input that enters a flexible mode with rank 2 (not a force).
    InputNotForce { frequency_hz: f64 },
    /// An output that reads a mode's velocity (only position outputs).
    VelocityOutput { frequency_hz: f64 },
    /// No input moves this rigid-body mode.
    UncontrollableRigidMode,
    /// No output sees this rigid-body mode.
    UnobservableRigidMode,
    /// A nonzero feedthrough D (position outputs of forces have none).
    Feedthrough,
    /// A discrete model whose A_d has an eigenvalue at 0 or on the negative
    /// real axis: no real matrix logarithm.
    NoRealLogarithm { re: f64, im: f64 },
    /// The eigenvalue clusters could not be separated into invariant
    /// subspaces (nearly repeated eigenvalues at the clustering tolerance).
    Unseparable(String),
    /// A numerical algorithm did not converge.
    NoConvergence(&'static str),
    /// The modal model itself refused the data (see [`ModelError`]).
    Model(ModelError),
}

impl PlantModelError {
    pub(crate) fn new(array: &'static str, reason: PlantModelReason) -> Self {
        Self { array, reason }
    }
}

impl fmt::Display for PlantModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.array, self.reason)
    }
}

impl fmt::Display for PlantModelReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use PlantModelReason as R;
        match self {
            R::Shape { expected, found } => write!(
                f,
                "is {}x{} but must be {}x{}",
                found.0, found.1, expected.0, expected.1
            ),
            R::NonFinite => write!(f, "holds a non-finite number"),
            R::NotSymmetric => write!(f, "is not symmetric"),
            R::SingularMass => write!(
                f,
                "is singular: a degree of freedom has no mass (condense it out, e.g. by static \
                 (Guyan) reduction, or give it a mass)"
            ),
            R::IndefiniteMass => write!(f, "is not positive definite (a negative mass)"),
            R::NegativeStiffness(l) => write!(
                f,
                "has a negative modal eigenvalue ω² = {l:e}: the structure is unstable"
            ),
            R::DampingMissing => write!(
                f,
                "no damping: give a damping matrix D or modal damping (ζ per mode or Rayleigh α/β)"
            ),
            R::DampingTwice => write!(
                f,
                "both a damping matrix D and modal damping were given: give one of them"
            ),
            R::RigidModeDamped { mode } => write!(
                f,
                "damps rigid-body mode {mode} (a damper to ground); the modal model has undamped \
                 rigid modes: remove the damper to ground, or use modal ζ or Rayleigh β"
            ),
            R::NonProportionalDamping { modes, coupling } => write!(
                f,
                "is not proportional: it couples modes {} and {} ({coupling:.3} of √(d_ii d_jj), \
                 more than 0.1); the modal model keeps diagonal damping: use modal ζ or Rayleigh \
                 α/β instead",
                modes.0, modes.1
            ),
            R::DampingOutOfRange { mode, zeta } => {
                write!(f, "gives mode {mode} ζ = {zeta}, outside [0, 1)")
            }
            R::InvalidDamping(s) => write!(f, "{s}"),
            R::OutOfRange(s) => write!(f, "{s}"),
            R::RealEigenvalue(l) => write!(
                f,
                "has a real eigenvalue {l:e} rad/s: an overdamped mode (ζ ≥ 1) or first-order \
                 dynamics (e.g. an actuator lag), not a structural mode (a complex pair)"
            ),
            R::Unstable { re, im } => write!(
                f,
                "has an unstable eigenvalue {re:e} ± {:e}i rad/s",
                im.abs()
            ),
            R::NotRigidBodyIntegrator {
                zero_eigenvalues,
                kernel_dim,
            } => write!(
                f,
                "has {zero_eigenvalues} zero eigenvalue(s) with {kernel_dim} independent \
                 eigenvector(s): a rigid-body mode is a pair (a 2x2 Jordan block, position and \
                 velocity); a single integrator or a longer chain is not a structural mode"
            ),
            R::DefectiveEigenvalue { frequency_hz } => write!(
                f,
                "has a repeated eigenvalue at {frequency_hz:.6} Hz with a Jordan block: not a \
                 structural mode"
            ),
            R::InputNotForce { frequency_hz } => write!(
                f,
                "enters the mode at {frequency_hz:.6} Hz with rank 2: a force enters a mode's \
                 acceleration only"
            ),
            R::VelocityOutput { frequency_hz } => write!(
                f,
                "reads the velocity of the mode at {frequency_hz:.6} Hz (or its input enters the \
                 position): only position outputs of force inputs are supported"
            ),
            R::UncontrollableRigidMode => write!(
                f,
                "leaves a rigid-body mode uncontrollable: no input moves it, it cannot be positioned"
            ),
            R::UnobservableRigidMode => write!(
                f,
                "leaves a rigid-body mode unobservable: no output sees it"
            ),
            R::Feedthrough => write!(
                f,
                "is nonzero: position outputs of force inputs have no feedthrough (a D of zeros is \
                 fine)"
            ),
            R::NoRealLogarithm { re, im } => write!(
                f,
                "has the eigenvalue {re:e}{im:+e}i, at 0 or on the negative real axis: no real \
                 continuous-time model has this ZOH (a pole beyond Nyquist or far faster than \
                 the sample rate)"
            ),
            R::Unseparable(s) => write!(f, "{s}"),
            R::NoConvergence(what) => write!(f, "{what} did not converge"),
            R::Model(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for PlantModelError {}

/// `m` is `rows` × `cols` and finite, else an error naming `array`.
pub(crate) fn check_array(
    m: &nalgebra::DMatrix<f64>,
    array: &'static str,
    rows: usize,
    cols: usize,
) -> Result<(), PlantModelError> {
    if m.shape() != (rows, cols) {
        return Err(PlantModelError::new(
            array,
            PlantModelReason::Shape {
                expected: (rows, cols),
                found: m.shape(),
            },
        ));
    }
    if m.iter().any(|v| !v.is_finite()) {
        return Err(PlantModelError::new(array, PlantModelReason::NonFinite));
    }
    Ok(())
}
