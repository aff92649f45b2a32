//! The loop designs of every model: dimensions, the sensor's position, the
//! stand-ins' decoupled PID and feedforward, and the field each refusal names.

use flexloop_control::models;
use flexloop_control::pid::PidTuning;
use flexloop_design::LoopDesign;
use flexloop_design::checks::{MAX_CHECKED_SAMPLES, check_horizon, feedforward_peak};
use flexloop_design::reference::Reference;
use flexloop_scenario::{Overrides, Scenario, ScenarioError};
use nalgebra::{Complex, DMatrix, DVector};
use std::f64::consts::PI;
use std::path::Path;

const LECTURE: &str = r#"
name = "t"
[loop]
rate_hz = 10000
[plant]
model = "double-integrator"
[observer]
design = "state-feedback"
"#;

const THESIS: &str = r#"
name = "t"
[loop]
rate_hz = 10000
duration_s = 0.3
[plant]
model = "thesis-chain"
input_limit = 2000
[observer]
design = "kalman"
mc = true
ad = true
[controller]
feedback = "pid"
bandwidth_hz = 35.5
[reference]
shape = "scan"
start_s = 0.01
"#;

fn design(text: &str) -> Result<LoopDesign, ScenarioError> {
    let mut s = Scenario::parse(Path::new("t.toml"), text)?;
    s.apply(&Overrides::default());
    s.validate()?;
    LoopDesign::from_scenario(&s)
}

#[test]
fn design_has_consistent_dimensions() {
    for text in [LECTURE, THESIS] {
        let d = design(text).unwrap();
        assert_eq!(d.plant.inputs(), 2 * d.n_inputs);
        assert_eq!(d.plant.outputs(), d.n_outputs);
        assert_eq!(d.observer.system.inputs(), d.n_outputs + d.n_inputs);
        assert_eq!(d.observer.system.outputs(), d.n_outputs + d.n_inputs);
        assert_eq!(
            d.output_prediction.c.ncols(),
            d.observer.estimate_map.nrows()
        );
    }
}

#[test]
fn thesis_chain_has_the_full_model_and_a_reduced_observer() {
    let d = design(THESIS).unwrap();
    // 8 modes in the plant, rigid + 3 flexible (+ noise model) in the observer.
    assert_eq!(d.plant.states(), 16);
    assert_eq!(d.flexible_modes.len(), 7);
    assert!((d.flexible_modes[0].0 - 470.06).abs() < 0.01);
    assert_eq!(d.observer.estimate_map.nrows(), 9);
    // The scan starts 10 ms into the run.
    assert_eq!(d.reference.scan_windows(0.3), vec![(0.05, 0.18)]);
}

#[test]
fn extra_delay_adds_the_pending_input() {
    let d = design(&THESIS.replace(
        "bandwidth_hz = 35.5",
        "bandwidth_hz = 35.5\nextra_delay_samples = 1",
    ))
    .unwrap();
    assert_eq!(d.loop_delay_samples, 2);
    assert_eq!(d.observer.system.inputs(), 3);
}

#[test]
fn unstable_design_names_the_tuning() {
    let err = design(&THESIS.replace("bandwidth_hz = 35.5", "bandwidth_hz = 400")).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("controller.bandwidth_hz"));
    assert!(err.reason.contains("unstable"), "{err}");
}

#[test]
fn trajectory_beyond_the_actuator_is_refused() {
    let err = design(&THESIS.replace("input_limit = 2000", "input_limit = 500")).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("plant.input_limit"));
    assert!(err.reason.contains("1250"), "{err}");
}

#[test]
fn scan_needs_a_lead_in() {
    let err = design(&THESIS.replace("start_s = 0.01", "start_s = 0.0")).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("reference.start_s"));
}

#[test]
fn mc_without_an_observer_is_refused() {
    // MC (and AD) are settings of a Kalman observer: they do not apply to none.
    let err = design(&THESIS.replace("design = \"kalman\"", "design = \"none\"")).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("observer.mc"));
    assert!(err.reason.contains("does not apply"), "{err}");
}

