//! A plant of the user's own (docs/own-plant.md) through `LoopDesign::
//! from_scenario`: the thesis chain entered inline as M, K, B, C and as a
//! physical A, B, C gives the built-in chain's modes and plant; every
//! parameter that is accepted acts as physics says; and every bad model is
//! refused with an error naming the scenario file, the field, the array and
//! the reason.

use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::models;
use flexloop_design::LoopDesign;
use flexloop_scenario::{Overrides, Scenario, ScenarioError};
use nalgebra::{Complex, DMatrix};
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

/// The Table 3.7 MC+AD loop at 10 kHz; `PLANT` is replaced by a `[plant]`
/// table's lines, `OBSERVER` by more `[observer]` lines.
const LOOP: &str = r#"
name = "t"
[loop]
rate_hz = 10000
duration_s = 0.3
[observer]
design = "kalman"
mc = true
ad = true
OBSERVER
[controller]
feedback = "pid"
bandwidth_hz = 35.5
[reference]
shape = "scan"
start_s = 0.01
[plant]
input_limit = 10000
PLANT
"#;

fn text(plant: &str, observer: &str) -> String {
    LOOP.replace("PLANT", plant).replace("OBSERVER", observer)
}

fn design_at(path: &Path, text: &str) -> Result<LoopDesign, ScenarioError> {
    let mut s = Scenario::parse(path, text)?;
    s.apply(&Overrides::default());
    s.validate()?;
    LoopDesign::from_scenario(&s)
}

fn design(plant: &str, observer: &str) -> Result<LoopDesign, ScenarioError> {
    design_at(Path::new("own/t.toml"), &text(plant, observer))
}

/// A matrix as TOML rows, every number to the last bit.
fn toml_matrix(m: &DMatrix<f64>) -> String {
    let rows: Vec<String> = m
        .row_iter()
        .map(|r| {
            let v: Vec<String> = r.iter().map(|x| format!("{x:?}")).collect();
            format!("[{}]", v.join(", "))
        })
        .collect();
    format!("[{}]", rows.join(", "))
}

/// `[plant.arrays]` with these arrays.
fn arrays(entries: &[(&str, &DMatrix<f64>)]) -> String {
    let mut out = String::from("[plant.arrays]\n");
    for (name, m) in entries {
        out.push_str(&format!("{name} = {}\n", toml_matrix(m)));
    }
    out
}

/// The chain of Table 3.2: nodal M, K, the force on ma (B), the sensor on
/// m5 (C), and the D that gives every flexible mode ζ = 0.005
/// (D = M Φ diag(2ζω) Φᵀ M).
struct Chain {
    m: DMatrix<f64>,
    k: DMatrix<f64>,
    d: DMatrix<f64>,
    b: DMatrix<f64>,
    c: DMatrix<f64>,
}

fn chain() -> Chain {
    let nodal = models::thesis_chain();
    let modal = models::thesis_chain_modal().unwrap();
    let phi = modal.shapes.clone().unwrap();
    let two_zeta_omega = DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
        modal.modes(),
        (0..modal.modes()).map(|i| 2.0 * modal.zeta[i] * modal.omega[i]),
    ));
    let m = nodal.mass.clone();
    let d = &m * &phi * two_zeta_omega * phi.transpose() * &m;
    Chain {
        k: nodal.stiffness.clone(),
        d: (&d + d.transpose()) * 0.5,
        b: nodal.actuators.clone(),
        c: nodal.sensors.rows(4, 1).into_owned(),
        m,
    }
}

impl Chain {
    /// The physical first-order model: x = [q; q̇].
    fn state_space(&self) -> (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>) {
        let n = self.m.nrows();
        let m_inv = self.m.clone().try_inverse().unwrap();
        let mut a = DMatrix::zeros(2 * n, 2 * n);
        a.view_mut((0, n), (n, n)).fill_with_identity();
        a.view_mut((n, 0), (n, n)).copy_from(&(-&m_inv * &self.k));
        a.view_mut((n, n), (n, n)).copy_from(&(-&m_inv * &self.d));
        let mut b = DMatrix::zeros(2 * n, self.b.ncols());
        b.view_mut((n, 0), (n, self.b.ncols()))
            .copy_from(&(&m_inv * &self.b));
        let mut c = DMatrix::zeros(self.c.nrows(), 2 * n);
        c.view_mut((0, 0), (self.c.nrows(), n)).copy_from(&self.c);
        (a, b, c)
    }
}

fn second_order_chain(with_d: bool) -> String {
    let c = chain();
    let mut entries = vec![("M", &c.m), ("K", &c.k), ("B", &c.b), ("C", &c.c)];
    if with_d {
        entries.push(("D", &c.d));
    }
    let zeta = if with_d { "" } else { "zeta = 0.005\n" };
    format!("model = \"second-order\"\n{zeta}{}", arrays(&entries))
}

