//! `flexloop bench` and `bench --sweep`: what they run and what they write.
//! Only counts and structure are asserted, never a latency.

use crate::util::{
    assert_bench_ran, describe, flexloop, processes_mentioning, run_bounded, temp_dir,
};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::bench::{
    BenchFile, LiveCost, LoggingCost, SweepFile, SweepMeasurement, SweepPoint, SweepResult,
};
use serde::de::DeserializeOwned;
use std::time::Duration;

fn json<T: DeserializeOwned>(path: &std::path::Path) -> T {
    flexloop_runfiles::json::read_json(path).unwrap_or_else(|e| panic!("{e}"))
}

/// `flexloop bench ARGS thesis-mc` for half a second at 2 kHz, which must
/// succeed; its stdout. thesis-mc designs at 2 kHz (the default's AD
/// band-passes sit above its Nyquist frequency).
fn bench_thesis_mc_briefly(args: &[&str], run_dir: &std::path::Path) -> String {
    let mut cmd = flexloop();
    cmd.arg("bench")
        .args(args)
        .args(["thesis-mc", "--duration", "0.5", "--rate", "2000"])
        .args(["--no-realtime", "--run-dir"])
        .arg(run_dir);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert_bench_ran(&out);
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn bench_measures_the_loop_and_every_floor() {
    let dir = temp_dir("bench-floors");
    let run = dir.join("run");
    let stdout = bench_thesis_mc_briefly(&[], &run);
    for row in [
        "round_trip",
        "tick_to_command",
        "probe: timer wake-up",
        "probe: iox2 ping-pong",
        "probe: iox2 polling",
        "probe: socket ring",
        "verdict:",
    ] {
        assert!(stdout.contains(row), "no `{row}` in\n{stdout}");
    }
    let bench: BenchFile = json(&RunDir::new(&run).bench());
    assert_eq!(bench.summary.ticks, 1000);
    // Each floor probes two seconds of ticks at the loop's rate; a polling
    // pong that never answers would leave its histogram empty.
    let probes = bench.probes.expect("bench.json without its probes");
    for (key, floor) in [
        ("timer_wakeup", probes.timer_wakeup),
        ("iceoryx2_event_ping_pong", probes.iceoryx2_event_ping_pong),
        (
            "iceoryx2_polling_ping_pong",
            probes.iceoryx2_polling_ping_pong,
        ),
        ("unix_socket_ring", probes.unix_socket_ring),
    ] {
        let count = floor.count;
        assert!(count > 0 && count <= 4000, "{key}: {count}");
    }
    assert!(processes_mentioning(&run.display().to_string()).is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_sweep_runs_every_point_and_writes_tables_and_plots() {
    let dir = temp_dir("bench-sweep");
    let out_dir = dir.join("sweep");
    let mut cmd = flexloop();
    cmd.args([
        "bench",
        "--sweep",
        "--series",
        "rate,states",
        "--rates",
        "1000,2000",
        "--states",
        "8,12",
        "--duration",
        "0.6",
        "--no-probes",
        "--no-realtime",
    ])
    .arg("--run-dir")
    .arg(&out_dir);
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
    let sweep: SweepFile = json(&out_dir.join("sweep.json"));
    let points = &sweep.points;
    let labels: Vec<&str> = points.iter().map(|p| p.label.as_str()).collect();
    assert_eq!(
        labels,
        [
            "rate-1000hz",
            "rate-2000hz",
            "default",
            "states-8",
            "states-12"
        ]
    );
    fn measured(p: &SweepPoint) -> &SweepMeasurement {
        match &p.result {
            SweepResult::Measured(r) => r,
            SweepResult::Failed { error } => panic!("{}: {error}", p.label),
        }
    }
    for p in points {
        let r = measured(p);
        let rate = p.rate_hz;
        assert_eq!(r.ticks as f64, (rate * 0.6).round(), "{}", p.label);
        assert!(r.round_trip.p50 > 0);
        // Every run is its own run directory with the logger's summary.
        let label = p.label.as_str();
        assert!(RunDir::new(out_dir.join(label)).summary().is_file());
    }
    // The uniform chain of n/2 masses has an observer of exactly n states;
    // the thesis' reduced observer has 9 (rigid + 3 modes, a noise state).
    let states: Vec<usize> = points.iter().map(|p| measured(p).states).collect();
    assert_eq!(states, [9, 9, 9, 8, 12]);
    let markdown = std::fs::read_to_string(out_dir.join("sweep.md")).unwrap();
    assert!(markdown.contains("### Latency per point"), "{markdown}");
    assert!(markdown.contains("compute p50 ∝ n^"), "{markdown}");
    for figure in ["sweep-rate.svg", "sweep-states.svg"] {
        let svg = std::fs::read_to_string(out_dir.join(figure)).unwrap();
        flexloop_plot::xml::check_well_formed(&svg).unwrap_or_else(|e| panic!("{figure}: {e}"));
        assert!(markdown.contains(figure));
    }
    assert!(processes_mentioning(&out_dir.display().to_string()).is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_sweep_refuses_bad_lists_by_flag() {
    for (args, flag) in [
        (&["--states", "7"][..], "--states"),
        (&["--rates", "2000,x"][..], "--rates"),
        (&["--series", "size"][..], "--series"),
    ] {
        let mut cmd = flexloop();
        cmd.args(["bench", "--sweep"]).args(args);
        let out = run_bounded(cmd, Duration::from_secs(30));
        assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
        assert!(
            String::from_utf8_lossy(&out.stderr).contains(flag),
            "{}",
            describe(&out)
        );
    }
}

/// `realtime.profile = "dedicated-cores"` with plant, observer and
/// controller on CPUs 1, 2, 3 and the logger on 0.
fn dedicated_copy(dir: &std::path::Path) -> std::path::PathBuf {
    crate::util::scenario_variant(
        dir,
        "default",
        "dedicated.toml",
        &[
            ("[realtime]", "[realtime]\nprofile = \"dedicated-cores\""),
            (
                "plant = { priority = 79, cpu = 0 }",
                "plant = { priority = 79, cpu = 1 }",
            ),
            (
                "observer = { priority = 80, cpu = 0 }",
                "observer = { priority = 80, cpu = 2 }",
            ),
            (
                "controller = { priority = 81, cpu = 0 }",
                "controller = { priority = 81, cpu = 3 }",
            ),
            (
                "logger = { priority = 10, cpu = 1 }",
                "logger = { priority = 10, cpu = 0 }",
            ),
        ],
        "",
    )
}

/// Commands of a lockstep run, bit for bit.
fn commands(run: &std::path::Path) -> Vec<u64> {
    let log = flexloop_recording::LogReader::open(&run.join("samples.mcap")).unwrap();
    log.commands().map(|c| c.u[0].to_bits()).collect()
}

#[test]
fn dedicated_cores_spins_the_same_loop_or_is_refused_on_too_few_cpus() {
    let dir = temp_dir("bench-dedicated");
    let file = dedicated_copy(&dir);
    let lockstep = |scenario: &std::path::Path, run: &std::path::Path| {
        let mut cmd = flexloop();
        cmd.arg("run")
            .arg(scenario)
            .args(["--mode", "lockstep", "--duration", "0.05", "--no-realtime"])
            .arg("--run-dir")
            .arg(run);
        run_bounded(cmd, Duration::from_secs(120))
    };
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    let out = lockstep(&file, &dir.join("dedicated"));
    if cpus < 4 {
        assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains("realtime.profile") && stderr.contains("needs at least 4 CPUs"),
            "{stderr}"
        );
        assert!(!dir.join("dedicated").join("samples.mcap").exists());
    } else {
        // Spinning changes how the processes wait, not what they compute.
        assert!(out.status.success(), "{}", describe(&out));
        let shared = lockstep(&crate::util::scenario("default"), &dir.join("shared"));
        assert!(shared.status.success(), "{}", describe(&shared));
        let (spun, waited) = (
            commands(&dir.join("dedicated")),
            commands(&dir.join("shared")),
        );
        assert_eq!(spun.len(), 500);
        assert_eq!(spun, waited);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn logging_cost_runs_the_loop_with_and_without_a_logger() {
    let dir = temp_dir("bench-logging-cost");
    let out_dir = dir.join("cost");
    let stdout = bench_thesis_mc_briefly(&["--logging-cost"], &out_dir);
    assert!(stdout.contains("round trip, logger off"), "{stdout}");
    let cost: LoggingCost = json(&out_dir.join("logging_cost.json"));
    for (run, r) in [
        ("with_logger", &cost.with_logger),
        ("without_logger", &cost.without_logger),
    ] {
        assert_eq!(r.ticks, 1000, "{run}");
        // One round trip per command of the active controller received: a
        // tick without one is a miss (the last one's may come after the
        // plant stopped).
        let count = r.latency["round_trip"].count;
        let missed = r.counters.misses + r.counters.stall_misses;
        assert!(
            count <= 1000 && count + missed + 1 >= 1000,
            "{run}: {count}, {missed} missed"
        );
        assert_eq!(r.latency["tick_lateness"].count, 1000, "{run}");
    }
    let with = out_dir.join("with-logger");
    let without = out_dir.join("without-logger");
    // The logger recorded the first run and never ran in the second.
    assert!(with.join("samples.mcap").is_file() && with.join("summary.json").is_file());
    assert!(!without.join("samples.mcap").exists() && !without.join("summary.json").exists());
    let copy = std::fs::read_to_string(out_dir.join("without-logger.toml")).unwrap();
    assert!(copy.contains("[logger]\nenabled = false"), "{copy}");
    assert!(processes_mentioning(&out_dir.display().to_string()).is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn live_cost_runs_the_loop_served_to_a_client_and_without_a_server() {
    let dir = temp_dir("bench-live-cost");
    let out_dir = dir.join("cost");
    let mut cmd = flexloop();
    // Long enough for the server to listen and the client to subscribe
    // after the first tick, however loaded the machine.
    cmd.args([
        "bench",
        "--live-cost",
        "thesis-mc",
        "--duration",
        "5",
        "--rate",
        "1000",
    ])
    .args(["--no-realtime", "--run-dir"])
    .arg(&out_dir);
    let out = run_bounded(cmd, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("round trip, no live server") && stdout.contains("the live view costs"),
        "{stdout}"
    );
    let cost: LiveCost = json(&out_dir.join("live_cost.json"));
    for (run, r) in [
        ("with_client", &cost.with_client),
        ("without_server", &cost.without_server),
    ] {
        assert_eq!(r.ticks, 5000, "{run}");
    }
    // The client subscribed to everything and got what the server handed
    // it (a client that reads as fast as it can, at 1 kHz).
    let handed = cost.server.messages_sent;
    let received = cost.client_messages;
    assert!(received > 0 && received <= handed, "{cost:?}");
    // The server ran in the first run only, and left no file behind.
    let with = out_dir.join("with-client");
    assert!(with.join("live_summary.json").is_file());
    assert!(!with.join("live.json").exists());
    assert!(
        !out_dir
            .join("without-server")
            .join("live_summary.json")
            .exists()
    );
    assert!(processes_mentioning(&out_dir.display().to_string()).is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}