/// THESIS with the sensor moved from `output` (default 5) to a position.
fn at_position(p: &str) -> String {
    THESIS.replace(
        "model = \"thesis-chain\"",
        &format!("model = \"thesis-chain\"\nsensor_position = {p}"),
    )
}

#[test]
fn an_integer_sensor_position_is_that_output_exactly() {
    for (position, output) in [("5.0", 5), ("1", 1), ("7.0", 7)] {
        let by_output = design(&THESIS.replace(
            "model = \"thesis-chain\"",
            &format!("model = \"thesis-chain\"\noutput = {output}"),
        ))
        .unwrap();
        let by_position = design(&at_position(position)).unwrap();
        // Bit for bit: the same sensor row, hence the same Kalman gain,
        // observer block, feedforward block and closed loop.
        assert_eq!(by_position.plant, by_output.plant, "{position}");
        assert_eq!(by_position.observer, by_output.observer, "{position}");
        assert_eq!(by_position.output_prediction, by_output.output_prediction);
        assert_eq!(
            by_position.modified_feedforward,
            by_output.modified_feedforward
        );
        assert_eq!(by_position.closed_loop, by_output.closed_loop);
    }
}

#[test]
fn a_sensor_between_nodes_interpolates_c_and_t_dc_but_not_b() {
    let [d4, d425, d5] = ["4", "4.25", "5"].map(|p| design(&at_position(p)).unwrap());
    // Plant: B is the actuator's (position-independent), C is 3/4 of m4's
    // row plus 1/4 of m5's.
    assert_eq!(d425.plant.b, d4.plant.b);
    let want = &d4.plant.c * 0.75 + &d5.plant.c * 0.25;
    assert!((&d425.plant.c - &want).amax() < 1e-15);
    assert!((&d425.plant.c - &d4.plant.c).amax() > 1e-3);
    // Observer model: C_t and T_DC (= D) follow the sensor linearly.
    let (p4, p425, p5) = (
        &d4.output_prediction,
        &d425.output_prediction,
        &d5.output_prediction,
    );
    assert!((&p425.c - (&p4.c * 0.75 + &p5.c * 0.25)).amax() < 1e-15);
    assert!((&p425.d - (&p4.d * 0.75 + &p5.d * 0.25)).amax() < 1e-24);
    assert!(p425.d[(0, 0)] != p4.d[(0, 0)]);
    // The actuator mass itself (collocated) is a position too.
    design(&at_position("0")).unwrap();
}

#[test]
fn bad_sensor_positions_name_the_field() {
    for bad in ["7.5", "-0.25", "nan", "inf"] {
        let err = design(&at_position(bad)).unwrap_err();
        assert_eq!(err.field.as_deref(), Some("plant.sensor_position"), "{bad}");
        assert!(err.reason.contains("[0, 7]"), "{bad}: {err}");
        assert!(err.to_string().contains("t.toml"), "{err}");
    }
    // Both ways of placing the sensor at once.
    let both = at_position("4.25").replace("input_limit", "output = 5\ninput_limit");
    let err = design(&both).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("plant.sensor_position"));
    assert!(err.reason.contains("not both"), "{err}");
    // Only the chain has positions.
    let lecture = LECTURE.replace(
        "model = \"double-integrator\"",
        "model = \"double-integrator\"\nsensor_position = 1.0",
    );
    let err = design(&lecture).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("plant.sensor_position"));
    assert!(err.reason.contains("thesis chain"), "{err}");
    // A wrong type is a parse error that names the key.
    let err = Scenario::parse(Path::new("t.toml"), &at_position("\"m5\"")).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("plant.sensor_position"), "{err}");
}

