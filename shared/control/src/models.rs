//! Built-in plant models: the thesis 8-mass chain (docs/control.md §1.3, the main
//! benchmark), the smaller thesis examples, and documented stand-ins for the
//! models whose data the thesis does not give (MIMO example, OAT, 2-DOF
//! flexible joint).
//!
//! Where a value is invented, the function's doc says so; nothing here is
//! tuned to make a test pass.

use crate::continuous::ContinuousStateSpace;
use crate::matrix_error::MatrixError;
use crate::modal::{ModalDamping, ModalModel, ModelError, NodalModel, ReducedModel};
use nalgebra::{DMatrix, DVector};
use std::f64::consts::PI;

/// Thesis chain: actuator mass ma [kg] (Table 3.2).
pub const CHAIN_MA: f64 = 2.5;
/// Thesis chain: mass of each of m1..m7 [kg] (10/7, so the total is 12.5 kg).
pub const CHAIN_MI: f64 = 10.0 / 7.0;
/// Thesis chain: spring between m_i and m_{i+1} [N/m].
pub const CHAIN_K: f64 = 9.6e7;
/// Thesis chain: spring between ma and m1 [N/m].
pub const CHAIN_KA: f64 = 1e8;
/// Thesis chain: uniform modal damping (Table 3.4 "original", docs/control.md §1.3).
pub const CHAIN_ZETA: f64 = 0.005;
/// Total moving mass of the thesis chain [kg].
pub const CHAIN_MASS: f64 = 12.5;
/// Thesis noise levels (docs/control.md §4.1): σ_w = 10 mN, σ_v = σ_d = 1 nm.
pub const SIGMA_W: f64 = 0.01;
pub const SIGMA_V: f64 = 1e-9;
pub const SIGMA_D: f64 = 1e-9;
/// Thesis sample rate for a real-time implementation (docs/control.md §10.1).
pub const TS_10KHZ: f64 = 1e-4;

/// A free–free mass–spring chain: node i has mass `masses[i]`, spring
/// `springs[i]` joins nodes i and i+1. Forces act on `actuator_nodes`, and
/// `sensor_nodes` are measured (one row each).
pub fn chain(
    masses: &[f64],
    springs: &[f64],
    damping: ModalDamping,
    actuator_nodes: &[usize],
    sensor_nodes: &[usize],
) -> Result<NodalModel, ModelError> {
    let n = masses.len();
    if n == 0 || springs.len() + 1 != n {
        return Err(ModelError::Matrix(MatrixError::DimensionMismatch {
            what: "chain springs",
            expected: (n.saturating_sub(1), 1),
            found: (springs.len(), 1),
        }));
    }
    if let Some(&i) = actuator_nodes
        .iter()
        .chain(sensor_nodes.iter())
        .find(|&&i| i >= n)
    {
        return Err(ModelError::OutOfRange(format!("node {i} of {n}")));
    }
    let mass = DMatrix::from_diagonal(&DVector::from_column_slice(masses));
    let mut stiffness = DMatrix::zeros(n, n);
    for (i, &k) in springs.iter().enumerate() {
        stiffness[(i, i)] += k;
        stiffness[(i + 1, i + 1)] += k;
        stiffness[(i, i + 1)] -= k;
        stiffness[(i + 1, i)] -= k;
    }
    let mut actuators = DMatrix::zeros(n, actuator_nodes.len());
    for (j, &i) in actuator_nodes.iter().enumerate() {
        actuators[(i, j)] = 1.0;
    }
    let mut sensors = DMatrix::zeros(sensor_nodes.len(), n);
    for (r, &i) in sensor_nodes.iter().enumerate() {
        sensors[(r, i)] = 1.0;
    }
    Ok(NodalModel {
        mass,
        stiffness,
        damping,
        actuators,
        sensors,
    })
}

/// The thesis SISO benchmark (docs/control.md §1.3): nodes [ma, m1, …, m7], force
/// on ma, ma–(ka)–m1–(k)–m2–…–m7, ζ = 0.005 on every flexible mode, outputs
/// y1..y7 = positions of m1..m7 (output row i−1 is y_i).
pub fn thesis_chain() -> NodalModel {
    let mut masses = vec![CHAIN_MI; 8];
    masses[0] = CHAIN_MA;
    let mut springs = vec![CHAIN_K; 7];
    springs[0] = CHAIN_KA;
    let sensors: Vec<usize> = (1..=7).collect();
    chain(
        &masses,
        &springs,
        ModalDamping::Uniform(CHAIN_ZETA),
        &[0],
        &sensors,
    )
    .expect("static thesis chain data is consistent")
}