fn state_space_chain() -> String {
    let (a, b, c) = chain().state_space();
    format!(
        "model = \"state-space\"\n{}",
        arrays(&[("A", &a), ("B", &b), ("C", &c)])
    )
}

const BUILT_IN: &str = "model = \"thesis-chain\"\noutput = 5";

/// The discrete frequency response C (zI − A)⁻¹ B of the command input
/// (the first half of the plant's inputs [u; w]) at z = e^{i2πf ts}.
fn response(plant: &DiscreteStateSpace, f_hz: f64) -> Complex<f64> {
    let n = plant.states();
    let z = Complex::from_polar(1.0, 2.0 * PI * f_hz * plant.ts);
    let a = plant.a.map(|v| Complex::new(v, 0.0));
    let zi_a = DMatrix::from_diagonal_element(n, n, z) - a;
    let b = plant.b.column(0).map(|v| Complex::new(v, 0.0));
    let x = zi_a.lu().solve(&b).unwrap();
    let c = plant.c.row(0).map(|v| Complex::new(v, 0.0));
    (c * x)[(0, 0)] + Complex::new(plant.d[(0, 0)], 0.0)
}

/// The largest relative difference of two plants' responses over a grid
/// from 1 Hz to Nyquist, through every resonance.
fn response_difference(own: &DiscreteStateSpace, built_in: &DiscreteStateSpace) -> f64 {
    let nyquist = 0.5 / own.ts;
    (1..=400)
        .map(|i| 1.0 + (nyquist - 1.0) * (i as f64 / 400.0).powi(3))
        .map(|f| {
            let (a, b) = (response(own, f), response(built_in, f));
            (a - b).norm() / b.norm()
        })
        .fold(0.0, f64::max)
}

fn assert_relative(what: &str, own: f64, built_in: f64, tolerance: f64) {
    let off = (own - built_in).abs() / built_in.abs().max(f64::MIN_POSITIVE);
    assert!(
        off <= tolerance,
        "{what}: {own} against {built_in} ({off:e} relative)"
    );
}

/// Frequencies (and ζ) of two designs' flexible modes agree to `tolerance`.
fn assert_same_modes(what: &str, own: &LoopDesign, built_in: &LoopDesign, tolerance: f64) {
    assert_eq!(own.flexible_modes.len(), built_in.flexible_modes.len());
    for (i, (a, b)) in own
        .flexible_modes
        .iter()
        .zip(&built_in.flexible_modes)
        .enumerate()
    {
        assert_relative(&format!("{what}: mode {i} Hz"), a.0, b.0, tolerance);
        assert_relative(&format!("{what}: mode {i} ζ"), a.1, b.1, tolerance);
    }
}

/// The observer's Kalman gain L: the first n_y columns of the block's B,
/// its first n_o rows (the estimate).
fn kalman_gain(d: &LoopDesign) -> DMatrix<f64> {
    let n_o = d.observer.estimate_map.nrows();
    d.observer
        .system
        .b
        .view((0, 0), (n_o, d.n_outputs))
        .into_owned()
}

#[test]
fn the_chain_inline_as_m_k_b_c_is_the_built_in_chain() {
    let built_in = design(BUILT_IN, "").unwrap();
    for with_d in [false, true] {
        let own = design(&second_order_chain(with_d), "").unwrap();
        let what = if with_d { "M, K, D" } else { "M, K, ζ" };
        assert_same_modes(what, &own, &built_in, 1e-9);
        let off = response_difference(&own.plant, &built_in.plant);
        assert!(off < 1e-9, "{what}: the plant's ZOH differs by {off:e}");
        // The observer keeps 470, 942 and 1396 Hz (0.15 f_s), as the thesis.
        assert_eq!(own.observer.estimate_map.nrows(), 9, "{what}");
    }
}

#[test]
fn the_chain_inline_as_a_physical_state_space_is_the_built_in_chain() {
    let built_in = design(BUILT_IN, "").unwrap();
    let own = design(&state_space_chain(), "").unwrap();
    assert_same_modes("A, B, C", &own, &built_in, 1e-9);
    let off = response_difference(&own.plant, &built_in.plant);
    assert!(off < 1e-9, "the plant's ZOH differs by {off:e}");
}

