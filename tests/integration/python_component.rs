//! The Python package (python/): its messages against shared/protocol's
//! tables, a Python subscriber on a running loop, and the Python PID
//! example (python/examples/pid.py) swapped into a running lockstep loop
//! and out again, its every command the law's.
//!
//! They run the Python of the tests' venv (tools/test installs the package
//! and iceoryx2 there from tools/python-requirements.txt).

use crate::util::*;
use flexloop_recording::LogReader;
use flexloop_runfiles::events::EventKind;
use serde_json::Value;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn python() -> String {
    python_with(&["flexloop", "iceoryx2"])
}

#[test]
fn python_messages_match_the_protocol_tables() {
    let mut cmd = Command::new(python());
    cmd.args(["-m", "unittest", "discover", "-s", "python/tests", "-v"])
        .current_dir(repo());
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    // The runner's own count: a discovery that found nothing fails here.
    let text = String::from_utf8_lossy(&out.stderr);
    assert!(text.contains("\nOK"), "{text}");
    assert!(!text.contains("Ran 0 tests"), "{text}");
}

#[test]
fn a_python_subscriber_receives_contiguous_measurements_from_a_running_loop() {
    let dir = temp_dir("python-subscriber");
    let (child, prefix) = start_and_await(&dir, "lecture-double-integrator", &[], 100);
    let mut cmd = Command::new(python());
    cmd.arg(repo().join("python/tests/receive_measurements.py"))
        .args([prefix.as_str(), "20000", "60"]);
    let out = run_bounded(cmd, Duration::from_secs(90));
    stop(&prefix, child);
    assert!(out.status.success(), "{}", describe(&out));
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["received"], 20_000, "{report}");
    assert_eq!(report["gaps"], 0, "{report}");
    assert_eq!(
        report["last"].as_u64().unwrap() - report["first"].as_u64().unwrap(),
        19_999,
        "{report}"
    );
    assert_eq!(report["type_name"], "flexloop.Measurement.v4");
    assert_clean(&dir);
}

/// The example's gains (its Rust twin's, examples/pid-controller).
const PID_PARAMS: [(&str, f64); 4] = [
    ("kp", 9000.0),
    ("ki", 90000.0),
    ("kd", 110.0),
    ("derivative_filter_rad_s", 3000.0),
];

/// The lecture scenario with the Python PID as its controller.
fn python_pid_scenario(dir: &Path) -> PathBuf {
    let params: String = PID_PARAMS
        .iter()
        .map(|(name, value)| format!("{name} = {value:?}\n"))
        .collect();
    let program = repo().join("python/examples/pid.py");
    scenario_variant(
        dir,
        "lecture-double-integrator",
        "python-pid.toml",
        &[],
        &format!(
            "[controller]\nexec = [{:?}, {:?}]\n\n[controller.params]\n{params}",
            python(),
            program.display().to_string()
        ),
    )
}

/// python/examples/pid.py's law, operation for operation, over the
/// measured y: the lecture's 1 mm 2 Hz sine set-point, a filtered
/// derivative, the plant's 100 N limit.
struct Pid {
    pid: ExamplePid,
    ts: f64,
}

impl Pid {
    fn new(rate_hz: f64) -> Self {
        let p: HashMap<&str, f64> = PID_PARAMS.into_iter().collect();
        let ts = 1.0 / rate_hz;
        let (kp, ki, kd, n) = (p["kp"], p["ki"], p["kd"], p["derivative_filter_rad_s"]);
        Self {
            pid: ExamplePid::new(kp, ki, kd, n, ts),
            ts,
        }
    }

    /// Its command for sample `seq`, measured `y`.
    fn step(&mut self, seq: u64, y: f64) -> f64 {
        let t = seq as f64 * self.ts;
        let r = 0.001 * (2.0 * std::f64::consts::PI * 2.0 * t).sin();
        self.pid.step(r - y).clamp(-100.0, 100.0)
    }
}

/// The first sample the Python law stepped, from its stderr line
/// (`generation N: law stepped from sample K`) in the run directory; the
/// law must have stepped every sample since (its exit report says when it
/// did not).
fn law_start(dir: &Path, generation: u32) -> u64 {
    let needle = format!("generation {generation}: law stepped from sample ");
    let Some((text, at)) = stderr_saying(dir, &needle) else {
        panic!("no stderr file in {} says `{needle}`", dir.display());
    };
    assert!(
        !text.contains(&format!("generation {generation}: law skipped")),
        "{text}"
    );
    let rest = &text[at + needle.len()..];
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits.parse().unwrap()
}

