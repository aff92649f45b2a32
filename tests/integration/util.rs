//! Helpers: temp run directories, bounded process waits, leftover checks.

use flexloop_protocol::Estimate;
use flexloop_recording::LogReader;
use flexloop_runfiles::events::{
    Crash, EventKind, Restart, Set, Silent, Standby, Stop, SupervisorEvent, Swap, parse_events,
};
use flexloop_runfiles::metrics::MetricsFile;
use flexloop_runfiles::summary::{PerChannel, RunSummary};
use flexloop_runfiles::supervision::{ProcessEntry, Processes, SwitchRecord};
use flexloop_runfiles::{FileError, RunDir};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

pub fn flexloop() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_flexloop"));
    cmd.current_dir(env!("CARGO_MANIFEST_DIR"));
    cmd
}

pub fn scenario(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios")
        .join(format!("{name}.toml"))
}

/// A test's own variant of the shipped scenario `name`, written as
/// `dir/file`: each `(from, to)` replaced once (every `from` must be in it),
/// then `append` added at the end (a table such as `[supervision]`).
pub fn scenario_variant(
    dir: &Path,
    name: &str,
    file: &str,
    edits: &[(&str, &str)],
    append: &str,
) -> PathBuf {
    let mut text = std::fs::read_to_string(scenario(name)).unwrap();
    for (from, to) in edits {
        assert!(text.contains(from), "{name} has no `{from}`");
        text = text.replacen(from, to, 1);
    }
    if !append.is_empty() {
        text = format!("{text}\n{append}\n");
    }
    let path = dir.join(file);
    std::fs::write(&path, text).unwrap();
    path
}

/// A standby controller covers the active one (`safe_action = "standby"`):
/// a table to append to a scenario.
pub const STANDBY_TABLE: &str = "[supervision]\nsafe_action = \"standby\"";

/// Adds `table` (a table such as `[supervision]`) at the end of the
/// scenario file `file`.
pub fn append_to_scenario(file: &Path, table: &str) {
    let text = std::fs::read_to_string(file).unwrap();
    std::fs::write(file, format!("{text}\n{table}\n")).unwrap();
}

/// Writes the thesis chain's model files (second-order M, K, D, B, C and a
/// state-space A, B, C, D, as .npz and .mat, by NumPy and SciPy) into `dir`.
pub fn write_chain_models(dir: &Path) {
    let mut cmd = Command::new(python_with(&["numpy", "scipy"]));
    cmd.arg(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/integration/python/write_chain_models.py"),
    )
    .arg(dir);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
}

/// A fresh directory under target/ for one test.
pub fn temp_dir(test: &str) -> TestDir {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    TestDir(dir)
}

/// A test's own directory under target/tmp: removed when the test passes
/// (runs leave megabytes of samples each), kept after a failure for its logs.
pub struct TestDir(PathBuf);

