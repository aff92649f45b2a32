//! The thesis chain entered in each form a user brings (lumped network,
//! second order M, K, D, B, C, first-order physical state space, its ZOH)
//! gives back the built-in modal model; a planar free body with three rigid
//! modes and a repeated flexible frequency does too.

use flexloop_control::continuous::ContinuousStateSpace;
use flexloop_control::discretise::zoh;
use flexloop_control::freq::freq_response_continuous;
use flexloop_control::lumped_network::{Attach, lumped_network};
use flexloop_control::modal::{ModalDamping, ModalModel};
use flexloop_control::models::{CHAIN_K, CHAIN_KA, CHAIN_MA, CHAIN_MI, CHAIN_ZETA, TS_10KHZ};
use flexloop_control::models::{thesis_chain, thesis_chain_modal};
use flexloop_control::real_modal_form::modal_from_state_space;
use flexloop_control::second_order::modal_from_second_order;
use flexloop_control::zoh_inverse::continuous_from_zoh;
use nalgebra::DMatrix;

/// D = Φ⁻ᵀ diag(2ζω) Φ⁻¹ = M Φ diag(2ζω) Φᵀ M (Φᵀ M Φ = I).
fn damping_matrix(mass: &DMatrix<f64>, modal: &ModalModel) -> DMatrix<f64> {
    let phi = modal.shapes.as_ref().unwrap();
    let z = DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
        modal.modes(),
        (0..modal.modes()).map(|i| 2.0 * modal.zeta[i] * modal.omega[i]),
    ));
    mass * phi * z * phi.transpose() * mass
}

/// x = (q, q̇): A = [[0, I], [−M⁻¹K, −M⁻¹D]], B = [0; M⁻¹B], C = [C, 0].
fn physical(
    m: &DMatrix<f64>,
    k: &DMatrix<f64>,
    d: &DMatrix<f64>,
    b: &DMatrix<f64>,
    c: &DMatrix<f64>,
) -> ContinuousStateSpace {
    let n = m.nrows();
    let minv = m.clone().try_inverse().unwrap();
    let mut a = DMatrix::zeros(2 * n, 2 * n);
    a.view_mut((0, n), (n, n))
        .copy_from(&DMatrix::identity(n, n));
    a.view_mut((n, 0), (n, n)).copy_from(&(-&minv * k));
    a.view_mut((n, n), (n, n)).copy_from(&(-&minv * d));
    let mut bb = DMatrix::zeros(2 * n, b.ncols());
    bb.view_mut((n, 0), (n, b.ncols())).copy_from(&(&minv * b));
    let mut cc = DMatrix::zeros(c.nrows(), 2 * n);
    cc.view_mut((0, 0), (c.nrows(), n)).copy_from(c);
    let dd = DMatrix::zeros(c.nrows(), b.ncols());
    ContinuousStateSpace::new(a, bb, cc, dd).unwrap()
}

/// The chain in physical coordinates.
fn chain_physical() -> ContinuousStateSpace {
    let nodal = thesis_chain();
    let modal = thesis_chain_modal().unwrap();
    let d = damping_matrix(&nodal.mass, &modal);
    physical(
        &nodal.mass,
        &nodal.stiffness,
        &d,
        &nodal.actuators,
        &nodal.sensors,
    )
}

/// A fixed, well-conditioned dense change of coordinates x = S T x' (what an
/// identification or a balanced realisation gives instead of q, q̇): S
/// scales the velocity half of the states by `w` [rad/s], so that with w
/// near the model's frequencies positions and velocities/w are alike, T is
/// I plus a dense pseudo-random part.
fn scramble(sys: &ContinuousStateSpace, w: f64) -> ContinuousStateSpace {
    let n = sys.states();
    let scale = DMatrix::from_fn(n, n, |i, j| {
        if i != j {
            0.0
        } else if i < n / 2 {
            1.0
        } else {
            w
        }
    });
    let mut seed: u64 = 0x2545_f491_4f6c_dd1d;
    let mut next = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
    };
    let t = scale * (DMatrix::<f64>::identity(n, n) + DMatrix::from_fn(n, n, |_, _| 0.4 * next()));
    let tinv = t.clone().try_inverse().unwrap();
    ContinuousStateSpace {
        a: &tinv * &sys.a * &t,
        b: &tinv * &sys.b,
        c: &sys.c * &t,
        d: sys.d.clone(),
    }
}

