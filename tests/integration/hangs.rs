//! A hung component is a fault like a dead one (docs/architecture.md): the controller
//! or the observer stopped (SIGSTOP) is found from the kernel's view of it
//! (at the plant's silence alarm), a program whose law sleeps from what
//! the loop shows (the plant's held ticks, the estimates falling behind);
//! either is killed and brought back as after a crash: a `silent`
//! event, a `crash` of cause "silent", a restart (a program rolled back to
//! the built-in design that served before it); the loop runs on and
//! nothing is left. (How many ticks that costs is a timing figure: `flexloop
//! chaos` measures it, no test asserts it.)

use crate::util::*;
use flexloop_runfiles::events::SupervisorEvent;
use std::path::Path;
use std::time::{Duration, Instant};

/// Waits (bounded) for the first event of `kind` for `role`.
fn await_event(dir: &Path, kind: &str, role: &str) -> SupervisorEvent {
    wait_for_event(
        dir,
        Duration::from_secs(60),
        &format!("no {kind} event for the {role}"),
        |e| e.kind.name() == kind && e.role == role,
    )
}

fn signal(pid: i32, signal: i32) {
    // SAFETY: a pid of a process this test's loop started (read from its
    // supervisor's list); at worst the call fails.
    unsafe { libc::kill(pid, signal) };
}

/// The hung `role` of a running loop in `dir` is detected, killed and
/// replaced; the loop goes on; returns the silent event.
fn hang_is_handled(dir: &Path, prefix: &str, up: Up, role: &str) -> SupervisorEvent {
    let hung = pid_on_duty(dir, role, "active");
    signal(hung, libc::SIGSTOP);
    let silent = await_event(dir, "silent", role);
    assert_eq!(silent_of(&silent).pid, hung, "{silent:?}");
    let crash = await_event(dir, "crash", role);
    assert_eq!(
        crash_of(&crash).cause.as_deref(),
        Some("silent"),
        "{crash:?}"
    );
    await_event(dir, "restart", role);
    // The stopped process is gone (SIGKILL reaches a stopped process).
    let since = Instant::now();
    while Path::new(&format!("/proc/{hung}")).exists() {
        assert!(since.elapsed() < Duration::from_secs(30), "{hung} lives on");
        std::thread::sleep(Duration::from_millis(20));
    }
    // The loop runs on, served by the replacement.
    let replacement = pid_on_duty(dir, role, "active");
    assert_ne!(replacement, hung);
    let out = stop_after_more_ticks(dir, prefix, up, 500);
    // Recovered: `up` ends as a run whose faults were all dealt with.
    assert_ran(&out);
    assert_clean(dir);
    silent
}

#[test]
fn a_stopped_controller_is_found_silent_killed_and_restarted() {
    let dir = temp_dir("hang-controller");
    let (up, prefix) = start(&dir, "lecture-double-integrator", &["--rate", "2000"]);
    wait_for_ticks(&dir, 2_000);
    let silent = hang_is_handled(&dir, &prefix, up, "controller");
    assert!(silent_of(&silent).stopped, "{silent:?}");
}

#[test]
fn a_stopped_observer_is_found_silent_killed_and_restarted() {
    let dir = temp_dir("hang-observer");
    let (up, prefix) = start(&dir, "lecture-double-integrator", &["--rate", "2000"]);
    wait_for_ticks(&dir, 2_000);
    let silent = hang_is_handled(&dir, &prefix, up, "observer");
    assert!(silent_of(&silent).stopped, "{silent:?}");
}

#[test]
fn in_lockstep_a_stopped_controller_is_found_silent_and_restarted() {
    let dir = temp_dir("hang-lockstep");
    let (up, prefix) = start_lecture_lockstep(&dir, 2_000);
    hang_is_handled(&dir, &prefix, up, "controller");
    // The plant held its input while it waited: the run's own counters
    // say so, nothing was lost from the record.
    let channels = ["measurement", "estimate"];
    assert_no_gaps_on(&summary(&dir), &channels, "a hung controller in lockstep");
}

/// A Python controller `law` swapped into a running loop (the built-in
/// controller serving before it) goes silent: it is found, killed and
/// rolled back to the built-in controller, and the loop runs on with
/// nothing left. Returns the `silent` and `crash` events.
fn program_is_silenced_and_rolled_back(
    test: &str,
    law: &str,
) -> (SupervisorEvent, SupervisorEvent) {
    let dir = temp_dir(test);
    let path = dir.join("law.py");
    std::fs::write(&path, law).unwrap();
    let (up, prefix) = start(&dir, "lecture-double-integrator", &["--rate", "1000"]);
    wait_for_ticks(&dir, 1_000);
    let python = python_with(&["flexloop", "iceoryx2"]);
    let mut swap = flexloop();
    swap.args(["swap", "--prefix", &prefix, "controller", "--exec"])
        .arg(&python)
        .arg(&path);
    let out = run_bounded(swap, Duration::from_secs(150));
    assert!(out.status.success(), "{}", describe(&out));
    let program = pid_on_duty(&dir, "controller", "active");
    let silent = await_event(&dir, "silent", "controller");
    assert_eq!(silent_of(&silent).pid, program, "{silent:?}");
    let crash = await_event(&dir, "crash", "controller");
    let restart = await_event(&dir, "restart", "controller");
    assert!(
        restart_of(&restart).rolled_back_from.is_some(),
        "a program is rolled back: {restart:?}"
    );
    let out = stop_after_more_ticks(&dir, &prefix, up, 500);
    assert_ran(&out);
    assert_clean(&dir);
    (silent, crash)
}