/// Modal form of [`thesis_chain`]: 1 rigid + 7 flexible modes, outputs y1..y7.
pub fn thesis_chain_modal() -> Result<ModalModel, ModelError> {
    ModalModel::from_nodal(&thesis_chain())
}

/// The thesis chain seen from one output y_i (i = 1..=7).
pub fn thesis_plant(output: usize) -> Result<ModalModel, ModelError> {
    if !(1..=7).contains(&output) {
        return Err(ModelError::OutOfRange(format!("output y{output}")));
    }
    thesis_chain_modal()?.select_outputs(&[output - 1])
}

/// The thesis chain at output y_i under exact ZOH (the plant emulator).
pub fn thesis_plant_discrete(
    output: usize,
    ts: f64,
) -> Result<crate::lti::DiscreteStateSpace, crate::design_error::DesignError> {
    Ok(crate::discretise::zoh(
        &thesis_plant(output)?.state_space(),
        ts,
    )?)
}

/// The thesis observer model for output y_i: rigid + first 3 flexible modes,
/// T_DC over flexible modes 4–6; mode 7 is "unknown" (docs/control.md §1.3).
pub fn thesis_reduced(output: usize) -> Result<ReducedModel, ModelError> {
    thesis_plant(output)?.truncate(4, &[4, 5, 6])
}

/// Node counts a [`uniform_chain`] may have: 2 (one flexible mode) to 64
/// (128 states, the largest observer the loop's messages carry).
pub const UNIFORM_CHAIN_NODES: std::ops::RangeInclusive<usize> = 2..=64;

/// The model-size stand-in (`bench --sweep`): `nodes` equal masses sharing
/// the thesis chain's 12.5 kg, joined by equal springs, free–free, ζ = 0.005
/// on every flexible mode, the force on the first node and the sensor at
/// node round(5·(nodes−1)/7), where the thesis measures y5 of m0..m7. The
/// springs keep the first flexible mode at the thesis chain's, so a loop
/// designed for one size suits all of them; the higher modes spread up to
/// 2·sin((nodes−1)π/(2·nodes))/sin(π/(2·nodes)) times the first. 2·nodes
/// states, invented to show how cost grows, not a structure from the thesis.
pub fn uniform_chain(nodes: usize) -> Result<NodalModel, ModelError> {
    if !UNIFORM_CHAIN_NODES.contains(&nodes) {
        return Err(ModelError::OutOfRange(format!(
            "{nodes} nodes (a uniform chain has {} to {})",
            UNIFORM_CHAIN_NODES.start(),
            UNIFORM_CHAIN_NODES.end()
        )));
    }
    let first_mode = thesis_chain_modal()?
        .frequencies_hz()
        .get(1)
        .copied()
        .ok_or_else(|| ModelError::OutOfRange("the thesis chain has no flexible mode".into()))?;
    let mass = CHAIN_MASS / nodes as f64;
    // Free–free uniform chain: ω_j = 2 √(k/m) sin(jπ / 2n).
    let half_angle = (PI / (2.0 * nodes as f64)).sin();
    let spring = mass * (2.0 * PI * first_mode / (2.0 * half_angle)).powi(2);
    chain(
        &vec![mass; nodes],
        &vec![spring; nodes - 1],
        ModalDamping::Uniform(CHAIN_ZETA),
        &[0],
        &[uniform_chain_sensor(nodes)],
    )
}

/// The node a [`uniform_chain`] measures: 5/7 of its length, as y5 of the
/// thesis' m0..m7.
pub fn uniform_chain_sensor(nodes: usize) -> usize {
    ((5 * nodes.saturating_sub(1)) as f64 / 7.0).round() as usize
}

/// Ex. 2.3.1 (docs/control.md §1.2): five 2 kg masses, springs 1e5 N/m, dampers
/// 5 N s/m along the springs (so ζ_i = b ω_i / (2k)), forces f1..f5 on every
/// mass, outputs x1..x5. Free–free (one rigid mode).
pub fn five_mass_chain() -> NodalModel {
    five_mass_chain_with(&[2.0; 5])
}

/// Ex. 2.3.2 variant: the same chain with chosen masses (e.g. 1.6 kg each
/// with one mass raised to 2.6 kg).
pub fn five_mass_chain_with(masses: &[f64; 5]) -> NodalModel {
    let k = 1e5;
    let b = 5.0;
    let all: Vec<usize> = (0..5).collect();
    chain(
        masses,
        &[k; 4],
        ModalDamping::StiffnessProportional(b / k),
        &all,
        &all,
    )
    .expect("static five-mass data is consistent")
}

