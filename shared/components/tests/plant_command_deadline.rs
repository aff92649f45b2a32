//! The plant with a command deadline τ_d (docs/deadline.md): a
//! command sent by t_{k−1} + τ_d acts from then on, integrated in two pieces
//! within its sample; one sent later is a miss and the plant holds.

use flexloop_components::{CommandVerdict, PlantCore};
use flexloop_control::discretise::zoh;
use flexloop_control::models::thesis_plant;
use flexloop_design::LoopDesign;
use flexloop_protocol::{Activation, Command, Measurement, flags};
use flexloop_scenario::Scenario;
use nalgebra::DVector;
use std::path::Path;

const PERIOD_NS: u64 = 100_000;

fn chain(deadline: &str) -> PlantCore {
    let text = format!(
        r#"
name = "deadline"
[loop]
rate_hz = 10000
{deadline}
[plant]
model = "thesis-chain"
output = 5
force_noise = 0.0
sensor_noise = 0.0
reference_noise = 0.0
[observer]
design = "none"
mc = false
ad = false
[controller]
feedback = "pid"
bandwidth_hz = 35.5
"#
    );
    let s = Scenario::parse(Path::new("deadline.toml"), &text).unwrap();
    let mut plant = PlantCore::new(&LoopDesign::from_scenario(&s).unwrap());
    plant.set_activation(&Activation::INITIAL);
    plant
}

fn command(seq: u64, u: f64, sent_after_tick_ns: u64) -> Command {
    let mut c = Command {
        seq,
        n_inputs: 1,
        published_ns: seq * PERIOD_NS + sent_after_tick_ns,
        ..Command::default()
    };
    c.u[0] = u;
    c
}

fn u_of(seq: u64) -> f64 {
    50.0 * (0.3 * seq as f64).sin()
}

/// Ticks 0..ticks on the grid t_k = k·T, each command k sent `sent` after
/// its tick; returns each tick's measurement and each offer's verdict.
fn run(
    plant: &mut PlantCore,
    ticks: u64,
    sent: impl Fn(u64) -> u64,
) -> (Vec<Measurement>, Vec<CommandVerdict>) {
    let (mut out, mut verdicts) = (Vec::new(), Vec::new());
    for k in 0..ticks {
        if k > 0 {
            let seq = k - 1;
            verdicts.push(plant.offer(&command(seq, u_of(seq), sent(seq)), k, k * PERIOD_NS));
        }
        let mut m = Measurement::default();
        plant.tick(k, k * PERIOD_NS, k * PERIOD_NS, false, &mut m);
        out.push(m);
        plant.advance();
    }
    (out, verdicts)
}

/// y(k) of the emulator against a fine-step simulation of the same
/// continuous chain (1000 exact ZOH steps per sample), whose input switches
/// to u_c(k) at t_k + 30 µs.
#[test]
fn the_two_piece_sample_matches_a_fine_step_simulation() {
    let mut plant = chain("command_deadline_us = 30.0");
    let ticks = 60;
    let (out, verdicts) = run(&mut plant, ticks, |_| 10_000);
    assert!(verdicts.iter().all(|v| *v == CommandVerdict::Accepted));
    let sys = thesis_plant(5).unwrap().state_space();
    let steps = 1000;
    let switch_at = 300;
    let fine = zoh(&sys, 1e-4 / steps as f64).unwrap();
    let mut x = DVector::zeros(sys.states());
    let mut held = 0.0;
    let mut largest: f64 = 0.0;
    for (k, m) in out.iter().enumerate() {
        let y = (&sys.c * &x)[0];
        largest = largest.max(y.abs());
        assert!(
            (m.y_true[0] - y).abs() <= 1e-9 * largest.max(1e-12),
            "tick {k}: {:e} vs {y:e}",
            m.y_true[0]
        );
        assert_eq!(m.u_applied[0], held, "tick {k}: the input present at t_k");
        let next = u_of(k as u64);
        for step in 0..steps {
            let u = if step < switch_at { held } else { next };
            x = &fine.a * &x + &fine.b * DVector::from_element(1, u);
        }
        held = next;
    }
    assert!(largest > 1e-7, "the chain moved: {largest:e} m");
}

/// A command sent after t_k + τ_d is a miss: counted, dropped, and the
/// plant holds the input for the whole sample. The same command is on time
/// for a loop with one sample of delay (due by t_{k+1}).
#[test]
fn a_command_after_its_deadline_is_a_miss_and_the_input_is_held() {
    let late_seq = 20;
    let sent = |seq: u64| if seq == late_seq { 40_000 } else { 25_000 };
    let mut plant = chain("command_deadline_us = 30.0");
    let (out, verdicts) = run(&mut plant, 40, sent);
    for (seq, v) in verdicts.iter().enumerate() {
        let want = if seq as u64 == late_seq {
            CommandVerdict::Late
        } else {
            CommandVerdict::Accepted
        };
        assert_eq!(*v, want, "command {seq}");
    }
    let after = &out[late_seq as usize + 1];
    assert_eq!(after.misses, 1);
    assert_eq!(after.late_commands, 1);
    assert_ne!(after.flags & flags::HELD_INPUT, 0);
    // The controller answered, late: flagged on that tick alone (what the
    // supervisor's hang watch reads as an answer, not a silence).
    let answered: Vec<usize> = out
        .iter()
        .enumerate()
        .filter(|(_, m)| m.flags & flags::ANSWERED_LATE != 0)
        .map(|(k, _)| k)
        .collect();
    assert_eq!(answered, [late_seq as usize + 1]);
    assert_eq!(after.u_applied[0], u_of(late_seq - 1), "held");
    assert_eq!(out[late_seq as usize + 2].u_applied[0], u_of(late_seq + 1));
    assert_eq!(out.last().unwrap().misses, 1);

    let mut one_sample = chain("");
    let (out, verdicts) = run(&mut one_sample, 40, sent);
    assert!(verdicts.iter().all(|v| *v == CommandVerdict::Accepted));
    assert_eq!(out.last().unwrap().misses, 0);
}
