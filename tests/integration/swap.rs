//! Live replacement of components: swaps on request, restarts after a crash,
//! and a plant that refuses commands it must not apply.

use crate::util::*;
use flexloop_components::{InProcessLoop, ObserverCore};
use flexloop_design::LoopDesign;
use flexloop_protocol::channels::{COMMAND, MEASUREMENT};
use flexloop_protocol::{Command, Estimate, Measurement, flags};
use flexloop_recording::LogReader;
use flexloop_runfiles::events::EventKind;
use flexloop_scenario::{Overrides, Scenario};
use flexloop_transport::{Domain, Inlet, Outlet};
use std::collections::HashMap;
use std::path::Path;
use std::time::{Duration, Instant};

fn swap(prefix: &str, role: &str, scenario_file: &Path) -> String {
    let out = run_bounded(
        {
            let mut c = flexloop();
            c.args(["swap", role])
                .arg(scenario_file)
                .args(["--prefix", prefix]);
            c
        },
        Duration::from_secs(120),
    );
    assert!(out.status.success(), "{}", describe(&out));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Kills the active `role` of a run once it logged `after` ticks and waits
/// until its restart is recorded.
fn kill_and_await_restart(dir: &Path, role: &str, after: usize) {
    wait_for_ticks(dir, after);
    let pid = pid_on_duty(dir, role, "active");
    // SAFETY: a pid of a process this test started (through flexloop).
    unsafe { libc::kill(pid, libc::SIGKILL) };
    wait_for_event(
        dir,
        Duration::from_secs(90),
        &format!("{role} did not come back"),
        |e| matches!(e.kind, EventKind::Restart(_)) && e.role == role,
    );
}

#[test]
fn identical_swaps_in_lockstep_leave_the_commands_bit_identical() {
    let dir = temp_dir("swap-lockstep");
    let (child, prefix) = start_lecture_lockstep(&dir, 430);
    let same = scenario("lecture-double-integrator");
    let first = swap(&prefix, "controller", &same);
    assert!(first.contains("generation 1"), "{first}");
    swap(&prefix, "observer", &same);
    swap(&prefix, "controller", &same);
    stop(&prefix, child);

    let summary = summary(&dir);
    assert_lost_nothing(&summary, "three identical swaps");
    assert_eq!(summary.counters.rejected_commands, 0, "{summary:?}");
    let swaps = swaps(&dir);
    assert_eq!(swaps.len(), 3, "{swaps:?}");

    // Every command, across three hand-overs, is the one an unswapped loop
    // computes: the state copy makes the switch exact.
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let generations = command_generations(&log);
    assert_eq!(generations.len(), 3, "controllers 0, 1, 2: {generations:?}");
    assert_commands_match_the_uninterrupted_lecture_loop(&log);
    assert_clean(&dir);
}

/// Every command of a lockstep lecture run is contiguous and bit-identical
/// to what the loop computes in one process, with no swap and no crash.
/// Returns how many were compared.
fn assert_commands_match_the_uninterrupted_lecture_loop(log: &LogReader) -> usize {
    // Two publishers during a hand-over: the log may hold k+1 before k.
    let mut commands: Vec<&Command> = log.commands().collect();
    commands.sort_by_key(|c| c.seq);
    let scenario = Scenario::load(
        &scenario("lecture-double-integrator"),
        &Overrides {
            mode: Some(flexloop_scenario::Mode::Lockstep),
            no_realtime: true,
            duration_s: Some(0.0),
            ..Overrides::default()
        },
    )
    .unwrap();
    let design = LoopDesign::from_scenario(&scenario).unwrap();
    let mut reference = InProcessLoop::new(&design).unwrap();
    for (k, c) in commands.iter().enumerate() {
        reference.tick();
        assert_eq!(c.seq, k as u64, "commands are contiguous");
        assert_eq!(
            c.u[0].to_bits(),
            reference.command.u[0].to_bits(),
            "u({k}) from generation {} differs from the uninterrupted loop",
            c.generation
        );
    }
    commands.len()
}

#[test]
fn a_retuned_controller_takes_over_without_a_step() {
    let dir = temp_dir("swap-retuned");
    // The default scenario scans back and forth; its PID (f_bw 43.5 Hz) is
    // replaced mid-scan by the original tuning (35.5 Hz), same trajectory.
    let retuned = scenario_variant(
        &dir,
        "default",
        "retuned.toml",
        &[("bandwidth_hz = 43.5", "bandwidth_hz = 35.5")],
        "",
    );
    let (child, prefix) = start_and_await(&dir, "default", &["--mode", "lockstep"], 3_200);
    swap(&prefix, "controller", &retuned);
    stop(&prefix, child);
    assert_lost_nothing(&summary(&dir), "the retuned swap");
    let swaps = swaps(&dir);
    // No larger than the ordinary steps of the old or the new design (twice,
    // with a 1 µN floor for a switch where the command barely moves): the
    // switch itself adds no transient. Without the hand-over it is the
    // difference of the two designs' feedforward blocks, about 6 N here.
    assert_bumpless(&swap_of(&swaps[0]).switch, "the retuned controller");
    assert_clean(&dir);
}

#[test]
fn a_swap_to_another_set_point_is_refused_and_the_old_controller_runs_on() {
    let dir = temp_dir("swap-reference");
    // The default loop scans every 0.25 s; the original design scans once:
    // its set-point would jump by the stroke at the switch.
    let (child, prefix) = start_and_await(&dir, "default", &["--mode", "lockstep"], 500);
    let controller = pid_on_duty(&dir, "controller", "active");
    let mut cmd = flexloop();
    cmd.args(["swap", "controller"])
        .arg(scenario("thesis-original"))
        .args(["--prefix", &prefix]);
    let out = run_bounded(cmd, Duration::from_secs(120));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("swap refused")
            && err.contains("thesis-original.toml")
            && err.contains("reference.repeat_s"),
        "{err}"
    );
    // Refused before anything started: the same instance serves on.
    let refused_at = recorded_ticks_in(&dir, "samples.mcap");
    wait_for_ticks(&dir, refused_at + 500);
    assert_eq!(pid_on_duty(&dir, "controller", "active"), controller);
    let active = processes(&dir)
        .into_iter()
        .find(|p| p.role == "controller" && p.duty == "active")
        .unwrap();
    assert_eq!(active.generation, Some(0), "{active:?}");
    stop(&prefix, child);
    assert!(swaps(&dir).is_empty(), "{:?}", events(&dir));
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert!(log.commands().count() > refused_at);
    assert!(log.commands().all(|c| c.generation == 0));
    assert_eq!(summary(&dir).counters.misses, 0);
    assert_clean(&dir);
}

