//! Components of one's own on every plant flexloop takes (docs/components.md):
//! {the built-in chain, a lumped network, a second-order file, a
//! state-space file, a MIMO plant} × {observer built-in, observer program}
//! × {controller built-in, Rust program, Python program}, and the chain
//! with a scanned sensor and with a command deadline, each in lockstep:
//! the loop starts on the controller from tick 0, swaps to another and back
//! (to and from a program by `swap --exec` with `--param`), and every
//! command of the controller that started is its law recomputed here from
//! the recorded inputs (1e-12), every estimate of an observer program is
//! its law's, no sample is missed or lost, and each switch steps the
//! command no more than ordinary samples do.
//!
//! The programs are the examples, as a user builds them: a PID per axis
//! (examples/pid-controller, python/examples/pid.py) and a predictor
//! observer per axis (examples/luenberger-observer).

use crate::own_components::{built, example_program};
use crate::util::*;
use flexloop_components::ControllerCore;
use flexloop_protocol::{Command, Estimate, MAX_INPUTS, Measurement};
use flexloop_recording::LogReader;
use flexloop_scenario::ProgramRole;
use flexloop_scenario::program::served_by_program;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Duration;

/// Ticks the starting controller serves, then each swap's.
const TICKS_BEFORE: usize = 1_500;
const TICKS_BETWEEN: usize = 1_000;

/// The PID's gains for a rigid mass `mass` [kg] at f_bw 20 Hz (Table 3.3's
/// single-parameter tuning in parallel form: K_p = m ω²/3, K_i = K_p ω/9,
/// K_d = 3 K_p/ω, the derivative filtered at 3 ω).
fn pid_params(mass: f64) -> [(&'static str, f64); 4] {
    let w = 2.0 * std::f64::consts::PI * 20.0;
    let kp = mass * w * w / 3.0;
    [
        ("kp", kp),
        ("ki", kp * w / 9.0),
        ("kd", 3.0 * kp / w),
        ("derivative_filter_rad_s", 3.0 * w),
    ]
}

/// The predictor observer's parameters for a rigid mass `mass` [kg].
fn observer_params(mass: f64) -> [(&'static str, f64); 3] {
    [("mass_kg", mass), ("bandwidth_hz", 200.0), ("damping", 0.7)]
}

fn params_table(params: &[(&str, f64)]) -> toml::Table {
    params
        .iter()
        .map(|(k, v)| (k.to_string(), toml::Value::Float(*v)))
        .collect()
}

/// A plant of the matrix: its scenario with the built-in controller and
/// observer (as shipped), and the rigid mass each actuator moves.
struct Plant {
    tag: &'static str,
    scenario: PathBuf,
    mass: f64,
}

/// The thesis chain's model files (second-order M, K, D, B, C and a
/// state-space A, B, C, D, written by NumPy), made once.
fn chain_model_files() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("program-matrix-models-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        write_chain_models(&dir);
        dir
    })
}

