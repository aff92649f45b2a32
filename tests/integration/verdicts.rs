//! Honest verdicts: a run whose figures are not the design's says so and
//! fails, and a loop started on the CPUs of another is warned about. Both
//! in lockstep, where what happens does not depend on the machine's timing.

use crate::util::*;
use std::process::Stdio;
use std::time::Duration;

/// `flexloop run` of the lecture loop in lockstep, in the background.
fn spawn_run(dir: &std::path::Path, extra: &[&str]) -> std::process::Child {
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(scenario("lecture-double-integrator"))
        .args(["--mode", "lockstep", "--no-realtime", "--duration", "2"])
        .arg("--run-dir")
        .arg(dir)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    cmd.spawn().unwrap()
}

/// Kills the active controller once `ticks` are logged: the plant holds its
/// input (or applies its safe action) until the replacement answers.
fn kill_the_controller(dir: &std::path::Path, ticks: usize) {
    wait_for_ticks(dir, ticks);
    let pid = pid_on_duty(dir, "controller", "active");
    // SAFETY: a pid of a process this test started (through flexloop).
    unsafe { libc::kill(pid, libc::SIGKILL) };
}

#[test]
fn a_run_whose_input_was_held_is_flagged_invalid_and_fails_unless_allowed() {
    let dir = temp_dir("verdict-invalid");
    let child = spawn_run(&dir, &[]);
    kill_the_controller(&dir, 300);
    let out = wait_bounded(child, Duration::from_secs(180));
    assert_eq!(out.status.code(), Some(3), "{}", describe(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stdout.contains("NOT the design's"), "{stdout}");
    assert!(stdout.contains("invalid: the control figures"), "{stdout}");
    assert!(stderr.contains("--allow-invalid"), "{stderr}");
    let m = metrics(&dir);
    assert!(!m.valid, "{m:?}");
    let reasons = &m.invalid_reasons;
    assert!(
        reasons
            .iter()
            .any(|r| r.contains("held the input") || r.contains("safe action")),
        "{reasons:?}"
    );
    assert_clean(&dir);

    // The same with --allow-invalid: flagged all the same, exit 0.
    let dir = temp_dir("verdict-allowed");
    let child = spawn_run(&dir, &["--allow-invalid"]);
    kill_the_controller(&dir, 300);
    let out = wait_bounded(child, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    assert!(!metrics(&dir).valid);
    assert_clean(&dir);
}

#[test]
fn a_loop_started_on_the_cpus_of_another_is_warned_about() {
    // Both pin the loop to CPU 0 and the logger to CPU 1.
    let first_dir = temp_dir("verdict-cpus-first");
    let (first, first_prefix) = start(
        &first_dir,
        "lecture-double-integrator",
        &["--mode", "lockstep"],
    );
    // Registered once it ticks.
    wait_for_ticks(&first_dir, 1);
    let second_dir = temp_dir("verdict-cpus-second");
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario("lecture-double-integrator"))
        .args(["--mode", "lockstep", "--no-realtime", "--duration", "0.05"])
        .arg("--run-dir")
        .arg(&*second_dir);
    let second = run_bounded(cmd, Duration::from_secs(120));
    stop(&first_prefix, first);
    assert!(second.status.success(), "{}", describe(&second));
    let err = String::from_utf8_lossy(&second.stderr);
    let warning = err
        .lines()
        .find(|l| l.contains("WARNING") && l.contains(&first_prefix))
        .unwrap_or_else(|| panic!("no warning about {first_prefix}: {err}"));
    assert!(warning.contains("CPU 0, 1"), "{warning}");
    assert_clean(&first_dir);
    assert_clean(&second_dir);
}