/// Two-inertia experimental setup (Table 3.8): J1 = J2 = 3.75e-6 kg m²,
/// torsional spring 0.02656 N m/rad with damper 3.125e-5 N m s/rad in
/// parallel (stiffness-proportional, ζ ≈ 0.070 at 18.9 Hz). The input is the
/// motor current [A] on the right inertia (node 1) through Km = 4.4e-2 N m/A;
/// both angles are measured (rows θ1, θ2). The bearing friction
/// b = 1e-5 N m s/rad to ground is neglected: it is not modal damping and
/// moves the rigid pole only to −1.3 rad/s.
pub fn two_inertia() -> NodalModel {
    let j = 3.75e-6;
    let k = 0.02656;
    let d = 3.125e-5;
    let km = 4.4e-2;
    let mut m = chain(
        &[j, j],
        &[k],
        ModalDamping::StiffnessProportional(d / k),
        &[1],
        &[0, 1],
    )
    .expect("static two-inertia data is consistent");
    m.actuators *= km;
    m
}

/// Lecture double integrator (docs/control.md §12.1): ẋ = [[0,1],[0,0]] x + [0;1] u,
/// y = x1. Its ZOH at h gives Φ = [[1,h],[0,1]], Γ = [h²/2; h].
pub fn double_integrator() -> ContinuousStateSpace {
    ContinuousStateSpace {
        a: DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]),
        b: DMatrix::from_column_slice(2, 1, &[0.0, 1.0]),
        c: DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
        d: DMatrix::zeros(1, 1),
    }
}

/// The 2×2 MIMO example of Ch. 4.3 (docs/control.md §1.5): 2 rigid + 3 flexible
/// modes at 161, 517 and 760 Hz. The thesis gives no mode shapes or damping;
/// these are INVENTED: a 10 kg beam-like stage with rotational inertia
/// 0.4 kg m², actuators at x = ±0.2 m, sensors at x = ±0.25 m; rigid shapes
/// 1/√m and x/√J; the first bending mode is symmetric, the second
/// antisymmetric and non-collocated (sensor sign opposite to the actuator),
/// the third symmetric; ζ = 0.005 for all flexible modes (as the SISO chain).
pub fn mimo_example() -> Result<ModalModel, ModelError> {
    let m: f64 = 10.0;
    let j: f64 = 0.4;
    let (xa, xs) = (0.2, 0.25);
    let r1 = 1.0 / m.sqrt();
    let r2 = 1.0 / j.sqrt();
    #[rustfmt::skip]
    let phi_a = DMatrix::from_row_slice(5, 2, &[
        r1, r1,
        -xa * r2, xa * r2,
        0.25, 0.25,
        0.20, -0.20,
        -0.15, -0.15,
    ]);
    #[rustfmt::skip]
    let phi_s = DMatrix::from_row_slice(2, 5, &[
        r1, -xs * r2, 0.30, -0.28, 0.22,
        r1, xs * r2, 0.30, 0.28, 0.22,
    ]);
    let omega = [0.0, 0.0, 161.0, 517.0, 760.0]
        .iter()
        .map(|f| 2.0 * PI * f)
        .collect();
    ModalModel::new(omega, vec![0.0, 0.0, 0.005, 0.005, 0.005], phi_a, phi_s)
}

/// Table 6.1 OAT frequencies [Hz].
pub const OAT_FREQ_HZ: [f64; 8] = [138.0, 380.0, 410.0, 504.0, 512.0, 525.0, 878.0, 1178.0];
/// Table 6.1 OAT modal damping.
pub const OAT_ZETA: [f64; 8] = [
    0.0025, 0.0156, 0.0161, 0.0066, 0.0056, 0.0033, 0.0017, 0.0023,
];

