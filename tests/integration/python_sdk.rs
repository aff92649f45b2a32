//! The Python SDK (python/flexloop) on par with the Rust one: the
//! reference a Python law gets equals shared/design's for every shape
//! and scenario; a Python controller's commands carry their parts; a
//! Python law's parameters are recorded as it uses them; a Python observer
//! serves the loop from its start and is swapped into a running loop and
//! back, its every estimate its law's.
//!
//! They run the Python of the tests' venv (tools/test installs the package
//! and iceoryx2 there from tools/python-requirements.txt).

use crate::util::*;
use flexloop_design::reference::Reference;
use flexloop_runfiles::events::EventKind;
use flexloop_scenario::{Overrides, Scenario};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn python() -> String {
    python_with(&["flexloop", "iceoryx2"])
}

/// Text replacements that make a scenario variant (`scenario_variant`).
type Edits = &'static [(&'static str, &'static str)];

/// `a` and `b` agree to 1e-12 relative, with a 1e-15 absolute floor.
fn close(a: f64, b: f64) -> bool {
    a == b || (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1e-3)
}

/// Every shipped scenario, and variants for the shapes and settings no
/// shipped one has: a hold, a step and a sine each with a command deadline,
/// a scan back and forth at another amplitude with a deadline, a step at
/// another rate.
fn reference_scenarios(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(repo().join("scenarios"))
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 20, "{files:?}");
    let variants: [(&str, &str, Edits); 5] = [
        (
            "lecture-double-integrator",
            "hold.toml",
            &[(
                "[reference]\nshape = \"sine\"\namplitude = 0.001\nfrequency_hz = 2.0",
                "[reference]\nshape = \"hold\"",
            )],
        ),
        (
            "lecture-double-integrator",
            "step-deadline.toml",
            &[
                (
                    "[reference]\nshape = \"sine\"\namplitude = 0.001\nfrequency_hz = 2.0",
                    "[reference]\nshape = \"step\"\namplitude = -0.002\nstart_s = 0.0123",
                ),
                ("[loop]\n", "[loop]\ncommand_deadline_us = 45.5\n"),
            ],
        ),
        (
            "lecture-double-integrator",
            "sine-deadline.toml",
            &[
                (
                    "[reference]\nshape = \"sine\"\namplitude = 0.001\nfrequency_hz = 2.0",
                    "[reference]\nshape = \"sine\"\namplitude = 0.003\nfrequency_hz = 37.0\nstart_s = 0.05",
                ),
                ("[loop]\n", "[loop]\ncommand_deadline_us = 30\n"),
            ],
        ),
        (
            "default",
            "meander-deadline.toml",
            &[
                (
                    "[reference]\nshape = \"scan\"\nstart_s = 0.01\nrepeat_s = 0.25",
                    "[reference]\nshape = \"scan\"\nstart_s = 0.0203\nrepeat_s = 0.2\namplitude = -0.0521",
                ),
                ("[loop]\n", "[loop]\ncommand_deadline_us = 61.0\n"),
            ],
        ),
        (
            "thesis-original",
            "scan-2500hz.toml",
            &[("rate_hz = 10000", "rate_hz = 2500")],
        ),
    ];
    for (name, file, edits) in variants {
        files.push(scenario_variant(dir, name, file, edits, ""));
    }
    files
}

fn f(bits: &Value) -> f64 {
    f64::from_bits(bits.as_u64().unwrap())
}

