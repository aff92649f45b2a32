//! Parsing and validation refuse a bad file with the field to blame.

use flexloop_scenario::{Overrides, Profile, Scenario, ScenarioError};
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

/// Parsed, overridden and validated, as `Scenario::load` does.
fn validated(text: &str) -> Result<Scenario, ScenarioError> {
    let mut s = Scenario::parse(Path::new("t.toml"), text)?;
    s.apply(&Overrides::default());
    s.validate()?;
    Ok(s)
}

fn shipped_text(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    std::fs::read_to_string(path).unwrap()
}

#[test]
fn unknown_field_is_refused_with_its_name_and_line() {
    let text = LECTURE.replace("[plant]\n", "[plant]\nmas_kg = 2.0\n");
    let err = Scenario::parse(Path::new("t.toml"), &text).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("mas_kg"));
    assert!(err.reason.contains("line 6"), "{}", err.reason);
}

#[test]
fn dedicated_cores_needs_a_cpu_per_loop_process_and_the_machine_for_it() {
    let shared = shipped_text("default");
    let dedicated = shared.replace("[realtime]", "[realtime]\nprofile = \"dedicated-cores\"");
    // The shipped placement shares CPU 0: refused, naming the second process there.
    let e = validated(&dedicated).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.observer.cpu"), "{e}");
    let own_cpus = dedicated
        .replace(
            "controller = { priority = 81, cpu = 0 }",
            "controller = { priority = 81, cpu = 2 }",
        )
        .replace(
            "observer = { priority = 80, cpu = 0 }",
            "observer = { priority = 80, cpu = 1 }",
        );
    let e = validated(&own_cpus).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.logger.cpu"), "{e}");
    let placed = own_cpus.replace(
        "logger = { priority = 10, cpu = 1 }",
        "logger = { priority = 10, cpu = 3 }",
    );
    let mut s = Scenario::parse(Path::new("t.toml"), &placed).unwrap();
    s.apply(&Overrides::default());
    s.validate().unwrap();
    assert_eq!(s.realtime.profile, Profile::DedicatedCores);
    let e = s.check_machine(2).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.profile"));
    assert!(
        e.to_string()
            .contains("needs at least 4 CPUs; this machine has 2"),
        "{e}"
    );
    let e = s.check_machine(3).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.profile"));
    let e = s.check_machine(4).map(|_| ()).and_then(|_| {
        let mut far = s.clone();
        far.realtime.controller.cpu = Some(7);
        far.check_machine(4)
    });
    assert_eq!(
        e.unwrap_err().field.as_deref(),
        Some("realtime.controller.cpu")
    );
    // Shared cores run anywhere.
    let mut s = Scenario::parse(Path::new("t.toml"), &shared).unwrap();
    s.apply(&Overrides::default());
    assert!(s.check_machine(1).is_ok());
    let e = Scenario::parse(
        Path::new("t.toml"),
        &shared.replace("[realtime]", "[realtime]\nprofile = \"spinning\""),
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("realtime") || e.to_string().contains("profile"),
        "{e}"
    );
}

#[test]
fn out_of_range_values_name_the_field() {
    let mut s = Scenario::parse(Path::new("t.toml"), LECTURE).unwrap();
    s.observer.observer_bandwidth_hz = 6000.0;
    let err = s.validate().unwrap_err();
    assert_eq!(err.field.as_deref(), Some("observer.observer_bandwidth_hz"));
}