/// The chain as a lumped network with `damping` (lines of `[plant]`).
fn lumped_chain(damping: &str) -> String {
    let mut springs = vec!["{ between = [0, 1], stiffness = 1e8 }".to_string()];
    springs.extend((1..7).map(|i| format!("{{ between = [{i}, {}], stiffness = 9.6e7 }}", i + 1)));
    format!(
        "model = \"lumped\"\n\
         masses_kg = [2.5, {m:?}, {m:?}, {m:?}, {m:?}, {m:?}, {m:?}, {m:?}]\n\
         springs = [{}]\n\
         {damping}\n\
         forces = [{{ at = 0 }}]\n\
         positions = [{{ at = 5 }}]\n",
        springs.join(", "),
        m = 10.0_f64 / 7.0
    )
}

#[test]
fn a_lumped_chain_with_rayleigh_or_dampers_is_damped_as_physics_says() {
    let built_in = design(BUILT_IN, "").unwrap();
    let modal = design(&lumped_chain("zeta = 0.005"), "").unwrap();
    assert_same_modes("lumped, ζ", &modal, &built_in, 1e-9);
    // D = β K: ζ_i = β ω_i / 2, the first mode at 0.005.
    let omega_1 = 2.0 * PI * built_in.flexible_modes[0].0;
    let beta = 2.0 * 0.005 / omega_1;
    let rayleigh = design(
        &lumped_chain(&format!("rayleigh = {{ beta = {beta:?} }}")),
        "",
    )
    .unwrap();
    // Dampers proportional to the springs are the same D = β K.
    let mut dampers = vec![format!(
        "{{ between = [0, 1], damping = {:?} }}",
        beta * 1e8
    )];
    dampers.extend((1..7).map(|i| {
        format!(
            "{{ between = [{i}, {}], damping = {:?} }}",
            i + 1,
            beta * 9.6e7
        )
    }));
    let dashpots = design(
        &lumped_chain(&format!("dampers = [{}]", dampers.join(", "))),
        "",
    )
    .unwrap();
    for (what, d) in [("rayleigh", &rayleigh), ("dampers", &dashpots)] {
        for (i, (&(f, zeta), &(f_0, _))) in d
            .flexible_modes
            .iter()
            .zip(&built_in.flexible_modes)
            .enumerate()
        {
            assert_relative(&format!("{what}: mode {i} Hz"), f, f_0, 1e-9);
            assert_relative(
                &format!("{what}: mode {i} ζ"),
                zeta,
                beta * 2.0 * PI * f_0 / 2.0,
                1e-9,
            );
        }
    }
}

#[test]
fn the_chains_own_parameters_act() {
    let built_in = design(BUILT_IN, "").unwrap();
    let with = |lines: &str| design(&format!("{BUILT_IN}\n{lines}"), "").unwrap();
    // Four times the masses: every frequency halves (ω = √(k/m)), ζ stays.
    let heavy = with(
        "masses_kg = [10.0, 5.714285714285714, 5.714285714285714, 5.714285714285714, \
         5.714285714285714, 5.714285714285714, 5.714285714285714, 5.714285714285714]",
    );
    // Four times the springs: every frequency doubles.
    let stiff = with("stiffness_n_per_m = [4e8, 3.84e8, 3.84e8, 3.84e8, 3.84e8, 3.84e8, 3.84e8]");
    for (i, &(f, zeta)) in built_in.flexible_modes.iter().enumerate() {
        assert_relative(
            &format!("heavy mode {i}"),
            heavy.flexible_modes[i].0,
            f / 2.0,
            1e-9,
        );
        assert_relative(
            &format!("stiff mode {i}"),
            stiff.flexible_modes[i].0,
            2.0 * f,
            1e-9,
        );
        assert_relative(
            &format!("heavy ζ {i}"),
            heavy.flexible_modes[i].1,
            zeta,
            1e-9,
        );
    }
    // ζ = 0.01 on every flexible mode, frequencies as they were.
    let damped = with("zeta = 0.01");
    for (i, &(f, _)) in built_in.flexible_modes.iter().enumerate() {
        assert_relative(
            &format!("mode {i} Hz"),
            damped.flexible_modes[i].0,
            f,
            1e-12,
        );
        assert_eq!(damped.flexible_modes[i].1, 0.01);
    }
    assert_ne!(damped.plant, built_in.plant);
    // The force on m7: the same plant as M, K, C with B on node 7.
    let at_m7 = with("actuator_node = 7");
    let mut c = chain();
    c.b = DMatrix::zeros(8, 1);
    c.b[(7, 0)] = 1.0;
    let second_order = design(
        &format!(
            "model = \"second-order\"\nzeta = 0.005\n{}",
            arrays(&[("M", &c.m), ("K", &c.k), ("B", &c.b), ("C", &c.c)])
        ),
        "",
    );
    // (The PID loop with the force on m7 may not be stable; the plant is
    // what is compared, so either both design or both are refused alike.)
    let second_order = second_order.unwrap();
    assert_same_modes("actuator on m7", &at_m7, &built_in, 1e-12);
    let off = response_difference(&at_m7.plant, &second_order.plant);
    assert!(off < 1e-9, "actuator on m7: {off:e}");
    assert!(response_difference(&at_m7.plant, &built_in.plant) > 1e-3);
}