#[test]
fn the_python_reference_is_the_rust_reference_for_every_scenario() {
    let dir = temp_dir("python-reference");
    let files = reference_scenarios(&dir);
    let mut cmd = Command::new(python());
    cmd.arg(repo().join("python/tests/reference_samples.py"))
        .args(&files)
        .current_dir(repo());
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let report: Vec<Value> = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report.len(), files.len());
    let mut shapes = std::collections::BTreeSet::new();
    let mut compared = 0;
    for (file, entry) in files.iter().zip(&report) {
        let scenario = Scenario::load(file, &Overrides::default())
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let reference = Reference::from_scenario(&scenario)
            .unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let name = file.display();
        shapes.insert(entry["shape"].as_str().unwrap().to_string());
        assert_eq!(
            entry["command_deadline_s"].as_f64(),
            scenario.command_deadline_s(),
            "{name}"
        );
        assert_eq!(
            entry["loop_delay_samples"].as_u64(),
            Some(1 + u64::from(scenario.controller.extra_delay_samples)),
            "{name}"
        );
        let direction: Option<Vec<f64>> = entry["direction"]
            .as_array()
            .map(|d| d.iter().map(|v| v.as_f64().unwrap()).collect());
        assert_eq!(direction, scenario.reference.direction, "{name}");
        let samples = entry["samples"].as_array().unwrap();
        assert!(samples.len() > 1000, "{name}: {} samples", samples.len());
        let mut moved = false;
        for sample in samples {
            let t = f(&sample[0]);
            let rust = reference.sample(t);
            for (i, want) in rust.iter().enumerate() {
                let got = f(&sample[i + 1]);
                assert!(
                    close(got, *want),
                    "{name}: derivative {i} at t = {t:e} ({:#x}): Python {got:e}, Rust {want:e}",
                    t.to_bits()
                );
            }
            moved |= rust[0] != 0.0;
            compared += 1;
        }
        assert!(
            moved || scenario.reference.shape == "hold",
            "{name}: the reference never moved"
        );
    }
    assert_eq!(
        shapes.into_iter().collect::<Vec<_>>(),
        ["hold", "scan", "sine", "step"]
    );
    assert!(compared > 50_000, "{compared} samples compared");
}

#[test]
fn a_python_law_refuses_a_bad_reference_as_the_rust_design_does() {
    let dir = temp_dir("python-reference-bad");
    let cases: [(&str, Edits, &str); 4] = [
        (
            "start.toml",
            &[("start_s = 0.01", "start_s = 0.00005")],
            "reference.start_s",
        ),
        (
            "repeat.toml",
            &[("repeat_s = 0.25", "repeat_s = 0.1")],
            "reference.repeat_s",
        ),
        (
            "amplitude.toml",
            &[("repeat_s = 0.25", "repeat_s = 0.25\namplitude = 11.0")],
            "reference.amplitude",
        ),
        (
            "frequency.toml",
            &[("repeat_s = 0.25", "repeat_s = 0.25\nfrequency_hz = 3.0")],
            "reference.frequency_hz",
        ),
    ];
    for (file, edits, field) in cases {
        let path = scenario_variant(&dir, "default", file, edits, "");
        // What Rust says of it (the scenario's check or the design's).
        let rust = Scenario::load(&path, &Overrides::default())
            .and_then(|s| Reference::from_scenario(&s).map(|_| ()))
            .expect_err(file)
            .to_string();
        let mut cmd = Command::new(python());
        cmd.arg(repo().join("python/tests/reference_samples.py"))
            .arg(&path)
            .current_dir(repo());
        let out = run_bounded(cmd, Duration::from_secs(60));
        assert!(!out.status.success(), "{}", describe(&out));
        let python = String::from_utf8_lossy(&out.stderr);
        assert!(rust.contains(&format!("field `{field}`")), "{rust}");
        // The same message, the file and the field named.
        assert!(python.contains(&rust), "Rust: {rust}\nPython: {python}");
    }
}

/// `flexloop up FILE` in lockstep for `duration` s into `run_dir`.
fn lockstep_run(scenario_file: &Path, run_dir: &Path, duration: &str) {
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario_file)
        .args([
            "--no-realtime",
            "--mode",
            "lockstep",
            "--duration",
            duration,
        ])
        .arg("--run-dir")
        .arg(run_dir);
    let out = run_bounded(cmd, Duration::from_secs(180));
    assert_ran(&out);
}

/// `exec = [the venv's python, python/<script>]`, as TOML.
fn python_exec(script: &str) -> String {
    format!(
        "exec = [{:?}, {:?}]",
        python(),
        repo().join(script).display().to_string()
    )
}

/// The params record `<run-dir>/params/<role>[.g<N>].json`, read as the
/// Rust type it is the contract of (unknown fields refused).
fn params_record(run_dir: &Path, role: &str, generation: u32) -> flexloop_runfiles::ProgramParams {
    let path = flexloop_runfiles::RunDir::new(run_dir).program_params(role, generation);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}\n{text}", path.display()))
}