impl std::ops::Deref for TestDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TestDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for TestDir {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for TestDir {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// Runs `cmd` to completion, killing it after `limit` (then panicking with its output).
pub fn run_bounded(mut cmd: Command, limit: Duration) -> Output {
    let child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_bounded(child, limit)
}

pub fn wait_bounded(mut child: Child, limit: Duration) -> Output {
    // Drained while it runs: a child that writes more than a pipe holds
    // (64 KiB) would otherwise block on its write and never end.
    // Read for at most 10 s after it ended: a grandchild that kept the
    // pipe open leaves what came so far.
    fn drain(mut pipe: Option<impl std::io::Read + Send + 'static>) -> impl FnOnce() -> Vec<u8> {
        let (sender, receiver) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut chunk = [0u8; 65536];
            while let Some(Ok(n @ 1..)) = pipe.as_mut().map(|p| p.read(&mut chunk)) {
                if sender.send(chunk[..n].to_vec()).is_err() {
                    break;
                }
            }
        });
        move || {
            let deadline = Instant::now() + Duration::from_secs(10);
            let mut bytes = Vec::new();
            while let Ok(chunk) =
                receiver.recv_timeout(deadline.saturating_duration_since(Instant::now()))
            {
                bytes.extend(chunk);
            }
            bytes
        }
    }
    let stdout = drain(child.stdout.take());
    let stderr = drain(child.stderr.take());
    let since = Instant::now();
    let mut timed_out = false;
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if since.elapsed() > limit {
            let _ = child.kill();
            timed_out = true;
            break child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = Output {
        status,
        stdout: stdout(),
        stderr: stderr(),
    };
    if timed_out {
        panic!(
            "timed out after {limit:?}\nstdout:\n{}\nstderr:\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    out
}

pub fn describe(out: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Processes whose command line mentions `needle` (our run directory).
pub fn processes_mentioning(needle: &str) -> Vec<String> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if !name.chars().all(|c| c.is_ascii_digit()) {
            continue;
        }
        if let Ok(cmdline) = std::fs::read(entry.path().join("cmdline")) {
            let text = String::from_utf8_lossy(&cmdline).replace('\0', " ");
            if text.contains(needle) {
                found.push(format!("{name}: {text}"));
            }
        }
    }
    found
}

/// The run's iceoryx2 prefix, from the sample log's metadata (read
/// without keeping the samples: a long lockstep run holds millions).
pub fn prefix_of(run_dir: &Path) -> String {
    let log = flexloop_recording::LogReader::scan(&run_dir.join("samples.mcap"), |_| {}).unwrap();
    let meta: serde_json::Value = serde_json::from_str(&log.metadata_json).unwrap();
    meta["prefix"].as_str().unwrap().to_string()
}

/// The logger's `summary.json`, typed.
pub fn summary(run_dir: &Path) -> RunSummary {
    RunDir::new(run_dir)
        .read_summary()
        .unwrap_or_else(|e| panic!("{e}"))
}

/// `flexloop run`'s `metrics.json`, typed (its control figures and modal
/// damping stay JSON: the analysis crate's types are not read back).
pub fn metrics(run_dir: &Path) -> MetricsFile {
    flexloop_runfiles::json::read_json(&RunDir::new(run_dir).metrics())
        .unwrap_or_else(|e| panic!("{e}"))
}

/// The count of the channel named `channel` (`measurement`, `estimate`,
/// `command`: [`PerChannel::NAMES`]).
pub fn of_channel(counts: &PerChannel, channel: &str) -> u64 {
    let i = PerChannel::NAMES
        .iter()
        .position(|name| *name == channel)
        .unwrap_or_else(|| panic!("no channel {channel}"));
    counts.get(i)
}

/// Asserts that the run counts no gap on any of `channels` (`measurement`,
/// `estimate`, `command`).
#[track_caller]
pub fn assert_no_gaps_on(summary: &RunSummary, channels: &[&str], context: &str) {
    for channel in channels {
        assert_eq!(
            of_channel(&summary.gaps, channel),
            0,
            "{context}: {channel} gaps: {summary:?}"
        );
    }
}

/// Asserts that the run lost nothing: no miss, no gap on any channel.
#[track_caller]
pub fn assert_lost_nothing(summary: &RunSummary, context: &str) {
    assert_eq!(summary.counters.misses, 0, "{context}: misses: {summary:?}");
    assert_no_gaps_on(summary, &PerChannel::NAMES, context);
}

/// Asserts that nothing of the run is left: no process, no shared memory.
pub fn assert_clean(run_dir: &Path) {
    let procs = processes_mentioning(&run_dir.display().to_string());
    assert!(procs.is_empty(), "processes left: {procs:?}");
    let prefix = prefix_of(run_dir);
    let files = flexloop_transport::leftover_files_for_prefix(&prefix);
    assert!(
        files.is_empty(),
        "shared memory left for {prefix}: {files:?}"
    );
}

/// `flexloop up` until stopped, in the background.
pub fn start(dir: &Path, scenario_name: &str, args: &[&str]) -> (Up, String) {
    start_file(dir, &scenario(scenario_name), args)
}

/// [`start`] with a scenario file anywhere.
pub fn start_file(dir: &Path, scenario_file: &Path, args: &[&str]) -> (Up, String) {
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario_file)
        .args(["--no-realtime", "--duration", "0", "--run-dir"])
        .arg(dir)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let child = cmd.spawn().unwrap();
    let prefix = format!("flx{}_", child.id());
    let up = Up {
        child: Some(child),
        prefix: prefix.clone(),
    };
    (up, prefix)
}

/// [`start`], then waits (bounded) until the loop has recorded `ticks`
/// measurements.
pub fn start_and_await(
    dir: &Path,
    scenario_name: &str,
    args: &[&str],
    ticks: usize,
) -> (Up, String) {
    start_file_and_await(dir, &scenario(scenario_name), args, ticks)
}

/// [`start_file`], then waits (bounded) until the loop has recorded `ticks`
/// measurements.
pub fn start_file_and_await(
    dir: &Path,
    scenario_file: &Path,
    args: &[&str],
    ticks: usize,
) -> (Up, String) {
    let started = start_file(dir, scenario_file, args);
    wait_for_ticks(dir, ticks);
    started
}

/// The lecture's loop (lecture-double-integrator) started in lockstep, once
/// it has recorded `ticks` measurements.
pub fn start_lecture_lockstep(dir: &Path, ticks: usize) -> (Up, String) {
    start_and_await(
        dir,
        "lecture-double-integrator",
        &["--mode", "lockstep"],
        ticks,
    )
}

/// A `flexloop up` a test started. A test that ends without stopping it
/// (it panicked) stops it on drop: its supervisor by its pid, then the
/// prefix's shared-memory files, so that a failed test leaves no loop
/// running and nothing in /dev/shm.
pub struct Up {
    child: Option<Child>,
    prefix: String,
}

impl Up {
    /// The supervisor's pid.
    pub fn id(&self) -> u32 {
        self.child.as_ref().map_or(0, Child::id)
    }

