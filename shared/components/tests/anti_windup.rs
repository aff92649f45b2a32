//! The feedback's tracking anti-windup: a clamped command, or one the plant
//! did not apply (it held the input, or its safe action acted), does not
//! wind up the PID's integrator; in the linear range nothing changes.

use flexloop_components::ControllerCore;
use flexloop_design::LoopDesign;
use flexloop_protocol::{Command, Estimate, Measurement, NO_SEQ};
use flexloop_scenario::Scenario;
use std::path::Path;

/// The two-inertia PID (5 Hz) holding θ1 at 0, without MC or AD: u = u_fb.
fn design(input_limit: f64) -> LoopDesign {
    let text = format!(
        r#"
name = "anti-windup"
[loop]
rate_hz = 10000
[plant]
model = "two-inertia"
output = 1
input_limit = {input_limit}
[observer]
design = "kalman"
mc = false
ad = false
[controller]
feedback = "pid"
bandwidth_hz = 5.0
[reference]
shape = "hold"
"#
    );
    let s = Scenario::parse(Path::new("anti-windup.toml"), &text).unwrap();
    LoopDesign::from_scenario(&s).unwrap()
}

/// Steps `controller` through `errors` (θ1 = −error, reference 0); the plant
/// applies each command one sample later when `applied`, else holds
/// `held`. Returns each command.
fn run(controller: &mut ControllerCore, errors: &[f64], applied: bool, held: f64) -> Vec<Command> {
    let mut out = Vec::new();
    let mut last: Option<Command> = None;
    for (k, e) in errors.iter().enumerate() {
        let mut m = Measurement {
            seq: k as u64,
            n_outputs: 1,
            n_inputs: 1,
            command_seq: NO_SEQ,
            ..Measurement::default()
        };
        m.y[0] = -e;
        m.u_applied[0] = held;
        if applied && let Some(c) = &last {
            m.command_seq = c.seq;
            m.u_applied[0] = c.u[0];
        }
        let estimate = Estimate {
            seq: k as u64,
            ..Estimate::default()
        };
        let mut c = Command::default();
        controller.step(&m, &estimate, &mut c);
        last = Some(c);
        out.push(c);
    }
    out
}

/// [`run`] with `design` as it is, and with its anti-windup off.
fn with_and_without(
    design: LoopDesign,
    errors: &[f64],
    applied: bool,
    held: f64,
) -> (Vec<Command>, Vec<Command>) {
    let with = run(&mut ControllerCore::new(&design, 0), errors, applied, held);
    let off = LoopDesign {
        anti_windup_s: 0.0,
        ..design
    };
    let without = run(&mut ControllerCore::new(&off, 0), errors, applied, held);
    (with, without)
}

const SECOND: usize = 10_000;

#[test]
fn a_clamped_command_does_not_wind_the_integrator_up() {
    let limit = 0.05;
    let d = design(limit);
    assert!(d.anti_windup_s > 0.0);
    // Two seconds against the limit, then the error reverses.
    let errors: Vec<f64> = (0..4 * SECOND)
        .map(|k| if k < 2 * SECOND { 0.5 } else { -0.5 })
        .collect();
    let (guarded, wound) = with_and_without(d, &errors, true, 0.0);
    let u_fb = |c: &[Command], k: usize| c[k].u_fb[0];
    // Without it the integrator ramps on for as long as the error lasts;
    // with it the feedback settles where the back-calculation balances it.
    let ramp = u_fb(&wound, 2 * SECOND - 1) - u_fb(&wound, SECOND);
    let drift = u_fb(&guarded, 2 * SECOND - 1) - u_fb(&guarded, SECOND);
    assert!(
        ramp > 0.0 && drift.abs() < 1e-2 * ramp,
        "ramp {ramp}, drift {drift}"
    );
    assert!(guarded[2 * SECOND - 1].u[0] == limit);
    // After the reversal the guarded loop leaves the limit far sooner.
    let leaves = |c: &[Command]| {
        (2 * SECOND..4 * SECOND)
            .find(|&k| c[k].u[0] < limit)
            .unwrap_or(4 * SECOND)
            - 2 * SECOND
    };
    let (guarded_after, wound_after) = (leaves(&guarded), leaves(&wound));
    assert!(
        guarded_after * 10 < wound_after,
        "left the limit after {guarded_after} samples with the anti-windup, {wound_after} without"
    );
}

#[test]
fn a_held_input_does_not_wind_the_integrator_up() {
    // The plant never applies the commands (held at 0): the integrator
    // follows what was applied instead of ramping on.
    let d = design(1e9);
    let errors = vec![0.01; 2 * SECOND];
    let (guarded, wound) = with_and_without(d, &errors, false, 0.0);
    let late = |c: &[Command]| c[2 * SECOND - 1].u_fb[0] - c[SECOND].u_fb[0];
    assert!(late(&wound) > 0.0);
    assert!(
        late(&guarded).abs() < 1e-3 * late(&wound),
        "{} against {}",
        late(&guarded),
        late(&wound)
    );
}

#[test]
fn in_the_linear_range_the_anti_windup_changes_nothing() {
    let d = design(1e9);
    let errors: Vec<f64> = (0..SECOND)
        .map(|k| 1e-3 * (k as f64 * 1e-3).sin())
        .collect();
    let (guarded, plain) = with_and_without(d, &errors, true, 0.0);
    for (a, b) in guarded.iter().zip(&plain) {
        assert_eq!(a.u[0].to_bits(), b.u[0].to_bits(), "sample {}", a.seq);
    }
}