fn rel(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    (a - b).norm() / b.norm()
}

/// Frequencies (relative), ζ (absolute) and φ_s,i φ_a,iᵀ (relative to its
/// norm) mode by mode, for models without repeated flexible frequencies;
/// the rigid modes' products as one sum (only the sum is defined).
fn assert_same_modes(got: &ModalModel, want: &ModalModel, tol: f64) {
    assert_eq!(got.modes(), want.modes());
    assert_eq!(got.n_rigid, want.n_rigid);
    let rigid = |m: &ModalModel| {
        (0..m.n_rigid)
            .map(|i| m.phi_s.column(i) * m.phi_a.row(i))
            .fold(DMatrix::zeros(m.outputs(), m.inputs()), |acc, x| acc + x)
    };
    if want.n_rigid > 0 {
        let e = rel(&rigid(got), &rigid(want));
        assert!(e < tol, "rigid modes: Σ φ_s φ_aᵀ off by {e:e}");
    }
    for i in 0..want.modes() {
        if want.omega[i] == 0.0 {
            assert_eq!(got.omega[i], 0.0);
        } else {
            let e = (got.omega[i] / want.omega[i] - 1.0).abs();
            assert!(e < tol, "mode {i}: ω off by {e:e}");
        }
        let e = (got.zeta[i] - want.zeta[i]).abs();
        assert!(e < tol, "mode {i}: ζ off by {e:e}");
        if i < want.n_rigid {
            continue;
        }
        let pg = got.phi_s.column(i) * got.phi_a.row(i);
        let pw = want.phi_s.column(i) * want.phi_a.row(i);
        let e = rel(&pg, &pw);
        assert!(e < tol, "mode {i}: φ_s φ_aᵀ off by {e:e}");
    }
}

/// ‖G₁(jω) − G₂(jω)‖ / ‖G₂(jω)‖ at the given frequencies [Hz].
fn assert_same_response(got: &ContinuousStateSpace, want: &ContinuousStateSpace, hz: &[f64]) {
    for &f in hz {
        let w = 2.0 * std::f64::consts::PI * f;
        let g = freq_response_continuous(got, w).unwrap();
        let h = freq_response_continuous(want, w).unwrap();
        let e = (&g - &h).norm() / h.norm();
        assert!(e < 1e-9, "response at {f} Hz off by {e:e}");
    }
}

/// Outputs of the ZOH model for a unit step on every input, `samples` long.
fn step_response(sys: &ContinuousStateSpace, samples: usize) -> DMatrix<f64> {
    let d = zoh(sys, TS_10KHZ).unwrap();
    let mut x = DMatrix::zeros(d.states(), d.inputs());
    let u = DMatrix::identity(d.inputs(), d.inputs());
    let mut out = DMatrix::zeros(samples * d.outputs(), d.inputs());
    for k in 0..samples {
        let y = &d.c * &x;
        out.view_mut((k * d.outputs(), 0), (d.outputs(), d.inputs()))
            .copy_from(&y);
        x = &d.a * &x + &d.b * &u;
    }
    out
}

const CHECK_HZ: [f64; 6] = [10.0, 300.0, 470.0, 1000.0, 2000.0, 5000.0];

#[test]
fn second_order_with_modal_damping_is_the_builtin_chain() {
    let nodal = thesis_chain();
    let got = modal_from_second_order(
        &nodal.mass,
        &nodal.stiffness,
        None,
        &nodal.actuators,
        &nodal.sensors,
        Some(ModalDamping::Uniform(CHAIN_ZETA)),
    )
    .unwrap();
    assert_eq!(got, thesis_chain_modal().unwrap());
}