#[test]
fn killed_components_come_back_and_the_plant_falls_back_meanwhile() {
    let dir = temp_dir("swap-crash");
    let (child, prefix) = start(&dir, "lecture-double-integrator", &["--rate", "1000"]);
    for role in ["controller", "observer", "logger"] {
        kill_and_await_restart(&dir, role, 100);
    }
    // The restarted logger records before the run ends.
    wait_for_ticks_in(&dir, "samples.g1.mcap", 10);
    stop(&prefix, child);
    let summary = summary(&dir);
    // The silent controller cost ticks under the safe action, and the loop
    // went on: the plant ran to the end.
    assert!(summary.counters.fallback_ticks > 0, "{summary:?}");
    let crashes = events(&dir)
        .iter()
        .filter(|e| matches!(e.kind, EventKind::Crash(_)))
        .count();
    assert_eq!(crashes, 3);
    // The restarted logger writes its own files, to the end, and sees only
    // the restarted controller.
    let second = LogReader::open(&dir.join("samples.g1.mcap")).unwrap();
    assert!(second.commands().all(|c| c.generation >= 1));
    let seqs: Vec<u64> = second.measurements().map(|m| m.seq).collect();
    assert!(seqs.len() > 10 && seqs.windows(2).all(|w| w[1] == w[0] + 1));
    let last = second.measurements().last().unwrap();
    assert!(last.flags & flags::END_OF_RUN != 0);
    assert_clean(&dir);
}

