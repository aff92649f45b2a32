//! The sample file and the latency log: read back by independent readers
//! (the official MCAP Python package with its ROS1 decoder, the HdrHistogram
//! Python package), exported as CSV, and finished or repaired whatever
//! happens to the run: Ctrl-C, a killed plant, a killed logger, a full disk.

use crate::util::*;
use flexloop_recording::LogReader;
use flexloop_runfiles::events::EventKind;
use flexloop_runfiles::json::read_json;
use flexloop_runfiles::summary::ClosedFile;
use flexloop_runfiles::supervision::Processes;
use flexloop_runfiles::{PlantLatency, RunDir};
use serde_json::Value;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

/// The Python with the pinned independent readers.
fn python() -> String {
    python_with(&["mcap", "mcap_ros1", "hdrh"])
}

/// Runs one of the checking scripts on `file`; its stdout is JSON.
fn python_check(python: &str, script: &str, file: &Path) -> Value {
    let mut cmd = Command::new(python);
    cmd.arg(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/integration/python")
            .join(script),
    )
    .arg(file);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(
        out.status.success(),
        "{}\n(the Python readers: pip install mcap mcap-ros1-support hdrhistogram; .ci/run installs them)",
        describe(&out)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {}", describe(&out)))
}

/// The plant's own `plant_latency.json`, typed.
fn plant_latency(dir: &Path) -> PlantLatency {
    RunDir::new(dir)
        .read_plant_latency()
        .unwrap_or_else(|e| panic!("{e}"))
}

/// A finished lockstep run of the lecture loop.
fn lockstep_run(name: &str, seconds: &str) -> TestDir {
    let dir = temp_dir(name);
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario("lecture-double-integrator"))
        .args(["--no-realtime", "--mode", "lockstep", "--duration", seconds])
        .arg("--run-dir")
        .arg(&dir);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    dir
}

const LOOP_TOPICS: [(&str, &str, &str); 3] = [
    ("/measurement", "flexloop/Measurement", "measurement"),
    ("/estimate", "flexloop/Estimate", "estimate"),
    ("/command", "flexloop/Command", "command"),
];

/// What the Python reader saw in `file` agrees with flexloop's reader.
fn assert_python_agrees(python: &str, file: &Path, log: &LogReader) -> Value {
    let seen = python_check(python, "check_mcap.py", file);
    let counts = [
        log.measurements().count(),
        log.estimates().count(),
        log.commands().count(),
    ];
    for ((topic, schema, _), count) in LOOP_TOPICS.iter().zip(counts) {
        let c = &seen["channels"][topic];
        assert_eq!(c["schema"], *schema, "{seen}");
        assert_eq!(c["schema_encoding"], "ros1msg");
        assert_eq!(c["message_encoding"], "ros1");
        assert_eq!(c["count"], count as u64, "{topic}");
        assert_eq!(
            seen["statistics"]["channel_message_counts"][topic],
            count as u64
        );
        // Decoded by genpy from the schema alone and written back: the same
        // bytes, so the file is ROS1 serialisation of its schemas.
        assert_eq!(c["reserialises_identically"], true, "{topic}");
        assert_eq!(c["header_sequence_matches"], true, "{topic}");
        assert_eq!(c["log_time_is_published_ns"], true, "{topic}");
    }
    let events = &seen["channels"]["/events"];
    assert_eq!(events["schema"], "flexloop/Event");
    assert_eq!(events["schema_encoding"], "jsonschema");
    assert_eq!(events["message_encoding"], "json");
    assert_eq!(events["count"], log.events.len() as u64);
    seen
}