/// The text of the stderr file in `dir` that says `needle`, and where.
fn stderr_saying(dir: &Path, needle: &str) -> Option<(String, usize)> {
    std::fs::read_dir(dir).unwrap().flatten().find_map(|entry| {
        let name = entry.file_name().to_string_lossy().into_owned();
        if !name.ends_with(".stderr") {
            return None;
        }
        let text = std::fs::read_to_string(entry.path()).unwrap_or_default();
        text.find(needle).map(|at| (text, at))
    })
}

#[test]
fn the_python_pid_swapped_into_a_lockstep_loop_commands_its_law_and_hands_back() {
    let dir = temp_dir("python-pid-swap");
    let pid_scenario = python_pid_scenario(&dir);
    let (child, prefix) = start_lecture_lockstep(&dir, 430);
    let answer = swap_to(&prefix, &pid_scenario);
    assert!(answer.contains("generation 1"), "{answer}");
    wait_for_more_ticks(&dir, 3000);
    let back = swap_to(&prefix, &scenario("lecture-double-integrator"));
    assert!(back.contains("generation 2"), "{back}");
    stop(&prefix, child);

    let summary = summary(&dir);
    for (counter, count) in [
        ("misses", summary.counters.misses),
        ("rejected_commands", summary.counters.rejected_commands),
    ] {
        assert_eq!(count, 0, "{counter}: {summary:?}");
    }
    assert_no_gaps_on(
        &summary,
        &["measurement", "command"],
        "into Python and back",
    );
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let y: HashMap<u64, f64> = log.measurements().map(|m| (m.seq, m.y[0])).collect();
    let u: HashMap<(u64, u32), f64> = log
        .commands()
        .map(|c| ((c.seq, c.generation), c.u[0]))
        .collect();
    let mut python: Vec<u64> = u.keys().filter(|(_, g)| *g == 1).map(|(s, _)| *s).collect();
    python.sort();
    let (from, last) = (python[0], *python.last().unwrap());
    assert_eq!(
        python.len() as u64,
        last - from + 1,
        "the Python controller's commands are contiguous"
    );
    assert!(python.len() >= 2000, "{} Python commands", python.len());
    assert!(
        u.contains_key(&(last + 1, 2)),
        "generation 2 took over after the Python controller's last command {last}"
    );

    // Its law from the first sample it stepped, shifted at the switch by
    // the old command minus its own (the bumpless hand-over), is what it sent.
    let mut law = Pid::new(10_000.0);
    let mut compared = 0;
    for seq in law_start(&dir, 1)..=last {
        let own = law.step(seq, y[&seq]);
        if seq + 1 == from {
            law.pid.integral += u[&(seq, 0)] - own;
        }
        if seq >= from {
            let sent = u[&(seq, 1)];
            assert!(
                (sent - own).abs() <= 1e-12,
                "u({seq}) {sent} from Python, {own} from the law"
            );
            compared += 1;
        }
    }
    assert_eq!(compared, python.len());
    // The Python controller exited when replaced; nothing of it is left.
    assert_clean(&dir);
}

#[test]
fn the_python_pid_runs_a_lockstep_loop_from_its_start() {
    let dir = temp_dir("python-pid-start");
    let pid_scenario = python_pid_scenario(&dir);
    let run_dir = dir.join("run");
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(&pid_scenario)
        .args([
            "--no-realtime",
            "--mode",
            "lockstep",
            "--duration",
            "0.3",
            "--run-dir",
        ])
        .arg(&run_dir);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert_ran(&out);
    let summary = summary(&run_dir);
    assert_eq!(summary.counters.misses, 0, "{summary:?}");
    let log = LogReader::open(&run_dir.join("samples.mcap")).unwrap();
    let y: HashMap<u64, f64> = log.measurements().map(|m| (m.seq, m.y[0])).collect();
    let mut commands: Vec<_> = log.commands().collect();
    commands.sort_by_key(|c| c.seq);
    assert_eq!(commands.len(), 3000, "0.3 s at 10 kHz");
    assert_eq!(
        law_start(&run_dir, 0),
        0,
        "the law steps from the first sample"
    );
    let mut law = Pid::new(10_000.0);
    for (k, c) in commands.iter().enumerate() {
        assert_eq!((c.seq, c.generation), (k as u64, 0));
        let own = law.step(c.seq, y[&c.seq]);
        assert!(
            (c.u[0] - own).abs() <= 1e-12,
            "u({k}) {} from Python, {own} from the law",
            c.u[0]
        );
    }
    assert_clean(&run_dir);
}

