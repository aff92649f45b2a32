//! The plant's watchdog: after the active controller's silence it applies
//! the scenario's safe action; a standby controller's commands count only then.

use flexloop_components::{CommandVerdict, PlantCore};
use flexloop_design::LoopDesign;
use flexloop_protocol::{Activation, Command, Measurement, flags};
use flexloop_scenario::Scenario;
use flexloop_scenario::schema::SafeAction;
use std::path::Path;

const LECTURE: &str = r#"
name = "lecture"
[loop]
rate_hz = 10000
[plant]
model = "double-integrator"
[observer]
design = "state-feedback"
"#;

fn plant(action: SafeAction) -> PlantCore {
    let s = Scenario::parse(Path::new("lecture.toml"), LECTURE).unwrap();
    let mut plant = PlantCore::new(&LoopDesign::from_scenario(&s).unwrap());
    plant.set_watchdog(2, action);
    plant.set_activation(&Activation::INITIAL);
    plant
}

fn command(seq: u64, generation: u32, u: f64, standby: bool) -> Command {
    let mut c = Command {
        seq,
        generation,
        n_inputs: 1,
        flags: if standby { flags::STANDBY } else { 0 },
        ..Command::default()
    };
    c.u[0] = u;
    c
}

/// Runs ticks 0..ticks; the active controller (generation 0) answers until
/// `silent_from`, a standby (generation 1) always. Returns each tick's
/// measurement.
fn run(action: SafeAction, ticks: u64, silent_from: u64) -> Vec<Measurement> {
    let mut plant = plant(action);
    let mut out = Vec::new();
    for k in 0..ticks {
        let mut m = Measurement::default();
        plant.tick(k, 0, 0, false, &mut m);
        out.push(m);
        plant.advance();
        // Commands for sample k, offered before tick k + 1.
        if k < silent_from {
            assert_eq!(
                plant.offer(&command(k, 0, 1.0 + k as f64, false), k + 1, u64::MAX),
                CommandVerdict::Accepted
            );
        }
        let verdict = plant.offer(&command(k, 1, -5.0, true), k + 1, u64::MAX);
        let expected = if action == SafeAction::Standby {
            CommandVerdict::Standby
        } else {
            CommandVerdict::WrongGeneration
        };
        assert_eq!(verdict, expected);
    }
    out
}

#[test]
fn standby_commands_apply_only_after_the_watchdog() {
    let m = run(SafeAction::Standby, 10, 5);
    // Ticks 1..=5 apply the active commands for samples 0..=4.
    for (k, tick) in m.iter().enumerate().take(6).skip(1) {
        assert_eq!(tick.u_applied[0], k as f64, "tick {k}");
        assert_eq!(tick.flags & (flags::FALLBACK | flags::STANDBY), 0);
    }
    // Tick 6: first silent tick, held (below the watchdog's 2 ticks).
    assert_eq!(m[6].u_applied[0], 5.0);
    assert_ne!(m[6].flags & flags::HELD_INPUT, 0);
    assert_eq!(m[6].flags & flags::FALLBACK, 0);
    // From tick 7 the standby's command, flagged.
    for (k, tick) in m.iter().enumerate().skip(7) {
        assert_eq!(tick.u_applied[0], -5.0, "tick {k}");
        assert_eq!(
            tick.flags & (flags::FALLBACK | flags::STANDBY),
            flags::FALLBACK | flags::STANDBY
        );
    }
    // The standby is never a rejected command, the active one's silence is a miss.
    assert_eq!(m[9].rejected_commands, 0);
    assert_eq!(m[9].misses, 4);
    assert_eq!(m[9].fallback_ticks, 3);
}

#[test]
fn without_a_standby_action_its_commands_are_rejected_and_the_plant_holds() {
    let m = run(SafeAction::Hold, 10, 5);
    for (k, tick) in m.iter().enumerate().skip(7) {
        assert_eq!(tick.u_applied[0], 5.0, "tick {k} holds the last command");
        assert_eq!(tick.flags & flags::STANDBY, 0);
        assert_ne!(tick.flags & flags::FALLBACK, 0);
    }
    // Offered after ticks 0..=8 (the measurement of tick 9 comes before its offer).
    assert_eq!(m[9].rejected_commands, 9);
    let zero = run(SafeAction::Zero, 10, 5);
    assert_eq!(zero[8].u_applied[0], 0.0);
}

#[test]
fn the_plant_times_the_active_instances_commands_only() {
    let mut plant = plant(SafeAction::Standby);
    for k in 0..3u64 {
        let mut m = Measurement::default();
        plant.tick(k, 1_000 * k, 1_000 * k + 7, false, &mut m);
        plant.advance();
        let mut own = command(k, 0, 1.0, false);
        own.tick_ns = 1_000 * k;
        own.measurement_published_ns = 1_000 * k + 10;
        own.published_ns = 1_000 * k + 10 + 50 * (k + 1);
        plant.offer(&own, k + 1, u64::MAX);
        // A standby's and a rogue's commands are not the loop's round trip.
        plant.offer(&command(k, 1, -5.0, true), k + 1, u64::MAX);
        plant.offer(&command(k, 7, 9.0, false), k + 1, u64::MAX);
    }
    let l = &plant.latencies;
    assert_eq!(l.tick_lateness.count(), 3);
    assert_eq!(l.round_trip.count(), 3);
    assert_eq!(l.tick_to_command.count(), 3);
    // Round trips of 50, 100 and 150 ns; tick to command 10 ns more.
    assert_eq!(l.round_trip.histogram().max(), 150);
    assert_eq!(l.round_trip.histogram().min(), 50);
    assert_eq!(l.tick_to_command.histogram().max(), 160);
    assert_eq!(l.tick_lateness.histogram().max(), 7);
}

/// Ticks 0..ticks where the active controller answers sample k when
/// `answers(k)`, its command flagged `flags_of(k)`; returns the ticks at
/// which the plant raised its silence alarm.
fn alarms(ticks: u64, answers: impl Fn(u64) -> bool, flags_of: impl Fn(u64) -> u32) -> Vec<u64> {
    let mut plant = plant(SafeAction::Hold);
    let mut raised = Vec::new();
    for k in 0..ticks {
        let mut m = Measurement::default();
        plant.tick(k, 0, 0, false, &mut m);
        if plant.take_alarm() {
            raised.push(k);
        }
        plant.advance();
        if answers(k) {
            let mut c = command(k, 0, 1.0, false);
            c.flags = flags_of(k);
            plant.offer(&c, k + 1, u64::MAX);
        }
    }
    raised
}

#[test]
fn the_alarm_rings_once_when_the_watchdog_first_acts_and_again_after_a_recovery() {
    // Silent for samples 5..=9 and 15..: the watchdog (2 ticks) acts at
    // ticks 7 and 17; the held tick before it and the later silent ticks
    // raise nothing.
    let raised = alarms(30, |k| !(5..10).contains(&k) && k < 15, |_| 0);
    assert_eq!(raised, vec![7, 17]);
    // A single miss is no alarm.
    assert!(alarms(30, |k| k != 12, |_| 0).is_empty());
}

#[test]
fn the_alarm_rings_when_commands_first_come_without_the_observer() {
    // Commands for samples 8..=11 say the observer's estimate was missing:
    // applied at ticks 9..=12, the alarm at the first of them only; again
    // at the next such spell.
    let without = |k: u64| (8..12).contains(&k) || k >= 20;
    let raised = alarms(
        30,
        |_| true,
        |k| {
            if without(k) {
                flags::OBSERVER_FALLBACK
            } else {
                0
            }
        },
    );
    assert_eq!(raised, vec![9, 21]);
}
