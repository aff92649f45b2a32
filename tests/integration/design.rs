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
    let (up, prefix) = start_file(&run, &auto, &["--mode", "lockstep"]);
    wait_for_ticks(&run, 100);
    let mut cmd = flexloop();
    cmd.args(["status", "--prefix", &prefix]);
    let status = run_bounded(cmd, Duration::from_secs(60));
    assert_ran(&status);
    let words = format!("PID f_bw {chosen:.1} Hz (auto)");
    let text = String::from_utf8_lossy(&status.stdout);
    assert!(text.contains(&format!("design: {words}")), "{text}");
    let out = stop(&prefix, up);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&words), "{err}");
    assert!(!err.contains("flexloop: warning"), "{err}");
    assert_clean(&run);
}
