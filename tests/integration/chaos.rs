//! `flexloop chaos`: it kills what it is asked to, sees each replacement,
//! stops the loop cleanly and accounts for every kill in chaos.json. (What
//! a kill costs in ticks is a timing figure: the command prints it, no test
//! asserts it.)

use crate::util::*;
use flexloop_runfiles::chaos::ChaosFile;
use flexloop_runfiles::events::{EventKind, SupervisorEvent};
use std::path::Path;
use std::process::Output;
use std::time::Duration;

/// `flexloop chaos` on the lecture loop at 1 kHz with every role in play
/// and `args`, into `dir`: its output, and chaos.json as written and read.
fn run_chaos(dir: &Path, args: &[&str]) -> (Output, String, ChaosFile) {
    let mut cmd = flexloop();
    cmd.args(["chaos", "lecture-double-integrator"])
        .args(args)
        .args(["--roles", "controller,observer,logger,spare"])
        .args(["--rate", "1000", "--no-realtime", "--run-dir"])
        .arg(dir);
    let out = run_bounded(cmd, Duration::from_secs(240));
    let text = std::fs::read_to_string(dir.join("chaos.json"))
        .unwrap_or_else(|e| panic!("no chaos.json ({e}): {}", describe(&out)));
    let chaos = serde_json::from_str(&text).unwrap();
    (out, text, chaos)
}

#[test]
fn chaos_kills_every_role_asked_for_and_accounts_for_each_kill() {
    let dir = temp_dir("chaos");
    let (out, text, chaos) = run_chaos(&dir, &["--kills", "4", "--seed", "3"]);
    assert_eq!(chaos.kills.len(), 4, "{}", describe(&out));
    assert!(chaos.kills.iter().all(|k| k.replaced), "{text}");
    let killed: Vec<&str> = chaos.kills.iter().map(|k| k.role.as_str()).collect();
    let summed: u32 = chaos.roles.iter().map(|r| r.kills).sum();
    assert_eq!(summed, 4, "{killed:?}");
    // The loop ended cleanly and left nothing behind; the recording is whole
    // outside the logger's own outages.
    // (Or `up`'s verdict that this machine stalled the plant's clock.)
    let up_stderr = std::fs::read_to_string(dir.join("up.stderr")).unwrap_or_default();
    let machine_stalled =
        chaos.exit_code == 3 && up_stderr.contains("FAILED: the plant did not keep its grid");
    assert!(
        chaos.exit_code == 0 || machine_stalled,
        "{}",
        describe(&out)
    );
    assert_eq!(chaos.files_left, 0);
    assert!(chaos.ticks > 0);
    let stdout = String::from_utf8_lossy(&out.stdout);
    for role in &chaos.roles {
        assert!(stdout.contains(&role.role), "{stdout}");
    }
    assert_clean(&dir.join("loop"));
}

/// `--fault hang`: any of the loop's processes stopped (SIGSTOP), alive and
/// silent; the supervisor finds each from the kernel's view of it, kills it
/// and replaces it, and the loop ends cleanly with nothing left.
#[test]
fn chaos_hangs_every_role_and_each_is_replaced() {
    let dir = temp_dir("chaos-hang");
    let (out, text, chaos) = run_chaos(&dir, &["--fault", "hang", "--kills", "4", "--seed", "5"]);
    assert_eq!(chaos.kills.len(), 4, "{}", describe(&out));
    assert!(chaos.kills.iter().all(|k| k.fault == "hang"), "{text}");
    assert!(chaos.kills.iter().all(|k| k.replaced), "{text}");
    assert_eq!(chaos.files_left, 0);
    let silent: Vec<SupervisorEvent> = events(&dir.join("loop"))
        .into_iter()
        .filter(|e| matches!(e.kind, EventKind::Silent(_)))
        .collect();
    assert_eq!(silent.len(), 4, "{silent:?}");
    for (kill, event) in chaos.kills.iter().zip(&silent) {
        assert_eq!(silent_of(event).pid, kill.pid);
    }
    assert_clean(&dir.join("loop"));
}