#[test]
fn observer_noise_and_kalman_weights_act() {
    let plant = second_order_chain(false);
    let gain = |observer: &str| kalman_gain(&design(&plant, observer).unwrap());
    let thesis = gain("");
    // The thesis' weights written out: Q = σ_w² = 1e-4, R = 2e-18.
    assert_eq!(gain("kalman_q = [[1e-4]]\nkalman_r = [[2e-18]]"), thesis);
    let by_sigma = gain(&format!(
        "process_noise = 0.01\nmeasurement_noise = {:?}",
        2e-18_f64.sqrt()
    ));
    assert!(
        (&by_sigma - &thesis).amax() <= 1e-12 * thesis.amax(),
        "σ_w = 0.01, σ = √2 nm: {by_sigma} against the thesis' {thesis}"
    );
    // More process noise (or less measurement noise): a faster observer.
    for observer in [
        "process_noise = 0.1",
        "measurement_noise = 1e-10",
        "kalman_q = [[1e-2]]",
        "kalman_r = [[2e-20]]",
    ] {
        let other = gain(observer);
        assert!(
            (&other - &thesis).amax() > 1e-3 * thesis.amax(),
            "{observer}: the gain did not change"
        );
    }
}

#[test]
fn max_mode_hz_chooses_the_modes_the_observer_keeps() {
    let plant = second_order_chain(false);
    // States: 2 per kept mode (rigid + flexible) and the noise model's one.
    for (observer, states) in [
        ("", 9),
        ("max_mode_hz = 1400", 9),
        ("max_mode_hz = 1390", 7),
        ("max_mode_hz = 500", 5),
        ("max_mode_hz = 2000", 11),
        ("flexible_modes = 1", 5),
    ] {
        let d = design(&plant, observer).unwrap();
        assert_eq!(d.observer.estimate_map.nrows(), states, "{observer}");
    }
}

/// ω of [`two_mass`]'s flexible mode, √(k (1/m1 + 1/m2)).
fn two_mass_omega() -> f64 {
    (1e8_f64 * (1.0 / 2.5 + 1.0 / 10.0)).sqrt()
}

/// A two-mass free structure: 2.5 and 10 kg on 1e8 N/m (1125 Hz), the
/// force on the first mass, the position of the second measured.
fn two_mass() -> Chain {
    let m = DMatrix::from_row_slice(2, 2, &[2.5, 0.0, 0.0, 10.0]);
    let k = DMatrix::from_row_slice(2, 2, &[1e8, -1e8, -1e8, 1e8]);
    Chain {
        d: &k * 1e-6,
        b: DMatrix::from_row_slice(2, 1, &[1.0, 0.0]),
        c: DMatrix::from_row_slice(1, 2, &[0.0, 1.0]),
        m,
        k,
    }
}

fn second_order(arrays_lines: &str, more: &str) -> String {
    format!("model = \"second-order\"\n{more}\n[plant.arrays]\n{arrays_lines}")
}

fn two_mass_second_order(edit: impl FnOnce(&mut Chain)) -> String {
    let mut c = two_mass();
    edit(&mut c);
    format!(
        "model = \"second-order\"\nzeta = 0.01\n{}",
        arrays(&[("M", &c.m), ("K", &c.k), ("B", &c.b), ("C", &c.c)])
    )
}

fn two_mass_state_space(edit: impl FnOnce(&mut Chain)) -> String {
    let mut c = two_mass();
    edit(&mut c);
    let (a, b, cc) = c.state_space();
    format!(
        "model = \"state-space\"\n{}",
        arrays(&[("A", &a), ("B", &b), ("C", &cc)])
    )
}

/// The error's text names the scenario file, `field` and every fragment.
fn assert_refused(
    result: Result<LoopDesign, ScenarioError>,
    file: &str,
    field: &str,
    reason: &[&str],
) {
    let e = match result {
        Ok(_) => panic!("{field} {reason:?}: designed"),
        Err(e) => e,
    };
    let message = e.to_string();
    assert_eq!(e.field.as_deref(), Some(field), "{message}");
    assert!(message.contains(file), "no {file} in: {message}");
    for r in reason {
        assert!(message.contains(r), "no `{r}` in: {message}");
    }
}

fn refused(plant: &str, observer: &str, field: &str, reason: &[&str]) {
    assert_refused(design(plant, observer), "own/t.toml", field, reason);
}

