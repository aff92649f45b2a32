//! An observer of one's own killed mid-run with warm spares on (the
//! default): the supervisor restarts the program, which takes over its dead
//! predecessor's x̂ and steps through the supervisor's replay of the
//! measurements since. The idle spare observer reads the replay channel
//! too; the replay must reach the restarted program all the same, or it
//! goes on with a hole and a lockstep loop, which waits for its estimate,
//! stops. The Rust example (examples/luenberger-observer) and its Python
//! twin (python/examples/luenberger.py).

use crate::own_components::{built, observer_scenario};
use crate::util::*;
use flexloop_protocol::Measurement;
use flexloop_recording::LogReader;
use flexloop_runfiles::events::{EventKind, SupervisorEvent};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The example observer's scenario (both examples' programs as built
/// here) with the observer served by `observer_exec`, in `dir`. Warm spares
/// are the default: asserted, not set.
fn scenario_with_observer(dir: &Path, observer_exec: Option<&[String]>) -> PathBuf {
    let path = observer_scenario(dir);
    let mut table: toml::Table = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert!(
        table.get("supervision").is_none(),
        "the example's scenario sets [supervision]: this test wants its defaults"
    );
    if let Some(exec) = observer_exec {
        table["observer"]["exec"] = toml::Value::Array(
            exec.iter()
                .map(|a| toml::Value::String(a.clone()))
                .collect(),
        );
    }
    std::fs::write(&path, toml::to_string(&table).unwrap()).unwrap();
    path
}