#[test]
fn the_sample_file_reads_back_with_the_official_mcap_reader() {
    let python = python();
    let dir = lockstep_run("mcap-python", "0.3");
    let file = dir.join("samples.mcap");
    let log = LogReader::open(&file).unwrap();
    assert!(!log.torn_tail, "{:?}", log.tail_error);
    let summary = summary(&dir);
    let seen = assert_python_agrees(&python, &file, &log);
    for (topic, _, channel) in LOOP_TOPICS {
        let c = &seen["channels"][topic];
        assert_eq!(c["count"], of_channel(&summary.samples, channel), "{topic}");
        // Sequence continuity: whatever is missing is what the logger
        // counted as gaps (on a starved machine it may lose samples, never
        // silently: those it never received and those its writer's queue
        // had no room for).
        assert_eq!(
            c["missing"],
            of_channel(&summary.gaps, channel),
            "{topic}: {c}"
        );
        assert_eq!(c["in_order"], true, "{topic}");
    }
    let m = &seen["channels"]["/measurement"];
    assert_eq!(m["first_seq"], 0);
    assert_eq!(m["last_seq"], 2_999, "0.3 s at 10 kHz");
    let first = log.measurements().next().unwrap();
    let y0 = seen["first_measurement"]["y"][0].as_f64().unwrap();
    assert!((y0 - first.y[0]).abs() <= 1e-12 * first.y[0].abs().max(1e-300));
    // Events: the logger's own, in the file's JSON schema.
    let kinds: Vec<&str> = seen["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|e| e["kind"].as_str())
        .collect();
    assert_eq!(kinds.first(), Some(&"recording-start"), "{kinds:?}");
    assert_eq!(kinds.last(), Some(&"recording-end"), "{kinds:?}");
    // Run metadata.
    let meta = &seen["metadata"]["flexloop"];
    assert_eq!(meta["scenario"], "lecture-double-integrator");
    assert_eq!(meta["mode"], "lockstep");
    assert_eq!(meta["rate_hz"], "10000");
    assert_eq!(meta["period_ns"], "100000");
    assert!(meta["scenario_toml"].as_str().unwrap().contains("[plant]"));
    assert!(!meta["kernel_release"].as_str().unwrap().is_empty());
    assert!(meta["cpu_count"].as_str().unwrap().parse::<u32>().unwrap() >= 1);
    assert!(meta["realtime_plant"].as_str().unwrap().contains("cpu="));
    assert_eq!(meta["flexloop_version"], env!("CARGO_PKG_VERSION"));
    assert_eq!(summary.recording.sample_file.state, "complete");
    assert_clean(&dir);
}

#[test]
fn the_latency_log_decodes_to_the_summary_percentiles() {
    let python = python();
    let dir = lockstep_run("hlog-python", "0.3");
    let decoded = python_check(&python, "check_hlog.py", &dir.join("latency.hlog"));
    let summary = summary(&dir);
    let latency = &summary.latency;
    // Within the histograms' precision: 3 significant digits.
    let close = |a: u64, b: u64| a.abs_diff(b) <= a.max(b) / 1000 + 1;
    let mut compared = 0;
    for (metric, s) in latency {
        let count = s.count;
        if count == 0 {
            continue;
        }
        let d = &decoded[metric];
        assert_eq!(d["count"].as_u64(), Some(count), "{metric}: {d} vs {s:?}");
        assert!(d["intervals"].as_u64().unwrap() >= 1);
        let labels = ["p50", "p90", "p99", "p99.9", "p99.99", "max"];
        for (label, b) in labels.into_iter().zip(s.percentiles.values()) {
            let key = format!("{label}_ns");
            let a = d[&key].as_u64().unwrap();
            assert!(close(a, b), "{metric} {label}: log {a} ns, summary {b} ns");
        }
        compared += 1;
    }
    assert!(compared >= 5, "{latency:?}");
    assert_clean(&dir);
}

#[test]
fn export_writes_one_csv_per_channel_with_units() {
    let dir = lockstep_run("export", "0.1");
    let mut cmd = flexloop();
    cmd.arg("export").arg(&dir).arg("--csv");
    let out = run_bounded(cmd, Duration::from_secs(60));
    assert!(out.status.success(), "{}", describe(&out));
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let read = |name: &str| std::fs::read_to_string(dir.join("csv").join(name)).unwrap();
    let measurements = read("measurement.csv");
    let mut lines = measurements.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(&header[..3], ["t (s)", "seq", "tick_ns (ns)"]);
    // One output, one input: the unused array slots are left out.
    assert!(header.contains(&"y[0] (m)") && !header.iter().any(|h| h.starts_with("y[1]")));
    assert!(header.contains(&"u_applied[0] (N)"));
    let y = header.iter().position(|h| *h == "y[0] (m)").unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), log.measurements().count());
    for (row, m) in rows.iter().zip(log.measurements()) {
        assert_eq!(row.len(), header.len());
        assert_eq!(row[1].parse::<u64>().unwrap(), m.seq);
        assert_eq!(row[y].parse::<f64>().unwrap(), m.y[0], "exact round trip");
        assert_eq!(row[0].parse::<f64>().unwrap(), m.seq as f64 * 1e-4);
    }
    let commands = read("command.csv");
    let header = commands.lines().next().unwrap();
    for column in [
        "u[0] (N)",
        "u_fb[0] (N)",
        "u_ff[0] (N)",
        "u_d[0] (N)",
        "r[0] (m)",
        "e_meas[0] (m)",
    ] {
        assert!(header.contains(column), "{column} in {header}");
    }
    assert_eq!(commands.lines().count(), log.commands().count() + 1);
    let estimates = read("estimate.csv");
    let n_states = log.estimates().next().unwrap().n_states as usize;
    let header = estimates.lines().next().unwrap();
    assert!(header.contains(&format!("x_hat[{}]", n_states - 1)));
    assert!(!header.contains(&format!("x_hat[{n_states}]")));
    let events = read("events.csv");
    assert!(events.starts_with("log_time (ns),source,kind,phase,seq,event (json)\n"));
    assert!(events.contains(",logger,recording-start,"), "{events}");
    assert_eq!(events.lines().count(), log.events.len() + 1);
    assert_clean(&dir);
}

