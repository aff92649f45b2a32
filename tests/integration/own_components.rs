//! A controller and an observer of one's own (docs/components.md): the
//! examples on flexloop-sdk outside the workspace (examples/pid-controller,
//! examples/luenberger-observer), built as a user builds them, run the loop
//! from its start and swap into a running loop and back; programs that
//! cannot serve are refused before anything starts, or their swap is, and
//! the loop runs on.

use crate::util::*;
use flexloop_protocol::{Command, Measurement};
use flexloop_recording::LogReader;
use flexloop_runfiles::events::EventKind;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Duration;

/// The examples' programs (pid-controller, luenberger-observer), built
/// once for every test here, into this build's target directory (their
/// dependencies are the workspace's own).
pub(crate) fn built(example: &str) -> PathBuf {
    static BUILT: OnceLock<PathBuf> = OnceLock::new();
    let debug = BUILT.get_or_init(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let target = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .parent()
            .expect("target/tmp is in the target directory")
            .to_path_buf();
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        for name in ["pid-controller", "luenberger-observer"] {
            let mut build = std::process::Command::new(&cargo);
            build
                .args(["build", "--offline", "--manifest-path"])
                .arg(root.join("examples").join(name).join("Cargo.toml"))
                .arg("--target-dir")
                .arg(&target);
            let out = run_bounded(build, Duration::from_secs(1_800));
            assert!(out.status.success(), "{}", describe(&out));
        }
        target.join("debug")
    });
    debug.join(example)
}

/// The pid-controller example (python_component compares its Python twin).
pub(crate) fn example_program() -> PathBuf {
    built("pid-controller")
}

/// The example's scenario, served by the built program, as `dir/file`.
fn example_scenario(dir: &Path, file: &str, params: &str) -> PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/pid-controller/scenario.toml"),
    )
    .unwrap();
    let exec = format!("exec = [{:?}]", example_program().display().to_string());
    let mut text = text.replacen("exec = [\"./target/release/pid-controller\"]", &exec, 1);
    if !params.is_empty() {
        let start = text.find("[controller.params]").unwrap();
        let end = text[start..].find("\n\n").map_or(text.len(), |e| start + e);
        text.replace_range(start..end, params);
    }
    let path = dir.join(file);
    std::fs::write(&path, text).unwrap();
    path
}

/// The example's law at its scenario's 10 kHz and 100 N limit: what the
/// program's commands must equal.
struct ReferencePid(ExamplePid);

impl ReferencePid {
    fn example() -> Self {
        Self(ExamplePid::new(9000.0, 90000.0, 110.0, 3000.0, 1e-4))
    }

    /// The example's law as it stands after its command `second`, the
    /// sample after `first`: the unclamped commands (`u_fb`) and errors
    /// (`e_meas`) of both give its integral and filtered derivative.
    fn resumed(first: &Command, second: &Command) -> Self {
        let Self(mut law) = Self::example();
        let (u0, e0, u1, e1) = (
            first.u_fb[0],
            first.e_meas[0],
            second.u_fb[0],
            second.e_meas[0],
        );
        // u0 = kp e0 + I0 + D0;  u1 = kp e1 + I0 + ki_ts e1 + a D0 + b (e1 − e0).
        let sum0 = u0 - law.kp * e0;
        let d0 = (law.b * (e1 - e0) + sum0 - u1 + (law.kp + law.ki_ts) * e1) / (1.0 - law.a);
        let i0 = sum0 - d0;
        law.integral = i0 + law.ki_ts * e1;
        law.derivative = law.a * d0 + law.b * (e1 - e0);
        law.last_error = e1;
        Self(law)
    }

    fn step(&mut self, r: f64, y: f64) -> f64 {
        self.0.step(r - y).clamp(-100.0, 100.0)
    }
}

/// An executable shell script `dir/name` with `body`.
fn script(dir: &Path, name: &str, body: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, format!("#!/bin/sh\n{body}\n")).unwrap();
    let mut permissions = std::fs::metadata(&path).unwrap().permissions();
    std::os::unix::fs::PermissionsExt::set_mode(&mut permissions, 0o755);
    std::fs::set_permissions(&path, permissions).unwrap();
    path
}