#[test]
fn the_two_mass_models_design() {
    // The base of the refusals below: each refusal is the edit's.
    let so = design(&two_mass_second_order(|_| {}), "").unwrap();
    let ss = design(&two_mass_state_space(|_| {}), "").unwrap();
    assert_relative(
        "1125 Hz",
        so.flexible_modes[0].0,
        two_mass_omega() / (2.0 * PI),
        1e-12,
    );
    assert_relative(
        "state space",
        ss.flexible_modes[0].0,
        so.flexible_modes[0].0,
        1e-9,
    );
    // D = 1e-6 K: ζ = 1e-6 ω / 2.
    assert_relative(
        "ζ",
        ss.flexible_modes[0].1,
        1e-6 * two_mass_omega() / 2.0,
        1e-9,
    );
}

#[test]
fn a_second_order_model_that_is_not_a_structure_is_refused_naming_the_array() {
    let t = "own/t.toml, table `plant.arrays`";
    let f = "plant.arrays";
    refused(
        &two_mass_second_order(|c| c.k = DMatrix::from_element(3, 3, 1.0)),
        "",
        f,
        &[t, "K: is 3x3 but must be 2x2"],
    );
    refused(
        &two_mass_second_order(|c| c.c = DMatrix::from_element(1, 3, 1.0)),
        "",
        f,
        &[t, "C: is 1x3 but must be 1x2"],
    );
    refused(
        &second_order(
            "M = [[2.5, 0.0], [0.0, 10.0]]\nK = [[1e8, -1e8], [-1e8, nan]]\nB = [1.0, 0.0]\nC = [0.0, 1.0]",
            "zeta = 0.01",
        ),
        "",
        f,
        &[t, "array `K`", "row 2, column 2", "NaN", "finite"],
    );
    refused(
        &two_mass_second_order(|c| c.k[(0, 1)] = -0.9e8),
        "",
        f,
        &[t, "K: is not symmetric"],
    );
    refused(
        &two_mass_second_order(|c| c.m[(0, 1)] = 1.0),
        "",
        f,
        &[t, "M: is not symmetric"],
    );
    refused(
        &two_mass_second_order(|c| c.m[(1, 1)] = 0.0),
        "",
        f,
        &[t, "M: is singular"],
    );
    // A grounded structure has no rigid body to put the PID on.
    refused(
        &two_mass_second_order(|c| c.k[(0, 0)] += 1e7),
        "",
        "plant",
        &["no rigid-body mode"],
    );
    // A force pair does not move the rigid body; a relative position does not see it.
    refused(
        &two_mass_second_order(|c| c.b = DMatrix::from_row_slice(2, 1, &[-1.0, 1.0])),
        "",
        f,
        &[t, "B: ", "rigid-body mode uncontrollable"],
    );
    refused(
        &two_mass_second_order(|c| c.c = DMatrix::from_row_slice(1, 2, &[-1.0, 1.0])),
        "",
        f,
        &[t, "C: ", "rigid-body mode unobservable"],
    );
}

#[test]
fn second_order_damping_is_given_once() {
    let c = two_mass();
    let with_d = arrays(&[
        ("M", &c.m),
        ("K", &c.k),
        ("D", &c.d),
        ("B", &c.b),
        ("C", &c.c),
    ]);
    let without_d = arrays(&[("M", &c.m), ("K", &c.k), ("B", &c.b), ("C", &c.c)]);
    let t = "own/t.toml, table `plant.arrays`";
    refused(
        &format!("model = \"second-order\"\nzeta = 0.01\n{with_d}"),
        "",
        "plant.zeta",
        &[t, "gives a damping matrix D"],
    );
    refused(
        &format!("model = \"second-order\"\nrayleigh = {{ beta = 1e-6 }}\n{with_d}"),
        "",
        "plant.rayleigh",
        &[t, "gives a damping matrix D"],
    );
    refused(
        &format!("model = \"second-order\"\n{without_d}"),
        "",
        "plant.zeta",
        &[t, "no damping matrix D", "plant.rayleigh"],
    );
    // An overdamped mode: ζ ≥ 1 from D.
    let heavy = &c.d * 1e4;
    refused(
        &format!(
            "model = \"second-order\"\n{}",
            arrays(&[
                ("M", &c.m),
                ("K", &c.k),
                ("D", &heavy),
                ("B", &c.b),
                ("C", &c.c)
            ])
        ),
        "",
        "plant.arrays",
        &[t, "D: gives mode 1 ζ", "outside [0, 1)"],
    );
    // A damper to the ground damps the rigid body.
    let mut grounded = c.d.clone();
    grounded[(0, 0)] += 10.0;
    refused(
        &format!(
            "model = \"second-order\"\n{}",
            arrays(&[
                ("M", &c.m),
                ("K", &c.k),
                ("D", &grounded),
                ("B", &c.b),
                ("C", &c.c)
            ])
        ),
        "",
        "plant.arrays",
        &[t, "D: damps rigid-body mode 0"],
    );
}

