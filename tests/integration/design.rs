//! `flexloop design` reports the scenario's own loop (a retuned copy of a
//! thesis scenario gets its own figures, and a broken 6 dB rule is said),
//! `up` warns about it in one line, and `"auto"` is resolved once and shown.

use crate::util::*;
use std::time::Duration;

fn design_json(path: &std::path::Path) -> serde_json::Value {
    let mut cmd = flexloop();
    cmd.args(["design", "--json"]).arg(path);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    serde_json::from_slice(&out.stdout).unwrap()
}

/// thesis-ad retuned to f_bw 60, damping +0.08 and band-pass Q 5: the
/// design breaks the 6 dB rule (6.51 dB, docs/control.md §10.1's model).
fn retuned_ad(dir: &std::path::Path) -> std::path::PathBuf {
    scenario_variant(
        dir,
        "thesis-ad",
        "retuned-ad.toml",
        &[
            ("bandwidth_hz = 35.5", "bandwidth_hz = 60.0"),
            ("damping_increase = 0.035", "damping_increase = 0.08"),
            ("bandpass_q = 2.0", "bandpass_q = 5.0"),
        ],
        "",
    )
}

#[test]
fn design_reports_the_scenarios_own_loop_and_its_broken_6_db_rule() {
    let dir = temp_dir("design_own_loop");
    let retuned = retuned_ad(&dir);
    let own = design_json(&retuned);
    let shipped = design_json(&scenario("thesis-ad"));
    let (l, s) = (&own["loop"], &shipped["loop"]);
    // Not the study: only with --study.
    assert!(own["study"].is_null());
    // Its own loop: the PID and the damping it asked for.
    assert_eq!(l["pid_bandwidth_hz"], 60.0);
    assert_ne!(l["flexible_modes"], s["flexible_modes"]);
    assert_eq!(l["stable"], true);
    // The 6 dB rule, broken at 6.51 dB and said.
    let peak = l["worst_peak_db"].as_f64().unwrap();
    assert!((peak - 6.51).abs() < 0.05, "{peak} dB");
    assert_eq!(l["meets_6db_rule"], false);
    // thesis-ad (f_bw 35.5) meets it, and at y5 38.0 is the largest that
    // does (docs/control.md §10.1).
    assert_eq!(s["meets_6db_rule"], true);
    assert_eq!(s["largest_bandwidth_hz"], 38.0);
    let mut cmd = flexloop();
    cmd.arg("design").arg(&retuned);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("breaks the 6 dB rule"), "{text}");
    assert!(text.contains("6.5"), "{text}");
    assert!(!text.contains("Thesis design report"), "{text}");
    // The study when asked: after the loop, not instead of it.
    let mut cmd = flexloop();
    cmd.args(["design", "--study"]).arg(&retuned);
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
    let text = String::from_utf8_lossy(&out.stdout);
    let (own, study) = (
        text.find("Loop design of").unwrap(),
        text.find("Thesis design report").unwrap(),
    );
    assert!(own < study, "{text}");
    // --continuous is the study's.
    let mut cmd = flexloop();
    cmd.args(["design", "--continuous"]).arg(&retuned);
    let out = run_bounded(cmd, Duration::from_secs(60));
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
}

#[test]
fn up_warns_in_one_line_about_a_design_that_breaks_the_rule() {
    let dir = temp_dir("design_up_warning");
    let retuned = retuned_ad(&dir);
    for (path, warned) in [(retuned, true), (scenario("thesis-ad"), false)] {
        let run = dir.join(if warned { "retuned" } else { "shipped" });
        let mut cmd = flexloop();
        cmd.arg("up")
            .arg(&path)
            .args(["--mode", "lockstep", "--no-realtime", "--duration", "0.05"])
            .arg("--run-dir")
            .arg(&run);
        let out = run_bounded(cmd, Duration::from_secs(120));
        assert!(out.status.success(), "{}", describe(&out));
        let err = String::from_utf8_lossy(&out.stderr);
        let warnings: Vec<&str> = err
            .lines()
            .filter(|l| l.starts_with("flexloop: warning"))
            .collect();
        if warned {
            assert_eq!(warnings.len(), 1, "{err}");
            assert!(warnings[0].contains("breaks the 6 dB rule"), "{err}");
        } else {
            assert!(warnings.is_empty(), "{err}");
        }
        assert_clean(&run);
    }
}