/// OAT-like out-of-plane model (Ch. 6, docs/control.md §1.8): 3 rigid modes
/// (z, rx, ry) + 8 flexible modes with the Table 6.1 frequencies and damping.
/// Geometry INVENTED (the thesis gives none): a uniform 0.5 m × 0.4 m plate of
/// 25 kg centred at the origin; rigid shapes 1/√m, y/√Ixx, −x/√Iyy; flexible
/// mode k has the plate-like shape c·cos(p π (x/a + ½)) cos(q π (y/b + ½))
/// with (p, q) = (1,1), (2,0), (0,2), (2,1), (1,2), (2,2), (3,1), (1,3) and c
/// the uniform-plate mass normalisation. Three vertical actuators at
/// (−0.20, −0.15), (0.20, −0.15), (0.05, 0.17) (asymmetric, so that they
/// excite the flexible modes, as in the thesis) and four corner encoders at
/// (±0.22, ±0.17); `sensors` picks three of them (encoder order: (−,−),
/// (+,−), (+,+), (−,+)), which emulates the thesis' "4 positions".
pub fn oat_like(sensors: [usize; 3]) -> Result<ModalModel, ModelError> {
    if sensors.iter().any(|&s| s >= 4) {
        return Err(ModelError::OutOfRange(format!("encoders {sensors:?} of 4")));
    }
    let (a, b, m): (f64, f64, f64) = (0.5, 0.4, 25.0);
    let ixx = m * b * b / 12.0;
    let iyy = m * a * a / 12.0;
    let pq = [
        (1, 1),
        (2, 0),
        (0, 2),
        (2, 1),
        (1, 2),
        (2, 2),
        (3, 1),
        (1, 3),
    ];
    let shape = |mode: usize, x: f64, y: f64| -> f64 {
        match mode {
            0 => 1.0 / m.sqrt(),
            1 => y / ixx.sqrt(),
            2 => -x / iyy.sqrt(),
            _ => {
                let (p, q) = pq[mode - 3];
                let norm = |k: i32| if k == 0 { 1.0 } else { 2f64.sqrt() };
                let c = norm(p) * norm(q) / m.sqrt();
                c * (p as f64 * PI * (x / a + 0.5)).cos() * (q as f64 * PI * (y / b + 0.5)).cos()
            }
        }
    };
    let act = [(-0.20, -0.15), (0.20, -0.15), (0.05, 0.17)];
    let enc = [(-0.22, -0.17), (0.22, -0.17), (0.22, 0.17), (-0.22, 0.17)];
    let n = 11;
    let phi_a = DMatrix::from_fn(n, 3, |i, j| shape(i, act[j].0, act[j].1));
    let phi_s = DMatrix::from_fn(3, n, |r, i| {
        let (x, y) = enc[sensors[r]];
        shape(i, x, y)
    });
    let mut omega = vec![0.0; 3];
    omega.extend(OAT_FREQ_HZ.iter().map(|f| 2.0 * PI * f));
    let mut zeta = vec![0.0; 3];
    zeta.extend_from_slice(&OAT_ZETA);
    ModalModel::new(omega, zeta, phi_a, phi_s)
}

