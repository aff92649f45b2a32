//! The four processes in lockstep and in realtime: sequence continuity,
//! clean shutdown, nothing left behind.

use crate::util::*;
use flexloop_recording::LogReader;
use flexloop_runfiles::events::EventKind;
use std::time::Duration;

fn up(run_dir: &std::path::Path, extra: &[&str]) -> std::process::Output {
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario("lecture-double-integrator"))
        .args(["--no-realtime", "--run-dir"])
        .arg(run_dir)
        .args(extra);
    run_bounded(cmd, Duration::from_secs(120))
}

fn contiguous(seqs: &[u64], first: u64) -> bool {
    seqs.iter().enumerate().all(|(i, s)| *s == first + i as u64)
}

#[test]
fn lockstep_run_records_every_sample_and_leaves_nothing() {
    let dir = temp_dir("lockstep");
    let out = up(&dir, &["--mode", "lockstep", "--duration", "0.5"]);
    assert!(out.status.success(), "{}", describe(&out));
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert!(!log.torn_tail);
    let m: Vec<u64> = log.measurements().map(|m| m.seq).collect();
    let c: Vec<u64> = log.commands().map(|c| c.seq).collect();
    let e: Vec<u64> = log.estimates().map(|e| e.seq).collect();
    let s = summary(&dir);
    // The logger polls and never slows the loop: when the machine starves it
    // (parallel tests on 2 cores) it may lose samples, but must count each one.
    let missing = |seqs: &[u64]| 5_000 - seqs.len() as u64;
    assert_eq!(s.gaps.measurement, missing(&m));
    assert_eq!(s.gaps.command, missing(&c));
    assert_eq!(m.last(), Some(&4_999), "0.5 s at 10 kHz");
    assert!(m.windows(2).all(|w| w[0] < w[1]) && c.windows(2).all(|w| w[0] < w[1]));
    assert!(e.windows(2).all(|w| w[0] < w[1]));
    if s.gaps.measurement == 0 && s.gaps.command == 0 {
        assert!(contiguous(&m, 0) && contiguous(&c, 0));
    }
    // In lockstep every command is on time and every estimate fresh.
    assert!(
        log.measurements()
            .skip(1)
            .all(|m| m.command_seq + 1 == m.seq)
    );
    assert!(log.commands().all(|c| c.estimate_seq == c.seq));
    assert_eq!(s.counters.misses, 0);
    assert_clean(&dir);
}

#[test]
fn lockstep_runs_are_bit_reproducible() {
    let outputs = |name: &str| {
        let dir = temp_dir(name);
        let out = up(&dir, &["--mode", "lockstep", "--duration", "0.2"]);
        assert!(out.status.success(), "{}", describe(&out));
        let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
        log.commands()
            .map(|c| c.u[0].to_bits())
            .collect::<Vec<u64>>()
    };
    let a = outputs("repro-a");
    let b = outputs("repro-b");
    assert_eq!(a.len(), 2_000);
    assert_eq!(a, b);
    assert!(
        a.iter().any(|u| f64::from_bits(*u) != 0.0),
        "the loop did something"
    );
}

#[test]
fn realtime_run_at_a_modest_rate_is_continuous_and_clean() {
    let dir = temp_dir("realtime");
    let out = up(
        &dir,
        &["--mode", "realtime", "--rate", "1000", "--duration", "1"],
    );
    assert_ran(&out);
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let m: Vec<u64> = log.measurements().map(|m| m.seq).collect();
    assert_eq!(m.len(), 1_000);
    assert!(
        contiguous(&m, 0),
        "the plant publishes every tick, the logger loses none"
    );
    // Every command answers a measurement of this run, in order.
    let c: Vec<u64> = log.commands().map(|c| c.seq).collect();
    assert!(c.windows(2).all(|w| w[0] < w[1]));
    assert!(c.last().is_some_and(|last| *last <= 999));
    assert_clean(&dir);
}