#[test]
fn second_order_with_damping_matrix_gives_zeta_back() {
    let nodal = thesis_chain();
    let want = thesis_chain_modal().unwrap();
    let d = damping_matrix(&nodal.mass, &want);
    let got = modal_from_second_order(
        &nodal.mass,
        &nodal.stiffness,
        Some(&d),
        &nodal.actuators,
        &nodal.sensors,
        None,
    )
    .unwrap();
    assert_same_modes(&got, &want, 1e-9);
    assert_eq!(got.omega, want.omega);
    assert_eq!(got.phi_a, want.phi_a);
}

#[test]
fn lumped_network_is_the_builtin_chain() {
    let mut masses = vec![CHAIN_MI; 8];
    masses[0] = CHAIN_MA;
    let springs: Vec<_> = (0..7)
        .map(|i| (i, Some(i + 1), if i == 0 { CHAIN_KA } else { CHAIN_K }))
        .collect();
    let positions: Vec<_> = (1..=7).map(Attach::At).collect();
    let net = lumped_network(&masses, &springs, &[], &[Attach::At(0)], &positions).unwrap();
    assert!(net.d.is_none());
    let got = modal_from_second_order(
        &net.m,
        &net.k,
        None,
        &net.b,
        &net.c,
        Some(ModalDamping::Uniform(CHAIN_ZETA)),
    )
    .unwrap();
    assert_eq!(got, thesis_chain_modal().unwrap());
}

#[test]
fn physical_state_space_is_the_builtin_chain() {
    let want = thesis_chain_modal().unwrap();
    let phys = chain_physical();
    let got = modal_from_state_space(&phys.a, &phys.b, &phys.c, Some(&phys.d)).unwrap();
    assert!(got.shapes.is_none());
    assert_same_modes(&got, &want, 1e-9);
    // Normalisation |φ_a,i| = |φ_s,i|.
    for i in 0..got.modes() {
        let (a, s) = (got.phi_a.row(i).norm(), got.phi_s.column(i).norm());
        assert!((a / s - 1.0).abs() < 1e-12);
        assert!(got.phi_a[(i, 0)] > 0.0);
    }
    assert_same_response(&got.state_space(), &phys, &CHECK_HZ);
    let ys = step_response(&got.state_space(), 100);
    let yp = step_response(&phys, 100);
    let e = (&ys - &yp).amax() / yp.amax();
    assert!(e < 1e-9, "ZOH step responses differ by {e:e}");
    // T_DC of flexible modes 4–6 (docs/control.md §1.3) is I/O and agrees.
    let t = got.compliance(&[4, 5, 6]).unwrap();
    let tw = want.compliance(&[4, 5, 6]).unwrap();
    assert!(rel(&t, &tw) < 1e-9);
}

#[test]
fn scrambled_coordinates_give_the_same_modes() {
    let want = thesis_chain_modal().unwrap();
    let phys = chain_physical();
    let s = scramble(&phys, 1e4);
    let got = modal_from_state_space(&s.a, &s.b, &s.c, None).unwrap();
    assert_same_modes(&got, &want, 1e-9);
    assert_same_response(&got.state_space(), &phys, &CHECK_HZ);
    // Unscaled, the coordinates mix 1 and 1e8 (‖A‖ ≈ 1e4 ω, which balancing
    // cannot undo through a dense T): rounding of order ε‖A‖ costs digits
    // (about 1e-7 here), and the form still comes out.
    let s = scramble(&phys, 1.0);
    let got = modal_from_state_space(&s.a, &s.b, &s.c, None).unwrap();
    assert_same_modes(&got, &want, 1e-6);
}