#[test]
fn set_sensor_position_overrides_a_files_output() {
    let mut s = Scenario::parse(
        Path::new("t.toml"),
        &THESIS.replace("input_limit", "output = 3\ninput_limit"),
    )
    .unwrap();
    assert!(s.plant.output_given);
    s.set_sensor_position(5.0);
    s.validate().unwrap();
    assert_eq!(s.plant.sensor_node(), 5.0);
    let d = LoopDesign::from_scenario(&s).unwrap();
    assert_eq!(d.plant, design(THESIS).unwrap().plant);
}

fn shipped(name: &str) -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    Scenario::load(&path, &Overrides::default()).unwrap()
}

fn shipped_text(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    std::fs::read_to_string(path).unwrap()
}

#[test]
fn stand_in_models_have_their_dimensions_and_a_decoupled_pid() {
    for (name, ny, nu, flexible, observer_states) in [
        // rigid + 2 flexible modes, noise model on 2 inputs
        ("mimo-example", 2, 2, 3, 10),
        // 3 rigid + 8 flexible, noise model on 3 inputs
        ("oat-like", 3, 3, 8, 25),
        // 1 rigid + 1 flexible, noise model on 1 input
        ("two-inertia", 1, 1, 1, 5),
    ] {
        let d = LoopDesign::from_scenario(&shipped(name)).unwrap();
        assert_eq!((d.n_outputs, d.n_inputs), (ny, nu), "{name}");
        assert_eq!(d.output_names.len(), ny);
        assert_eq!(d.reference_direction.len(), ny);
        assert_eq!(d.flexible_modes.len(), flexible, "{name}");
        assert_eq!(d.observer.estimate_map.nrows(), observer_states, "{name}");
        let fb = d.feedback.as_ref().unwrap();
        assert_eq!((fb.inputs(), fb.outputs()), (ny, nu));
        assert_eq!(d.feedforward.len(), nu);
        assert!(d.modified_feedforward.is_some());
    }
}