/// 2-DOF serial flexible joint (Seed 001, Quanser): linearised about the
/// stationary collinear pose with the inertial coupling between the links
/// neglected, as four rotational nodes q = [θ1, θ1+α1, θ2, θ2+α2] (hub 1,
/// link 1, hub 2, link 2, absolute angles in rad). Inputs: motor currents
/// i1, i2 [A]; motor 2 sits on link 1, so its torque acts on hub 2 with the
/// reaction on link 1. Outputs: hub angles θ1, θ2. All parameters INVENTED
/// (the paper gives none): hub inertias 2e-3 and 1e-3 kg m², link inertias
/// 3.5e-3 and 1.5e-3 kg m², joint springs 1.2 and 0.8 N m/rad, motor
/// constants 0.12 and 0.08 N m/A, ζ = 0.02. This gives 2 rigid modes and
/// flexible modes near 4.9 and 5.8 Hz.
pub fn flexible_joint() -> NodalModel {
    let inertia = [2e-3, 3.5e-3, 1e-3, 1.5e-3];
    let mass = DMatrix::from_diagonal(&DVector::from_column_slice(&inertia));
    let (k1, k2) = (1.2, 0.8);
    #[rustfmt::skip]
    let stiffness = DMatrix::from_row_slice(4, 4, &[
        k1, -k1, 0.0, 0.0,
        -k1, k1, 0.0, 0.0,
        0.0, 0.0, k2, -k2,
        0.0, 0.0, -k2, k2,
    ]);
    let (km1, km2) = (0.12, 0.08);
    #[rustfmt::skip]
    let actuators = DMatrix::from_row_slice(4, 2, &[
        km1, 0.0,
        0.0, -km2,
        0.0, km2,
        0.0, 0.0,
    ]);
    #[rustfmt::skip]
    let sensors = DMatrix::from_row_slice(2, 4, &[
        1.0, 0.0, 0.0, 0.0,
        0.0, 0.0, 1.0, 0.0,
    ]);
    NodalModel {
        mass,
        stiffness,
        damping: ModalDamping::Uniform(0.02),
        actuators,
        sensors,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const THESIS_HZ: [f64; 7] = [470.06, 941.88, 1396.06, 1805.13, 2145.46, 2399.72, 2556.45];

    #[test]
    fn uniform_chains_keep_the_thesis_first_mode_and_total_mass() {
        for nodes in [2, 8, 17, 64] {
            let m = ModalModel::from_nodal(&uniform_chain(nodes).unwrap()).unwrap();
            assert_eq!(m.modes(), nodes);
            assert_eq!(m.n_rigid, 1);
            let f = m.frequencies_hz();
            assert!(
                (f[1] - THESIS_HZ[0]).abs() < 0.01,
                "{nodes} nodes: {}",
                f[1]
            );
            // Free–free uniform chain: the modes follow sin(jπ / 2n).
            let expected_last = f[1] * ((nodes - 1) as f64 * PI / (2.0 * nodes as f64)).sin()
                / (PI / (2.0 * nodes as f64)).sin();
            assert!(
                (f[nodes - 1] / expected_last - 1.0).abs() < 1e-6,
                "{nodes} nodes"
            );
            let rigid_gain = m.phi_a[(0, 0)] * m.phi_s[(0, 0)];
            assert!((rigid_gain - 1.0 / CHAIN_MASS).abs() < 1e-12);
        }
        assert!(uniform_chain(1).is_err());
        assert!(uniform_chain(65).is_err());
    }

    #[test]
    fn thesis_chain_frequencies_and_rigid_gain() {
        let m = thesis_chain_modal().unwrap();
        assert_eq!(m.n_rigid, 1);
        let f = m.frequencies_hz();
        assert_eq!(f[0], 0.0);
        for (got, want) in f[1..].iter().zip(THESIS_HZ) {
            assert!((got - want).abs() < 0.006, "{got} vs {want}");
        }
        // Rigid mode gives 1/(12.5 s²) at every output.
        for r in 0..7 {
            let g = m.phi_a[(0, 0)] * m.phi_s[(r, 0)];
            assert!((g - 1.0 / CHAIN_MASS).abs() < 1e-12);
        }
        // Mode shapes of docs/control.md §1.3 (up to the column sign).
        let at_ma: [f64; 8] = [
            0.2828, 0.3658, -0.2938, -0.2240, 0.1669, 0.1197, -0.0780, -0.0386,
        ];
        let at_m5: [f64; 8] = [
            0.2828, -0.2500, 0.1126, -0.3987, -0.3293, -0.0483, -0.3825, 0.3588,
        ];
        for i in 0..8 {
            assert!(m.phi_a[(i, 0)] > 0.0, "sign convention");
            assert!((m.phi_a[(i, 0)] - at_ma[i].abs()).abs() < 6e-5);
            let sign = at_ma[i].signum();
            assert!((m.phi_s[(4, i)] - sign * at_m5[i]).abs() < 6e-5, "mode {i}");
        }
        // T_DC at y5 from flexible modes 4–6 = −3.28e-10 m/N.
        let red = thesis_reduced(5).unwrap();
        assert!(
            (red.t_dc[(0, 0)] + 3.28e-10).abs() < 0.006e-10,
            "{}",
            red.t_dc
        );
        assert_eq!(red.modal.modes(), 4);
        assert!(thesis_plant(8).is_err());
    }

    #[test]
    fn small_models() {
        let five = ModalModel::from_nodal(&five_mass_chain()).unwrap();
        assert_eq!(five.n_rigid, 1);
        // ζ = b ω / (2k).
        let i = 4;
        assert!((five.zeta[i] - 5.0 * five.omega[i] / 2e5).abs() < 1e-15);
        let two = ModalModel::from_nodal(&two_inertia()).unwrap();
        assert!((two.frequencies_hz()[1] - 18.94).abs() < 0.01);
        assert!((two.zeta[1] - 0.070).abs() < 0.001);
        let mimo = mimo_example().unwrap();
        assert_eq!(mimo.n_rigid, 2);
        let (dec, _, _) = mimo.rigid_body_decoupled().unwrap();
        // Decoupled rigid part is the identity.
        let rig = dec.phi_s.columns(0, 2) * dec.phi_a.rows(0, 2);
        assert!((rig - DMatrix::identity(2, 2)).amax() < 1e-12);
        let oat = oat_like([0, 1, 2]).unwrap();
        assert_eq!(oat.n_rigid, 3);
        assert!((oat.frequencies_hz()[3] - 138.0).abs() < 1e-9);
        assert!(oat.rigid_body_decoupled().is_ok());
        assert!(oat_like([0, 1, 4]).is_err());
        let joint = ModalModel::from_nodal(&flexible_joint()).unwrap();
        assert_eq!(joint.n_rigid, 2);
        let f = joint.frequencies_hz();
        assert!(
            (f[2] - 4.88).abs() < 0.02 && (f[3] - 5.81).abs() < 0.02,
            "{f:?}"
        );
    }
}
