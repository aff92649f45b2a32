//! Bad input: a clear error naming the file and the field, nothing started.

use crate::util::*;
use std::time::Duration;

fn up_with(scenario_path: &std::path::Path, run_dir: &std::path::Path) -> std::process::Output {
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario_path)
        .args(["--no-realtime", "--duration", "0.1", "--run-dir"])
        .arg(run_dir);
    run_bounded(cmd, Duration::from_secs(30))
}

fn write_variant(dir: &std::path::Path, from: &str, to: &str) -> std::path::PathBuf {
    let text = std::fs::read_to_string(scenario("lecture-double-integrator")).unwrap();
    assert!(text.contains(from));
    let path = dir.join("bad.toml");
    std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
    path
}

#[test]
fn unknown_field_names_file_and_field() {
    let dir = temp_dir("bad-field");
    let path = write_variant(&dir, "mass_kg = 1.0", "mass_kilograms = 1.0");
    let out = up_with(&path, &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("bad.toml") && err.contains("mass_kilograms"),
        "{err}"
    );
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
}

#[test]
fn invalid_value_names_the_field() {
    let dir = temp_dir("bad-value");
    let path = write_variant(
        &dir,
        "observer_bandwidth_hz = 200.0",
        "observer_bandwidth_hz = 9000.0",
    );
    let out = up_with(&path, &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("observer.observer_bandwidth_hz") && err.contains("Nyquist"),
        "{err}"
    );
}

#[test]
fn missing_scenario_file_is_reported() {
    let dir = temp_dir("missing");
    let out = up_with(&dir.join("nope.toml"), &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        err.contains("nope.toml") && err.contains("cannot read"),
        "{err}"
    );
}

#[test]
fn unwritable_run_directory_is_reported_before_anything_starts() {
    let dir = temp_dir("unwritable");
    let out = up_with(
        &scenario("lecture-double-integrator"),
        std::path::Path::new("/proc/flexloop-run"),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(err.contains("/proc/flexloop-run"), "{err}");
    assert!(processes_mentioning("/proc/flexloop-run").is_empty());
    let _ = dir;
}

#[test]
fn supervision_settings_are_checked() {
    let dir = temp_dir("bad-supervision");
    let text = std::fs::read_to_string(scenario("lecture-double-integrator")).unwrap();
    for (section, field) in [
        (
            "command_watchdog_ticks = 0",
            "supervision.command_watchdog_ticks",
        ),
        ("safe_action = \"explode\"", "safe_action"),
    ] {
        let path = dir.join("bad.toml");
        std::fs::write(&path, format!("{text}\n[supervision]\n{section}\n")).unwrap();
        let out = up_with(&path, &dir.join("run"));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
        assert!(err.contains("bad.toml") && err.contains(field), "{err}");
    }
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
}

#[test]
fn a_swap_into_another_plant_is_refused_and_the_loop_runs_on() {
    let dir = temp_dir("bad-swap");
    let (child, prefix) = start(&dir, "lecture-double-integrator", &["--rate", "1000"]);
    wait_for_ticks(&dir, 1);
    let mut swap = flexloop();
    swap.args(["swap", "controller"])
        .arg(scenario("thesis-original"))
        .args(["--prefix", &prefix]);
    let out = run_bounded(swap, Duration::from_secs(60));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("thesis-original.toml") && err.contains("plant"),
        "{err}"
    );
    stop(&prefix, child);
    assert_clean(&dir);
}