fn plant(tag: &str) -> Plant {
    let from_file = |model: &str, file: &str| {
        let text = std::fs::read_to_string(scenario("default")).unwrap();
        let path = chain_model_files().join(format!("{tag}.toml"));
        let plant = format!("model = \"{model}\"\nfile = \"{file}\"\n");
        let text = text.replacen("model = \"thesis-chain\"\noutput = 5\n", &plant, 1);
        assert!(text.contains(file));
        std::fs::write(&path, text).unwrap();
        path
    };
    let chain_mass = 2.5 + 10.0;
    match tag {
        "chain" => Plant {
            tag: "chain",
            scenario: scenario("default"),
            mass: chain_mass,
        },
        "lumped" => Plant {
            tag: "lumped",
            scenario: scenario("drive-train"),
            mass: 2.0 + 8.0 + 1.5 + 0.6,
        },
        "second-order" => Plant {
            tag: "second-order",
            scenario: from_file("second-order", "chain_mkd.npz"),
            mass: chain_mass,
        },
        "state-space" => Plant {
            tag: "state-space",
            scenario: from_file("state-space", "chain_abcd.npz"),
            mass: chain_mass,
        },
        // The chain with its sensor scanned along it (a scheduled observer).
        "sensor-scan" => Plant {
            tag: "sensor-scan",
            scenario: scenario("thesis-sensor-scan-ad"),
            mass: chain_mass,
        },
        // The chain with each command applied on arrival, 30 µs after its tick.
        "deadline" => Plant {
            tag: "deadline",
            scenario: scenario("thesis-mc-ad-deadline-30us"),
            mass: chain_mass,
        },
        // Two actuators on a 10 kg beam: about half the mass each.
        "mimo" => Plant {
            tag: "mimo",
            scenario: scenario("mimo-example"),
            mass: 5.0,
        },
        other => panic!("no plant {other}"),
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Controller {
    BuiltIn,
    Rust,
    Python,
}

/// The program and its arguments that serve `controller` (a program).
fn controller_exec(controller: Controller) -> Vec<String> {
    match controller {
        Controller::Rust => vec![example_program().display().to_string()],
        Controller::Python => vec![
            python_with(&["flexloop", "iceoryx2"]),
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("python/examples/pid.py")
                .display()
                .to_string(),
        ],
        Controller::BuiltIn => unreachable!("the built-in controller is no program"),
    }
}

/// `plant`'s scenario in `dir` with the observer as `observer_program`
/// says and the controller `controller`, as `name`.
fn variant(
    dir: &Path,
    plant: &Plant,
    observer_program: bool,
    controller: Controller,
    name: &str,
) -> PathBuf {
    let mut table: toml::Table =
        toml::from_str(&std::fs::read_to_string(&plant.scenario).unwrap()).unwrap();
    flexloop_scenario::plant_description::anchor_files(&mut table, &plant.scenario);
    if observer_program {
        let exec = [built("luenberger-observer").display().to_string()];
        let params = params_table(&observer_params(plant.mass));
        served_by_program(&mut table, ProgramRole::Observer, &exec, None, Some(params));
    }
    if controller != Controller::BuiltIn {
        let params = params_table(&pid_params(plant.mass));
        served_by_program(
            &mut table,
            ProgramRole::Controller,
            &controller_exec(controller),
            None,
            Some(params),
        );
    }
    let path = dir.join(name);
    std::fs::write(&path, toml::to_string(&table).unwrap()).unwrap();
    path
}

/// `flexloop swap --prefix P ARGS…`, which must succeed; the switch it made.
fn swap(prefix: &str, args: &[String]) -> serde_json::Value {
    let mut c = flexloop();
    c.args(["swap", "--prefix", prefix]).args(args);
    let out = run_bounded(c, Duration::from_secs(150));
    assert!(out.status.success(), "swap {args:?}: {}", describe(&out));
    serde_json::Value::Null
}

/// `swap controller` to `controller`'s program with the PID's parameters
/// for `mass`, by `--exec` and `--param`.
fn swap_to_program(prefix: &str, controller: Controller, mass: f64) {
    let mut args = vec!["controller".to_string()];
    for (k, v) in pid_params(mass) {
        args.push("--param".into());
        args.push(format!("{k}={v:?}"));
    }
    args.push("--exec".into());
    args.extend(controller_exec(controller));
    swap(prefix, &args);
}

/// One cell of the matrix: `plant` under `observer_program` and the
/// controller `first`, from tick 0, swapped to `second` and back.
fn run_cell(plant: &Plant, observer_program: bool, first: Controller) {
    let tag = format!(
        "matrix-{}-{}-{first:?}",
        plant.tag,
        if observer_program { "oprog" } else { "obuilt" }
    )
    .to_lowercase();
    let dir = temp_dir(&tag);
    let start_file = variant(&dir, plant, observer_program, first, "start.toml");
    let built_in_file = variant(
        &dir,
        plant,
        observer_program,
        Controller::BuiltIn,
        "built-in.toml",
    );
    // Built-in first: to the Rust program and back; a program first: to
    // the built-in controller and back to the program.
    let (child, prefix) =
        start_file_and_await(&dir, &start_file, &["--mode", "lockstep"], TICKS_BEFORE);
    let swap_to_built_in = |prefix: &str| {
        swap(
            prefix,
            &[
                "controller".to_string(),
                built_in_file.display().to_string(),
            ],
        );
    };
    match first {
        Controller::BuiltIn => swap_to_program(&prefix, Controller::Rust, plant.mass),
        _ => swap_to_built_in(&prefix),
    }
    wait_for_more_ticks(&dir, TICKS_BETWEEN);
    match first {
        Controller::BuiltIn => swap_to_built_in(&prefix),
        program => swap_to_program(&prefix, program, plant.mass),
    }
    stop_after_more_ticks(&dir, &prefix, child, TICKS_BETWEEN);

    assert_lost_nothing(&summary(&dir), &tag);
    let swaps = swaps(&dir);
    assert_eq!(swaps.len(), 2, "{tag}: {swaps:?}");
    for swap in &swaps {
        assert_bumpless(&swap_of(swap).switch, &tag);
    }
    assert_no_crash(&dir, &tag);

    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    assert_eq!(command_generations(&log), [0, 1, 2]);
    let served = match first {
        Controller::BuiltIn => assert_built_in_law_from_tick_0(&start_file, &log),
        _ => assert_pid_law_from_tick_0(&start_file, plant.mass, &log),
    };
    assert!(served >= TICKS_BEFORE, "{tag}: {served} commands checked");
    if observer_program {
        let checked = assert_predictor_law(&start_file, plant.mass, &log);
        assert!(checked > 3 * TICKS_BETWEEN, "{tag}: {checked} estimates");
    }
    assert_clean(&dir);
}

/// The loop's design from `file`, as every process makes it.
fn design(file: &Path) -> flexloop_design::LoopDesign {
    flexloop_design::acceptance::accept(file, &flexloop_scenario::Overrides::default(), 2)
        .unwrap()
        .design
}

/// The recorded measurements from tick 0, each with the command generation
/// 0 sent for it, up to the first it sent none for.
fn served_by_generation_0(log: &LogReader) -> Vec<(&Measurement, &Command)> {
    let commands: HashMap<u64, &Command> = log
        .commands()
        .filter(|c| c.generation == 0)
        .map(|c| (c.seq, c))
        .collect();
    log.measurements()
        .map_while(|m| Some((m, *commands.get(&m.seq)?)))
        .collect()
}

/// Every command generation 0 sent equals the built-in controller's law
/// (`ControllerCore`, as the process runs it) stepped here from tick 0 on
/// the recorded measurements and estimates; returns how many.
fn assert_built_in_law_from_tick_0(file: &Path, log: &LogReader) -> usize {
    let design = design(file);
    let mut law = ControllerCore::new(&design, 0);
    let estimates: HashMap<u64, &Estimate> = log.estimates().map(|e| (e.seq, e)).collect();
    let mut checked = 0;
    for (m, sent) in served_by_generation_0(log) {
        let mut out = Command::default();
        law.step(m, estimates[&m.seq], &mut out);
        for i in 0..design.n_inputs {
            assert!(
                (sent.u[i] - out.u[i]).abs() <= 1e-12 * out.u[i].abs().max(1.0),
                "sample {} input {i}: sent {}, the built-in law gives {}",
                m.seq,
                sent.u[i],
                out.u[i]
            );
        }
        checked += 1;
    }
    checked
}

/// The example PID per axis (its gains for `mass`), clamped to `limit`.
struct ReferencePid {
    axes: [ExamplePid; MAX_INPUTS],
    limit: f64,
}

impl ReferencePid {
    fn new(mass: f64, ts: f64, limit: f64) -> Self {
        let p: HashMap<&str, f64> = pid_params(mass).into_iter().collect();
        let (kp, ki, kd, n) = (p["kp"], p["ki"], p["kd"], p["derivative_filter_rad_s"]);
        Self {
            axes: std::array::from_fn(|_| ExamplePid::new(kp, ki, kd, n, ts)),
            limit,
        }
    }

    /// Axis `i`'s step: its command and that before the limit (`u_fb`).
    fn step(&mut self, i: usize, r: f64, y: f64) -> (f64, f64) {
        let u = self.axes[i].step(r - y);
        (u.clamp(-self.limit, self.limit), u)
    }
}

/// Every command generation 0 (the example PID) sent equals its law
/// stepped here from tick 0 on the recorded measurements, with the set-point
/// the scenario's reference gives each axis; returns how many.
fn assert_pid_law_from_tick_0(file: &Path, mass: f64, log: &LogReader) -> usize {
    let design = design(file);
    let mut law = ReferencePid::new(mass, design.ts, design.input_limit);
    let mut checked = 0;
    for (m, sent) in served_by_generation_0(log) {
        let r = design.reference.sample(m.seq as f64 * design.ts)[0];
        for i in 0..design.n_inputs {
            let (u, u_fb) = law.step(i, design.reference_direction[i] * r, m.y[i]);
            assert!(
                (sent.u[i] - u).abs() <= 1e-12 * u.abs().max(1.0),
                "sample {} input {i}: sent {}, the PID gives {u}",
                m.seq,
                sent.u[i]
            );
            // Its parts, as the built-in controller records them.
            assert_eq!(sent.u_fb[i], u_fb);
            assert_eq!(sent.u_ff[i], 0.0);
        }
        checked += 1;
    }
    checked
}

/// Every estimate equals the example predictor (per axis) stepped here
/// from tick 0 on the recorded measurements and applied inputs; returns
/// how many.
fn assert_predictor_law(file: &Path, mass: f64, log: &LogReader) -> usize {
    let design = design(file);
    let ts = design.ts;
    let p: HashMap<&str, f64> = observer_params(mass).into_iter().collect();
    let predictor = Predictor::new(ts, mass, p["bandwidth_hz"], p["damping"]);
    let n = design.n_inputs;
    let mut x = vec![0.0; 2 * n];
    let estimates: HashMap<u64, &Estimate> = log.estimates().map(|e| (e.seq, e)).collect();
    let mut checked = 0;
    let measurements: Vec<&Measurement> = log.measurements().collect();
    assert_eq!(estimates[&0].x_hat[..2 * n], x[..], "the initial estimate");
    for m in measurements {
        for i in 0..n {
            let axis = [x[2 * i], x[2 * i + 1]];
            [x[2 * i], x[2 * i + 1]] = predictor.step(axis, m.y[i], m.u_applied[i]);
        }
        let Some(e) = estimates.get(&(m.seq + 1)) else {
            break;
        };
        assert_eq!(e.n_states as usize, 2 * n);
        for (j, want) in x.iter().enumerate() {
            assert!(
                (e.x_hat[j] - want).abs() <= 1e-12 * want.abs().max(1e-6),
                "estimate for tick {} state {j}: {} against the predictor's {want}",
                e.seq,
                e.x_hat[j]
            );
        }
        checked += 1;
    }
    checked
}

macro_rules! matrix {
    ($($name:ident: $plant:literal, $observer_program:literal, $controller:ident;)*) => {
        $(
            #[test]
            fn $name() {
                run_cell(&plant($plant), $observer_program, Controller::$controller);
            }
        )*
    };
}

matrix! {
    chain_built_in_observer_built_in_controller: "chain", false, BuiltIn;
    chain_built_in_observer_rust_controller: "chain", false, Rust;
    chain_observer_program_built_in_controller: "chain", true, BuiltIn;
    chain_observer_program_rust_controller: "chain", true, Rust;
    lumped_built_in_observer_built_in_controller: "lumped", false, BuiltIn;
    lumped_built_in_observer_rust_controller: "lumped", false, Rust;
    lumped_observer_program_built_in_controller: "lumped", true, BuiltIn;
    lumped_observer_program_rust_controller: "lumped", true, Rust;
    second_order_built_in_observer_built_in_controller: "second-order", false, BuiltIn;
    second_order_built_in_observer_rust_controller: "second-order", false, Rust;
    second_order_observer_program_built_in_controller: "second-order", true, BuiltIn;
    second_order_observer_program_rust_controller: "second-order", true, Rust;
    state_space_built_in_observer_built_in_controller: "state-space", false, BuiltIn;
    state_space_built_in_observer_rust_controller: "state-space", false, Rust;
    state_space_observer_program_built_in_controller: "state-space", true, BuiltIn;
    state_space_observer_program_rust_controller: "state-space", true, Rust;
    mimo_built_in_observer_built_in_controller: "mimo", false, BuiltIn;
    mimo_built_in_observer_rust_controller: "mimo", false, Rust;
    mimo_observer_program_built_in_controller: "mimo", true, BuiltIn;
    mimo_observer_program_rust_controller: "mimo", true, Rust;
    chain_built_in_observer_python_controller: "chain", false, Python;
    chain_observer_program_python_controller: "chain", true, Python;
    lumped_built_in_observer_python_controller: "lumped", false, Python;
    lumped_observer_program_python_controller: "lumped", true, Python;
    second_order_built_in_observer_python_controller: "second-order", false, Python;
    second_order_observer_program_python_controller: "second-order", true, Python;
    state_space_built_in_observer_python_controller: "state-space", false, Python;
    state_space_observer_program_python_controller: "state-space", true, Python;
    mimo_built_in_observer_python_controller: "mimo", false, Python;
    mimo_observer_program_python_controller: "mimo", true, Python;
    sensor_scan_built_in_observer_built_in_controller: "sensor-scan", false, BuiltIn;
    sensor_scan_built_in_observer_rust_controller: "sensor-scan", false, Rust;
    sensor_scan_observer_program_rust_controller: "sensor-scan", true, Rust;
    deadline_built_in_observer_built_in_controller: "deadline", false, BuiltIn;
    deadline_built_in_observer_rust_controller: "deadline", false, Rust;
    deadline_built_in_observer_python_controller: "deadline", false, Python;
}

/// With a command deadline τ_d (each command acts from t_k + τ_d,
/// docs/deadline.md) a program serves the loop too: the Rust example with
/// its model feedforward evaluates the reference at the SDK's actuation
/// instant, t_k + τ_d, and its every command is its law's; the plant
/// counts no miss in lockstep.
#[test]
fn a_program_serves_a_loop_with_a_command_deadline() {
    let dir = temp_dir("matrix-deadline");
    let base = Plant {
        tag: "deadline",
        scenario: scenario("thesis-mc-ad-deadline-30us"),
        mass: 12.5,
    };
    let mut table: toml::Table =
        toml::from_str(&std::fs::read_to_string(&base.scenario).unwrap()).unwrap();
    let mut params = params_table(&pid_params(base.mass));
    params.insert("feedforward".into(), toml::Value::Boolean(true));
    served_by_program(
        &mut table,
        ProgramRole::Controller,
        &controller_exec(Controller::Rust),
        None,
        Some(params),
    );
    let file = dir.join("deadline.toml");
    std::fs::write(&file, toml::to_string(&table).unwrap()).unwrap();
    let mut up = flexloop();
    up.arg("up")
        .arg(&file)
        .args(["--no-realtime", "--mode", "lockstep", "--run-dir"])
        .arg(dir.join("run"));
    let out = run_bounded(up, Duration::from_secs(300));
    assert_ran(&out);
    let run = dir.join("run");
    let summary = summary(&run);
    assert_eq!(summary.counters.misses, 0, "{summary:?}");
    let design = design(&file);
    let tau = design.command_deadline_s.unwrap();
    assert_eq!(tau, 30e-6);
    let log = LogReader::open(&run.join("samples.mcap")).unwrap();
    let commands: HashMap<u64, &Command> = log.commands().map(|c| (c.seq, c)).collect();
    let mut law = ReferencePid::new(base.mass, design.ts, design.input_limit);
    let mut checked = 0;
    let mut feedforward_seen = 0.0f64;
    for m in log.measurements() {
        let Some(sent) = commands.get(&m.seq) else {
            break;
        };
        let r = design.reference.sample(m.seq as f64 * design.ts)[0];
        let (_, u_fb) = law.step(0, r, m.y[0]);
        let ahead = design.reference.sample(m.seq as f64 * design.ts + tau);
        let u_ff: f64 = design.feedforward[0]
            .iter()
            .zip(&ahead)
            .map(|(g, d)| g * d)
            .sum();
        let u = (u_fb + u_ff).clamp(-design.input_limit, design.input_limit);
        assert!(
            (sent.u[0] - u).abs() <= 1e-12 * u.abs().max(1.0),
            "sample {}: sent {}, the law at t_k + τ_d gives {u}",
            m.seq,
            sent.u[0]
        );
        assert_eq!(sent.u_ff[0], u_ff);
        feedforward_seen = feedforward_seen.max(u_ff.abs());
        checked += 1;
    }
    assert!(checked > 2_000, "{checked}");
    assert!(
        feedforward_seen > 100.0,
        "the scan's feedforward: {feedforward_seen} N"
    );
    assert_clean(&run);
}