#[test]
fn a_standby_controller_covers_a_crash_and_is_promoted_without_a_step() {
    let dir = temp_dir("swap-standby");
    let file = scenario_variant(
        &dir,
        "lecture-double-integrator",
        "lecture-standby.toml",
        &[],
        STANDBY_TABLE,
    );
    let (child, prefix) = start_file_and_await(&dir, &file, &["--rate", "1000"], 100);
    let standby_running = |dir: &Path| !pids_on_duty(dir, "controller", "standby").is_empty();
    let since = Instant::now();
    while !standby_running(&dir) {
        assert!(
            since.elapsed() < Duration::from_secs(60),
            "no standby started"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // Let the standby follow the loop a while, then kill the active controller.
    std::thread::sleep(Duration::from_millis(500));
    let active = pids_on_duty(&dir, "controller", "active");
    assert_eq!(active.len(), 1, "one active controller");
    // SAFETY: a pid of a process this test started (through flexloop).
    unsafe { libc::kill(active[0], libc::SIGKILL) };
    let promoted = wait_for_event(&dir, Duration::from_secs(90), "standby not promoted", |e| {
        matches!(e.kind, EventKind::PromoteStandby(_))
    });
    // A new standby follows the promoted controller.
    let since = Instant::now();
    while events(&dir)
        .iter()
        .filter(|e| matches!(e.kind, EventKind::Standby(_)))
        .count()
        < 2
    {
        assert!(
            since.elapsed() < Duration::from_secs(60),
            "no second standby"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    stop(&prefix, child);

    let summary = summary(&dir);
    assert!(summary.counters.fallback_ticks > 0, "{summary:?}");
    assert_eq!(summary.counters.rejected_commands, 0, "{summary:?}");
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let standby_ticks = log
        .measurements()
        .filter(|m| m.flags & flags::STANDBY != 0)
        .count();
    let fallback_ticks = log
        .measurements()
        .filter(|m| m.flags & flags::FALLBACK != 0)
        .count();
    // The standby answered the samples the crashed controller left (in time
    // for the plant or not: on a loaded machine they may all be late, and
    // the plant holds instead); the plant applied them only as its safe
    // action.
    let crashed_at = events(&dir)
        .iter()
        .find(|e| matches!(e.kind, EventKind::Crash(_)))
        .and_then(|e| e.seq)
        .unwrap();
    assert!(
        log.commands()
            .any(|c| c.flags & flags::STANDBY != 0 && c.seq > crashed_at),
        "the standby answered the samples after the crash"
    );
    assert!(standby_ticks <= fallback_ticks);
    assert!(
        log.measurements()
            .all(|m| m.flags & flags::STANDBY == 0 || m.flags & flags::FALLBACK != 0)
    );
    // The standby computed what the active one would have: its commands run
    // on without a step where it became the active one, beyond the ordinary
    // sample-to-sample changes. (Judged on the commands it computed, all of
    // them recorded: what the plant applied also carries the steps of the
    // inputs a loaded machine made it hold.)
    let generation = promoted.generation.unwrap();
    let mut stream: Vec<&Command> = log
        .commands()
        .filter(|c| c.generation == generation)
        .collect();
    stream.sort_by_key(|c| c.seq);
    stream.dedup_by_key(|c| c.seq);
    let at = stream
        .windows(2)
        .position(|p| p[0].flags & flags::STANDBY != 0 && p[1].flags & flags::STANDBY == 0)
        .map(|i| i + 1)
        .expect("the standby's commands, then the promoted controller's");
    let window = &stream[at.saturating_sub(100)..(at + 101).min(stream.len())];
    let at = at - at.saturating_sub(100);
    let step = |p: &[&Command]| (p[0].seq + 1 == p[1].seq).then(|| (p[1].u[0] - p[0].u[0]).abs());
    match step(&window[at - 1..=at]) {
        Some(du) => {
            let ordinary = window
                .windows(2)
                .enumerate()
                .filter(|(i, _)| *i != at - 1)
                .filter_map(|(_, p)| step(p))
                .fold(0.0, f64::max);
            // (1 % over the largest: on a ramp the step at one sample may
            // exceed the hundred before it by a hair; a hand-over's bump is
            // orders larger.)
            assert!(
                du <= 1.01 * ordinary + 1e-9,
                "step {du} at the promotion (sample {}), ordinary {ordinary}",
                window[at].seq
            );
        }
        // The promoted controller skipped to the newest sample after a
        // backlog (a loaded machine): no two consecutive samples to compare.
        None => eprintln!("no consecutive commands across the promotion: its step is not judged"),
    }
    assert_clean(&dir);
}

#[test]
fn a_rogue_publisher_and_non_finite_commands_leave_the_plant_unharmed() {
    let dir = temp_dir("swap-rogue");
    let (child, prefix) = start_lecture_lockstep(&dir, 215);
    {
        // Answers every measurement before or beside the real controller:
        // once from a generation that is not active, once with NaN.
        let domain = Domain::new(&prefix).unwrap();
        let node = domain.node("rogue").unwrap();
        let measurements = Inlet::<Measurement>::open_polling(&node, &MEASUREMENT, 16).unwrap();
        let rogue = Outlet::<Command>::open(&node, &COMMAND).unwrap();
        let since = Instant::now();
        while since.elapsed() < Duration::from_millis(500) {
            while let Some(m) = measurements.receive().unwrap() {
                for (generation, value) in [(7, 500.0), (0, f64::NAN)] {
                    rogue
                        .publish(|c| {
                            c.seq = m.seq;
                            c.tick_ns = m.tick_ns;
                            c.measurement_published_ns = m.published_ns;
                            c.received_ns = flexloop_protocol::time::monotonic_ns();
                            c.published_ns = c.received_ns;
                            c.generation = generation;
                            c.n_inputs = 1;
                            c.u[0] = value;
                        })
                        .unwrap();
                }
                rogue.notify().unwrap();
            }
            std::thread::sleep(Duration::from_micros(200));
        }
    }
    stop(&prefix, child);
    let summary = summary(&dir);
    assert!(summary.counters.rejected_commands > 0, "{summary:?}");
    assert_eq!(summary.counters.misses, 0, "{summary:?}");
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    for m in log.measurements() {
        assert!(m.u_applied[0].is_finite() && m.u_applied[0].abs() < 100.0);
    }
    assert_clean(&dir);
}

#[test]
fn swaps_at_a_modest_realtime_rate_lose_no_sample() {
    let dir = temp_dir("swap-realtime");
    let (child, prefix) =
        start_and_await(&dir, "lecture-double-integrator", &["--rate", "1000"], 100);
    let same = scenario("lecture-double-integrator");
    swap(&prefix, "controller", &same);
    swap(&prefix, "observer", &same);
    stop(&prefix, child);
    let summary = summary(&dir);
    // Timing on a shared machine is not asserted (a stall may cost a tick,
    // and the controller then skips the older sample: no command for it);
    // what is: every measurement and estimate recorded, every command from
    // the owner of its sample.
    assert_no_gaps_on(&summary, &["measurement", "estimate"], "two swaps at 1 kHz");
    assert_eq!(summary.counters.rejected_commands, 0, "{summary:?}");
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let mut seqs: Vec<u64> = log.measurements().map(|m| m.seq).collect();
    seqs.sort_unstable();
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1));
    let generations = command_generations(&log);
    assert_eq!(generations.len(), 2, "controllers 0 and 1: {generations:?}");
    assert_clean(&dir);
}

#[test]
fn a_component_killed_at_start_up_is_replaced_and_the_loop_starts() {
    for role in ["controller", "observer"] {
        let dir = temp_dir(&format!("swap-early-{role}"));
        let (child, prefix) = start(&dir, "lecture-double-integrator", &["--rate", "1000"]);
        // Kill it as soon as it exists: usually before tick 0 (the test holds
        // either way, a later kill is an ordinary restart).
        let since = Instant::now();
        let pid = loop {
            if let [pid] = pids_on_duty(&dir, role, "active")[..] {
                break pid;
            }
            assert!(since.elapsed() < Duration::from_secs(60), "no {role}");
            std::thread::sleep(Duration::from_millis(2));
        };
        // SAFETY: a pid of a process this test started (through flexloop).
        unsafe { libc::kill(pid, libc::SIGKILL) };
        wait_for_ticks(&dir, 43);
        stop(&prefix, child);
        let restarted = events(&dir)
            .iter()
            .any(|e| matches!(e.kind, EventKind::Restart(_)) && e.role == role);
        assert!(restarted, "{role}: {:?}", events(&dir));
        let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
        assert!(log.measurements().last().unwrap().flags & flags::END_OF_RUN != 0);
        assert_clean(&dir);
    }
}

#[test]
fn a_restarted_observer_replays_its_way_to_the_state_the_crashed_one_would_have_had() {
    let dir = temp_dir("swap-observer-replay");
    let (child, prefix) = start(&dir, "two-inertia", &["--rate", "1000"]);
    kill_and_await_restart(&dir, "observer", 300);
    // Some estimates of the restarted observer's own.
    std::thread::sleep(Duration::from_millis(300));
    stop(&prefix, child);
    // The restart's own words, in the stderr file of whichever process
    // served it (a warm spare's, or a new one's).
    let said: String = std::fs::read_dir(&dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.starts_with("observer") && name.ends_with(".stderr")
        })
        .map(|p| std::fs::read_to_string(p).unwrap())
        .collect();
    assert!(
        said.contains("replayed") && !said.contains("hole"),
        "{said}"
    );

    // The observer that never stopped: designed from the same file and
    // stepped here through every measurement the plant published.
    let overrides = Overrides {
        rate_hz: Some(1000.0),
        ..Overrides::default()
    };
    let file = scenario("two-inertia");
    let design = LoopDesign::from_scenario(&Scenario::load(&file, &overrides).unwrap()).unwrap();
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let seqs: Vec<u64> = log.measurements().map(|m| m.seq).collect();
    assert!(seqs[0] == 0 && seqs.windows(2).all(|w| w[1] == w[0] + 1));
    let mut uninterrupted = ObserverCore::for_design(&design).unwrap();
    let mut expected = HashMap::new();
    for m in log.measurements() {
        let mut e = Estimate::default();
        uninterrupted.step(m, &mut e);
        expected.insert(e.seq, e);
    }
    // Every estimate the restarted observer published is that one's.
    let mut compared = 0;
    for e in log.estimates().filter(|e| e.generation == 1) {
        let x = &expected[&e.seq];
        let scale = x.x_hat.iter().fold(1e-9_f64, |a, v| a.max(v.abs()));
        for (got, want) in e
            .x_hat
            .iter()
            .chain(&e.free)
            .zip(x.x_hat.iter().chain(&x.free))
        {
            assert!(
                (got - want).abs() <= 1e-12 * scale,
                "estimate {}: {got} against {want} uninterrupted",
                e.seq
            );
        }
        compared += 1;
    }
    assert!(
        compared > 100,
        "{compared} estimates of the restarted observer"
    );
    assert_clean(&dir);
}

#[test]
fn after_a_swap_to_a_retuned_controller_the_standby_follows_the_new_design() {
    let dir = temp_dir("swap-standby-retuned");
    // Two-inertia, a PID in the controller retuned from 5 to 4 Hz; lockstep,
    // so that every instance sees every estimate in time.
    let file = scenario_variant(&dir, "two-inertia", "standby.toml", &[], STANDBY_TABLE);
    let retuned = scenario_variant(
        &dir,
        "two-inertia",
        "retuned.toml",
        &[("bandwidth_hz = 5.0", "bandwidth_hz = 4.0")],
        STANDBY_TABLE,
    );
    let (child, prefix) = start_file_and_await(&dir, &file, &["--mode", "lockstep"], 100);
    let standbys = |dir: &Path| -> Vec<String> {
        processes(dir)
            .iter()
            .filter(|p| p.role == "controller" && p.duty == "standby")
            .map(|p| p.scenario.clone())
            .collect()
    };
    let since = Instant::now();
    while standbys(&dir).is_empty() {
        assert!(
            since.elapsed() < Duration::from_secs(60),
            "no standby started"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let old_standby = pid_on_duty(&dir, "controller", "standby");
    // A standby taken from the spares is replaced by a new spare: the
    // processes to compare are those once both roles have their spare again.
    let since = Instant::now();
    while pids_on_duty(&dir, "controller", "spare").is_empty()
        || pids_on_duty(&dir, "observer", "spare").is_empty()
    {
        assert!(
            since.elapsed() < Duration::from_secs(30),
            "no spares: {:?}",
            processes(&dir)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let pids_before: std::collections::BTreeSet<i32> =
        processes(&dir).iter().map(|p| p.pid).collect();
    swap(&prefix, "controller", &retuned);
    // The swap returns once the new standby follows and the old one is
    // told to retire: one standby is left, of the new design, and the old
    // one idles as the spare (no process started or stopped).
    let since = Instant::now();
    loop {
        let running = standbys(&dir);
        if running.len() == 1 && running[0].contains("retuned.toml") {
            break;
        }
        assert!(
            since.elapsed() < Duration::from_secs(30),
            "standbys after the swap: {running:?}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    await_spare(&dir, "controller", old_standby);
    let pids_after: std::collections::BTreeSet<i32> =
        processes(&dir).iter().map(|p| p.pid).collect();
    assert_eq!(pids_before, pids_after, "{:?}", processes(&dir));
    let renewed = events(&dir)
        .into_iter()
        .find(|e| matches!(&e.kind, EventKind::Standby(s) if s.replaces.is_some()))
        .expect("a standby event for the renewal");
    assert!(
        standby_of(&renewed)
            .scenario
            .as_deref()
            .unwrap()
            .ends_with("retuned.toml")
    );
    // It follows the new controller: its commands (kept by the plant for a
    // fallback, recorded by the logger) are the active one's, bit for bit,
    // whenever it found the active state of the sample before (it acts on
    // the newest sample only and may miss one when it lags: the promotion
    // copies the state anyway). A standby of the old design matches none.
    // Samples, not time: a loaded machine runs few ticks in a while.
    stop_after_more_ticks(&dir, &prefix, child, 1_000);
    let standby_generation = renewed.generation.unwrap();
    let active_generation = swaps(&dir)[0].generation.unwrap();
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let active: HashMap<u64, [f64; 8]> = log
        .commands()
        .filter(|c| c.generation == active_generation && c.flags & flags::STANDBY == 0)
        .map(|c| (c.seq, c.u))
        .collect();
    let (mut compared, mut identical) = (0, 0);
    for c in log
        .commands()
        .filter(|c| c.generation == standby_generation && c.flags & flags::STANDBY != 0)
    {
        if let Some(u) = active.get(&c.seq) {
            compared += 1;
            identical += usize::from(c.u == *u);
        }
    }
    assert!(compared > 100, "{compared} standby commands compared");
    assert!(
        identical * 2 > compared,
        "{identical} of {compared} standby commands identical to the active one's"
    );
    assert_clean(&dir);
}

/// The live pids of the run, by role and duty.
fn duties(dir: &Path) -> std::collections::BTreeSet<(String, String, i32)> {
    processes(dir)
        .into_iter()
        .map(|p| (p.role, p.duty, p.pid))
        .collect()
}

/// Waits until the supervisor lists the replaced instance as the new spare.
fn await_spare(dir: &Path, role: &str, pid: i32) {
    let since = Instant::now();
    while !pids_on_duty(dir, role, "spare").contains(&pid) {
        assert!(
            since.elapsed() < Duration::from_secs(30),
            "{role} {pid} did not become the spare: {:?}",
            processes(dir)
        );
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn with_warm_spares_a_swap_starts_and_stops_no_process() {
    let dir = temp_dir("swap-warm");
    let (child, prefix) = start_lecture_lockstep(&dir, 215);
    let same = scenario("lecture-double-integrator");
    // One idle spare of each beside the active instances, from the start.
    let before = duties(&dir);
    let spare_controller = pid_on_duty(&dir, "controller", "spare");
    let active_controller = pid_on_duty(&dir, "controller", "active");
    let spare_observer = pid_on_duty(&dir, "observer", "spare");
    let active_observer = pid_on_duty(&dir, "observer", "active");

    swap(&prefix, "controller", &same);
    await_spare(&dir, "controller", active_controller);
    assert_eq!(
        pid_on_duty(&dir, "controller", "active"),
        spare_controller,
        "the spare serves"
    );
    swap(&prefix, "observer", &same);
    await_spare(&dir, "observer", active_observer);
    assert_eq!(pid_on_duty(&dir, "observer", "active"), spare_observer);
    // And back: the first instances serve again.
    swap(&prefix, "controller", &same);
    await_spare(&dir, "controller", spare_controller);
    assert_eq!(pid_on_duty(&dir, "controller", "active"), active_controller);
    let pids = |set: &std::collections::BTreeSet<(String, String, i32)>| {
        set.iter()
            .map(|(_, _, pid)| *pid)
            .collect::<std::collections::BTreeSet<_>>()
    };
    assert_eq!(
        pids(&duties(&dir)),
        pids(&before),
        "the same processes before and after"
    );
    stop(&prefix, child);

    let swaps = swaps(&dir);
    assert_eq!(swaps.len(), 3, "{swaps:?}");
    assert!(swaps.iter().all(|e| swap_of(e).switch.warm), "{swaps:?}");
    // No process was started after the loop's start.
    assert!(
        !events(&dir)
            .iter()
            .any(|e| matches!(e.kind, EventKind::Spare(_) | EventKind::Crash(_))),
        "{:?}",
        events(&dir)
    );
    let summary = summary(&dir);
    assert_lost_nothing(&summary, "three swaps to warm spares");
    assert_eq!(summary.counters.rejected_commands, 0, "{summary:?}");
    assert_clean(&dir);
}

#[test]
fn without_warm_spares_a_swap_starts_a_process_and_the_old_one_exits() {
    let dir = temp_dir("swap-cold");
    let file = scenario_variant(
        &dir,
        "lecture-double-integrator",
        "cold.toml",
        &[],
        "[supervision]\nwarm_spares = false",
    );
    let (child, prefix) = start_file_and_await(&dir, &file, &["--mode", "lockstep"], 215);
    assert!(pids_on_duty(&dir, "controller", "spare").is_empty());
    let old = pid_on_duty(&dir, "controller", "active");
    swap(&prefix, "controller", &file);
    let new = pid_on_duty(&dir, "controller", "active");
    assert_ne!(new, old);
    let since = Instant::now();
    while processes(&dir).iter().any(|p| p.pid == old) {
        assert!(
            since.elapsed() < Duration::from_secs(30),
            "{old} still runs"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    stop(&prefix, child);
    let swaps = swaps(&dir);
    assert!(!swap_of(&swaps[0]).switch.warm);
    assert_lost_nothing(&summary(&dir), "a swap without warm spares");
    assert_clean(&dir);
}

#[test]
fn in_lockstep_a_killed_observer_comes_back_and_no_command_changes() {
    let dir = temp_dir("swap-lockstep-observer-crash");
    let (child, prefix) = start(&dir, "lecture-double-integrator", &["--mode", "lockstep"]);
    kill_and_await_restart(&dir, "observer", 300);
    // The loop goes on past the crash.
    wait_for_ticks(&dir, 3_000);
    stop(&prefix, child);
    let summary = summary(&dir);
    assert_lost_nothing(&summary, "across the observer's crash");
    assert_eq!(summary.counters.stale_estimates, 0, "{summary:?}");
    // The replacement took over the dead one's state and stepped through
    // every measurement since: every command is the one a loop without the
    // crash computes.
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let generations = estimate_generations(&log);
    assert_eq!(generations.len(), 2, "{generations:?}");
    assert!(assert_commands_match_the_uninterrupted_lecture_loop(&log) > 3_000);
    assert_clean(&dir);
}

#[test]
fn in_lockstep_a_killed_controller_comes_back_after_one_held_tick() {
    let dir = temp_dir("swap-lockstep-controller-crash");
    let (child, prefix) = start(&dir, "lecture-double-integrator", &["--mode", "lockstep"]);
    kill_and_await_restart(&dir, "controller", 300);
    wait_for_ticks(&dir, 3_000);
    stop(&prefix, child);
    let summary = summary(&dir);
    // The plant waited its second for the dead one's command, held the
    // input (a miss; the watchdog's safe action if it lasts), and went on
    // with the replacement.
    let misses = summary.counters.misses;
    assert!((1..=5).contains(&misses), "{summary:?}");
    assert_eq!(summary.gaps.measurement, 0, "{summary:?}");
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let generations = command_generations(&log);
    assert_eq!(generations.len(), 2, "{generations:?}");
    assert!(log.measurements().last().unwrap().flags & flags::END_OF_RUN != 0);
    assert_clean(&dir);
}

#[test]
fn in_lockstep_a_killed_logger_comes_back_and_the_loop_goes_on() {
    let dir = temp_dir("swap-lockstep-logger-crash");
    let (child, prefix) = start(&dir, "lecture-double-integrator", &["--mode", "lockstep"]);
    kill_and_await_restart(&dir, "logger", 300);
    // The plant paces itself on the logger's progress: it waits for the
    // dead one (at most its patience) until the restarted one reports; that
    // one records from where it joined, and the loop runs on with it.
    wait_for_ticks_in(&dir, "samples.g1.mcap", 2_000);
    stop(&prefix, child);
    let plant = std::fs::read_to_string(dir.join("plant.stderr")).unwrap();
    let second = LogReader::open(&dir.join("samples.g1.mcap")).unwrap();
    let seqs: Vec<u64> = second.measurements().map(|m| m.seq).collect();
    assert!(
        seqs.len() >= 2_000,
        "{} recorded after the restart",
        seqs.len()
    );
    assert!(
        seqs.windows(2).all(|w| w[1] == w[0] + 1),
        "the restarted logger's record has gaps"
    );
    let last = second.measurements().last().unwrap();
    assert!(last.flags & flags::END_OF_RUN != 0);
    // No tick waited for a command: the logger is not on the loop's path.
    assert_eq!(last.misses, 0, "{plant}");
    assert_clean(&dir);
}

#[test]
fn a_killed_spare_is_replaced_and_the_loop_never_notices() {
    let dir = temp_dir("swap-spare-crash");
    let (child, prefix) = start_lecture_lockstep(&dir, 215);
    let spare = pid_on_duty(&dir, "controller", "spare");
    // SAFETY: a pid of a process this test started (through flexloop).
    unsafe { libc::kill(spare, libc::SIGKILL) };
    wait_for_event(&dir, Duration::from_secs(60), "no new spare", |e| {
        matches!(e.kind, EventKind::Spare(_))
    });
    // The supervisor writes its process list before the events that
    // announce a change: who has read the event finds the new spare listed.
    let replacement = match pids_on_duty(&dir, "controller", "spare")[..] {
        [pid] if pid != spare => pid,
        _ => panic!(
            "the spare event came before the list: {:?}",
            processes(&dir)
        ),
    };
    // And it serves: a swap hands the loop to it.
    swap(
        &prefix,
        "controller",
        &scenario("lecture-double-integrator"),
    );
    assert_eq!(pid_on_duty(&dir, "controller", "active"), replacement);
    stop(&prefix, child);
    let crash = events(&dir)
        .into_iter()
        .find(|e| matches!(e.kind, EventKind::Crash(_)))
        .unwrap();
    assert!(crash_of(&crash).spare, "{crash:?}");
    assert_lost_nothing(&summary(&dir), "across the spare's crash");
    assert_clean(&dir);
}
