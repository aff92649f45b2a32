//! `realtime.tick`: a spinning plant keeps the tick grid (counts only, no
//! timing), falls back with one clear line where it cannot spin, and the
//! setting is refused where the plant does not wait on its clock.

use crate::util::{
    assert_bench_ran, describe, flexloop, processes_mentioning, run_bounded, temp_dir,
};
use flexloop_recording::LogReader;
use flexloop_runfiles::bench::BenchFile;
use flexloop_runfiles::{PlantLatency, RunDir};
use std::path::Path;
use std::time::Duration;

/// The plant's own `plant_latency.json`, typed.
fn plant_latency(run: &Path) -> PlantLatency {
    RunDir::new(run)
        .read_plant_latency()
        .unwrap_or_else(|e| panic!("{e}"))
}

/// `flexloop bench thesis-mc --tick sleep-then-spin ARGS` for half a second
/// at 2 kHz (1000 ticks); it must run (its verdict is this machine's).
fn bench_spinning(args: &[&str], run_dir: &Path) -> String {
    let mut cmd = flexloop();
    cmd.args(["bench", "thesis-mc", "--duration", "0.5", "--rate", "2000"])
        .args(["--tick", "sleep-then-spin", "--no-probes"])
        .args(args)
        .arg("--run-dir")
        .arg(run_dir);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert_bench_ran(&out);
    assert!(processes_mentioning(&run_dir.display().to_string()).is_empty());
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Every tick 0..ticks published once, in order, in the sample file.
fn assert_every_tick_once_in_order(run: &Path, ticks: u64) {
    let log = LogReader::open(&run.join("samples.mcap")).unwrap();
    let seqs: Vec<u64> = log.measurements().map(|m| m.seq).collect();
    assert_eq!(seqs, (0..ticks).collect::<Vec<_>>());
}

#[test]
fn a_spinning_plant_keeps_the_tick_grid() {
    let dir = temp_dir("tick-spin-grid");
    let run = dir.join("run");
    // Real-time priorities as shipped (plant 79 below observer 80 and
    // controller 81), so that the plant does spin; bounded: at most the
    // margin (≤ 60 µs) plus 50 µs of every 500 µs period.
    let stdout = bench_spinning(&[], &run);
    let plant = plant_latency(&run);
    // ticks == duration × rate, each published once, in order.
    assert_eq!(plant.ticks, 1000);
    assert_eq!(plant.latency["tick_lateness"].count, 1000);
    assert_every_tick_once_in_order(&run, 1000);
    let bench: BenchFile = flexloop_runfiles::json::read_json(&RunDir::new(&run).bench())
        .unwrap_or_else(|e| panic!("{e}"));
    let sampling = bench.sampling.expect("bench.json without its sampling");
    assert_eq!(sampling.published_after_tick.count, 1000);
    assert_eq!(sampling.interval_error.count, 999);
    assert_eq!(bench.tick_wait, plant.tick_wait);
    let wait = plant
        .tick_wait
        .as_ref()
        .expect("plant_latency.json without its tick_wait");
    let setting = wait.setting.as_str();
    if setting == "sleep-then-spin" {
        // Every tick either spun up to its time or woke after it.
        let spin = wait
            .spin
            .unwrap_or_else(|| panic!("sleep-then-spin without its spin: {wait:?}"));
        let spun = spin.spun_ticks;
        let late = spin.late_wakeups;
        assert_eq!(spun + late, 1000, "{wait:?}");
        let margin = spin.margin_ns;
        let (lo, hi) = (spin.margin_lower_bound_ns, spin.margin_upper_bound_ns);
        assert!(lo <= margin && margin <= hi, "{wait:?}");
        assert!(
            stdout.contains("tick wait sleep-then-spin; margin"),
            "{stdout}"
        );
    } else {
        // A machine that refuses SCHED_FIFO: the plant said why and slept.
        assert!(setting.contains("refused its priority"), "{wait:?}");
    }
}

#[test]
fn without_real_time_the_spin_falls_back_to_sleep_and_says_so() {
    let dir = temp_dir("tick-spin-fallback");
    let run = dir.join("run");
    let stdout = bench_spinning(&["--no-realtime"], &run);
    let stderr = std::fs::read_to_string(run.join("plant.stderr")).unwrap();
    let said: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("realtime.tick"))
        .collect();
    assert_eq!(said.len(), 1, "{stderr}");
    assert!(
        said[0].contains("cannot work here") && said[0].contains("--no-realtime"),
        "{stderr}"
    );
    let plant = plant_latency(&run);
    let wait = plant
        .tick_wait
        .as_ref()
        .unwrap_or_else(|| panic!("no tick_wait: {plant:?}"));
    let setting = wait.setting.as_str();
    assert!(setting.starts_with("sleep (fallback: "), "{setting}");
    assert!(wait.spin.is_none(), "{plant:?}");
    assert_eq!(plant.ticks, 1000);
    assert!(stdout.contains("tick wait sleep (fallback: "), "{stdout}");
    // The run's recorded settings say the same.
    let log = LogReader::open(&run.join("samples.mcap")).unwrap();
    let recorded = &log.metadata["realtime_tick"];
    assert!(recorded.starts_with("sleep (fallback: "), "{recorded}");
}

#[test]
fn in_lockstep_the_setting_is_refused_before_anything_starts() {
    let dir = temp_dir("tick-lockstep");
    let run = dir.join("run");
    let mut cmd = flexloop();
    cmd.args([
        "run",
        "thesis-mc",
        "--mode",
        "lockstep",
        "--duration",
        "0.1",
    ])
    .args(["--no-realtime", "--tick", "sleep-then-spin", "--run-dir"])
    .arg(&run);
    let out = run_bounded(cmd, Duration::from_secs(60));
    assert!(!out.status.success(), "{}", describe(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("realtime.tick") && stderr.contains("does not apply"),
        "{stderr}"
    );
    assert!(processes_mentioning(&run.display().to_string()).is_empty());
}