    /// The supervisor's output if it has ended (a test waiting for one of
    /// its files fails at once, with the reason, rather than at its limit).
    pub fn ended(&mut self) -> Option<Output> {
        let child = self.child.as_mut()?;
        child.try_wait().ok().flatten()?;
        self.child.take()?.wait_with_output().ok()
    }

    /// Waits (bounded) for the supervisor to end by itself; its output.
    pub fn wait(mut self, limit: Duration) -> Output {
        let since = Instant::now();
        let child = self.child.as_mut().expect("not waited for yet");
        while child.try_wait().unwrap().is_none() {
            if since.elapsed() > limit {
                let out = self.end();
                panic!(
                    "timed out after {limit:?}\n{}",
                    out.map(|o| describe(&o)).unwrap_or_default()
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        self.child.take().unwrap().wait_with_output().unwrap()
    }

    /// Stops the supervisor if it runs (SIGTERM, which stops its processes
    /// and removes its files; SIGKILL after 20 s), then removes whatever
    /// of its prefix is left (its processes die with it).
    fn end(&mut self) -> Option<Output> {
        let mut child = self.child.take()?;
        if child.try_wait().ok().flatten().is_none() {
            // SAFETY: our own child, not reaped yet, so the pid is not reused.
            unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
            let since = Instant::now();
            while child.try_wait().ok().flatten().is_none()
                && since.elapsed() < Duration::from_secs(20)
            {
                std::thread::sleep(Duration::from_millis(20));
            }
            let _ = child.kill();
        }
        let out = child.wait_with_output().ok();
        flexloop_transport::remove_leftovers(&self.prefix);
        out
    }
}

impl Drop for Up {
    fn drop(&mut self) {
        self.end();
    }
}

/// The measurements the logger's sample file `file` in `dir` holds so far
/// (from the file's indexes: reading it whole each time would take the
/// loop's CPU).
pub fn recorded_ticks_in(dir: &Path, file: &str) -> usize {
    flexloop_recording::mcap_repair::topic_counts(&dir.join(file))
        .map_or(0, |c| c.get("/measurement").copied().unwrap_or(0) as usize)
}

/// Waits (bounded) until the logger's sample file `file` in `dir` holds
/// `ticks` measurements (it gets a chunk every 100 ms).
pub fn wait_for_ticks_in(dir: &Path, file: &str, ticks: usize) {
    let since = Instant::now();
    loop {
        let recorded = recorded_ticks_in(dir, file);
        if recorded >= ticks {
            return;
        }
        assert!(
            since.elapsed() < Duration::from_secs(90),
            "loop did not run: {recorded} of {ticks} ticks in {file}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Waits (bounded) until the first logger has recorded `ticks` measurements.
pub fn wait_for_ticks(dir: &Path, ticks: usize) {
    wait_for_ticks_in(dir, "samples.mcap", ticks);
}

/// Waits (bounded) until the first logger has recorded `ticks` more
/// measurements than it holds now.
pub fn wait_for_more_ticks(dir: &Path, ticks: usize) {
    let now = recorded_ticks_in(dir, "samples.mcap");
    wait_for_ticks(dir, now + ticks);
}

/// Lets the loop run `ticks` more ticks, then stops it ([`stop`]: asserts
/// that it ran to its end); its output.
pub fn stop_after_more_ticks(dir: &Path, prefix: &str, up: Up, ticks: usize) -> Output {
    wait_for_more_ticks(dir, ticks);
    stop(prefix, up)
}

/// `flexloop down` for `prefix`, then waits for `up`; returns its output.
pub fn stop(prefix: &str, up: Up) -> Output {
    let down = run_bounded(
        {
            let mut c = flexloop();
            c.args(["down", "--prefix", prefix]);
            c
        },
        Duration::from_secs(60),
    );
    assert!(down.status.success(), "{}", describe(&down));
    let out = up.wait(Duration::from_secs(60));
    assert_ran(&out);
    out
}

/// The loop ran to its end: exit 0, or the verdict's exit 3 because the
/// machine stalled the plant's clock (a loaded CI machine in realtime:
/// what the tests judge is the loop's behaviour, not this machine's timing).
pub fn assert_ran(out: &Output) {
    let said = |text: &[u8]| {
        String::from_utf8_lossy(text).contains("FAILED: the plant did not keep its grid")
    };
    let machine_stalled = out.status.code() == Some(3) && (said(&out.stderr) || said(&out.stdout));
    assert!(out.status.success() || machine_stalled, "{}", describe(out));
}

/// `flexloop bench` ran: exit 0, or exit 3 with a verdict that failed (a
/// loaded test machine may not keep the rate: the bench says so in its exit
/// status, which is what this accepts, not a timing figure).
pub fn assert_bench_ran(out: &Output) {
    let stdout = String::from_utf8_lossy(&out.stdout);
    let failed_verdict = out.status.code() == Some(3)
        && (stdout.contains("verdict: FAILED") || stdout.contains("does NOT fit"));
    assert!(out.status.success() || failed_verdict, "{}", describe(out));
}

/// The supervisor's events so far (complete lines only: it may be writing).
pub fn events(dir: &Path) -> Vec<SupervisorEvent> {
    let path = RunDir::new(dir).events();
    let text = std::fs::read_to_string(&path).unwrap_or_default();
    parse_events(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Waits (at most `limit`) until the supervisor has written an event that
/// `wanted` accepts; the first such event. Fails saying `missing`, with the
/// events so far.
#[track_caller]
pub fn wait_for_event(
    dir: &Path,
    limit: Duration,
    missing: &str,
    wanted: impl Fn(&SupervisorEvent) -> bool,
) -> SupervisorEvent {
    let since = Instant::now();
    loop {
        if let Some(e) = events(dir).into_iter().find(|e| wanted(e)) {
            return e;
        }
        assert!(since.elapsed() < limit, "{missing}: {:?}", events(dir));
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Asserts that the supervisor recorded no crash of any process.
#[track_caller]
pub fn assert_no_crash(dir: &Path, context: &str) {
    let events = events(dir);
    assert!(
        !events.iter().any(|e| matches!(e.kind, EventKind::Crash(_))),
        "{context}: {events:?}"
    );
}

/// The supervisor's swap events so far, in order.
pub fn swaps(dir: &Path) -> Vec<SupervisorEvent> {
    events(dir)
        .into_iter()
        .filter(|e| matches!(e.kind, EventKind::Swap(_)))
        .collect()
}

/// The supervisor's set events so far, in order.
pub fn sets(dir: &Path) -> Vec<SupervisorEvent> {
    events(dir)
        .into_iter()
        .filter(|e| matches!(e.kind, EventKind::Set(_)))
        .collect()
}

/// Asserts that a switch was bumpless: its step of the command no larger
/// than twice the larger ordinary step before or after it (1 µN floor).
#[track_caller]
pub fn assert_bumpless(switch: &SwitchRecord, context: &str) {
    let (du_switch, du_before, du_after) = (switch.du_switch, switch.du_before, switch.du_after);
    assert!(
        du_switch <= 2.0 * du_before.max(du_after) + 1e-6,
        "{context}: a switch larger than ordinary steps: step at the switch {du_switch} N, \
         ordinary steps up to {du_before} N before, {du_after} N after: {switch:?}"
    );
}

/// The detail of an event that must be of one kind (a panic showing the
/// event if it is not): `crash_of(&e).cause`, `swap_of(&e).switch`, ...
macro_rules! detail_of {
    ($($name:ident: $variant:ident($detail:ty);)*) => {$(
        #[track_caller]
        pub fn $name(event: &SupervisorEvent) -> &$detail {
            match &event.kind {
                EventKind::$variant(detail) => detail,
                _ => panic!(concat!("not a ", stringify!($variant), " event: {:?}"), event),
            }
        }
    )*};
}

detail_of! {
    crash_of: Crash(Crash);
    silent_of: Silent(Silent);
    restart_of: Restart(Restart);
    swap_of: Swap(Swap);
    set_of: Set(Set);
    standby_of: Standby(Standby);
    stop_of: Stop(Stop);
}

/// Waits (bounded) until the process `pid` is gone (the supervisor reaps
/// its children at once).
pub fn assert_gone(pid: i32) {
    let since = Instant::now();
    while Path::new(&format!("/proc/{pid}")).exists() {
        assert!(
            since.elapsed() < Duration::from_secs(30),
            "process {pid} is still there"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The run's live processes as its supervisor lists them (`processes.json`;
/// none before it wrote one).
pub fn processes(dir: &Path) -> Vec<ProcessEntry> {
    match flexloop_runfiles::json::read_json::<Processes>(&RunDir::new(dir).processes()) {
        Ok(list) => list.processes,
        Err(FileError::Io { .. }) => Vec::new(),
        Err(e) => panic!("{e}"),
    }
}

/// The pids the supervisor lists for `role` on `duty`.
pub fn pids_on_duty(dir: &Path, role: &str, duty: &str) -> Vec<i32> {
    processes(dir)
        .iter()
        .filter(|p| p.role == role && p.duty == duty)
        .map(|p| p.pid)
        .collect()
}

/// Waits (at most 60 s) until the supervisor lists one `role` process on
/// `duty`; its pid.
pub fn pid_on_duty(dir: &Path, role: &str, duty: &str) -> i32 {
    let since = std::time::Instant::now();
    loop {
        if let [pid] = pids_on_duty(dir, role, duty)[..] {
            return pid;
        }
        assert!(
            since.elapsed() < Duration::from_secs(60),
            "no single {role} on duty {duty}: {:?}",
            processes(dir)
        );
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Pids of the running instances of `role` in the run at `dir`, oldest first.
pub fn pids_of(dir: &Path, role: &str) -> Vec<i32> {
    let binary = format!("flexloop-{role}");
    let mut found: Vec<i32> = processes_mentioning(&dir.display().to_string())
        .into_iter()
        .filter(|p| p.contains(&binary))
        .filter_map(|p| p.split(':').next()?.parse().ok())
        .collect();
    found.sort();
    found
}

/// The Python of the tests' venv (`tools/test` makes it from
/// tools/python-requirements.txt and sets `FLEXLOOP_PYTHON`), checked to
/// import `modules`. A test that needs it fails without it, saying how to
/// get it: it never passes without having checked anything.
/// The lecture's double integrator with the Python program `law` as its
/// controller, written to `dir/name`.
pub fn python_controller_scenario(dir: &Path, name: &str, law: &Path) -> PathBuf {
    let mut table: toml::Table =
        toml::from_str(&std::fs::read_to_string(scenario("lecture-double-integrator")).unwrap())
            .unwrap();
    let exec = [
        python_with(&["flexloop", "iceoryx2"]),
        law.display().to_string(),
    ];
    flexloop_scenario::program::served_by_program(
        &mut table,
        flexloop_scenario::ProgramRole::Controller,
        &exec,
        None,
        None,
    );
    let file = dir.join(name);
    std::fs::write(&file, toml::to_string(&table).unwrap()).unwrap();
    file
}

pub fn python_with(modules: &[&str]) -> String {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-python/bin/python");
    let python = std::env::var("FLEXLOOP_PYTHON").unwrap_or_else(|_| venv.display().to_string());
    let mut probe = Command::new(&python);
    probe.args(["-c", &format!("import {}", modules.join(", "))]);
    match probe.output() {
        Ok(out) if out.status.success() => python,
        Ok(out) => panic!(
            "{python} cannot import {} ({}); run the tests with tools/test, which installs them",
            modules.join(", "),
            String::from_utf8_lossy(&out.stderr).trim()
        ),
        Err(e) => panic!(
            "{python}: {e}; run the tests with tools/test (it makes that venv), or set \
             FLEXLOOP_PYTHON to a Python with tools/python-requirements.txt"
        ),
    }
}

/// After refused swaps: the loop runs `ticks` more samples and stops, and
/// the first controller kept it: every command from generation 0, no miss,
/// nothing left behind.
pub fn assert_first_controller_kept_the_loop(dir: &Path, prefix: &str, up: Up, ticks: usize) {
    stop_after_more_ticks(dir, prefix, up, ticks);
    let summary = summary(dir);
    assert_eq!(summary.counters.misses, 0, "{summary:?}");
    let mut commands_of_others = 0;
    flexloop_recording::LogReader::scan(&dir.join("samples.mcap"), |r| {
        if let flexloop_recording::Record::Command(c) = r {
            commands_of_others += u64::from(c.generation != 0);
        }
    })
    .unwrap();
    assert_eq!(commands_of_others, 0);
    assert_clean(dir);
}

/// The run's scenario as it stands after swaps and sets (`scenario-now.toml`).
pub fn scenario_now(dir: &Path) -> toml::Table {
    toml::from_str(&std::fs::read_to_string(dir.join("scenario-now.toml")).unwrap()).unwrap()
}

/// The generations that sent the run's commands, ascending, each once.
pub fn command_generations(log: &LogReader) -> Vec<u32> {
    let generations: BTreeSet<u32> = log.commands().map(|c| c.generation).collect();
    generations.into_iter().collect()
}

/// The generations that sent the run's estimates, ascending, each once.
pub fn estimate_generations(log: &LogReader) -> Vec<u32> {
    let generations: BTreeSet<u32> = log.estimates().map(|e| e.generation).collect();
    generations.into_iter().collect()
}

/// The observer examples' law (examples/luenberger-observer,
/// python/examples/luenberger.py) on one axis, written again here: a
/// predictor on a rigid mass with its poles at `bandwidth_hz`, damped
/// `damping`. Each operation in the examples' order: the tests compare
/// estimates to 1e-12.
pub struct Predictor {
    ts: f64,
    mass: f64,
    l1: f64,
    l2: f64,
}

impl Predictor {
    pub fn new(ts: f64, mass: f64, bandwidth_hz: f64, damping: f64) -> Self {
        let (w, zeta) = (2.0 * std::f64::consts::PI * bandwidth_hz, damping);
        let decay = (-zeta * w * ts).exp();
        let a1 = -2.0 * decay * (w * ts * (1.0 - zeta * zeta).sqrt()).cos();
        let l1 = a1 + 2.0;
        let l2 = (decay * decay - 1.0 + l1) / ts;
        Self { ts, mass, l1, l2 }
    }

    /// The examples' scenario: 1 kg, 200 Hz, ζ 0.7 at 10 kHz.
    pub fn example() -> Self {
        Self::new(1e-4, 1.0, 200.0, 0.7)
    }

    /// x̂ (position, velocity) after the measurement `y` with the applied
    /// input `u`, from `x`.
    pub fn step(&self, [p, v]: [f64; 2], y: f64, u: f64) -> [f64; 2] {
        let (ts, mass) = (self.ts, self.mass);
        let innovation = y - p;
        [
            p + ts * v + ts * ts / (2.0 * mass) * u + self.l1 * innovation,
            v + ts / mass * u + self.l2 * innovation,
        ]
    }
}

/// Asserts that the estimate `e` is `want`: two states, each to 1e-12
/// relative (with a 1e-3 floor).
#[track_caller]
pub fn assert_estimate_is(e: &Estimate, want: [f64; 2]) {
    for (i, (got, want)) in e.x_hat.iter().zip(want).enumerate() {
        assert!(
            (got - want).abs() <= 1e-12 * want.abs().max(1e-3),
            "estimate for {} (generation {}): x̂[{i}] {got} against {want}",
            e.seq,
            e.generation,
        );
    }
    assert_eq!(e.n_states, 2);
}

/// The controller examples' law (examples/pid-controller,
/// python/examples/pid.py) on one axis, written again here from their
/// documentation: a discrete PID with a backward-Euler filtered derivative.
/// Each operation in the examples' order: the tests compare commands to
/// 1e-12 or to the bit.
pub struct ExamplePid {
    pub kp: f64,
    pub ki_ts: f64,
    pub a: f64,
    pub b: f64,
    pub integral: f64,
    pub derivative: f64,
    pub last_error: f64,
}

impl ExamplePid {
    /// The law with gains `kp`, `ki`, `kd` and the derivative filtered at
    /// `derivative_filter_rad_s`, sampled every `ts` s, from rest.
    pub fn new(kp: f64, ki: f64, kd: f64, derivative_filter_rad_s: f64, ts: f64) -> Self {
        let n = derivative_filter_rad_s;
        Self {
            kp,
            ki_ts: ki * ts,
            a: 1.0 / (1.0 + n * ts),
            b: kd * n / (1.0 + n * ts),
            integral: 0.0,
            derivative: 0.0,
            last_error: 0.0,
        }
    }

    /// One step on the error `r − y`: the command before the input limit.
    pub fn step(&mut self, error: f64) -> f64 {
        self.integral += self.ki_ts * error;
        self.derivative = self.a * self.derivative + self.b * (error - self.last_error);
        self.last_error = error;
        self.kp * error + self.integral + self.derivative
    }
}