/// A Python controller whose law sleeps 4 s after it started: alive, its
/// process answers signals, but it sends nothing: found by the loop's
/// silence (not stopped, so not by the kernel's view of it).
#[test]
fn a_program_whose_law_sleeps_is_rolled_back_to_the_built_in_controller() {
    let (silent, crash) = program_is_silenced_and_rolled_back(
        "hang-program",
        "import time\nimport flexloop\n\n\
         class Sleepy(flexloop.Controller):\n\
         \x20   def __init__(self, setup):\n\
         \x20       super().__init__(setup)\n\
         \x20       self.since = time.monotonic()\n\n\
         \x20   def step(self, m, estimate):\n\
         \x20       if time.monotonic() - self.since > 4.0:\n\
         \x20           time.sleep(3600)\n\
         \x20       return -100.0 * m.y[0]\n\n\
         flexloop.run(Sleepy)\n",
    );
    assert!(silent_of(&silent).ticks_without_output >= 200, "{silent:?}");
    assert_eq!(
        crash_of(&crash).cause.as_deref(),
        Some("silent"),
        "{crash:?}"
    );
}

/// A Python controller that sends NaN from its 500th sample: it answers
/// every sample, but the plant refuses every command (not finite) and
/// holds: found silent for that cause.
#[test]
fn a_program_sending_non_finite_commands_is_diagnosed_and_rolled_back() {
    let (silent, crash) = program_is_silenced_and_rolled_back(
        "hang-nan",
        "import flexloop\n\n\
         class NotANumber(flexloop.Controller):\n\
         \x20   def __init__(self, setup):\n\
         \x20       super().__init__(setup)\n\
         \x20       self.steps = 0\n\n\
         \x20   def step(self, m, estimate):\n\
         \x20       self.steps += 1\n\
         \x20       if self.steps > 500:\n\
         \x20           return float(\"nan\")\n\
         \x20       return -100.0 * m.y[0]\n\n\
         flexloop.run(NotANumber)\n",
    );
    assert_eq!(
        silent_of(&silent).cause.as_deref(),
        Some("non-finite output"),
        "{silent:?}"
    );
    assert_eq!(
        crash_of(&crash).cause.as_deref(),
        Some("non-finite output"),
        "{crash:?}"
    );
}

/// The loop owns what it started: when its supervisor is killed (kill -9),
/// a program of one's own that does not end on the SIGTERM its
/// supervisor's death sends (here: a law asleep in its step, whose handler
/// only sets a flag) is ended by the next command that finishes the dead
/// loop, which says so, and nothing is left. (A stopped one is ended by
/// the kernel: its process group is orphaned, and a stopped member of an
/// orphaned group gets SIGHUP.)
#[test]
fn a_hung_program_does_not_outlive_its_killed_supervisor() {
    let dir = temp_dir("hang-orphan");
    let marker = dir.join("sleep-now");
    let law = dir.join("sleepy.py");
    std::fs::write(
        &law,
        format!(
            "import os, time\nimport flexloop\n\n\
             class Sleepy(flexloop.Controller):\n\
             \x20   def step(self, m, estimate):\n\
             \x20       if os.path.exists({:?}):\n\
             \x20           time.sleep(3600)\n\
             \x20       return -100.0 * m.y[0]\n\n\
             flexloop.run(Sleepy)\n",
            marker.display().to_string()
        ),
    )
    .unwrap();
    let file = python_controller_scenario(&dir, "sleepy.toml", &law);
    let (up, prefix) = start_file_and_await(&dir, &file, &["--mode", "lockstep"], 500);
    let program = pid_on_duty(&dir, "controller", "active");
    std::fs::write(&marker, "").unwrap();
    // The law is asleep once the loop stops moving (lockstep).
    let mut last = recorded_ticks_in(&dir, "samples.mcap");
    loop {
        std::thread::sleep(Duration::from_millis(300));
        let now = recorded_ticks_in(&dir, "samples.mcap");
        if now == last {
            break;
        }
        last = now;
    }
    signal(up.id() as i32, libc::SIGKILL);
    let out = up.wait(Duration::from_secs(30));
    assert!(!out.status.success());
    assert!(
        Path::new(&format!("/proc/{program}")).exists(),
        "it died with its supervisor"
    );
    let mut down = flexloop();
    down.args(["down", "--prefix", &prefix]);
    let down = run_bounded(down, Duration::from_secs(120));
    assert!(down.status.success(), "{}", describe(&down));
    let said = String::from_utf8_lossy(&down.stdout);
    // (Another test's command may have finished the dead loop first.)
    if said.contains(&prefix) {
        assert!(said.contains("outlived it and were killed"), "{said}");
    }
    let since = Instant::now();
    while Path::new(&format!("/proc/{program}")).exists() {
        assert!(
            since.elapsed() < Duration::from_secs(30),
            "{program} lives on"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_clean(&dir);
}