/// `flexloop swap --prefix P ARGS…` (`--exec` takes the rest of the line).
fn swap_to(prefix: &str, args: &[&str]) -> std::process::Output {
    let mut c = flexloop();
    c.args(["swap", "--prefix", prefix]).args(args);
    run_bounded(c, Duration::from_secs(150))
}

/// The lecture loop, started in lockstep and run `ticks` ticks, then
/// swapped to the controller of the scenario `program` (the swap must
/// succeed): the loop, its prefix and the swap's answer.
fn lecture_loop_swapped_to(dir: &Path, program: &Path, ticks: usize) -> (Up, String, String) {
    let (up, prefix) = start_lecture_lockstep(dir, ticks);
    let out = swap_to(&prefix, &["controller", program.to_str().unwrap()]);
    assert!(out.status.success(), "{}", describe(&out));
    (
        up,
        prefix,
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

#[test]
fn the_example_controller_runs_a_lockstep_loop_as_its_law_says() {
    let dir = temp_dir("own-controller-law");
    let scenario = example_scenario(&dir, "pid.toml", "");
    let mut up = flexloop();
    up.arg("up")
        .arg(&scenario)
        .args(["--no-realtime", "--mode", "lockstep", "--duration", "0.5"])
        .arg("--run-dir")
        .arg(dir.join("run"));
    let out = run_bounded(up, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    // `design` names the program and claims no closed loop: that needs the
    // program's law, which flexloop does not have.
    let mut design = flexloop();
    design.arg("design").arg(&scenario);
    let report = run_bounded(design, Duration::from_secs(60));
    assert!(report.status.success(), "{}", describe(&report));
    let said = String::from_utf8_lossy(&report.stdout);
    assert!(
        said.starts_with("Served by programs of one's own: the controller by ")
            && said.contains("closed loop: NOT ANALYSED")
            && !said.contains("spectral radius"),
        "{said}"
    );
    let mut json = flexloop();
    json.arg("design").arg(&scenario).arg("--json");
    let report = run_bounded(json, Duration::from_secs(60));
    assert!(report.status.success(), "{}", describe(&report));
    let report: serde_json::Value = serde_json::from_slice(&report.stdout).unwrap();
    assert_eq!(
        report["loop"]["program_roles"],
        serde_json::json!(["controller"])
    );
    assert!(report["loop"].get("spectral_radius").is_none(), "{report}");
    let run = dir.join("run");
    let log = LogReader::open(&run.join("samples.mcap")).unwrap();
    // The set-point the law follows is the scenario's (1 mm at 2 Hz), and
    // the command is the law's from the first sample to the last.
    assert_eq!(
        assert_commands_follow_the_law_from_tick_0(&log),
        5_000,
        "every sample has its command"
    );
    assert!(log.commands().all(|c| c.generation == 0));
    let measurements: Vec<&Measurement> = log.measurements().collect();
    // The PID follows the sine: after the first half second the error is
    // a small fraction of the amplitude.
    let last = measurements.last().unwrap();
    let r_last = 1e-3 * (2.0 * std::f64::consts::PI * 2.0 * (last.seq as f64 * 1e-4)).sin();
    assert!(
        (last.y[0] - r_last).abs() < 2e-4,
        "{} vs {r_last}",
        last.y[0]
    );
    assert_clean(&run);
}

/// Every command of the run equals the example's law stepped from tick 0
/// on the recorded measurements (whichever generation sent it); returns
/// how many there were.
fn assert_commands_follow_the_law_from_tick_0(log: &LogReader) -> usize {
    let measurements: Vec<&Measurement> = log.measurements().collect();
    let commands: Vec<&Command> = log.commands().collect();
    let mut law = ReferencePid::example();
    for (m, c) in measurements.iter().zip(&commands) {
        assert_eq!(m.seq, c.seq);
        let r = 1e-3 * (2.0 * std::f64::consts::PI * 2.0 * (m.seq as f64 * 1e-4)).sin();
        let u = law.step(r, m.y[0]);
        assert!(
            (c.u[0] - u).abs() <= 1e-12 * u.abs().max(1.0),
            "sample {} (generation {}): the program sent {}, the law gives {u}",
            c.seq,
            c.generation,
            c.u[0]
        );
    }
    commands.len()
}

#[test]
fn a_program_swapped_by_exec_to_itself_continues_its_own_state() {
    let dir = temp_dir("own-controller-exec");
    let scenario = example_scenario(&dir, "pid.toml", "");
    let (child, prefix) = start_file_and_await(&dir, &scenario, &["--mode", "lockstep"], 1_500);
    // `--exec`: the loop as it stands (its [controller.params] too), served
    // by the program named on the command line: here the same law, which
    // takes its predecessor's state (`load`) and so continues exactly.
    let out = swap_to(
        &prefix,
        &["controller", "--exec", example_program().to_str().unwrap()],
    );
    assert!(out.status.success(), "{}", describe(&out));
    stop_after_more_ticks(&dir, &prefix, child, 1_500);
    let summary = summary(&dir);
    assert_eq!(summary.counters.misses, 0, "{summary:?}");
    assert_no_gaps_on(
        &summary,
        &["measurement", "command"],
        "after the swap by --exec",
    );
    let written = dir.join("tuned").join("exec-001.toml");
    let table: toml::Table = toml::from_str(&std::fs::read_to_string(&written).unwrap()).unwrap();
    assert_eq!(
        table["controller"]["exec"][0].as_str(),
        example_program().to_str()
    );
    assert_eq!(table["controller"]["params"]["kp"].as_float(), Some(9000.0));
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert_eq!(command_generations(&log), [0, 1]);
    assert!(assert_commands_follow_the_law_from_tick_0(&log) > 3_000);
    assert_clean(&dir);
}

#[test]
fn the_example_controller_swaps_into_a_running_loop_and_back() {
    let dir = temp_dir("own-controller-swap");
    let program = example_scenario(&dir, "pid.toml", "");
    let (child, prefix, said) = lecture_loop_swapped_to(&dir, &program, 2_000);
    assert!(said.contains("controller generation 1"), "{said}");
    let program_pid = pid_on_duty(&dir, "controller", "active");
    // `status` names the program that serves.
    let mut status = flexloop();
    status.args(["status", "--prefix", &prefix]);
    let shown = run_bounded(status, Duration::from_secs(30));
    let shown = String::from_utf8_lossy(&shown.stdout).into_owned();
    assert!(
        shown.contains(&format!(
            "controller active g1 (pid {program_pid}, program pid-controller)"
        )),
        "{shown}"
    );
    wait_for_more_ticks(&dir, 2_000);
    // Back to the built-in controller; the program, replaced, exits (it is
    // never a spare: a spare must serve whatever law the next order names).
    let back = swap_to(
        &prefix,
        &[
            "controller",
            scenario("lecture-double-integrator").to_str().unwrap(),
        ],
    );
    assert!(back.status.success(), "{}", describe(&back));
    wait_for_more_ticks(&dir, 1_000);
    assert_gone(program_pid);
    stop(&prefix, child);

    assert_lost_nothing(&summary(&dir), "into the program and back");
    // Into the program bumplessly: its integrator takes the old command
    // over (the law's `shift_output`), so the switch steps no more than an
    // ordinary sample does.
    let swaps = swaps(&dir);
    assert_eq!(swaps.len(), 2, "{swaps:?}");
    assert_bumpless(&swap_of(&swaps[0]).switch, "into the program");
    // The program's commands from the switch on are its law's: its state
    // at the switch is what the hand-over made it (two unknowns, the
    // integral and the filtered derivative, solved from its first two
    // commands); from there the law stepped on the recorded measurements
    // gives every command it sent.
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let measurements: HashMap<u64, &Measurement> = log.measurements().map(|m| (m.seq, m)).collect();
    let served: Vec<&Command> = log.commands().filter(|c| c.generation == 1).collect();
    assert!(served.len() > 1_000, "{} commands", served.len());
    let (first, second) = (served[0], served[1]);
    let mut law = ReferencePid::resumed(first, second);
    for c in &served[2..] {
        let m = measurements[&c.seq];
        let u = law.step(c.r[0], m.y[0]);
        assert!(
            (c.u[0] - u).abs() <= 1e-9 * u.abs().max(1.0),
            "sample {}: the program sent {}, the law gives {u}",
            c.seq,
            c.u[0]
        );
    }
    assert_eq!(command_generations(&log), [0, 1, 2]);
    // Back to the lecture's state feedback, a built-in design without an
    // integrator (feedback = "none"): nothing in it can take the old
    // command over, so it runs its own law from its first sample, and the
    // switch is the two laws' difference there, measured and reported
    // (docs/components.md, "Back to a built-in design").
    let design = flexloop_design::acceptance::accept(
        &scenario("lecture-double-integrator"),
        &flexloop_scenario::Overrides::default(),
        2,
    )
    .unwrap()
    .design;
    assert!(design.feedback.is_none());
    let estimates: HashMap<u64, &flexloop_protocol::Estimate> =
        log.estimates().map(|e| (e.seq, e)).collect();
    let back: Vec<&Command> = log.commands().filter(|c| c.generation == 2).collect();
    assert!(back.len() > 500, "{} commands", back.len());
    for c in &back {
        let mut law = flexloop_components::ControllerCore::new(&design, 2);
        let mut out = Command::default();
        law.step(measurements[&c.seq], estimates[&c.seq], &mut out);
        assert_eq!(
            c.u[0], out.u[0],
            "sample {}: not the built-in law's own",
            c.seq
        );
    }
    let last_of_program = served.last().unwrap();
    assert_eq!(last_of_program.seq + 1, back[0].seq);
    let du_switch = swap_of(&swaps[1]).switch.du_switch;
    assert!(
        (du_switch - (back[0].u[0] - last_of_program.u[0]).abs()).abs() < 1e-12,
        "{du_switch}"
    );
    assert_no_crash(&dir, "into the program and back");
    assert_clean(&dir);
}

#[test]
fn a_program_that_cannot_serve_is_refused_and_the_loop_runs_on() {
    let dir = temp_dir("own-controller-bad");
    // Before anything starts: a program that does not exist, one that is
    // not executable, parameters the law does not take.
    // `up` of the lecture loop with `[controller] exec = [program]`: refused (exit 2), its stderr.
    let refused_up = |name: &str, program: &str| {
        let scenario = scenario_variant(
            &dir,
            "lecture-double-integrator",
            &format!("{name}.toml"),
            &[],
            &format!("[controller]\nexec = [\"{program}\"]"),
        );
        let mut up = flexloop();
        up.arg("up")
            .arg(&scenario)
            .args(["--no-realtime", "--duration", "0.1", "--run-dir"])
            .arg(dir.join(format!("{name}-run")));
        let out = run_bounded(up, Duration::from_secs(60));
        assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let err = refused_up("missing", "./no-such-controller");
    assert!(
        err.contains("missing.toml")
            && err.contains("controller.exec")
            && err.contains("no-such-controller"),
        "{err}"
    );
    std::fs::write(dir.join("plain"), "not a program").unwrap();
    let err = refused_up("plain", "./plain");
    assert!(err.contains("not executable"), "{err}");

    // On a running loop: a law whose parameters do not read (it exits at
    // its start, naming the field), a program that crashes at start, and
    // `--exec` of a program that does not exist. Each swap is refused; the
    // built-in controller keeps the loop.
    // Written (and the example built, minutes on a fresh machine) before
    // the loop starts: a lockstep loop left running meanwhile records
    // millions of samples.
    let bad_params = example_scenario(
        &dir,
        "bad-params.toml",
        "[controller.params]\nkp = 9000.0\nki = 90000.0\nkd = 110.0\nderivative_filter = 3000.0",
    );
    let (child, prefix) = start_lecture_lockstep(&dir, 1_000);
    let controller = pid_on_duty(&dir, "controller", "active");
    let out = swap_to(&prefix, &["controller", bad_params.to_str().unwrap()]);
    assert!(!out.status.success(), "{}", describe(&out));
    let generation = 1;
    let stderr = std::fs::read_to_string(dir.join(format!("controller.g{generation}.stderr")))
        .unwrap_or_default();
    assert!(
        stderr.contains("controller.params") && stderr.contains("derivative_filter"),
        "{stderr}\n{}",
        describe(&out)
    );
    let crashing = script(&dir, "crashing", "exit 7");
    let out = swap_to(
        &prefix,
        &["controller", "--exec", crashing.to_str().unwrap()],
    );
    assert!(!out.status.success(), "{}", describe(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("exited with 7"),
        "{}",
        describe(&out)
    );
    let out = swap_to(&prefix, &["controller", "--exec", "./no-such-controller"]);
    assert!(!out.status.success(), "{}", describe(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no-such-controller"),
        "{}",
        describe(&out)
    );
    assert_eq!(pid_on_duty(&dir, "controller", "active"), controller);
    assert_first_controller_kept_the_loop(&dir, &prefix, child, 500);
}

#[test]
fn a_program_that_never_follows_the_loop_is_stopped_and_its_swap_refused() {
    let dir = temp_dir("own-controller-silent");
    let (child, prefix) = start_lecture_lockstep(&dir, 1_000);
    let controller = pid_on_duty(&dir, "controller", "active");
    // Starts, opens nothing, publishes nothing.
    let silent = script(&dir, "silent", "exec sleep 600");
    let out = swap_to(&prefix, &["controller", "--exec", silent.to_str().unwrap()]);
    assert!(!out.status.success(), "{}", describe(&out));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("did not follow the loop"),
        "{}",
        describe(&out)
    );
    // The supervisor stopped it; the built-in controller kept the loop.
    let silent_pids: Vec<i32> = processes(&dir)
        .iter()
        .filter(|p| p.role == "controller" && p.generation == Some(1))
        .map(|p| p.pid)
        .collect();
    for pid in silent_pids {
        assert_gone(pid);
    }
    assert!(processes_mentioning(silent.to_str().unwrap()).is_empty());
    assert_eq!(pid_on_duty(&dir, "controller", "active"), controller);
    assert_first_controller_kept_the_loop(&dir, &prefix, child, 500);
}

#[test]
fn a_program_that_dies_mid_run_is_rolled_back_to_the_built_in_controller() {
    let dir = temp_dir("own-controller-dies");
    let program = example_scenario(&dir, "pid.toml", "");
    let (child, prefix, _) = lecture_loop_swapped_to(&dir, &program, 1_000);
    let program_pid = pid_on_duty(&dir, "controller", "active");
    wait_for_more_ticks(&dir, 500);
    // SAFETY: a process of this test's loop, by the pid its supervisor lists.
    unsafe { libc::kill(program_pid, libc::SIGKILL) };
    assert_gone(program_pid);
    // The supervisor brings the built-in design that served before it back
    // (a program that crashed once is likely to crash again).
    let restart = wait_for_event(&dir, Duration::from_secs(60), "no restart", |e| {
        matches!(e.kind, EventKind::Restart(_))
    });
    let detail = restart_of(&restart);
    assert_eq!(
        detail.rolled_back_from.as_deref(),
        Some(program.to_str().unwrap()),
        "{restart:?}"
    );
    assert!(
        detail
            .scenario
            .as_deref()
            .is_some_and(|s| s.ends_with("lecture-double-integrator.toml")),
        "{restart:?}"
    );
    stop_after_more_ticks(&dir, &prefix, child, 1_000);
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert_eq!(command_generations(&log), [0, 1, 2]);
    assert_clean(&dir);
}

/// The observer example's scenario, with both programs as built here.
pub(crate) fn observer_scenario(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/luenberger-observer/scenario.toml"),
    )
    .unwrap()
    .replacen(
        "exec = [\"./target/release/luenberger-observer\"]",
        &format!(
            "exec = [{:?}]",
            built("luenberger-observer").display().to_string()
        ),
        1,
    )
    .replacen(
        "exec = [\"../pid-controller/target/release/pid-controller\"]",
        &format!("exec = [{:?}]", example_program().display().to_string()),
        1,
    );
    let path = dir.join("observer.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// Every estimate of the run equals the observer example's predictor
/// stepped from x̂ = 0 on the recorded measurements; returns how many.
fn assert_estimates_follow_the_predictor(log: &LogReader) -> usize {
    let predictor = Predictor::example();
    let mut x = [0.0_f64; 2];
    let measurements: HashMap<u64, &Measurement> = log.measurements().map(|m| (m.seq, m)).collect();
    let mut checked = 0;
    for e in log.estimates() {
        if e.seq == 0 {
            assert_eq!(&e.x_hat[..2], &[0.0, 0.0]);
            continue;
        }
        let m = measurements[&(e.seq - 1)];
        x = predictor.step(x, m.y[0], m.u_applied[0]);
        assert_estimate_is(e, x);
        checked += 1;
    }
    checked
}

#[test]
fn the_example_observer_estimates_as_its_law_says_and_swaps_to_itself_by_exec() {
    let dir = temp_dir("own-observer");
    let scenario = observer_scenario(&dir);
    let (child, prefix) = start_file_and_await(&dir, &scenario, &["--mode", "lockstep"], 1_500);
    let out = swap_to(
        &prefix,
        &[
            "observer",
            "--exec",
            built("luenberger-observer").to_str().unwrap(),
        ],
    );
    assert!(out.status.success(), "{}", describe(&out));
    stop_after_more_ticks(&dir, &prefix, child, 1_500);
    let summary = summary(&dir);
    assert_eq!(summary.counters.misses, 0, "{summary:?}");
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert_eq!(estimate_generations(&log), [0, 1]);
    // Across the swap: the successor took its predecessor's x̂ (`load`).
    assert!(assert_estimates_follow_the_predictor(&log) > 3_000);
    // And the position estimate follows the measured position.
    let last = log.estimates().last().unwrap();
    let y = log.measurements().last().unwrap().y[0];
    assert!((last.x_hat[0] - y).abs() < 1e-5, "{} vs {y}", last.x_hat[0]);
    assert_clean(&dir);
}

#[test]
fn a_port_of_the_wrong_type_is_refused_and_a_flood_is_counted_not_applied() {
    use flexloop_protocol::Estimate;
    use flexloop_protocol::channels::{COMMAND, MEASUREMENT};
    use flexloop_transport::{Domain, Inlet, Outlet};
    let dir = temp_dir("own-components-flood");
    let (child, prefix) = start_lecture_lockstep(&dir, 500);
    {
        let domain = Domain::new(&prefix).unwrap();
        let node = domain.node("bad-component").unwrap();
        // A program whose command is of another type (size and type name):
        // iceoryx2 refuses its port, so it never reaches the plant.
        assert!(Outlet::<Estimate>::open(&node, &COMMAND).is_err());
        // One that floods: 64 commands of a generation that owns no sample
        // for every measurement. Each publisher has its own queue at the
        // plant, so the flood overflows only its own: the active
        // controller's commands all arrive.
        let measurements = Inlet::<Measurement>::open_polling(&node, &MEASUREMENT, 16).unwrap();
        let flood = Outlet::<Command>::open(&node, &COMMAND).unwrap();
        let since = std::time::Instant::now();
        while since.elapsed() < Duration::from_millis(500) {
            while let Some(m) = measurements.receive().unwrap() {
                for _ in 0..64 {
                    flood
                        .publish(|c| {
                            c.seq = m.seq;
                            c.generation = 7;
                            c.n_inputs = 1;
                            c.u[0] = 50.0;
                        })
                        .unwrap();
                }
                flood.notify().unwrap();
            }
            std::thread::sleep(Duration::from_micros(200));
        }
    }
    stop_after_more_ticks(&dir, &prefix, child, 200);
    let summary = summary(&dir);
    // The plant rejected the flood; the logger counted it apart and kept it
    // out of the record: the loop's own commands, gaps and latencies only.
    let counters = summary.counters;
    assert!(counters.rejected_commands > 0, "{summary:?}");
    assert!(counters.foreign_commands > 0, "{summary:?}");
    assert_lost_nothing(&summary, "under the flood");
    assert_eq!(counters.stale_estimates, 0, "{summary:?}");
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert!(log.measurements().all(|m| m.u_applied[0] != 50.0));
    assert!(log.commands().all(|c| c.generation == 0 && c.u[0] != 50.0));
    assert_eq!(log.commands().count() as u64, summary.samples.command);
    assert_clean(&dir);
}

#[test]
fn a_programs_params_are_set_live_and_handed_over_bumplessly() {
    let dir = temp_dir("own-controller-set");
    let scenario = example_scenario(&dir, "pid.toml", "");
    let (child, prefix) = start_file_and_await(&dir, &scenario, &["--mode", "lockstep"], 1_500);
    let on_loop = |args: &[&str]| {
        let mut c = flexloop();
        c.args(args).args(["--prefix", &prefix]);
        run_bounded(c, Duration::from_secs(150))
    };
    let stdout = |out: &std::process::Output| String::from_utf8_lossy(&out.stdout).into_owned();
    let get = on_loop(&["get", "controller.params.kp"]);
    assert_eq!(stdout(&get).trim(), "9000.0", "{}", describe(&get));
    // The program's own tunable: a new process of it with the changed
    // parameters takes the loop over at a boundary.
    let set = on_loop(&["set", "controller.params.kp=8000"]);
    assert!(set.status.success(), "{}", describe(&set));
    let said = stdout(&set);
    assert!(
        said.contains("controller.params.kp 9000.0 -> 8000")
            && said.contains("controller generation 1"),
        "{said}"
    );
    // `get` shows what the running law reads (the new process's record of
    // its parameters, `params/controller.g1.json`): a float, its default
    // marked, and none of the built-in controller's fields.
    assert_eq!(
        stdout(&on_loop(&["get", "controller.params.kp"])).trim(),
        "8000.0"
    );
    let all = stdout(&on_loop(&["get"]));
    assert!(all.contains("controller.params.ki = 90000.0"), "{all}");
    assert!(
        all.contains("controller.params.feedforward = false  # the law's default"),
        "{all}"
    );
    assert!(!all.contains("controller.bandwidth_hz"), "{all}");
    assert!(all.contains("supervision.safe_action"), "{all}");
    // The built-in controller's fields do not act on a program.
    let refused = on_loop(&["set", "controller.bandwidth_hz=40"]);
    assert_eq!(refused.status.code(), Some(2), "{}", describe(&refused));
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("program of one's own"),
        "{}",
        describe(&refused)
    );
    // A parameter the law does not take: its new process exits naming it,
    // the set fails, and the running program keeps the loop.
    let serving = pid_on_duty(&dir, "controller", "active");
    let bad = on_loop(&["set", "controller.params.kq=1"]);
    assert!(!bad.status.success(), "{}", describe(&bad));
    let stderr = std::fs::read_to_string(dir.join("controller.g2.stderr")).unwrap_or_default();
    assert!(stderr.contains("kq"), "{stderr}\n{}", describe(&bad));
    assert_eq!(pid_on_duty(&dir, "controller", "active"), serving);
    stop_after_more_ticks(&dir, &prefix, child, 500);
    let summary = summary(&dir);
    assert_eq!(summary.counters.misses, 0, "{summary:?}");
    let sets = sets(&dir);
    assert_eq!(sets.len(), 1, "{sets:?}");
    let switch = set_of(&sets[0])
        .outcome
        .switches
        .first()
        .unwrap_or_else(|| panic!("a set without a switch: {sets:?}"));
    assert_bumpless(switch, "the set of controller.params.kp");
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert_eq!(command_generations(&log), [0, 1]);
    assert_clean(&dir);
}

/// A scenario naming its program by a relative path (as the examples'
/// scenarios do): the run's copy of the scenario finds it too, so `run`
/// prints its metrics and `report` reads the run (both design the loop
/// again from the copy in the run directory).
#[test]
fn a_program_named_by_a_relative_path_is_found_again_by_run_and_report() {
    let dir = temp_dir("own-controller-relative");
    std::fs::create_dir_all(dir.join("bin")).unwrap();
    std::fs::copy(example_program(), dir.join("bin/pid-controller")).unwrap();
    let scenario = example_scenario(&dir, "pid.toml", "");
    let text = std::fs::read_to_string(&scenario).unwrap();
    let exec = format!("exec = [{:?}]", example_program().display().to_string());
    std::fs::write(
        &scenario,
        text.replacen(&exec, "exec = [\"./bin/pid-controller\"]", 1),
    )
    .unwrap();
    let run = dir.join("run");
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(&scenario)
        .args(["--mode", "lockstep", "--no-realtime", "--duration", "0.3"])
        .arg("--run-dir")
        .arg(&run);
    let out = run_bounded(cmd, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    assert!(run.join("metrics.json").is_file());
    let mut report = flexloop();
    report.arg("report").arg(&run);
    let out = run_bounded(report, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    assert!(run.join("report/report.html").is_file());
    assert_clean(&run);
}