#[test]
fn a_state_space_that_is_not_a_structure_is_refused_naming_the_array() {
    let t = "own/t.toml, table `plant.arrays`";
    let f = "plant.arrays";
    // Negative damping: a growing oscillation.
    refused(
        &two_mass_state_space(|c| c.d = -&c.d),
        "",
        f,
        &[t, "A: has an unstable eigenvalue"],
    );
    // ζ = 1.5: two real poles, not a structural mode.
    refused(
        &two_mass_state_space(|c| c.d *= 1.5 / (1e-6 * two_mass_omega() / 2.0)),
        "",
        f,
        &[t, "A: has a real eigenvalue", "overdamped"],
    );
    refused(
        &two_mass_state_space(|c| c.b = DMatrix::from_row_slice(2, 1, &[-1.0, 1.0])),
        "",
        f,
        &[t, "rigid-body mode uncontrollable"],
    );
    refused(
        &two_mass_state_space(|c| c.c = DMatrix::from_row_slice(1, 2, &[-1.0, 1.0])),
        "",
        f,
        &[t, "rigid-body mode unobservable"],
    );
    // A single integrator, a velocity output, a feedthrough, a wrong shape.
    refused(
        "model = \"state-space\"\n[plant.arrays]\nA = [[0.0]]\nB = [[1.0]]\nC = [[1.0]]",
        "",
        f,
        &[t, "A: has 1 zero eigenvalue(s)", "single integrator"],
    );
    let (a, b, c) = two_mass().state_space();
    let mut velocity = c.clone();
    // q2 + q̇2: sees the rigid body, and a velocity.
    velocity[(0, 3)] = 1.0;
    refused(
        &format!(
            "model = \"state-space\"\n{}",
            arrays(&[("A", &a), ("B", &b), ("C", &velocity)])
        ),
        "",
        f,
        &[t, "C: ", "reads the velocity"],
    );
    let d = DMatrix::from_element(1, 1, 0.1);
    refused(
        &format!(
            "model = \"state-space\"\n{}",
            arrays(&[("A", &a), ("B", &b), ("C", &c), ("D", &d)])
        ),
        "",
        f,
        &[t, "D: is nonzero", "feedthrough"],
    );
    let short_b = b.rows(0, 3).into_owned();
    refused(
        &format!(
            "model = \"state-space\"\n{}",
            arrays(&[("A", &a), ("B", &short_b), ("C", &c)])
        ),
        "",
        f,
        &[t, "B: is 3x1 but must be 4x1"],
    );
    // A discrete model at another rate than the loop's.
    let ts = DMatrix::from_element(1, 1, 1e-3);
    refused(
        &format!(
            "model = \"state-space\"\n{}",
            arrays(&[("A", &a), ("B", &b), ("C", &c), ("ts", &ts)])
        ),
        "",
        f,
        &[t, "`ts` = 0.001 s", "10000 Hz"],
    );
}

#[test]
fn an_array_the_model_does_not_take_is_refused() {
    let c = two_mass();
    let t = "own/t.toml, table `plant.arrays`";
    let x = DMatrix::from_element(1, 1, 1.0);
    refused(
        &format!(
            "model = \"second-order\"\nzeta = 0.01\n{}",
            arrays(&[
                ("M", &c.m),
                ("K", &c.k),
                ("B", &c.b),
                ("C", &c.c),
                ("X", &x)
            ])
        ),
        "",
        "plant.arrays",
        &[t, "`X` is not part of a `second-order` model"],
    );
    refused(
        &format!(
            "model = \"second-order\"\nzeta = 0.01\n{}",
            arrays(&[
                ("M", &c.m),
                ("K", &c.k),
                ("B", &c.b),
                ("C", &c.c),
                ("A", &c.k)
            ])
        ),
        "",
        "plant.arrays",
        &[t, "`A` is not part of a `second-order` model"],
    );
    let (a, b, cc) = c.state_space();
    refused(
        &format!(
            "model = \"state-space\"\n{}",
            arrays(&[("A", &a), ("B", &b), ("C", &cc), ("M", &c.m)])
        ),
        "",
        "plant.arrays",
        &[t, "`M` is not part of a `state-space` model"],
    );
    // A missing array is named with those present.
    refused(
        &format!(
            "model = \"second-order\"\nzeta = 0.01\n{}",
            arrays(&[("M", &c.m), ("B", &c.b), ("C", &c.c)])
        ),
        "",
        "plant.arrays",
        &[t, "array `K`: missing (the arrays present: B, C, M)"],
    );
}