#[test]
fn a_uniform_chain_has_an_observer_of_twice_its_nodes() {
    let text = shipped_text("uniform-chain");
    // 64 nodes (128 states) designs too, in 20 s of a debug build: `bench --sweep` runs it.
    for nodes in [2, 8, 24] {
        let d = design(&text.replace("nodes = 32", &format!("nodes = {nodes}"))).unwrap();
        assert_eq!(d.observer.estimate_map.nrows(), 2 * nodes);
        assert_eq!(d.flexible_modes.len(), nodes - 1);
        assert_eq!(d.plant.states(), 2 * nodes);
        let radius =
            flexloop_control::linalg::spectral_radius(&d.closed_loop.as_ref().unwrap().a).unwrap();
        assert!(radius < 1.0, "{nodes} nodes: {radius}");
    }
    for (replace, with, reason) in [
        ("nodes = 32\n", "", "needs its number of masses"),
        ("nodes = 32", "nodes = 65", "must lie in 2..=64"),
        ("nodes = 32", "nodes = 32\noutput = 3", "one sensor"),
    ] {
        let e = design(&text.replace(replace, with))
            .unwrap_err()
            .to_string();
        let field = if reason == "one sensor" {
            "plant.output"
        } else {
            "plant.nodes"
        };
        assert!(e.contains(field) && e.contains(reason), "{e}");
    }
    let e = design(&shipped_text("oat-like").replace("[plant]", "[plant]\nnodes = 4"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("plant.nodes") && e.contains("only the uniform chain"),
        "{e}"
    );
}

#[test]
fn the_decoupled_pid_is_one_pid_per_rigid_axis() {
    // Υ P Γ has the identity over s² as its rigid part, so Υ⁻¹… no: the
    // controller seen through the decoupling, Γ⁻¹ C Υ⁻¹, must be the
    // single-parameter PID on 1/s² on every axis and zero across.
    let s = shipped("mimo-example");
    let d = LoopDesign::from_scenario(&s).unwrap();
    let full = models::mimo_example().unwrap();
    let (_, gamma, upsilon) = full.rigid_body_decoupled().unwrap();
    let one = PidTuning::single_parameter(1.0, s.controller.bandwidth_hz.hz().unwrap())
        .unwrap()
        .discrete(d.ts)
        .unwrap();
    let fb = d.feedback.unwrap();
    for hz in [1.0, 30.0, 300.0] {
        let w = 2.0 * PI * hz;
        let c = flexloop_control::freq::freq_response_discrete(&fb, w).unwrap();
        let to_c = |m: &DMatrix<f64>| m.map(|v| Complex::new(v, 0.0));
        let seen = to_c(&gamma.clone().try_inverse().unwrap())
            * c
            * to_c(&upsilon.clone().try_inverse().unwrap());
        let want = flexloop_control::freq::freq_response_discrete(&one, w).unwrap()[(0, 0)];
        for i in 0..2 {
            for j in 0..2 {
                let expect = if i == j { want } else { Complex::new(0.0, 0.0) };
                assert!(
                    (seen[(i, j)] - expect).norm() < 1e-9 * want.norm(),
                    "{hz} Hz"
                );
            }
        }
    }
}

#[test]
fn the_rigid_body_feedforward_moves_the_direction_and_holds_the_rest() {
    // u0 = Γ Υ d r̈ drives the rigid body exactly: through the rigid part
    // of the plant (φ_s,rig φ_a,rigᵀ) it gives d r̈.
    let d = LoopDesign::from_scenario(&shipped("mimo-example")).unwrap();
    let full = models::mimo_example().unwrap();
    let acc = DVector::from_iterator(2, d.feedforward.iter().map(|g| g[2]));
    let rigid = full.phi_s.columns(0, 2) * full.phi_a.rows(0, 2);
    let moved = rigid * acc;
    assert!(
        (moved[0] - 1.0).abs() < 1e-12 && moved[1].abs() < 1e-12,
        "{moved}"
    );
    // The snap gain takes out the flexible modes' static compliance.
    assert!(
        d.feedforward
            .iter()
            .all(|g| g[4] != 0.0 && g[1] == 0.0 && g[3] == 0.0)
    );
}

#[test]
fn mimo_settings_that_do_not_fit_the_plant_name_their_field() {
    let cases = [
        // A MIMO reference on the SISO chain.
        (
            THESIS.replace("start_s = 0.01", "start_s = 0.01\ndirection = [1.0, 0.0]"),
            "reference.direction",
            "1 output",
        ),
        // An observer keeping more flexible modes than the plant has.
        (
            shipped_text("two-inertia").replace(
                "design = \"kalman\"",
                "design = \"kalman\"\nflexible_modes = 2",
            ),
            "observer.flexible_modes",
            "1 flexible mode",
        ),
        // Four-gain feedforward on a two-input plant.
        (
            format!(
                "{}\n[controller.feedforward]\nacc = 10.0\n",
                shipped_text("mimo-example")
            ),
            "controller.feedforward",
            "rigid-body",
        ),
        // Three output directions on two outputs.
        (
            shipped_text("mimo-example")
                .replace("direction = [1.0, 0.0]", "direction = [1.0, 0.0, 0.0]"),
            "reference.direction",
            "2 outputs",
        ),
    ];
    for (text, field, fragment) in cases {
        let err = design(&text).unwrap_err();
        assert_eq!(err.field.as_deref(), Some(field), "{err}");
        assert!(err.reason.contains(fragment), "{err}");
    }
    // Schema-level: encoders on another model, output on a MIMO model,
    // a two-inertia output that does not exist, a zero direction.
    for (text, field) in [
        (
            THESIS.replace("input_limit", "encoders = [1, 2, 3]\ninput_limit"),
            "plant.encoders",
        ),
        (
            shipped_text("oat-like").replace("encoders = [1, 2, 3]", "encoders = [1, 2, 2]"),
            "plant.encoders",
        ),
        (
            shipped_text("mimo-example").replace("input_limit", "output = 1\ninput_limit"),
            "plant.output",
        ),
        (
            shipped_text("two-inertia").replace("output = 1", "output = 3"),
            "plant.output",
        ),
        (
            shipped_text("mimo-example")
                .replace("direction = [1.0, 0.0]", "direction = [0.0, 0.0]"),
            "reference.direction",
        ),
    ] {
        let err = design(&text).unwrap_err();
        assert_eq!(err.field.as_deref(), Some(field), "{err}");
    }
}

#[test]
fn a_mimo_design_checks_stability_and_every_actuator() {
    let text = shipped_text("mimo-example");
    let err = design(&text.replace("bandwidth_hz = 37.0", "bandwidth_hz = 400.0")).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("controller.bandwidth_hz"));
    assert!(err.reason.contains("unstable"), "{err}");
    // Without MC and AD the 37 Hz loop cannot live with the 161 Hz mode.
    // (the Kalman observer's settings go with it: they would not apply).
    let kalman_only = ["mc =", "ad =", "q_nu =", "damping_target =", "bandpass_q ="];
    let bare: String = text
        .replace("design = \"kalman\"", "design = \"none\"")
        .replace("\"modified\"", "\"plain\"")
        .lines()
        .filter(|l| !kalman_only.iter().any(|k| l.starts_with(k)))
        .map(|l| format!("{l}\n"))
        .collect();
    assert!(design(&bare).unwrap_err().reason.contains("unstable"));
    let err = design(&text.replace("input_limit = 2000.0", "input_limit = 100.0")).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("plant.input_limit"));
    assert!(err.reason.contains("on input 1"), "{err}");
}