#[test]
fn export_of_a_bad_run_path_says_what_is_wrong() {
    let missing = temp_dir("export-bad").join("no-such-run");
    let mut cmd = flexloop();
    cmd.arg("export").arg(&missing).arg("--csv");
    let out = run_bounded(cmd, Duration::from_secs(30));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("no-such-run") && err.contains("no such run directory"),
        "{err}"
    );
    let empty = temp_dir("export-empty");
    let mut cmd = flexloop();
    cmd.arg("export").arg(&empty).arg("--csv");
    let out = run_bounded(cmd, Duration::from_secs(30));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(err.contains("no samples.mcap"), "{err}");
    let mut cmd = flexloop();
    cmd.arg("export").arg(&empty);
    let out = run_bounded(cmd, Duration::from_secs(30));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--csv"));
}

fn seqs(log: &LogReader) -> Vec<u64> {
    log.measurements().map(|m| m.seq).collect()
}

fn ends_in_mcap_magic(path: &Path) -> bool {
    std::fs::read(path).is_ok_and(|b| b.ends_with(b"\x89MCAP0\r\n"))
}

#[test]
fn a_killed_logger_leaves_its_complete_chunks_and_the_run_closes_its_file() {
    let dir = temp_dir("kill-logger");
    let (child, prefix) = start_lecture_lockstep(&dir, 500);
    let pid = *pids_of(&dir, "logger").first().expect("a logger");
    // SAFETY: a pid of a process this test started (through flexloop).
    unsafe { libc::kill(pid, libc::SIGKILL) };
    let since = Instant::now();
    while pids_of(&dir, "logger").contains(&pid) {
        assert!(since.elapsed() < Duration::from_secs(30), "logger lives");
        std::thread::sleep(Duration::from_millis(20));
    }
    // As the killed logger left it: every complete chunk reads back.
    let torn = LogReader::parse(&std::fs::read(dir.join("samples.mcap")).unwrap()).unwrap();
    assert!(torn.torn_tail);
    let kept = seqs(&torn);
    assert!(kept.len() >= 500, "{} ticks", kept.len());
    assert!(kept.windows(2).all(|w| w[0] < w[1]));
    let out = stop(&prefix, child);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("samples.mcap: the logger did not finish it; closed"),
        "{err}"
    );
    // Closed by flexloop at the end of the run: a finished, indexed file
    // with everything the torn one held.
    let repaired = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert!(!repaired.torn_tail, "{:?}", repaired.tail_error);
    assert!(ends_in_mcap_magic(&dir.join("samples.mcap")));
    assert_eq!(seqs(&repaired)[..kept.len()], kept[..]);
    assert_python_agrees(&python(), &dir.join("samples.mcap"), &repaired);
    // A restarted logger (if it came back before the stop) wrote its own,
    // finished file.
    if let Ok(second) = LogReader::open(&dir.join("samples.g1.mcap")) {
        assert!(!second.torn_tail, "{:?}", second.tail_error);
    }
    assert_clean(&dir);
}

