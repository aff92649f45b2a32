//! The PID's f_bw: `"auto"` resolved by the design on the scenario's own
//! loop, what it refuses, and the running controller's notches equal to
//! the design report's.

use flexloop_control::freq::{freq_response_discrete, pid_response, prewarped_notch, tustin_point};
use flexloop_control::models::CHAIN_MASS;
use flexloop_control::pid::PidTuning;
use flexloop_design::LoopDesign;
use flexloop_design::pid_bandwidth::{SisoLoop, observer_of};
use flexloop_scenario::{Overrides, Scenario, ScenarioError};
use nalgebra::Complex;
use std::f64::consts::PI;

type C64 = Complex<f64>;
use std::path::Path;

fn shipped_text(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    std::fs::read_to_string(path).unwrap()
}

fn scenario(text: &str) -> Result<Scenario, ScenarioError> {
    Scenario::from_text(Path::new("t.toml"), text, &Overrides::default())
}

fn design(text: &str) -> Result<LoopDesign, ScenarioError> {
    LoopDesign::from_scenario(&scenario(text)?)
}

/// A shipped scenario with `controller.bandwidth_hz` replaced by `value`.
fn with_bandwidth(name: &str, value: &str) -> String {
    let text = shipped_text(name);
    let line = text
        .lines()
        .find(|l| l.starts_with("bandwidth_hz = "))
        .unwrap()
        .to_string();
    text.replace(&line, &format!("bandwidth_hz = {value}"))
}

/// The plant of a design without its disturbance inputs.
fn plant_u(d: &LoopDesign) -> flexloop_control::lti::DiscreteStateSpace {
    flexloop_control::lti::DiscreteStateSpace::new(
        d.plant.a.clone(),
        d.plant.b.columns(0, d.n_inputs).into_owned(),
        d.plant.c.clone(),
        d.plant.d.columns(0, d.n_inputs).into_owned(),
        d.ts,
    )
    .unwrap()
}

#[test]
fn auto_picks_the_largest_bandwidth_meeting_the_6_db_rule_at_10_khz() {
    // docs/control.md §10.1, 10 kHz with one sample of loop delay, the
    // rule over y1..y7: MC+AD with band-pass 43.5 Hz; the scenario's own
    // loop, at y5 alone, allows one grid step more (44.0). AD with
    // band-pass at y5 alone: 38.0 (36.0 over y1..y7). The two-inertia
    // setup (one decoupled axis) at 10 kHz: its shipped 5.0 Hz.
    for (name, want) in [
        ("thesis-mc-ad", 43.5),
        ("thesis-ad", 38.0),
        ("two-inertia", 5.0),
    ] {
        let d = design(&with_bandwidth(name, "\"auto\"")).unwrap();
        let chosen = d.pid_bandwidth.unwrap();
        assert!(chosen.auto);
        assert!((chosen.hz - want).abs() <= 0.5, "{name}: {}", chosen.hz);
        // The same loop, searched again: the chosen f_bw meets the rule
        // with a stable loop, the next grid value does not.
        let plant = plant_u(&d);
        let siso = SisoLoop {
            plant: &plant,
            observer: observer_of(&d.observer),
            loop_delay: d.loop_delay_samples as usize,
            mass: d.pid_mass.unwrap(),
            notches_hz: &[],
        };
        let problem = siso.problem().unwrap();
        assert!(problem.feasible(chosen.hz).unwrap(), "{name}");
        assert!(!problem.feasible(chosen.hz + 0.5).unwrap(), "{name}");
        // The running PID is the one tuned to it.
        let fixed = design(&with_bandwidth(name, &chosen.hz.to_string())).unwrap();
        assert_eq!(fixed.feedback, d.feedback);
        assert!(!fixed.pid_bandwidth.unwrap().auto);
    }
}

#[test]
fn auto_is_refused_where_it_cannot_act_and_bad_strings_name_the_field() {
    // A PID decoupled over several axes: the search tunes one SISO loop.
    let err = design(&with_bandwidth("mimo-example", "\"auto\"")).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("controller.bandwidth_hz"));
    assert!(err.reason.contains("decoupled"), "{err}");
    for bad in ["\"fast\"", "\"Auto\"", "true", "[1.0]"] {
        let err = scenario(&with_bandwidth("thesis-ad", bad)).unwrap_err();
        assert_eq!(
            err.field.as_deref(),
            Some("controller.bandwidth_hz"),
            "{bad}: {err}"
        );
        assert!(err.reason.contains("\"auto\""), "{bad}: {err}");
    }
}

#[test]
fn the_running_notches_are_the_design_reports() {
    // The design report and the bandwidth search evaluate the Tustin PID
    // with pre-warped notches in closed form; the running controller is
    // the state space the processes run. Equal at the notches and near
    // them, and each notch's zero exactly where it was asked for.
    let notches_hz = [470.06, 941.88, 1500.0];
    let text = shipped_text("thesis-original").replace(
        "bandwidth_hz = 35.5",
        "bandwidth_hz = 35.5\nnotches_hz = [470.06, 941.88, 1500.0]",
    );
    let d = design(&text).unwrap();
    let ts = d.ts;
    let running = d.feedback.as_ref().unwrap();
    let warped: Vec<f64> = notches_hz
        .iter()
        .map(|hz| prewarped_notch(2.0 * PI * hz, ts).unwrap())
        .collect();
    let report = PidTuning::single_parameter(CHAIN_MASS, 35.5)
        .unwrap()
        .with_notches(&warped);
    let plain = PidTuning::single_parameter(CHAIN_MASS, 35.5).unwrap();
    let at = |w: f64| -> C64 { freq_response_discrete(running, w).unwrap()[(0, 0)] };
    for hz in notches_hz {
        for r in [0.9, 0.99, 0.999, 1.0, 1.001, 1.01, 1.1] {
            let w = 2.0 * PI * hz * r;
            let want = pid_response(&report, tustin_point(w, ts));
            let got = at(w);
            assert!(
                (got - want).norm() <= 1e-6 * want.norm(),
                "{hz} Hz x {r}: running {got}, report {want}"
            );
        }
        // At the asked frequency each notch is its own depth, 0.01 (the
        // other notches' gains there aside): the zero is exactly there.
        let w = 2.0 * PI * hz;
        let others: C64 = warped
            .iter()
            .zip(notches_hz)
            .filter(|(_, h)| *h != hz)
            .map(|(&wn, _)| {
                let s = tustin_point(w, ts);
                (s * s + s * (0.002 * wn) + wn * wn) / (s * s + s * (0.2 * wn) + wn * wn)
            })
            .product();
        let depth = at(w).norm() / (pid_response(&plain, tustin_point(w, ts)) * others).norm();
        assert!((depth - 0.01).abs() < 1e-6, "{hz} Hz: depth {depth}");
    }
    // Without pre-warping (the former running controller) the 1.5 kHz
    // notch would sit below 1.5 kHz and be far shallower there.
    let unwarped = PidTuning::single_parameter(CHAIN_MASS, 35.5)
        .unwrap()
        .with_notches(&notches_hz.map(|hz| 2.0 * PI * hz))
        .discrete(ts)
        .unwrap();
    let w = 2.0 * PI * 1500.0;
    let ratio = freq_response_discrete(&unwarped, w).unwrap()[(0, 0)].norm() / at(w).norm();
    assert!(ratio > 5.0, "{ratio}");
}