#[test]
fn a_scanned_sensor_is_designed_and_checked() {
    let d = LoopDesign::from_scenario(&shipped("thesis-sensor-scan-ad")).unwrap();
    let scan = d.sensor_scan.as_ref().unwrap();
    // 29 grid points over the chain; the position follows the reference.
    let o = scan.observer.as_ref().unwrap();
    assert_eq!(o.schedule.models().grid().points(), 29);
    assert_eq!(scan.position_at(scan.r_start), 0.0);
    assert_eq!(scan.position_at(scan.r_end), 7.0);
    assert!((scan.position_at(0.5 * (scan.r_start + scan.r_end)) - 3.5).abs() < 1e-12);
    // The plant row at a node is that node's output row.
    let mut row = vec![0.0; d.plant.states()];
    scan.plant_row(5.0, &mut row);
    let y5 = models::thesis_plant(5).unwrap().state_space().c;
    assert!((DMatrix::from_row_slice(1, row.len(), &row) - y5).amax() < 1e-15);
    // Bad scans name the field.
    let text = shipped_text("thesis-sensor-scan-ad");
    for (from, to, field) in [
        (
            "sensor_scan = [0.0, 7.0]",
            "sensor_scan = [0.0, 7.5]",
            "plant.sensor_scan",
        ),
        (
            "sensor_scan = [0.0, 7.0]",
            "sensor_scan = [2.0, 2.0]",
            "plant.sensor_scan",
        ),
        (
            "sensor_scan = [0.0, 7.0]",
            "sensor_scan = [0.0, 7.0]\noutput = 5",
            "plant.sensor_scan",
        ),
        ("shape = \"scan\"", "shape = \"sine\"", "plant.sensor_scan"),
        (
            "feedforward_form = \"plain\"",
            "feedforward_form = \"modified\"",
            "controller.feedforward_form",
        ),
        (
            "\nscheduling = \"interpolated\"",
            "\nscheduling = \"nearest\"",
            "observer.scheduling",
        ),
    ] {
        let Err(err) = design(&text.replacen(from, to, 1)) else {
            panic!("{to}: accepted");
        };
        assert_eq!(err.field.as_deref(), Some(field), "{to}: {err}");
    }
}

#[test]
fn unknown_model_names_the_field() {
    let err = design(&LECTURE.replace("double-integrator", "triple-integrator")).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("plant.model"));
    assert!(err.to_string().contains("t.toml"));
}