#[test]
fn down_stops_a_running_loop_cleanly_and_status_sees_it() {
    let dir = temp_dir("down");
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario("lecture-double-integrator"))
        .args([
            "--no-realtime",
            "--rate",
            "1000",
            "--duration",
            "0",
            "--run-dir",
        ])
        .arg(&dir)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    let child = cmd.spawn().unwrap();
    let prefix = format!("flx{}_", child.id());
    wait_for_ticks(&dir, 21);
    let status = run_bounded(
        {
            let mut c = flexloop();
            c.args(["status", "--prefix", &prefix]);
            c
        },
        Duration::from_secs(30),
    );
    let text = String::from_utf8_lossy(&status.stdout);
    assert_ran(&status);
    assert!(
        text.contains("round trip") && text.contains("verdict:"),
        "{text}"
    );
    let down = run_bounded(
        {
            let mut c = flexloop();
            c.args(["down", "--prefix", &prefix]);
            c
        },
        Duration::from_secs(30),
    );
    assert!(down.status.success(), "{}", describe(&down));
    let out = wait_bounded(child, Duration::from_secs(30));
    assert_ran(&out);
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let m: Vec<u64> = log.measurements().map(|m| m.seq).collect();
    assert!(contiguous(&m, 0));
    assert!(log.measurements().last().unwrap().flags & flexloop_protocol::flags::END_OF_RUN != 0);
    assert!(dir.join("summary.json").is_file());
    assert_clean(&dir);
}

/// A loop belongs to the user who started it: every swap and stop names
/// who sent it (pid, uid), and another user's swap, set or down is refused
/// while `status` reads the loop. (Another user is played by giving the
/// loop's registry file to uid 65534, which needs root: this machine's CI
/// runs as root; as another user the ownership refusal is covered by the
/// registry's unit test.)
#[test]
fn swaps_and_stops_name_their_sender_and_another_users_are_refused() {
    let dir = temp_dir("loop-owner");
    let (up, prefix) = start_lecture_lockstep(&dir, 500);
    let on_loop = |args: &[&str]| {
        let mut c = flexloop();
        c.args(args).args(["--prefix", &prefix]);
        run_bounded(c, std::time::Duration::from_secs(150))
    };
    let swap = on_loop(&[
        "swap",
        "controller",
        scenario("lecture-double-integrator").to_str().unwrap(),
    ]);
    assert!(swap.status.success(), "{}", describe(&swap));
    // SAFETY: geteuid has no preconditions.
    let uid = unsafe { libc::geteuid() };
    let swapped = events(&dir)
        .into_iter()
        .find(|e| matches!(e.kind, EventKind::Swap(_)))
        .unwrap();
    let sender = swap_of(&swapped).sender;
    assert_eq!(sender.map(|s| s.uid), Some(uid), "{swapped:?}");
    assert!(sender.and_then(|s| s.pid).unwrap() > 0);
    let registry = std::path::Path::new("/tmp/flexloop/loops").join(format!("{prefix}.json"));
    if uid == 0 {
        std::os::unix::fs::chown(&registry, Some(65534), None).unwrap();
        for args in [
            &["swap", "controller", "x.toml"][..],
            &["set", "controller.bandwidth_hz=40"],
            &["down"],
        ] {
            let out = on_loop(args);
            assert!(!out.status.success(), "{args:?}: {}", describe(&out));
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(
                err.contains("started by another user (uid 65534)"),
                "{args:?}: {err}"
            );
        }
        let status = on_loop(&["status"]);
        assert!(
            String::from_utf8_lossy(&status.stdout).contains(&prefix),
            "{}",
            describe(&status)
        );
        std::os::unix::fs::chown(&registry, Some(0), None).unwrap();
    }
    stop(&prefix, up);
    let stopped = events(&dir)
        .into_iter()
        .find(|e| matches!(e.kind, EventKind::Stop(_)))
        .unwrap_or_else(|| panic!("no stop event: {:?}", events(&dir)));
    let stop = stop_of(&stopped);
    assert_eq!(stop.by, "flexloop down", "{stopped:?}");
    assert_eq!(stop.sender.map(|s| s.uid), Some(uid), "{stopped:?}");
    assert_clean(&dir);
}