/// Waits (bounded) until the run's first sample file holds `ticks`
/// measurements; fails at once, with its output, if the run has ended.
fn await_ticks(up: &mut Up, dir: &Path, ticks: usize) {
    let since = Instant::now();
    loop {
        let recorded = recorded_ticks_in(dir, "samples.mcap");
        if recorded >= ticks {
            return;
        }
        if let Some(out) = up.ended() {
            panic!(
                "the run ended at {recorded} of {ticks} ticks: {}\nevents: {:?}\n{}",
                describe(&out),
                events(dir),
                stderr_files(dir)
            );
        }
        assert!(
            since.elapsed() < Duration::from_secs(90),
            "the loop stopped: {recorded} of {ticks} ticks\nevents: {:?}\n{}",
            events(dir),
            stderr_files(dir)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Every observer and controller stderr file of the run, named, for a
/// failure's message.
fn stderr_files(dir: &Path) -> String {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    files.retain(|p| {
        let name = p.file_name().unwrap().to_string_lossy();
        name.ends_with(".stderr")
            && (name.starts_with("observer") || name.starts_with("controller"))
    });
    files.sort();
    files
        .iter()
        .map(|p| {
            format!(
                "--- {}:\n{}",
                p.display(),
                std::fs::read_to_string(p).unwrap_or_default()
            )
        })
        .collect()
}

/// The example's predictor (1 kg, 200 Hz, ζ 0.7 at 10 kHz) stepped from
/// x̂ = 0 at tick 0 through the recorded measurements: x̂ by tick. Asserts
/// that the measurements are contiguous from 0.
fn predictor(log: &LogReader) -> Vec<[f64; 2]> {
    let law = Predictor::example();
    let measurements: BTreeMap<u64, &Measurement> =
        log.measurements().map(|m| (m.seq, m)).collect();
    let seqs: Vec<u64> = measurements.keys().copied().collect();
    assert_eq!(seqs[0], 0);
    assert_eq!(
        seqs.len() as u64,
        seqs.last().unwrap() + 1,
        "the recorded measurements have gaps"
    );
    let mut x = vec![[0.0, 0.0]];
    for m in measurements.values() {
        x.push(law.step(*x.last().unwrap(), m.y[0], m.u_applied[0]));
    }
    x
}

/// Runs the example loop in lockstep on `observer_exec` (None: the Rust
/// example), kills the observer program mid-run and checks the restart.
fn a_killed_observer_program_catches_up_with_warm_spares(
    test: &str,
    observer_exec: Option<&[String]>,
    program: &str,
) {
    let dir = temp_dir(test);
    let file = scenario_with_observer(&dir, observer_exec);
    let (mut up, prefix) = start_file(&dir, &file, &["--mode", "lockstep"]);
    await_ticks(&mut up, &dir, 1_500);
    // With warm spares: an idle spare observer (built-in) beside the program.
    let spares = pids_on_duty(&dir, "observer", "spare");
    assert_eq!(spares.len(), 1, "{:?}", processes(&dir));
    let observer = pid_on_duty(&dir, "observer", "active");
    let cmdline = std::fs::read(format!("/proc/{observer}/cmdline")).unwrap_or_default();
    assert!(
        String::from_utf8_lossy(&cmdline).contains(program),
        "the active observer is not the program {program}: {}",
        String::from_utf8_lossy(&cmdline)
    );
    // SAFETY: a process of this test's loop, by the pid its supervisor lists.
    unsafe { libc::kill(observer, libc::SIGKILL) };
    assert_gone(observer);
    let since = Instant::now();
    let restart: SupervisorEvent = loop {
        if let Some(e) = events(&dir)
            .into_iter()
            .find(|e| matches!(e.kind, EventKind::Restart(_)) && e.role == "observer")
        {
            break e;
        }
        if let Some(out) = up.ended() {
            panic!(
                "the run ended before a restart: {}\nevents: {:?}\n{}",
                describe(&out),
                events(&dir),
                stderr_files(&dir)
            );
        }
        assert!(
            since.elapsed() < Duration::from_secs(60),
            "no restart: {:?}\n{}",
            events(&dir),
            stderr_files(&dir)
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(restart.generation, Some(1), "{restart:?}");
    let switch = restart
        .kind
        .switch()
        .unwrap_or_else(|| panic!("a restart without its switch: {restart:?}"));
    // A program is never a spare: a new process of it took over.
    assert!(!switch.warm, "{restart:?}");
    assert!(
        restart_of(&restart).rolled_back_from.is_none(),
        "the loop started on the program: nothing to roll back to: {restart:?}"
    );
    let from_seq = switch.from_seq;
    // The loop keeps running past the restart.
    let after = recorded_ticks_in(&dir, "samples.mcap");
    await_ticks(&mut up, &dir, after + 1_500);
    stop(&prefix, up);

    // The restart's own words: the dead one's state, the replay, no hole.
    let said = std::fs::read_to_string(dir.join("observer.g1.stderr")).unwrap_or_default();
    eprintln!("{test}: {restart:?}\n{said}");
    assert!(
        said.contains("took over the state after sample") && !said.contains("hole"),
        "{said}"
    );

    let summary = summary(&dir);
    let counters = summary.counters;
    for (counter, count) in [
        ("stale_estimates", counters.stale_estimates),
        ("rejected_commands", counters.rejected_commands),
    ] {
        assert_eq!(count, 0, "{counter}: {summary:?}");
    }
    // Lockstep waits for the restart: it misses no tick and accounts for
    // no lost sample.
    assert_lost_nothing(&summary, test);

    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let x = predictor(&log);
    let mut by_generation: BTreeMap<u32, BTreeSet<u64>> = BTreeMap::new();
    for e in log.estimates() {
        by_generation.entry(e.generation).or_default().insert(e.seq);
        // Every estimate, before the crash and after the restart, is the
        // predictor's on the recorded measurements from tick 0: the restart
        // loaded its predecessor's x̂ and stepped every measurement since.
        assert_estimate_is(e, x[e.seq as usize]);
    }
    assert_eq!(
        by_generation.keys().copied().collect::<Vec<_>>(),
        [0, 1],
        "{summary:?}"
    );
    let (first, second) = (&by_generation[&0], &by_generation[&1]);
    // One estimate for every tick, the restart's from its boundary on.
    let all: BTreeSet<u64> = first.union(second).copied().collect();
    let last = *all.last().unwrap();
    assert_eq!(all.len() as u64, last + 1, "estimates missing");
    // The restart owns from the first sample after the dead one's last
    // state; a kill between an estimate and the state that follows it
    // leaves that one estimate from both (equal, as checked above).
    assert!(
        *second.first().unwrap() >= from_seq && *first.last().unwrap() <= from_seq,
        "generation 0 up to {}, generation 1 from {}, boundary {from_seq}",
        first.last().unwrap(),
        second.first().unwrap()
    );
    assert!(
        second.len() > 1_000,
        "{} estimates after the restart",
        second.len()
    );
    assert_clean(&dir);
}

#[test]
fn a_killed_rust_observer_program_catches_up_with_warm_spares() {
    a_killed_observer_program_catches_up_with_warm_spares(
        "observer-restart-rust",
        None,
        &built("luenberger-observer").display().to_string(),
    );
}

#[test]
fn a_killed_python_observer_program_catches_up_with_warm_spares() {
    let python = python_with(&["flexloop", "iceoryx2"]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("python/examples/luenberger.py")
        .display()
        .to_string();
    a_killed_observer_program_catches_up_with_warm_spares(
        "observer-restart-python",
        Some(&[python, script.clone()]),
        &script,
    );
}