#[test]
fn the_python_pid_swapped_for_itself_continues_from_its_state_to_the_bit() {
    let dir = temp_dir("python-pid-self");
    let pid_scenario = python_pid_scenario(&dir);
    let (child, prefix) = start_file_and_await(&dir, &pid_scenario, &["--mode", "lockstep"], 430);
    let answer = swap_to(&prefix, &pid_scenario);
    assert!(answer.contains("generation 1"), "{answer}");
    stop_after_more_ticks(&dir, &prefix, child, 1000);

    let summary = summary(&dir);
    assert_eq!(summary.counters.misses, 0, "{summary:?}");
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let y: HashMap<u64, f64> = log.measurements().map(|m| (m.seq, m.y[0])).collect();
    let mut commands: Vec<_> = log.commands().collect();
    commands.sort_by_key(|c| c.seq);
    assert_eq!(command_generations(&log), [0, 1]);
    // The successor copied the state (same class, parameters and rate)
    // before every sample it followed: the run is one law from tick 0,
    // to the last bit, across the hand-over.
    let mut law = Pid::new(10_000.0);
    for (k, c) in commands.iter().enumerate() {
        assert_eq!(c.seq, k as u64, "commands are contiguous");
        let own = law.step(c.seq, y[&c.seq]);
        assert_eq!(
            c.u[0].to_bits(),
            own.to_bits(),
            "u({k}) {} from generation {}, {own} from the law",
            c.u[0],
            c.generation
        );
    }
    assert_clean(&dir);
}

#[test]
fn a_python_standby_covers_a_killed_python_controller_and_is_promoted() {
    let dir = temp_dir("python-pid-standby");
    let pid_scenario = python_pid_scenario(&dir);
    append_to_scenario(&pid_scenario, STANDBY_TABLE);
    let (child, prefix) = start_file_and_await(&dir, &pid_scenario, &["--rate", "1000"], 100);
    let standby = pid_on_duty(&dir, "controller", "standby");
    // Once the standby steps its law (a Python start-up takes a while on a
    // loaded machine) and has followed a while, kill the active controller.
    let since = std::time::Instant::now();
    while stderr_saying(&dir, "generation 1: law stepped from sample ").is_none() {
        assert!(
            since.elapsed() < Duration::from_secs(60),
            "the standby never stepped its law"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    wait_for_more_ticks(&dir, 300);
    let active = pid_on_duty(&dir, "controller", "active");
    // SAFETY: a pid of a process this test started (through flexloop).
    unsafe { libc::kill(active, libc::SIGKILL) };
    let promoted = wait_for_event(&dir, Duration::from_secs(90), "standby not promoted", |e| {
        matches!(e.kind, EventKind::PromoteStandby(_))
    });
    assert_eq!(pid_on_duty(&dir, "controller", "active"), standby);
    stop_after_more_ticks(&dir, &prefix, child, 300);

    let summary = summary(&dir);
    assert_eq!(summary.counters.rejected_commands, 0, "{summary:?}");
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    // The standby published its commands, marked, for the safe action, and
    // after its promotion the loop's commands are its own.
    let standby_commands = log
        .commands()
        .filter(|c| c.flags & flexloop_protocol::flags::STANDBY != 0)
        .count();
    assert!(
        standby_commands > 100,
        "{standby_commands} standby commands"
    );
    let generation = promoted.generation.unwrap();
    let served = log
        .commands()
        .filter(|c| c.generation == generation && c.flags & flexloop_protocol::flags::STANDBY == 0)
        .count();
    assert!(
        served > 100,
        "{served} commands after the promotion: {promoted:?}"
    );
    assert_clean(&dir);
}

#[test]
fn a_python_law_with_parameters_it_cannot_use_is_refused_and_the_loop_runs_on() {
    let dir = temp_dir("python-pid-bad-params");
    let good = python_pid_scenario(&dir);
    let text = std::fs::read_to_string(&good).unwrap();
    // One parameter missing, one the law never reads.
    let missing = dir.join("missing.toml");
    std::fs::write(&missing, text.replace("kd = 110.0\n", "")).unwrap();
    let unknown = dir.join("unknown.toml");
    std::fs::write(
        &unknown,
        text.replace("kd = 110.0\n", "kd = 110.0\ngain = 2.0\n"),
    )
    .unwrap();
    let (child, prefix) = start_lecture_lockstep(&dir, 430);
    for (file, says) in [
        (&missing, "field `controller.params.kd`: missing"),
        (
            &unknown,
            "field `controller.params.gain`: unknown parameter",
        ),
    ] {
        let mut cmd = flexloop();
        cmd.args(["swap", "controller"])
            .arg(file)
            .args(["--prefix", &prefix]);
        let out = run_bounded(cmd, Duration::from_secs(120));
        assert!(!out.status.success(), "{}", describe(&out));
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("swap refused"),
            "{}",
            describe(&out)
        );
        // The program's own stderr names the file and the field.
        assert!(
            stderr_saying(&dir, says).is_some(),
            "no stderr file in {} says `{says}`",
            dir.display()
        );
    }
    assert_first_controller_kept_the_loop(&dir, &prefix, child, 300);
}

/// examples/pid-controller/scenario.toml served by `exec`, as `dir/file`.
fn example_scenario_with(dir: &Path, file: &str, exec: &[String]) -> PathBuf {
    let text =
        std::fs::read_to_string(repo().join("examples/pid-controller/scenario.toml")).unwrap();
    let from = "exec = [\"./target/release/pid-controller\"]";
    assert!(
        text.contains(from),
        "the example's scenario names its program"
    );
    let exec: Vec<String> = exec.iter().map(|a| format!("{a:?}")).collect();
    let text = text.replacen(from, &format!("exec = [{}]", exec.join(", ")), 1);
    let path = dir.join(file);
    std::fs::write(&path, text).unwrap();
    path
}

/// The recorded commands of a lockstep run of `scenario_file`, 0.5 s:
/// each with u and its parts (u_fb, u_ff, u_d, r, e_meas).
fn lockstep_commands(scenario_file: &Path, run_dir: &Path) -> Vec<(u64, [f64; 6])> {
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario_file)
        .args([
            "--no-realtime",
            "--mode",
            "lockstep",
            "--duration",
            "0.5",
            "--run-dir",
        ])
        .arg(run_dir);
    let out = run_bounded(cmd, Duration::from_secs(180));
    assert_ran(&out);
    let log = LogReader::open(&run_dir.join("samples.mcap")).unwrap();
    let mut commands: Vec<(u64, [f64; 6])> = log
        .commands()
        .map(|c| {
            let parts = [c.u[0], c.u_fb[0], c.u_ff[0], c.u_d[0], c.r[0], c.e_meas[0]];
            (c.seq, parts)
        })
        .collect();
    commands.sort_by_key(|c| c.0);
    assert_clean(run_dir);
    commands
}