#[test]
fn a_full_disk_stops_the_recording_not_the_loop() {
    let dir = temp_dir("disk-full");
    let (child, prefix) =
        start_and_await(&dir, "lecture-double-integrator", &["--rate", "1000"], 100);
    let pid = *pids_of(&dir, "logger").first().expect("a logger");
    let file = dir.join("samples.mcap");
    // The logger alone may write at most 64 KiB more into any file: its disk
    // is full from there on (a file-size limit fails writes as ENOSPC does).
    let limit = std::fs::metadata(&file).unwrap().len() + 64 * 1024;
    let rlimit = libc::rlimit {
        rlim_cur: limit,
        rlim_max: limit,
    };
    // SAFETY: lowers a limit of a process this test started.
    let set = unsafe { libc::prlimit(pid, libc::RLIMIT_FSIZE, &rlimit, std::ptr::null_mut()) };
    assert_eq!(set, 0, "prlimit: {}", std::io::Error::last_os_error());
    // The logger closes the file when a write fails: it then ends in magic.
    let since = Instant::now();
    while !ends_in_mcap_magic(&file) {
        assert!(
            since.elapsed() < Duration::from_secs(60),
            "the file never filled up"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let closed_len = std::fs::metadata(&file).unwrap().len();
    assert!(closed_len <= limit);
    // The loop goes on meanwhile.
    std::thread::sleep(Duration::from_millis(500));
    let out = stop(&prefix, child);
    // `up` says so at its end: the loop ran on without a recording.
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(
        said.contains("the recording stopped before the run ended: samples.mcap holds"),
        "{}",
        describe(&out)
    );
    let err = std::fs::read_to_string(dir.join("logger.stderr")).unwrap();
    assert!(
        err.contains("samples.mcap: File too large") && err.contains("recording stopped"),
        "{err}"
    );
    let s = summary(&dir);
    let recording = &s.recording.sample_file;
    assert_eq!(recording.state, "stopped", "{recording:?}");
    assert!(
        recording
            .error
            .as_deref()
            .unwrap()
            .contains("File too large"),
        "{recording:?}"
    );
    assert!(recording.dropped_messages > 0);
    let log = LogReader::open(&file).unwrap();
    assert!(!log.torn_tail, "{:?}", log.tail_error);
    let kept = seqs(&log);
    assert_eq!(kept.first(), Some(&0));
    assert!(kept.windows(2).all(|w| w[0] < w[1]));
    // The logger counted every tick after the recording stopped.
    let ticks = s.samples.measurement;
    assert!(
        ticks > kept.len() as u64 + 100,
        "{ticks} ticks, {} kept",
        kept.len()
    );
    let Some(ClosedFile::Closed {
        messages, indexed, ..
    }) = recording.closed
    else {
        panic!("not closed: {recording:?}");
    };
    assert_eq!(messages, (log.records.len() + log.events.len()) as u64);
    // Indexed when the summary fitted in the room cutting the torn chunk made.
    let bytes = std::fs::read(&file).unwrap();
    assert_eq!(mcap::Summary::read(&bytes).unwrap().is_some(), indexed);
    if indexed {
        assert_python_agrees(&python(), &file, &log);
    }
    // The report says that the recording stopped, and when.
    let mut report = flexloop();
    report.arg("report").arg(&*dir);
    let out = run_bounded(report, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("the recording stopped at t = ") && err.contains("File too large"),
        "{err}"
    );
    assert_clean(&dir);
}

#[test]
fn ctrl_c_and_a_killed_plant_leave_finished_sample_files() {
    // Ctrl-C: SIGINT to the supervisor.
    let dir = temp_dir("ctrl-c");
    let (child, _prefix) = start_lecture_lockstep(&dir, 200);
    // SAFETY: the supervisor this test started.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let out = child.wait(Duration::from_secs(60));
    assert!(out.status.success(), "{}", describe(&out));
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert!(!log.torn_tail, "{:?}", log.tail_error);
    assert!(seqs(&log).len() >= 200);
    assert_eq!(summary(&dir).recording.sample_file.state, "complete");
    assert!(
        log.events
            .iter()
            .any(|e| e.message.kind() == "recording-end")
    );
    assert_clean(&dir);

    // kill -9 of the plant: the supervisor stops the rest, the logger finishes.
    let dir = temp_dir("kill-plant");
    let (child, _prefix) = start_lecture_lockstep(&dir, 200);
    let plant = *pids_of(&dir, "plant").first().expect("a plant");
    // SAFETY: a pid of a process this test started (through flexloop).
    unsafe { libc::kill(plant, libc::SIGKILL) };
    let out = child.wait(Duration::from_secs(60));
    assert!(
        !out.status.success(),
        "a dead plant fails the run: {}",
        describe(&out)
    );
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert!(!log.torn_tail, "{:?}", log.tail_error);
    assert!(seqs(&log).len() >= 200);
    assert_eq!(summary(&dir).recording.sample_file.state, "complete");
    assert_clean(&dir);
}

/// `flexloop <command> --prefix <prefix>`, bounded.
fn flexloop_on(command: &str, prefix: &str) -> std::process::Output {
    let mut cmd = flexloop();
    cmd.args([command, "--prefix", prefix]);
    run_bounded(cmd, Duration::from_secs(120))
}

#[test]
fn the_next_down_finishes_a_loop_whose_supervisor_and_logger_were_killed() {
    let dir = temp_dir("dead-supervisor");
    let (child, prefix) = start_lecture_lockstep(&dir, 500);
    let logger = pid_on_duty(&dir, "logger", "active");
    // SAFETY: pids of processes this test started (through flexloop).
    unsafe {
        libc::kill(child.id() as i32, libc::SIGKILL);
        libc::kill(logger, libc::SIGKILL);
    }
    let out = child.wait(Duration::from_secs(30));
    assert!(!out.status.success());
    // What the dead supervisor left: its last process list and its files.
    assert!(!processes(&dir).is_empty());
    let down = flexloop_on("down", &prefix);
    assert!(down.status.success(), "{}", describe(&down));
    let said = String::from_utf8_lossy(&down.stdout);
    // Another test's command may have found the dead loop first; then it
    // said so, and this one waited until it was done.
    if said.contains(&prefix) {
        assert!(said.contains("lost its supervisor"), "{said}");
        assert!(
            said.contains("samples.mcap: the logger did not finish it; closed"),
            "{said}"
        );
        assert!(said.contains("processes.json: marked ended"), "{said}");
    }
    // Nothing left: no process, no shared memory, no registry entry.
    assert_clean(&dir);
    let status = flexloop_on("status", &prefix);
    assert!(
        String::from_utf8_lossy(&status.stdout).contains("no loop running"),
        "{}",
        describe(&status)
    );
    let listed: Processes =
        read_json(&RunDir::new(&*dir).processes()).unwrap_or_else(|e| panic!("{e}"));
    assert!(listed.processes.is_empty(), "{listed:?}");
    assert!(
        listed.ended.as_deref().unwrap().contains("died"),
        "{listed:?}"
    );
    // The file is closed: the official reader's indexed read opens it.
    let file = dir.join("samples.mcap");
    let log = LogReader::open(&file).unwrap();
    assert!(!log.torn_tail, "{:?}", log.tail_error);
    assert!(seqs(&log).len() >= 500);
    assert_python_agrees(&python(), &file, &log);
    // The summary the logger could not write, rebuilt from the file: every
    // tick the plant counted is recorded or a gap.
    let s = summary(&dir);
    let plant = plant_latency(&dir);
    assert_eq!(s.ticks, plant.ticks, "{s:?}");
    let recorded = s.samples.measurement;
    assert_eq!(recorded, seqs(&log).len() as u64);
    assert_eq!(recorded + s.gaps.measurement, s.ticks, "{s:?}");
    assert_eq!(
        s.generations.first().map(|g| g.state.as_str()),
        Some("killed"),
        "{s:?}"
    );
}

#[test]
fn a_logger_killed_three_times_leaves_one_summary_and_every_tick_accounted_for() {
    logger_killed_three_times("logger-generations-lockstep", &["--mode", "lockstep"]);
}

#[test]
fn in_realtime_too_every_tick_of_a_logger_killed_three_times_is_recorded_or_a_gap() {
    logger_killed_three_times(
        "logger-generations-realtime",
        &["--mode", "realtime", "--rate", "1000"],
    );
}

/// Kills a run's logger three times, then checks that the summary, the
/// export and its gap events account for every tick the plant counted.
fn logger_killed_three_times(name: &str, mode: &[&str]) {
    let dir = temp_dir(name);
    let (child, prefix) = start(&dir, "lecture-double-integrator", mode);
    let files = [
        "samples.mcap",
        "samples.g1.mcap",
        "samples.g2.mcap",
        "samples.g3.mcap",
    ];
    for (kill, file) in files[..3].iter().enumerate() {
        wait_for_ticks_in(&dir, file, 300);
        let pid = pid_on_duty(&dir, "logger", "active");
        // SAFETY: a pid of a process this test started (through flexloop).
        unsafe { libc::kill(pid, libc::SIGKILL) };
        let since = Instant::now();
        while events(&dir)
            .iter()
            .filter(|e| matches!(e.kind, EventKind::Restart(_)) && e.role == "logger")
            .count()
            <= kill
        {
            assert!(
                since.elapsed() < Duration::from_secs(90),
                "the logger did not come back: {:?}",
                events(&dir)
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    wait_for_ticks_in(&dir, files[3], 300);
    stop(&prefix, child);
    // One summary for the run: every generation, every tick the plant
    // counted recorded or in a gap.
    let s = summary(&dir);
    let generations: Vec<&str> = s.generations.iter().map(|g| g.file.as_str()).collect();
    assert_eq!(generations, files, "{s:?}");
    let plant = plant_latency(&dir);
    let ticks = s.ticks;
    assert_eq!(ticks, plant.ticks, "{s:?}");
    for channel in ["measurement", "command"] {
        assert_eq!(
            of_channel(&s.samples, channel) + of_channel(&s.gaps, channel),
            ticks,
            "{channel}: {s:?}"
        );
    }
    // The export joins the four files: its rows and its gap events add up
    // to the run's ticks.
    let mut cmd = flexloop();
    cmd.arg("export").arg(&dir).arg("--csv");
    let export = run_bounded(cmd, Duration::from_secs(120));
    assert!(export.status.success(), "{}", describe(&export));
    assert!(
        String::from_utf8_lossy(&export.stderr).contains("joined 4 sample files"),
        "{}",
        describe(&export)
    );
    let csv = |name: &str| std::fs::read_to_string(dir.join("csv").join(name)).unwrap();
    let events_csv = csv("events.csv");
    let gap_events: Vec<Value> = events_csv
        .lines()
        .skip(1)
        .filter_map(|l| {
            let json = &l[l.find(",\"{").map(|i| i + 2)?..l.len() - 1];
            serde_json::from_str::<Value>(&json.replace("\"\"", "\"")).ok()
        })
        .filter(|e| e["kind"] == "gap")
        .collect();
    for channel in ["measurement", "command"] {
        let rows = csv(&format!("{channel}.csv")).lines().count() as u64 - 1;
        let gaps: u64 = gap_events
            .iter()
            .filter(|e| e["channel"] == channel)
            .map(|e| e["count"].as_u64().unwrap())
            .sum();
        assert_eq!(rows + gaps, ticks, "{channel}: {rows} rows, {gaps} in gaps");
    }
    // Every outage between two loggers is a gap event of the summary.
    for o in &s.outages {
        assert!(
            gap_events
                .iter()
                .any(|e| e["cause"] == "logger-outage" && e["seq"] == o.seq),
            "{o:?}"
        );
    }
    assert_clean(&dir);
}

#[test]
fn a_test_that_does_not_stop_its_loop_leaves_nothing_behind() {
    let dir = temp_dir("unstopped");
    let (child, prefix) = start_lecture_lockstep(&dir, 100);
    // As a failing test's unwinding drops it.
    drop(child);
    let left = processes_mentioning(&dir.display().to_string());
    assert!(left.is_empty(), "processes left: {left:?}");
    let files = flexloop_transport::leftover_files_for_prefix(&prefix);
    assert!(files.is_empty(), "shared memory left: {files:?}");
}