#[test]
fn auto_bandwidth_is_resolved_once_and_shown() {
    let dir = temp_dir("design_auto");
    let auto = scenario_variant(
        &dir,
        "thesis-mc-ad",
        "auto.toml",
        &[("bandwidth_hz = 35.5", "bandwidth_hz = \"auto\"")],
        "",
    );
    let l = &design_json(&auto)["loop"];
    // docs/control.md §10.1: MC+AD with band-pass, 10 kHz, one sample: 43.5 Hz.
    assert_eq!(l["pid_bandwidth_auto"], true);
    let chosen = l["pid_bandwidth_hz"].as_f64().unwrap();
    assert!((chosen - 43.5).abs() <= 0.5, "{chosen}");
    assert_eq!(l["meets_6db_rule"], true);
    assert_eq!(l["largest_bandwidth_hz"], chosen);
    // `up` says it, `status` shows it, no warning: the choice meets the rule.
    let run = dir.join("run");
    let (up, prefix) = start_file_and_await(&run, &auto, &["--mode", "lockstep"], 100);
    let mut cmd = flexloop();
    cmd.args(["status", "--prefix", &prefix]);
    let status = run_bounded(cmd, Duration::from_secs(60));
    assert_ran(&status);
    let words = format!("PID f_bw {chosen:.1} Hz (auto)");
    let text = String::from_utf8_lossy(&status.stdout);
    assert!(
        text.contains(&format!(
            "controller: PID f_bw {chosen:.1} Hz (\"auto\": the largest meeting the 6 dB rule)"
        )),
        "{text}"
    );
    let out = stop(&prefix, up);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&words), "{err}");
    assert!(!err.contains("flexloop: warning"), "{err}");
    assert_clean(&run);
}

/// `design --deadline-sweep`: the largest f_bw against the command
/// deadline, on y5 and, for a thesis case, on y1..y7 (docs/deadline.md's table at
/// 30 µs and one sample); a lockstep run has no command times to judge a
/// deadline by, and a deadline scenario's own report says when its
/// commands act.
#[test]
fn the_deadline_sweep_tables_what_each_deadline_buys() {
    let mut cmd = flexloop();
    cmd.args(["design", "--json", "--deadline-sweep"])
        .arg(scenario("thesis-mc-ad-redesigned"));
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let rows = report["deadline_sweep"]["rows"].as_array().unwrap();
    let deadlines: Vec<f64> = rows
        .iter()
        .map(|r| r["deadline_us"].as_f64().unwrap())
        .collect();
    assert_eq!(deadlines.len(), 10);
    assert!((deadlines[2] - 30.0).abs() < 1e-9 && (deadlines[9] - 100.0).abs() < 1e-9);
    let y1_y7: Vec<f64> = rows
        .iter()
        .map(|r| r["largest_bandwidth_y1_y7_hz"].as_f64().unwrap())
        .collect();
    assert_eq!((y1_y7[2], y1_y7[9]), (62.0, 43.5), "{y1_y7:?}");
    assert!(y1_y7.windows(2).all(|w| w[0] >= w[1]), "{y1_y7:?}");
    assert_eq!(
        report["loop"]["largest_bandwidth_hz"], rows[9]["largest_bandwidth_hz"],
        "the one-sample row is the scenario's own loop"
    );
    assert!(report["deadline_sweep"]["recommended_deadline_us"].is_null());

    let dir = temp_dir("deadline-sweep-lockstep");
    let mut run = flexloop();
    run.args([
        "run",
        "lecture-double-integrator",
        "--mode",
        "lockstep",
        "--no-realtime",
    ])
    .arg("--run-dir")
    .arg(dir.join("run"));
    let out = run_bounded(run, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let mut cmd = flexloop();
    cmd.args(["design", "--deadline-sweep", "--latency"])
        .arg(dir.join("run"))
        .arg(scenario("thesis-mc-ad-redesigned"));
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("samples.mcap") && err.contains("lockstep"),
        "{err}"
    );

    let own = design_json(&scenario("thesis-mc-ad-deadline-30us"));
    assert_eq!(own["loop"]["command_deadline_us"], 30.0);
    assert_eq!(own["loop"]["pid_bandwidth_hz"], 62.0);
    assert_eq!(own["loop"]["meets_6db_rule"], true, "{}", own["loop"]);
}