#[test]
fn the_python_pid_commands_a_lockstep_run_as_the_rust_example_does() {
    let dir = temp_dir("python-pid-vs-rust");
    let program = repo().join("python/examples/pid.py");
    let python_file = example_scenario_with(
        &dir,
        "python.toml",
        &[python(), program.display().to_string()],
    );
    let rust_file = example_scenario_with(
        &dir,
        "rust.toml",
        &[crate::own_components::example_program()
            .display()
            .to_string()],
    );
    let from_python = lockstep_commands(&python_file, &dir.join("python-run"));
    let from_rust = lockstep_commands(&rust_file, &dir.join("rust-run"));
    assert_eq!(from_python.len(), 5_000, "0.5 s at 10 kHz");
    assert_eq!(from_python.len(), from_rust.len());
    let mut largest = 0.0_f64;
    for ((seq_p, parts_p), (seq_r, parts_r)) in from_python.iter().zip(&from_rust) {
        assert_eq!(seq_p, seq_r);
        // The command and its parts for the record (the example writes
        // u_fb, r and e_meas; u_ff and u_d stay 0).
        for (name, (p, r)) in ["u", "u_fb", "u_ff", "u_d", "r", "e_meas"]
            .iter()
            .zip(parts_p.iter().zip(parts_r))
        {
            assert!(
                (p - r).abs() <= 1e-12,
                "{name}({seq_p}): {p} from Python, {r} from Rust"
            );
        }
        largest = largest.max(parts_p[0].abs());
    }
    // The law did work: it drove the plant after the 1 mm sine.
    assert!(largest > 1e-3, "largest |u| {largest}");
}

/// `flexloop swap controller FILE`; its answer.
fn swap_to(prefix: &str, scenario_file: &Path) -> String {
    let out = run_bounded(
        {
            let mut c = flexloop();
            c.args(["swap", "controller"])
                .arg(scenario_file)
                .args(["--prefix", prefix]);
            c
        },
        Duration::from_secs(120),
    );
    assert!(out.status.success(), "{}", describe(&out));
    String::from_utf8_lossy(&out.stdout).into_owned()
}
