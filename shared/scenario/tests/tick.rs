//! `realtime.tick`: refused where it does not act or where the chain could
//! not preempt a spinning plant; a fallback where the machine cannot spin.

use flexloop_scenario::tick::{FALLBACK_NO_PRIORITY, FALLBACK_ONE_CPU};
use flexloop_scenario::{Mode, Overrides, Scenario, ScenarioError, TickDecision, TickWait};
use std::path::Path;

fn shipped_default() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/default.toml");
    std::fs::read_to_string(path).unwrap()
}

fn spin_text() -> String {
    shipped_default().replace("[realtime]", "[realtime]\ntick = \"sleep-then-spin\"")
}

fn load(text: &str, overrides: &Overrides) -> Result<Scenario, ScenarioError> {
    let mut s = Scenario::parse(Path::new("t.toml"), text)?;
    s.apply(overrides);
    s.validate()?;
    Ok(s)
}

#[test]
fn the_shipped_priorities_let_the_plant_spin() {
    let s = load(&spin_text(), &Overrides::default()).unwrap();
    assert_eq!(s.realtime.tick, TickWait::SleepThenSpin);
    assert_eq!(
        s.tick_decision(2),
        TickDecision::As(TickWait::SleepThenSpin)
    );
    // Unnamed, the setting is the default, which the plant uses as is.
    let s = load(&shipped_default(), &Overrides::default()).unwrap();
    assert_eq!(s.realtime.tick, TickWait::DEFAULT);
    assert_eq!(s.tick_decision(2).wait(), TickWait::DEFAULT);
}

#[test]
fn a_plant_not_below_observer_and_controller_is_refused() {
    let inverted = spin_text().replace(
        "observer = { priority = 80, cpu = 0 }",
        "observer = { priority = 79, cpu = 0 }",
    );
    let e = load(&inverted, &Overrides::default()).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.plant.priority"), "{e}");
    assert!(e.reason.contains("the observer runs at 79"), "{e}");
    let no_controller_priority = spin_text().replace(
        "controller = { priority = 81, cpu = 0 }",
        "controller = { cpu = 0 }",
    );
    let e = load(&no_controller_priority, &Overrides::default()).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.plant.priority"), "{e}");
    assert!(
        e.reason.contains("realtime.controller.priority is absent"),
        "{e}"
    );
    // Sleeping, the same priorities are the user's business.
    load(
        &inverted.replace("tick = \"sleep-then-spin\"", "tick = \"sleep\""),
        &Overrides::default(),
    )
    .unwrap();
}

#[test]
fn without_real_time_priority_or_a_second_cpu_the_plant_falls_back_to_sleep() {
    let no_rt = Overrides {
        no_realtime: true,
        ..Overrides::default()
    };
    let s = load(&spin_text(), &no_rt).unwrap();
    let d = s.tick_decision(2);
    assert_eq!(
        d,
        TickDecision::Fallback {
            reason: FALLBACK_NO_PRIORITY
        }
    );
    assert_eq!(d.wait(), TickWait::Sleep);
    assert!(
        d.describe().starts_with("sleep (fallback: "),
        "{}",
        d.describe()
    );
    let s = load(&spin_text(), &Overrides::default()).unwrap();
    assert_eq!(
        s.tick_decision(1),
        TickDecision::Fallback {
            reason: FALLBACK_ONE_CPU
        }
    );
}

#[test]
fn the_setting_is_refused_where_the_plant_does_not_sleep_for_its_tick() {
    let lockstep = Overrides {
        mode: Some(Mode::Lockstep),
        ..Overrides::default()
    };
    for value in ["sleep", "sleep-then-spin"] {
        let text = spin_text().replace("sleep-then-spin", value);
        let e = load(&text, &lockstep).unwrap_err();
        assert_eq!(e.field.as_deref(), Some("realtime.tick"), "{e}");
        assert!(e.reason.contains("lockstep"), "{e}");
    }
    let dedicated = spin_text().replace("[realtime]", "[realtime]\nprofile = \"dedicated-cores\"");
    let e = load(&dedicated, &Overrides::default()).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.tick"), "{e}");
    // Unnamed, lockstep runs as ever.
    let s = load(&shipped_default(), &lockstep).unwrap();
    assert!(!s.plant_sleeps_for_ticks());
}

#[test]
fn an_unknown_setting_is_refused_with_its_field() {
    let text = shipped_default().replace("[realtime]", "[realtime]\ntick = \"spin\"");
    let e = Scenario::parse(Path::new("t.toml"), &text).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.tick"), "{e}");
    assert_eq!("sleep-then-spin".parse(), Ok(TickWait::SleepThenSpin));
    assert!("spin".parse::<TickWait>().is_err());
}
