//! `flexloop positions` and the position scenarios: a sensor between two
//! masses through the real processes, bit-identical to the in-process scan
//! that Table 4.1 is made of.

use crate::util::*;
use std::time::Duration;

fn json_of(out: &std::process::Output) -> serde_json::Value {
    assert!(out.status.success(), "{}", describe(out));
    serde_json::from_slice(&out.stdout).unwrap()
}

/// rms e_true [m] per position of the first case of `flexloop positions --json`.
fn rms_per_position(v: &serde_json::Value) -> Vec<f64> {
    v["cases"][0]["scan"]["runs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["rms_e_true"].as_f64().unwrap())
        .collect()
}

#[test]
fn a_sensor_between_masses_runs_through_the_processes_as_in_process() {
    let dir = temp_dir("position-run");
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(scenario("thesis-position-mc-ad"))
        .args(["--mode", "lockstep", "--no-realtime", "--run-dir"])
        .arg(&dir);
    let out = run_bounded(cmd, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    // The metrics name the sensor measured, not the y5 of the files it came from.
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(report.contains("output sensor at 4.25"), "{report}");
    let metrics = metrics(&dir);
    assert_clean(&dir);
    assert_eq!(
        metrics.outputs.first().map(String::as_str),
        Some("sensor at 4.25")
    );
    let run = metrics.control["rms_e_true_scan"].as_f64().unwrap();

    let mut cmd = flexloop();
    cmd.args([
        "positions",
        "thesis-position-mc-ad",
        "--at",
        "4.25",
        "--json",
    ]);
    let table = json_of(&run_bounded(cmd, Duration::from_secs(120)));
    // The scenario's own position: its gains unchanged, the same run.
    assert_eq!(rms_per_position(&table), [run]);
    // MC + AD between m4 and m5 stays near its y5 value (2.47 nm, §10.1).
    assert!(run > 1.0e-9 && run < 3.5e-9, "{run}");
}

#[test]
fn positions_through_the_processes_match_the_in_process_table() {
    let dir = temp_dir("positions-processes");
    let args = ["positions", "thesis-position-original", "--at", "0.5,6.75"];
    let mut cmd = flexloop();
    cmd.args(args)
        .args(["--json", "--processes", "--keep-logs", "--run-dir"])
        .arg(&dir);
    let processes = json_of(&run_bounded(cmd, Duration::from_secs(240)));
    for run in [
        "thesis-position-original-p0.50",
        "thesis-position-original-p6.75",
    ] {
        assert_clean(&dir.join(run));
    }
    let mut cmd = flexloop();
    cmd.args(args).arg("--json");
    let in_process = json_of(&run_bounded(cmd, Duration::from_secs(120)));
    assert_eq!(processes["runs"], "processes-lockstep");
    let (a, b) = (rms_per_position(&processes), rms_per_position(&in_process));
    assert_eq!(a.len(), 2);
    // Bit for bit: lockstep through iceoryx2 is the in-process loop.
    assert_eq!(a, b);
}

#[test]
fn a_position_off_the_chain_names_the_file_and_the_field() {
    let mut cmd = flexloop();
    cmd.args(["positions", "thesis-original", "--at", "7.5"]);
    let out = run_bounded(cmd, Duration::from_secs(60));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("thesis-original.toml")
            && err.contains("plant.sensor_position")
            && err.contains("[0, 7]"),
        "{err}"
    );
    let mut cmd = flexloop();
    cmd.args(["positions", "--per-span", "0"]);
    let out = run_bounded(cmd, Duration::from_secs(60));
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--per-span"));
}