#[test]
fn continuous_from_zoh_inverts_the_chain_at_10_khz() {
    let phys = chain_physical();
    let d = zoh(&phys, TS_10KHZ).unwrap();
    let (a, b) = continuous_from_zoh(&d.a, &d.b, TS_10KHZ).unwrap();
    let n = 8;
    // Each block to its own scale: the identity block (1) and −M⁻¹K (1e8).
    for (r, c) in [(0, 0), (0, n), (n, 0), (n, n)] {
        let got = a.view((r, c), (n, n)).into_owned();
        let want = phys.a.view((r, c), (n, n)).into_owned();
        let scale = want.norm().max(1.0);
        let e = (&got - &want).norm() / scale;
        assert!(e < 1e-9, "A block ({r}, {c}) off by {e:e}");
    }
    let e = rel(&b, &phys.b);
    assert!(e < 1e-9, "B off by {e:e}");
    // And on to the modal form.
    let got = modal_from_state_space(&a, &b, &phys.c, None).unwrap();
    assert_same_modes(&got, &thesis_chain_modal().unwrap(), 1e-8);
}

#[test]
fn continuous_from_zoh_inverts_a_rigid_body() {
    // 12.5 kg free mass, position output: ẍ = f/m.
    let a = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, 0.0, 0.0]);
    let b = DMatrix::from_column_slice(2, 1, &[0.0, 1.0 / 12.5]);
    let sys = ContinuousStateSpace::new(
        a.clone(),
        b.clone(),
        DMatrix::from_row_slice(1, 2, &[1.0, 0.0]),
        DMatrix::zeros(1, 1),
    )
    .unwrap();
    let d = zoh(&sys, TS_10KHZ).unwrap();
    let (ga, gb) = continuous_from_zoh(&d.a, &d.b, TS_10KHZ).unwrap();
    assert!((&ga - &a).norm() < 1e-9);
    assert!(rel(&gb, &b) < 1e-9);
    let modal = modal_from_state_space(&ga, &gb, &sys.c, None).unwrap();
    assert_eq!(modal.n_rigid, 1);
    assert!((modal.phi_a[(0, 0)] * modal.phi_s[(0, 0)] * 12.5 - 1.0).abs() < 1e-9);
}

/// A planar free body (x, y, θ: 10 kg, 10 kg, 0.4 kg m²) carrying two equal
/// 1 kg masses on 1e6 N/m springs in x and in y (one repeated frequency,
/// √1.1e6 rad/s = 166.9 Hz) and a 0.01 kg m² inertia on a 1e3 N m/rad
/// torsion spring (51.0 Hz); forces Fx, Fy, the torque, and a force pair between the body and
/// the x mass; outputs x, y, θ and the x mass's deflection. Rayleigh damping.
fn planar_body() -> (ModalModel, ContinuousStateSpace) {
    let masses = [10.0, 10.0, 0.4, 1.0, 1.0, 0.01];
    let springs = [(0, Some(3), 1e6), (1, Some(4), 1e6), (2, Some(5), 1e3)];
    let forces = [
        Attach::At(0),
        Attach::At(1),
        Attach::At(2),
        Attach::Between(0, 3),
    ];
    let positions = [
        Attach::At(0),
        Attach::At(1),
        Attach::At(2),
        Attach::Between(0, 3),
    ];
    let net = lumped_network(&masses, &springs, &[], &forces, &positions).unwrap();
    let beta = 2e-5;
    let modal = modal_from_second_order(
        &net.m,
        &net.k,
        None,
        &net.b,
        &net.c,
        Some(ModalDamping::Rayleigh { alpha: 0.0, beta }),
    )
    .unwrap();
    let phys = physical(&net.m, &net.k, &(&net.k * beta), &net.b, &net.c);
    (modal, phys)
}