fn params_of(record: &flexloop_runfiles::ProgramParams) -> Vec<(String, f64)> {
    record
        .params
        .iter()
        .map(|(k, v)| (k.clone(), v.as_f64().unwrap()))
        .collect()
}

#[test]
fn a_python_controllers_commands_carry_their_parts_and_its_params_are_recorded() {
    let dir = temp_dir("python-parts");
    let file = scenario_variant(
        &dir,
        "lecture-double-integrator",
        "parts.toml",
        &[],
        &format!(
            "[controller]\n{}\n\n[controller.params]\nkp = 9000.0\nkd = 110\n",
            python_exec("python/tests/parts_controller.py")
        ),
    );
    let run_dir = dir.join("run");
    lockstep_run(&file, &run_dir, "0.3");
    let scenario = Scenario::load(&file, &Overrides::default()).unwrap();
    let reference = Reference::from_scenario(&scenario).unwrap();
    let ts = 1.0 / scenario.timing.rate_hz;
    let log = flexloop_recording::LogReader::open(&run_dir.join("samples.mcap")).unwrap();
    let y: std::collections::HashMap<u64, f64> =
        log.measurements().map(|m| (m.seq, m.y[0])).collect();
    let x_hat: std::collections::HashMap<u64, f64> =
        log.estimates().map(|e| (e.seq, e.x_hat[1])).collect();
    let mut commands: Vec<_> = log.commands().collect();
    commands.sort_by_key(|c| c.seq);
    assert_eq!(commands.len(), 3000, "0.3 s at 10 kHz");
    let (mut feedforward, mut damping) = (0.0_f64, 0.0_f64);
    for (k, c) in commands.iter().enumerate() {
        assert_eq!(
            (c.seq, c.generation, c.estimate_seq),
            (k as u64, 0, k as u64)
        );
        // The law, recomputed: u_fb = kp (r − y), u_ff = m r̈, u_d = kd (ṙ − x̂₂).
        let [r, v, a, _, _] = reference.sample(c.seq as f64 * ts);
        let y = y[&c.seq];
        let (fb, ff, d) = (9000.0 * (r - y), 1.0 * a, 110.0 * (v - x_hat[&c.seq]));
        for (name, got, want) in [
            ("u", c.u[0], fb + ff + d),
            ("u_fb", c.u_fb[0], fb),
            ("u_ff", c.u_ff[0], ff),
            ("u_d", c.u_d[0], d),
            ("r", c.r[0], r),
            ("e_meas", c.e_meas[0], r - y),
        ] {
            assert!(
                close(got, want),
                "command {}: {name} {got:e}, the law's {want:e}",
                c.seq
            );
        }
        feedforward = feedforward.max(ff.abs());
        damping = damping.max(d.abs());
    }
    // Each part did work.
    assert!(
        feedforward > 1e-3 && damping > 1e-3,
        "{feedforward} {damping}"
    );
    // The params record: what the law read, as it uses them, the default
    // it took named; the built-in observer writes none.
    let record = params_record(&run_dir, "controller", 0);
    assert_eq!((record.role.as_str(), record.generation), ("controller", 0));
    assert_eq!(
        params_of(&record),
        [
            ("kd".to_string(), 110.0),
            ("kp".to_string(), 9000.0),
            ("mass_kg".to_string(), 1.0)
        ]
    );
    assert_eq!(record.defaulted, ["mass_kg"]);
    let files: Vec<String> = std::fs::read_dir(run_dir.join("params"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(files, ["controller.json"], "nothing but the record is left");
    assert_clean(&run_dir);
}

/// The observer example's scenario with python/examples/luenberger.py as
/// its observer and python/examples/pid.py (which reads no estimate) as its
/// controller.
fn python_observer_scenario(dir: &Path) -> PathBuf {
    let text =
        std::fs::read_to_string(repo().join("examples/luenberger-observer/scenario.toml")).unwrap();
    let from = [
        "exec = [\"./target/release/luenberger-observer\"]",
        "exec = [\"../pid-controller/target/release/pid-controller\"]",
    ];
    assert!(from.iter().all(|f| text.contains(f)), "{text}");
    let text = text
        .replacen(from[0], &python_exec("python/examples/luenberger.py"), 1)
        .replacen(from[1], &python_exec("python/examples/pid.py"), 1);
    let path = dir.join("python-observer.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The example's predictor (examples/luenberger-observer, 1 kg, 200 Hz,
/// ζ 0.7 at 10 kHz): x̂ for every tick from `from` (where it starts at 0)
/// on the recorded measurements, by tick.
fn predictor(log: &flexloop_recording::LogReader, from: u64) -> Vec<Option<[f64; 2]>> {
    let law = Predictor::example();
    let measurements: std::collections::BTreeMap<u64, &flexloop_protocol::Measurement> =
        log.measurements().map(|m| (m.seq, m)).collect();
    let last = *measurements.keys().last().unwrap();
    let mut x = vec![None; last as usize + 2];
    x[from as usize] = Some([0.0, 0.0]);
    for seq in from..=last {
        let (Some(x_now), Some(m)) = (x[seq as usize], measurements.get(&seq)) else {
            panic!("no measurement {seq}");
        };
        x[seq as usize + 1] = Some(law.step(x_now, m.y[0], m.u_applied[0]));
    }
    x
}

/// Every estimate of `generations` equals the predictor started at `from`;
/// returns how many there were.
fn assert_estimates_follow_the_predictor(
    log: &flexloop_recording::LogReader,
    from: u64,
    generations: &[u32],
) -> usize {
    let x = predictor(log, from);
    let mut checked = 0;
    for e in log
        .estimates()
        .filter(|e| generations.contains(&e.generation))
    {
        let want = x[e.seq as usize].unwrap_or_else(|| panic!("estimate {} before {from}", e.seq));
        assert_estimate_is(e, want);
        checked += 1;
    }
    checked
}

/// The first measurement the Python observer of `generation` stepped, from
/// its stderr file (`generation N: law stepped from measurement K`).
fn observer_law_start(dir: &Path, generation: u32) -> u64 {
    let file = dir.join(if generation == 0 {
        "observer.stderr".to_string()
    } else {
        format!("observer.g{generation}.stderr")
    });
    let text = std::fs::read_to_string(&file).unwrap_or_default();
    let needle = format!("generation {generation}: law stepped from measurement ");
    let at = text
        .find(&needle)
        .unwrap_or_else(|| panic!("{} says no `{needle}`:\n{text}", file.display()));
    let digits: String = text[at + needle.len()..]
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits.parse().unwrap()
}

/// `flexloop swap --prefix P ARGS…`; asserts it succeeded, returns its answer.
fn swap(prefix: &str, args: &[&str]) -> String {
    let mut c = flexloop();
    c.args(["swap", "--prefix", prefix]).args(args);
    let out = run_bounded(c, Duration::from_secs(150));
    assert!(out.status.success(), "{}", describe(&out));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn the_python_observer_estimates_as_its_law_says_and_swaps_to_itself_by_exec() {
    let dir = temp_dir("python-observer");
    let file = python_observer_scenario(&dir);
    let (child, prefix) = start_file_and_await(&dir, &file, &["--mode", "lockstep"], 1_500);
    // `--exec`: the loop as it stands (its [observer.params] too), served
    // by the same law, which takes its predecessor's x̂ and so continues.
    let py = python();
    let example = repo().join("python/examples/luenberger.py");
    let answer = swap(
        &prefix,
        &["observer", "--exec", &py, example.to_str().unwrap()],
    );
    assert!(answer.contains("observer generation 1"), "{answer}");
    stop_after_more_ticks(&dir, &prefix, child, 1_500);
    assert_lost_nothing(&summary(&dir), "after the swap to itself by --exec");
    let log = flexloop_recording::LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert_eq!(estimate_generations(&log), [0, 1]);
    // One law from tick 0, across the swap.
    assert_eq!(observer_law_start(&dir, 0), 0);
    assert!(assert_estimates_follow_the_predictor(&log, 0, &[0, 1]) > 3_000);
    let last = log.estimates().last().unwrap();
    let y = log.measurements().last().unwrap().y[0];
    assert!((last.x_hat[0] - y).abs() < 1e-5, "{} vs {y}", last.x_hat[0]);
    // Each instance recorded its parameters.
    for generation in [0, 1] {
        let record = params_record(&dir, "observer", generation);
        assert_eq!(
            (record.role.as_str(), record.generation),
            ("observer", generation)
        );
        assert_eq!(
            params_of(&record),
            [
                ("bandwidth_hz".to_string(), 200.0),
                ("damping".to_string(), 0.7),
                ("mass_kg".to_string(), 1.0)
            ]
        );
        assert!(record.defaulted.is_empty(), "{record:?}");
    }
    assert_eq!(params_record(&dir, "controller", 0).params.len(), 4);
    assert_clean(&dir);
}

#[test]
fn the_python_observer_swaps_into_a_running_loop_and_back() {
    let dir = temp_dir("python-observer-swap");
    // The lecture loop with the built-in observer and the Python PID
    // (which reads no estimate: the loop is the same whichever observer).
    let file = scenario_variant(
        &dir,
        "lecture-double-integrator",
        "loop.toml",
        &[],
        &format!(
            "[controller]\n{}\n\n[controller.params]\nkp = 9000.0\nki = 90000.0\n\
             kd = 110.0\nderivative_filter_rad_s = 3000.0\n",
            python_exec("python/examples/pid.py")
        ),
    );
    let (child, prefix) = start_file_and_await(&dir, &file, &["--mode", "lockstep"], 1_000);
    let py = python();
    let example = repo().join("python/examples/luenberger.py");
    let answer = swap(
        &prefix,
        &[
            "observer",
            "--param",
            "mass_kg=1.0",
            "--param",
            "bandwidth_hz=200.0",
            "--param",
            "damping=0.7",
            "--exec",
            &py,
            example.to_str().unwrap(),
        ],
    );
    assert!(answer.contains("observer generation 1"), "{answer}");
    let program = pid_on_duty(&dir, "observer", "active");
    wait_for_more_ticks(&dir, 1_500);
    // Back to the built-in observer; the program, replaced, exits.
    let back = swap(&prefix, &["observer", file.to_str().unwrap()]);
    assert!(back.contains("observer generation 2"), "{back}");
    wait_for_more_ticks(&dir, 500);
    assert_gone(program);
    stop(&prefix, child);
    assert_lost_nothing(&summary(&dir), "into the Python observer and back");
    let log = flexloop_recording::LogReader::open(&dir.join("samples.mcap")).unwrap();
    let mut served: Vec<u64> = log
        .estimates()
        .filter(|e| e.generation == 1)
        .map(|e| e.seq)
        .collect();
    served.sort();
    let (first, last) = (served[0], *served.last().unwrap());
    assert_eq!(served.len() as u64, last - first + 1, "contiguous");
    assert!(served.len() > 1_000, "{} estimates", served.len());
    assert!(
        log.estimates()
            .any(|e| e.generation == 2 && e.seq == last + 1),
        "the built-in observer took over after the program's last estimate {last}"
    );
    // Another design than the built-in one: it followed with its own law
    // from the first measurement it saw (x̂ = 0), and every estimate it
    // published is that law's.
    let from = observer_law_start(&dir, 1);
    assert!(from < first, "{from} {first}");
    assert_eq!(
        assert_estimates_follow_the_predictor(&log, from, &[1]),
        served.len()
    );
    let record = params_record(&dir, "observer", 1);
    assert_eq!(record.generation, 1);
    assert_eq!(record.params.len(), 3);
    assert!(
        !dir.join("params/observer.json").exists(),
        "the built-in one writes none"
    );
    assert_clean(&dir);
}

#[test]
fn a_killed_python_observer_is_restarted_and_catches_up_from_its_state() {
    let dir = temp_dir("python-observer-restart");
    let file = python_observer_scenario(&dir);
    // Without warm spares (tests/integration/observer_restart.rs runs the
    // same with them).
    append_to_scenario(&file, "[supervision]\nwarm_spares = false");
    let (child, prefix) = start_file_and_await(&dir, &file, &["--mode", "lockstep"], 1_500);
    let observer = pid_on_duty(&dir, "observer", "active");
    // SAFETY: a process of this test's loop, by the pid its supervisor lists.
    unsafe { libc::kill(observer, libc::SIGKILL) };
    assert_gone(observer);
    wait_for_event(&dir, Duration::from_secs(60), "no restart", |e| {
        matches!(e.kind, EventKind::Restart(_))
    });
    stop_after_more_ticks(&dir, &prefix, child, 1_500);
    // The restart took the dead one's x̂ and stepped through every
    // measurement since: the run is one law from tick 0.
    let text = std::fs::read_to_string(dir.join("observer.g1.stderr")).unwrap_or_default();
    assert!(
        text.contains("took over the state after sample") && !text.contains("hole"),
        "{text}"
    );
    let log = flexloop_recording::LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert_eq!(estimate_generations(&log), [0, 1]);
    assert!(assert_estimates_follow_the_predictor(&log, 0, &[0, 1]) > 3_000);
    let summary = summary(&dir);
    assert_eq!(summary.gaps.estimate, 0, "{summary:?}");
    assert_clean(&dir);
}

/// The scan rms of e_true of a lockstep `flexloop run` of `scenario_file`.
fn scan_rms(scenario_file: &Path, run_dir: &Path) -> f64 {
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(scenario_file)
        .args(["--mode", "lockstep", "--no-realtime", "--run-dir"])
        .arg(run_dir);
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
    let metrics = metrics(run_dir);
    assert!(metrics.valid, "{:?}", metrics.invalid_reasons);
    metrics.control["rms_e_true_scan"].as_f64().unwrap()
}

/// The thesis' MC + AD scan (thesis-mc-ad-redesigned, f_bw 43.5 Hz, the
/// fitted feedforward gains) under the thesis' controller written in
/// Python (python/examples/thesis_pid.py: Table 3.3's PID, MC and AD from
/// the estimate's parts, the feedforward on the reference's derivatives at
/// the actuation instant) against the built-in controller at the same
/// gains, both with the plain feedforward form: the same scan error.
#[test]
fn the_thesis_controller_in_python_scans_as_the_built_in_one_at_the_same_gains() {
    let dir = temp_dir("python-thesis-pid");
    let plain = [(
        "feedforward_form = \"modified\"",
        "feedforward_form = \"plain\"",
    )];
    let built_in = scenario_variant(&dir, "thesis-mc-ad-redesigned", "built-in.toml", &plain, "");
    let text = std::fs::read_to_string(&built_in).unwrap();
    let mut table: toml::Table = toml::from_str(&text).unwrap();
    let ff = table["controller"]["feedforward"].clone();
    let gain = |k: &str| ff[k].as_float().unwrap();
    let mut params = toml::Table::new();
    for (key, value) in [
        ("bandwidth_hz", 43.5),
        // The mass the built-in PID is tuned on (the chain's rigid body).
        ("mass_kg", 12.5),
        ("ff_snap", gain("snap")),
        ("ff_jerk", gain("jerk")),
        ("ff_acc", gain("acc")),
        ("ff_vel", gain("vel")),
    ] {
        params.insert(key.into(), toml::Value::Float(value));
    }
    let exec = [
        python(),
        repo()
            .join("python/examples/thesis_pid.py")
            .display()
            .to_string(),
    ];
    flexloop_scenario::program::served_by_program(
        &mut table,
        flexloop_scenario::ProgramRole::Controller,
        &exec,
        None,
        Some(params),
    );
    let in_python = dir.join("python.toml");
    std::fs::write(&in_python, toml::to_string(&table).unwrap()).unwrap();
    let rms_built_in = scan_rms(&built_in, &dir.join("run-built-in"));
    let rms_python = scan_rms(&in_python, &dir.join("run-python"));
    let off = (rms_python - rms_built_in).abs() / rms_built_in;
    assert!(
        off < 0.01,
        "scan rms {:.4} nm in Python against {:.4} nm built-in ({:.3} %)",
        rms_python * 1e9,
        rms_built_in * 1e9,
        off * 100.0
    );
    // The Python law's command carries its parts as the built-in one's does.
    let log = flexloop_recording::LogReader::open(&dir.join("run-python/samples.mcap")).unwrap();
    let c = log.commands().nth(1_000).unwrap();
    assert!(
        c.u_ff[0] != 0.0 && c.u_d[0] != 0.0 && c.u_fb[0] != 0.0,
        "{c:?}"
    );
    assert!((c.u[0] - (c.u_fb[0] + c.u_ff[0] + c.u_d[0])).abs() < 1e-9);
    assert_clean(&dir.join("run-python"));
}