/// A directory of this test's own for model files.
fn files_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "flexloop-design-own-plant-{}-{test}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn model_files_that_cannot_be_read_are_refused_naming_them() {
    let dir = files_dir("files");
    let scenario = dir.join("own.toml");
    let with_file = |file: &str| text(&format!("model = \"state-space\"\nfile = \"{file}\""), "");
    let missing = dir.join("nope.npz").display().to_string();
    assert_refused(
        design_at(&scenario, &with_file("nope.npz")),
        "own.toml",
        "plant.file",
        &[&missing, "cannot read the file"],
    );
    assert_refused(
        design_at(&scenario, &with_file("plant.csv")),
        "own.toml",
        "plant.file",
        &[
            "plant.csv",
            "unknown model file type `.csv`",
            ".npz",
            ".mat",
        ],
    );
    // MATLAB's v7.3 (HDF5): the 128-byte header, the HDF5 signature at 512.
    let mut v73 =
        b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan 13 2025 HDF5 schema 1.00 ."
            .to_vec();
    v73.resize(116, b' ');
    v73.extend_from_slice(&[0; 8]);
    v73.extend_from_slice(&[0x00, 0x02, b'I', b'M']);
    v73.resize(512, 0);
    v73.extend_from_slice(b"\x89HDF\r\n\x1a\n");
    v73.resize(2048, 0);
    std::fs::write(dir.join("plant.mat"), &v73).unwrap();
    assert_refused(
        design_at(&scenario, &with_file("plant.mat")),
        "own.toml",
        "plant.file",
        &["plant.mat", "v7.3", "-v7"],
    );
    // A file and inline arrays at once.
    let both = text(
        "model = \"state-space\"\nfile = \"plant.mat\"\n[plant.arrays]\nA = [[0.0]]",
        "",
    );
    assert_refused(
        design_at(&scenario, &both),
        "own.toml",
        "plant.arrays",
        &["not both"],
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

fn lumped(lines: &str) -> String {
    format!(
        "model = \"lumped\"\nmasses_kg = [2.5, 10.0]\n\
         springs = [{{ between = [0, 1], stiffness = 1e8 }}]\n{lines}"
    )
}

#[test]
fn lumped_networks_are_checked_entry_by_entry() {
    let ok = "zeta = 0.01\nforces = [{ at = 0 }]\npositions = [{ at = 1 }]";
    design(&lumped(ok), "").unwrap();
    refused(
        &lumped(
            &format!("{ok}\ndampers = [{{ between = [1, 1], damping = 3.0 }}]")
                .replace("zeta = 0.01\n", ""),
        ),
        "",
        "plant.dampers",
        &["entry 0 joins mass 1 to itself"],
    );
    refused(
        &format!(
            "model = \"lumped\"\nmasses_kg = [2.5, 10.0]\n\
             springs = [{{ between = [0, 0], stiffness = 1e8 }}]\n{ok}"
        ),
        "",
        "plant.springs",
        &["entry 0 joins mass 0 to itself"],
    );
    refused(
        &format!(
            "model = \"lumped\"\nmasses_kg = [2.5, 10.0]\n\
             springs = [{{ between = [0, 1], stiffness = 1e8 }}, {{ at = 2, stiffness = 1.0 }}]\n{ok}"
        ),
        "",
        "plant.springs",
        &["entry 1 names mass 2", "masses 0..2"],
    );
    refused(
        &lumped("zeta = 0.01\nforces = []\npositions = [{ at = 1 }]"),
        "",
        "plant.forces",
        &["at least one force"],
    );
    refused(
        &lumped("zeta = 0.01\nforces = [{ at = 0 }]\npositions = [{ between = [0, 5] }]"),
        "",
        "plant.positions",
        &["names mass 5"],
    );
    refused(
        &lumped("forces = [{ at = 0 }]\npositions = [{ at = 1 }]"),
        "",
        "plant.zeta",
        &["needs its damping"],
    );
    refused(
        &lumped(&format!("{ok}\nrayleigh = {{ beta = 1e-6 }}")),
        "",
        "plant.zeta",
        &["give one of zeta, rayleigh and dampers"],
    );
    // A relative position does not see the rigid body.
    refused(
        &lumped("zeta = 0.01\nforces = [{ at = 0 }]\npositions = [{ between = [0, 1] }]"),
        "",
        "plant.positions",
        &["rigid-body mode unobservable"],
    );
    refused(
        &lumped("zeta = 0.01\nforces = [{ between = [0, 1] }]\npositions = [{ at = 1 }]"),
        "",
        "plant.forces",
        &["rigid-body mode uncontrollable"],
    );
}

#[test]
fn fields_that_do_not_apply_to_the_model_are_refused() {
    let ss = two_mass_state_space(|_| {});
    let with = |line: &str| ss.replacen("\n", &format!("\n{line}\n"), 1);
    refused(
        &with("zeta = 0.01"),
        "",
        "plant.zeta",
        &["does not apply to `state-space`"],
    );
    refused(
        &with("rayleigh = { beta = 1e-6 }"),
        "",
        "plant.rayleigh",
        &["does not apply to `state-space`"],
    );
    refused(
        &with("output = 1"),
        "",
        "plant.output",
        &["`state-space` measures the outputs"],
    );
    refused(
        &with("masses_kg = [1.0, 2.0]"),
        "",
        "plant.masses_kg",
        &["does not apply to `state-space`"],
    );
    refused(
        &with("actuator_node = 1"),
        "",
        "plant.actuator_node",
        &["does not apply"],
    );
    refused(
        &with("forces = [{ at = 0 }]"),
        "",
        "plant.forces",
        &["does not apply"],
    );
    refused(
        &format!("{BUILT_IN}\nfile = \"plant.npz\""),
        "",
        "plant.file",
        &["does not apply to `thesis-chain`"],
    );
    refused(
        BUILT_IN,
        "max_mode_hz = 1000",
        "observer.max_mode_hz",
        &["built-in"],
    );
    refused(
        &ss,
        "max_mode_hz = 1000\nflexible_modes = 1",
        "observer.max_mode_hz",
        &["not both"],
    );
    refused(
        &ss,
        "flexible_modes = 2",
        "observer.flexible_modes",
        &["1 flexible mode"],
    );
}

#[test]
fn kalman_weights_of_the_wrong_shape_or_sign_are_refused() {
    let ss = two_mass_state_space(|_| {});
    refused(
        &ss,
        "kalman_q = [[1.0, 0.0], [0.0, 1.0]]",
        "observer.kalman_q",
        &["1×1", "one row per input"],
    );
    refused(
        &ss,
        "kalman_q = [[-1e-4]]",
        "observer.kalman_q",
        &["positive semi-definite"],
    );
    refused(
        &ss,
        "kalman_r = [[0.0]]",
        "observer.kalman_r",
        &["positive definite"],
    );
    refused(
        &ss,
        "kalman_r = [[1e-18, 1e-18]]",
        "observer.kalman_r",
        &["1×1"],
    );
    refused(
        &ss,
        "kalman_q = [[1e-4]]\nprocess_noise = 0.01",
        "observer.kalman_q",
        &["not both"],
    );
    refused(
        &ss,
        "kalman_r = [[1e-18]]\nmeasurement_noise = 1e-9",
        "observer.kalman_r",
        &["not both"],
    );
    // Two free two-mass structures side by side: two inputs, two outputs,
    // two rigid modes; Q and R are 2×2.
    let mimo = "model = \"lumped\"\nmasses_kg = [2.5, 10.0, 2.5, 10.0]\n\
        springs = [{ between = [0, 1], stiffness = 1e8 }, { between = [2, 3], stiffness = 1e8 }]\n\
        zeta = 0.01\nforces = [{ at = 0 }, { at = 2 }]\npositions = [{ at = 1 }, { at = 3 }]";
    refused(
        mimo,
        "kalman_r = [[1e-18, 1e-18], [1e-18, 1e-18]]",
        "observer.kalman_r",
        &["positive definite", "eigenvalues"],
    );
    refused(
        mimo,
        "kalman_r = [[1e-18, 0.0], [1e-19, 1e-18]]",
        "observer.kalman_r",
        &["symmetric"],
    );
    refused(
        mimo,
        "kalman_q = [[1e-4, 2e-4], [2e-4, 1e-4]]",
        "observer.kalman_q",
        &["positive semi-definite"],
    );
    refused(mimo, "kalman_q = [[1e-4]]", "observer.kalman_q", &["2×2"]);
    // Accepted, they act: a correlated Q is another gain than a diagonal one.
    let gain = |observer: &str| kalman_gain(&design(mimo, observer).unwrap());
    let diagonal =
        gain("kalman_q = [[1e-4, 0.0], [0.0, 1e-4]]\nkalman_r = [[2e-18, 0.0], [0.0, 2e-18]]");
    assert_eq!(diagonal, gain(""));
    let correlated =
        gain("kalman_q = [[1e-4, 5e-5], [5e-5, 1e-4]]\nkalman_r = [[2e-18, 0.0], [0.0, 2e-18]]");
    assert!((&correlated - &diagonal).amax() > 1e-3 * diagonal.amax());
}