#[test]
fn planar_free_body_with_repeated_frequency() {
    let (modal, phys) = planar_body();
    assert_eq!(modal.n_rigid, 3);
    assert_eq!(modal.modes(), 6);
    // The x and y modes share one frequency.
    assert!((modal.omega[5] / modal.omega[4] - 1.0).abs() < 1e-12);
    let hz = [0.5, 20.0, 100.0, 170.0, 300.0, 3000.0];
    assert_same_response(&modal.state_space(), &phys, &hz);
    for sys in [phys.clone(), scramble(&phys, 1e3)] {
        let got = modal_from_state_space(&sys.a, &sys.b, &sys.c, None).unwrap();
        assert_eq!(got.n_rigid, 3);
        assert_eq!(got.modes(), 6);
        for i in 0..6 {
            assert!((got.omega[i] - modal.omega[i]).abs() <= 1e-9 * modal.omega[i]);
            assert!((got.zeta[i] - modal.zeta[i]).abs() < 1e-9);
        }
        assert_same_response(&got.state_space(), &phys, &hz);
        // Only the sums over the rigid modes and over the repeated pair are
        // defined; they agree.
        let sum = |m: &ModalModel, r: std::ops::Range<usize>| {
            r.map(|i| m.phi_s.column(i) * m.phi_a.row(i))
                .fold(DMatrix::zeros(4, 4), |acc, x| acc + x)
        };
        for r in [0..3, 3..4, 4..6] {
            let e = rel(&sum(&got, r.clone()), &sum(&modal, r.clone()));
            assert!(e < 1e-9, "modes {r:?}: Σ φ_s φ_aᵀ off by {e:e}");
        }
    }
}

#[test]
fn planar_free_body_with_different_dampers_on_equal_springs() {
    // Dampers 20 and 50 N s/m along the equal x and y springs, 0.02 N m s/rad
    // on the torsion spring: proportional in the body's own directions, not
    // in the arbitrary basis a symmetric eigen-solver gives the repeated pair.
    let masses = [10.0, 10.0, 0.4, 1.0, 1.0, 0.01];
    let springs = [(0, Some(3), 1e6), (1, Some(4), 1e6), (2, Some(5), 1e3)];
    let dampers = [(0, Some(3), 20.0), (1, Some(4), 50.0), (2, Some(5), 0.02)];
    let io = [
        Attach::At(0),
        Attach::At(1),
        Attach::At(2),
        Attach::Between(0, 3),
    ];
    let net = lumped_network(&masses, &springs, &dampers, &io, &io).unwrap();
    let d = net.d.as_ref().unwrap();
    let modal = modal_from_second_order(&net.m, &net.k, Some(d), &net.b, &net.c, None).unwrap();
    // ζ = c / (2 m_r ω) with m_r = 10/11 kg, ω = √1.1e6 rad/s.
    let w = 1.1e6f64.sqrt();
    let zx = 20.0 / (2.0 * (10.0 / 11.0) * w);
    let zy = 50.0 / (2.0 * (10.0 / 11.0) * w);
    assert!((modal.zeta[4] - zx).abs() < 1e-12, "{:?}", modal.zeta);
    assert!((modal.zeta[5] - zy).abs() < 1e-12, "{:?}", modal.zeta);
    let phys = physical(&net.m, &net.k, d, &net.b, &net.c);
    let hz = [0.5, 20.0, 51.0, 100.0, 166.9, 300.0, 3000.0];
    assert_same_response(&modal.state_space(), &phys, &hz);
    let got = modal_from_state_space(&phys.a, &phys.b, &phys.c, None).unwrap();
    assert_eq!(got.n_rigid, 3);
    assert_same_modes(&got, &modal, 1e-9);
}

#[test]
fn continuous_from_zoh_inverts_the_planar_free_body() {
    // Three rigid modes: A_d has three 2×2 Jordan blocks at 1.
    let (modal, phys) = planar_body();
    let d = zoh(&phys, TS_10KHZ).unwrap();
    let (a, b) = continuous_from_zoh(&d.a, &d.b, TS_10KHZ).unwrap();
    let e = (&a - &phys.a).norm() / phys.a.norm();
    assert!(e < 1e-9, "A off by {e:e}");
    let e = rel(&b, &phys.b);
    assert!(e < 1e-9, "B off by {e:e}");
    let got = modal_from_state_space(&a, &b, &phys.c, None).unwrap();
    assert_eq!(got.n_rigid, 3);
    assert_same_response(
        &got.state_space(),
        &modal.state_space(),
        &[0.5, 51.0, 300.0],
    );
}