#[test]
fn a_repeating_scan_is_checked_over_one_period_with_the_same_peak() {
    let text = THESIS
        .replace("duration_s = 0.3", "duration_s = 3600")
        .replace("start_s = 0.01", "start_s = 0.01\nrepeat_s = 0.25");
    let mut s = Scenario::parse(Path::new("t.toml"), &text).unwrap();
    s.apply(&Overrides::default());
    s.validate().unwrap();
    let d = LoopDesign::from_scenario(&s).unwrap();
    let horizon = check_horizon(&s, &d.reference, d.loop_delay_samples, d.ts);
    // Forth and back once after the lead-in, not the hour.
    assert!((0.51..0.52).contains(&horizon), "{horizon}");
    // Three periods hold the same peak as one, at the same place in the period.
    let one = feedforward_peak(&d.reference, &d.feedforward, (horizon / d.ts) as u64, d.ts);
    let three = feedforward_peak(&d.reference, &d.feedforward, (1.51 / d.ts) as u64, d.ts);
    assert!(one.0 > 1000.0, "{one:?}");
    assert!((one.0 - three.0).abs() <= 1e-9 * one.0, "{one:?} {three:?}");
    // A period that is not a whole number of samples: the whole run,
    // up to the bound.
    let Reference::Scan { setpoint, .. } = &d.reference else {
        panic!("a scan");
    };
    let odd = Reference::Scan {
        setpoint: setpoint.clone(),
        start_s: 0.01,
        repeat_s: 0.25003,
        scale: 1.0,
    };
    let horizon = check_horizon(&s, &odd, d.loop_delay_samples, d.ts);
    assert!(
        (horizon - MAX_CHECKED_SAMPLES as f64 * d.ts).abs() < 1e-6,
        "{horizon}"
    );
}

/// `loop.command_deadline_us`: inside the period, without an extra sample
/// of delay, and only where the design can use it; each refusal names the
/// field and says why.
#[test]
fn a_command_deadline_is_refused_where_it_cannot_act() {
    let with = |text: &str, deadline: &str| {
        text.replace(
            "rate_hz = 10000\n",
            &format!("rate_hz = 10000\n{deadline}\n"),
        )
    };
    for (text, reason) in [
        (
            with(THESIS, "command_deadline_us = 0.0"),
            "strictly between 0",
        ),
        (
            with(THESIS, "command_deadline_us = -5.0"),
            "strictly between 0",
        ),
        (
            with(THESIS, "command_deadline_us = 100.0"),
            "sample period 100 µs",
        ),
        (
            with(THESIS, "command_deadline_us = 30.0")
                .replace("[controller]\n", "[controller]\nextra_delay_samples = 1\n"),
            "extra sample",
        ),
        (
            with(LECTURE, "command_deadline_us = 30.0"),
            "placed for one sample of delay",
        ),
        (
            with(THESIS, "command_deadline_us = 30.0").replace(
                "design = \"kalman\"",
                "design = \"io\"\ncorrection = \"observer-based\"",
            ),
            "observer.design = \"io\"",
        ),
    ] {
        let e = design(&text).unwrap_err();
        assert_eq!(e.field.as_deref(), Some("loop.command_deadline_us"), "{e}");
        assert!(e.reason.contains(reason), "{e}");
    }
    // At the deadline the design is the two-piece plant and counts on it.
    let d = design(&with(THESIS, "command_deadline_us = 30.0")).unwrap();
    assert_eq!(d.command_deadline_s, Some(30e-6));
    let one = design(THESIS).unwrap();
    assert_eq!(one.command_deadline_s, None);
    assert!(d.plant.d[(0, 0)] != 0.0 && one.plant.d.amax() == 0.0);
    assert_eq!(
        d.plant.b.column(1),
        one.plant.b.column(1),
        "w: whole samples"
    );
}
