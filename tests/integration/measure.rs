//! `[measure]` through the processes and `flexloop measure` on the run
//! directory (docs/control.md §14): the built-in loop's responses against
//! its design and a plant file fitted to them that `design` takes (its
//! modes and largest f_bw the chain's); a plant file of one's own measured
//! as its model and its design; a program of one's own measured at the
//! sensor, and the Rust example PID at the plant input, with no model of
//! their law.

use crate::own_components::example_program;
use crate::util::*;
use flexloop_modelfile::{Array, ModelArrays, VectorAs};
use flexloop_runfiles::events::EventKind;
use flexloop_scenario::ProgramRole;
use flexloop_scenario::program::served_by_program;
use nalgebra::{Complex, DMatrix, DVector};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// `flexloop run` of `file` in lockstep into `run_dir`.
fn run_lockstep(file: &Path, run_dir: &Path) {
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(file)
        .args(["--mode", "lockstep", "--no-realtime", "--run-dir"])
        .arg(run_dir);
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
}

/// `flexloop measure run_dir args…`: its stdout.
fn measure(run_dir: &Path, args: &[&str]) -> String {
    let mut cmd = flexloop();
    cmd.arg("measure").arg(run_dir).args(args);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A column of the responses file.
fn column(frf: &ModelArrays, name: &str) -> DVector<f64> {
    let m = frf.matrix(name, VectorAs::Column).unwrap();
    DVector::from_iterator(m.len(), m.iter().copied())
}

/// One response of the file: measured, the model's (if written), and the
/// coherence at each line.
struct Response {
    measured: Vec<Complex<f64>>,
    model: Option<Vec<Complex<f64>>>,
    coherence: Vec<f64>,
}

fn response(frf: &ModelArrays, name: &str) -> Response {
    let complex = |re: DVector<f64>, im: DVector<f64>| {
        re.iter()
            .zip(im.iter())
            .map(|(r, i)| Complex::new(*r, *i))
            .collect::<Vec<_>>()
    };
    let measured = complex(
        column(frf, &format!("{name}_re")),
        column(frf, &format!("{name}_im")),
    );
    let model = frf
        .names()
        .contains(&format!("{name}_model_re").as_str())
        .then(|| {
            complex(
                column(frf, &format!("{name}_model_re")),
                column(frf, &format!("{name}_model_im")),
            )
        });
    let coherence = column(frf, &format!("{name}_coherence"))
        .iter()
        .copied()
        .collect();
    Response {
        measured,
        model,
        coherence,
    }
}

/// How far the measured `name` is from the model's on the lines of
/// coherence >= 0.99: the lines compared, the largest deviation in dB and
/// in degrees. Asserts that every such line is within `db` and `degrees`
/// and that at least `lines` of them are.
#[track_caller]
fn assert_model_within(
    frf: &ModelArrays,
    name: &str,
    (db, degrees): (f64, f64),
    lines: usize,
    printed: &str,
) -> (usize, f64, f64) {
    let Response {
        measured,
        model,
        coherence,
    } = response(frf, name);
    let model = model.unwrap_or_else(|| panic!("{name}: no model"));
    let (mut checked, mut worst_db, mut worst_degrees) = (0, 0.0_f64, 0.0_f64);
    for i in 0..measured.len() {
        if coherence[i] < 0.99 {
            continue;
        }
        checked += 1;
        let ratio = measured[i] / model[i];
        let (off_db, off_degrees) = (20.0 * ratio.norm().log10(), ratio.arg().to_degrees());
        assert!(
            off_db.abs() < db && off_degrees.abs() < degrees,
            "{name} line {i}: {off_db} dB, {off_degrees} deg\n{printed}"
        );
        worst_db = worst_db.max(off_db.abs());
        worst_degrees = worst_degrees.max(off_degrees.abs());
    }
    assert!(
        checked >= lines,
        "{name}: {checked} lines trusted\n{printed}"
    );
    (checked, worst_db, worst_degrees)
}

/// The peak of |name| (dB) measured on the lines of coherence >= 0.99, and
/// the model's on every line.
fn peaks_db(frf: &ModelArrays, name: &str) -> (f64, f64) {
    let r = response(frf, name);
    let db = |h: &Complex<f64>| 20.0 * h.norm().log10();
    let measured = r
        .measured
        .iter()
        .zip(&r.coherence)
        .filter(|(_, c)| **c >= 0.99)
        .map(|(h, _)| db(h))
        .fold(f64::NEG_INFINITY, f64::max);
    let model = r
        .model
        .unwrap_or_else(|| panic!("{name}: no model"))
        .iter()
        .map(db)
        .fold(f64::NEG_INFINITY, f64::max);
    (measured, model)
}

/// `flexloop design --json` of `file`: its loop report.
fn design_json(file: &Path) -> serde_json::Value {
    let mut cmd = flexloop();
    cmd.arg("design").arg(file).arg("--json");
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    report["loop"].clone()
}

/// The scenario `file` as a table, to edit.
fn scenario_table(file: &Path) -> toml::Table {
    toml::from_str(&std::fs::read_to_string(file).unwrap()).unwrap()
}

/// `table` (a scenario) as `dir/name`.
fn write_table(dir: &Path, name: &str, table: &toml::Table) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, toml::to_string(table).unwrap()).unwrap();
    path
}

#[test]
fn a_measured_loop_shows_its_design_and_gives_a_plant_file_the_design_takes() {
    let dir = temp_dir("measure-default");
    let run_dir = dir.join("run");
    run_lockstep(&scenario("measure-default"), &run_dir);
    let printed = measure(&run_dir, &["--fit", "4"]);
    assert!(printed.contains("keeps the 6 dB rule"), "{printed}");
    assert!(
        printed.contains("46 lines from 5.000 to 2000.0 Hz"),
        "{printed}"
    );

    // The file: each response against the design, on the trusted lines.
    let frf = ModelArrays::read(&run_dir.join("measurement/frf.npz")).unwrap();
    assert_eq!(column(&frf, "frequency_hz").len(), 46);
    for name in ["P", "S_i", "T_i", "PS", "L_i"] {
        assert_model_within(&frf, name, (0.5, 3.0), 40, &printed);
    }
    let csv = std::fs::read_to_string(run_dir.join("measurement/frf.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 46);
    assert!(csv.starts_with("frequency_hz,P_re,P_im,P_coherence,P_model_re,P_model_im,"));

    // The fitted plant: a rigid body near the chain's 12.5 kg and four
    // modes, as a state-space plant the design takes.
    assert!(printed.contains("fitted rigid body: 1/(12.5"), "{printed}");
    assert_eq!(printed.matches("fitted mode:").count(), 4, "{printed}");
    let fitted = dir.join("fitted.toml");
    let text = std::fs::read_to_string(scenario("measure-default")).unwrap();
    let (before, after) = text.split_once("[plant]\n").unwrap();
    let plant = format!(
        "[plant]\nmodel = \"state-space\"\nfile = \"{}\"\n",
        run_dir.join("measurement/plant-fit.npz").display()
    );
    let rest = after
        .replace("model = \"thesis-chain\"\n", "")
        .replace("output = 5\n", "");
    std::fs::write(&fitted, format!("{before}{plant}{rest}")).unwrap();
    let on_fit = design_json(&fitted);
    assert_eq!(on_fit["meets_6db_rule"], true, "{on_fit}");

    // The fitted file's modes are the chain's: the first three (the ones
    // the observer keeps) within 0.5 % in frequency and 10 % in damping;
    // and the design finds the same largest f_bw on it as on the chain.
    let chain = design_json(&scenario("measure-default"));
    for i in 0..3 {
        let (mode, truth) = (&on_fit["flexible_modes"][i], &chain["flexible_modes"][i]);
        let off = |field: &str| {
            let (got, want) = (
                mode[field].as_f64().unwrap(),
                truth[field].as_f64().unwrap(),
            );
            (got - want).abs() / want
        };
        assert!(
            off("frequency_hz") < 0.005,
            "mode {i}: {mode} against {truth}"
        );
        assert!(off("open_loop") < 0.10, "mode {i}: {mode} against {truth}");
    }
    let bandwidth = |design: &serde_json::Value| {
        design["largest_bandwidth_hz"]
            .as_f64()
            .unwrap_or_else(|| panic!("no largest f_bw: {design}"))
    };
    assert!(
        (bandwidth(&on_fit) - bandwidth(&chain)).abs() <= 0.5,
        "fitted {on_fit}\nchain {chain}"
    );
}

#[test]
fn a_program_of_ones_own_is_measured_at_the_sensor_without_a_model_of_its_law() {
    let dir = temp_dir("measure-program");
    let law = dir.join("pd.py");
    // A PD law on the measured position, its gains its own.
    std::fs::write(
        &law,
        "import flexloop\n\n\
         class Pd(flexloop.Controller):\n\
         \x20   def __init__(self, setup):\n\
         \x20       super().__init__(setup)\n\
         \x20       self.ts, self.last = setup.ts, 0.0\n\n\
         \x20   def step(self, m, estimate):\n\
         \x20       y = m.y[0]\n\
         \x20       u = -4000.0 * y - 80.0 * (y - self.last) / self.ts\n\
         \x20       self.last = y\n\
         \x20       return u\n\n\
         flexloop.run(Pd)\n",
    )
    .unwrap();
    let file = python_controller_scenario(&dir, "pd.toml", &law);
    append_to_scenario(
        &file,
        "[measure]\npoint = \"sensor\"\nf_min_hz = 10.0\nf_max_hz = 1000.0\nlines = 20\n\
         amplitude = 1e-5\ntransient_periods = 3\nperiods = 4\nstart_s = 0.05",
    );
    // The lecture's 10 s are more than the measurement needs.
    let text = std::fs::read_to_string(&file)
        .unwrap()
        .replace("duration_s = 10.0", "duration_s = 1.0");
    std::fs::write(&file, text).unwrap();
    let run_dir = dir.join("run");
    run_lockstep(&file, &run_dir);
    let printed = measure(&run_dir, &[]);
    assert!(printed.contains("peak of |S_o|"), "{printed}");
    assert!(
        printed.contains("no prediction (the loop is not analysed)"),
        "{printed}"
    );

    // The plant is flexloop's: measured against its model through the
    // program's loop, with no model of the program.
    let frf = ModelArrays::read(&run_dir.join("measurement/frf.npz")).unwrap();
    let Response {
        measured,
        model,
        coherence,
    } = response(&frf, "P");
    let model = model.unwrap();
    let trusted: Vec<usize> = (0..measured.len())
        .filter(|&i| coherence[i] >= 0.99)
        .collect();
    assert!(trusted.len() >= 15, "{printed}");
    for i in trusted {
        let db = 20.0 * (measured[i] / model[i]).norm().log10();
        assert!(db.abs() < 0.1, "P line {i}: {db} dB\n{printed}");
    }
    // The sensitivity and the loop gain agree with each other: L = T / S.
    let s = response(&frf, "S_o");
    let (t, l) = (
        response(&frf, "T_o").measured,
        response(&frf, "L_o").measured,
    );
    assert!(s.model.is_none());
    let s = s.measured;
    for i in 0..s.len() {
        let from_parts = t[i] / s[i];
        assert!((from_parts - l[i]).norm() <= 1e-6 * l[i].norm(), "line {i}");
    }
}

/// The drive train of scenarios/drive-train.toml (motor 2 kg, carriage
/// 8 kg, tool holder 1.5 kg, end effector 0.6 kg; belt 3e6, 1.5e7 and
/// 6e6 N/m; the force on the motor, the sensor on the end effector) as a
/// finite-element export would give it: M, K, B, C in an .npz.
fn write_drive_train_mk(path: &Path) {
    let masses = [2.0, 8.0, 1.5, 0.6];
    let springs = [(0, 1, 3e6), (1, 2, 1.5e7), (2, 3, 6e6)];
    let m = DMatrix::from_diagonal(&DVector::from_column_slice(&masses));
    let mut k = DMatrix::zeros(4, 4);
    for (i, j, stiffness) in springs {
        k[(i, i)] += stiffness;
        k[(j, j)] += stiffness;
        k[(i, j)] -= stiffness;
        k[(j, i)] -= stiffness;
    }
    let mut b = DMatrix::zeros(4, 1);
    b[(0, 0)] = 1.0;
    let mut c = DMatrix::zeros(1, 4);
    c[(0, 3)] = 1.0;
    let arrays =
        [("M", m), ("K", k), ("B", b), ("C", c)].map(|(name, a)| (name, Array::from_matrix(&a)));
    ModelArrays::write_npz(path, &arrays).unwrap();
}

/// A short measurement of 200 N at the plant input: 40 lines asked from
/// 10 Hz (periods of 0.1 s) to `f_max_hz`, 2 transient and 5 measured
/// periods from 0.05 s, done by 0.85 s with its fade-out.
fn short_measure_at_plant_input(f_max_hz: f64) -> toml::Value {
    toml::Value::Table(
        toml::from_str(&format!(
            "point = \"plant-input\"\nf_min_hz = 10.0\nf_max_hz = {f_max_hz:?}\nlines = 40\n\
             amplitude = 200.0\ntransient_periods = 2\nperiods = 5\nstart_s = 0.05\n"
        ))
        .unwrap(),
    )
}

#[test]
fn a_plant_of_ones_own_is_measured_as_its_model_and_its_design() {
    let dir = temp_dir("measure-own-plant");
    let model = dir.join("drive_train_mk.npz");
    write_drive_train_mk(&model);
    // The drive train's loop (Kalman, MC + AD, PID f_bw "auto") on the
    // file, the reference held, measured at the plant input.
    let mut table = scenario_table(&scenario("drive-train"));
    let plant = table["plant"].as_table_mut().unwrap();
    for field in ["masses_kg", "springs", "forces", "positions"] {
        plant.remove(field).unwrap();
    }
    plant.insert("model".into(), "second-order".into());
    plant.insert("file".into(), model.display().to_string().into());
    // Held: no scan, and so no feedforward either.
    table.remove("reference");
    let controller = table["controller"].as_table_mut().unwrap();
    controller.remove("feedforward").unwrap();
    controller.remove("feedforward_form").unwrap();
    table["loop"]["duration_s"] = toml::Value::Float(1.0);
    // To 1 kHz: the modes are at 212 to 700 Hz, and above them the end
    // effector's response falls below its sensor's noise.
    table.insert("measure".into(), short_measure_at_plant_input(1000.0));
    let file = write_table(&dir, "own-plant.toml", &table);
    let run_dir = dir.join("run");
    run_lockstep(&file, &run_dir);
    let printed = measure(&run_dir, &[]);

    // P is the file's model, S_i the design's loop on it, line by line and
    // at its peak.
    let frf = ModelArrays::read(&run_dir.join("measurement/frf.npz")).unwrap();
    for name in ["P", "S_i"] {
        let (lines, db, degrees) = assert_model_within(&frf, name, (0.5, 2.0), 25, &printed);
        eprintln!("own plant: {name} within {db:.3} dB and {degrees:.2} deg on {lines} lines");
    }
    let (measured, design) = peaks_db(&frf, "S_i");
    eprintln!("own plant: peak of |S_i| {measured:.5} dB, the design's {design:.5} dB");
    assert!(
        (measured - design).abs() <= 0.3,
        "peak of |S_i| {measured} dB, the design's {design} dB\n{printed}"
    );
}

#[test]
fn a_controller_of_ones_own_in_rust_is_measured_at_the_plant_input() {
    let dir = temp_dir("measure-own-controller");
    // The measured chain (the thesis chain with its noise) under the
    // example PID at f_bw 20 Hz for its 12.5 kg (Table 3.3's tuning, as the
    // program matrix gives it): flexible modes in P, a law flexloop has no
    // model of.
    let mut table = scenario_table(&scenario("measure-default"));
    let w = 2.0 * std::f64::consts::PI * 20.0;
    let kp = 12.5 * w * w / 3.0;
    let params: toml::Table = [
        ("kp", kp),
        ("ki", kp * w / 9.0),
        ("kd", 3.0 * kp / w),
        ("derivative_filter_rad_s", 3.0 * w),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), toml::Value::Float(v)))
    .collect();
    served_by_program(
        &mut table,
        ProgramRole::Controller,
        &[example_program().display().to_string()],
        None,
        Some(params),
    );
    table["loop"]["duration_s"] = toml::Value::Float(1.0);
    table.insert("measure".into(), short_measure_at_plant_input(2000.0));
    let file = write_table(&dir, "own-controller.toml", &table);
    let run_dir = dir.join("run");
    run_lockstep(&file, &run_dir);
    let printed = measure(&run_dir, &[]);
    assert!(printed.contains("peak of |S_i|"), "{printed}");

    // The plant is flexloop's: its model, through the program's loop.
    let frf = ModelArrays::read(&run_dir.join("measurement/frf.npz")).unwrap();
    let (lines, db, degrees) = assert_model_within(&frf, "P", (0.5, 2.0), 25, &printed);
    eprintln!("own controller: P within {db:.3} dB and {degrees:.2} deg on {lines} lines");
    // No model of the program's law, but the file's S_i and L_i agree
    // with each other: S_i = 1 / (1 + L_i).
    let s = response(&frf, "S_i");
    assert!(s.model.is_none());
    let l = response(&frf, "L_i").measured;
    let mut worst = 0.0_f64;
    for i in (0..s.measured.len()).filter(|&i| s.coherence[i] >= 0.99) {
        let from_loop = 1.0 / (1.0 + l[i]);
        let off = (from_loop - s.measured[i]).norm() / s.measured[i].norm();
        assert!(off <= 1e-6, "line {i}: {off}\n{printed}");
        worst = worst.max(off);
    }
    eprintln!("own controller: S_i = 1/(1 + L_i) to {worst:e}");
}

/// `flexloop measure --running --prefix P fields…`, started.
fn order(prefix: &str, fields: &[&str]) -> std::process::Child {
    let mut cmd = flexloop();
    cmd.args(["measure", "--running", "--prefix", prefix])
        .args(fields)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    cmd.spawn().unwrap()
}

/// An order that must be refused for `words`, before anything runs.
fn refused(prefix: &str, fields: &[&str], words: &str) {
    let out = wait_bounded(order(prefix, fields), Duration::from_secs(60));
    let said = describe(&out);
    assert!(!out.status.success(), "{said}");
    assert!(
        said.contains("measurement refused") && said.contains(words),
        "{said}"
    );
}

const AT_PLANT_INPUT: [&str; 4] = [
    "point=\"plant-input\"",
    "f_min_hz=5",
    "f_max_hz=2000",
    "amplitude=200",
];

#[test]
fn a_measurement_ordered_on_a_running_loop_is_checked_run_and_computed() {
    let dir = temp_dir("measure-running");
    // The measured loop without a [measure] of its own (its reference held).
    let held = dir.join("held.toml");
    let text = std::fs::read_to_string(scenario("measure-default")).unwrap();
    let (loop_only, _) = text.split_once("[measure]").unwrap();
    std::fs::write(&held, loop_only).unwrap();
    let (up, prefix) = start_file_and_await(&dir, &held, &["--mode", "lockstep"], 2_000);

    // Refused as a scenario's [measure] would be, naming the field.
    let mut above = AT_PLANT_INPUT;
    above[2] = "f_max_hz=6000";
    refused(&prefix, &above, "measure.f_max_hz");
    let mut saturating = AT_PLANT_INPUT;
    saturating[3] = "amplitude=1500";
    refused(&prefix, &saturating, "saturate");
    let mut nowhere = AT_PLANT_INPUT;
    nowhere[0] = "point=\"actuator\"";
    refused(&prefix, &nowhere, "unknown variant `actuator`");

    // Twenty periods of 0.2 s: seconds of a lockstep loop, during which a
    // second order and a swap are refused.
    let mut fields = AT_PLANT_INPUT.to_vec();
    fields.push("periods=20");
    let measuring = order(&prefix, &fields);
    let ordered = wait_for_event(&dir, Duration::from_secs(60), "no measure event", |e| {
        matches!(e.kind, EventKind::Measure(_))
    });
    let EventKind::Measure(ordered) = ordered.kind else {
        unreachable!()
    };
    refused(
        &prefix,
        &AT_PLANT_INPUT,
        "a measurement of the loop runs until sample",
    );
    let mut swap = flexloop();
    swap.args(["swap", "--prefix", &prefix, "controller"])
        .arg(&held);
    let swapped = run_bounded(swap, Duration::from_secs(60));
    let said = describe(&swapped);
    assert!(
        !swapped.status.success() && said.contains("a measurement of the loop runs"),
        "{said}"
    );

    let out = wait_bounded(measuring, Duration::from_secs(300));
    let printed = describe(&out);
    assert!(out.status.success(), "{printed}");
    let label = format!("at-{}", ordered.outcome.start_seq);
    assert!(
        printed.contains(&format!("measurement {label}:")),
        "{printed}"
    );
    assert!(printed.contains("keeps the 6 dB rule"), "{printed}");
    let frf = ModelArrays::read(&dir.join("measurement").join(&label).join("frf.npz")).unwrap();
    let s = response(&frf, "S_i");
    let model = s.model.unwrap();
    let trusted: Vec<usize> = (0..s.measured.len())
        .filter(|&i| s.coherence[i] >= 0.99)
        .collect();
    assert!(trusted.len() >= 40, "{printed}");
    for i in trusted {
        let db = 20.0 * (s.measured[i] / model[i]).norm().log10();
        assert!(db.abs() < 0.5, "S_i line {i}: {db} dB\n{printed}");
    }
    stop(&prefix, up);

    // From the run directory alone, afterwards: the same measurement.
    let again = measure(&dir, &[]);
    assert!(again.contains(&format!("measurement {label}:")), "{again}");
    assert!(again.contains("keeps the 6 dB rule"), "{again}");
}

#[test]
fn a_measurement_needs_a_running_loop_and_a_run_that_measured() {
    let dir = temp_dir("measure-none");
    let mut cmd = flexloop();
    cmd.args(["measure", "--running", "--prefix", "flx0_nothing_"])
        .args(AT_PLANT_INPUT);
    let out = run_bounded(cmd, Duration::from_secs(60));
    let said = describe(&out);
    assert!(
        !out.status.success() && said.contains("measurement refused"),
        "{said}"
    );
    // A run without [measure] and without an order measured nothing.
    let run_dir = dir.join("run");
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(scenario("lecture-double-integrator"))
        .args([
            "--mode",
            "lockstep",
            "--no-realtime",
            "--duration",
            "0.2",
            "--run-dir",
        ])
        .arg(&run_dir);
    assert!(run_bounded(cmd, Duration::from_secs(120)).status.success());
    let mut cmd = flexloop();
    cmd.arg("measure").arg(&run_dir);
    let out = run_bounded(cmd, Duration::from_secs(60));
    let said = describe(&out);
    assert!(
        !out.status.success() && said.contains("measured nothing"),
        "{said}"
    );
}

/// A swept and a stepped sine through the processes: the plant runs each
/// (a stepped sine's tones one after another, each faded in and out), the
/// recording holds it, and the plant measured through the loop is its
/// model (the same bounds as the multisine's).
#[test]
fn a_swept_and_a_stepped_sine_measure_the_plant_through_the_processes() {
    let dir = temp_dir("measure-signals");
    // (signal, lines, loop.duration_s): a stepped sine's 4 tones of 0.6 s
    // (2 transient, 3 measured and a fade-out period of 0.1 s) each.
    for (signal, lines, duration_s, trusted) in
        [("swept-sine", 40, 1.0, 25), ("stepped-sine", 4, 2.6, 4)]
    {
        let mut table = scenario_table(&scenario("measure-default"));
        table["loop"]["duration_s"] = toml::Value::Float(duration_s);
        let mut section = short_measure_at_plant_input(2000.0);
        let fields = section.as_table_mut().unwrap();
        fields.insert("signal".into(), signal.into());
        fields.insert("lines".into(), toml::Value::Integer(lines));
        fields.insert("periods".into(), toml::Value::Integer(3));
        table.insert("measure".into(), section);
        let file = write_table(&dir, &format!("{signal}.toml"), &table);
        let run_dir = dir.join(signal);
        run_lockstep(&file, &run_dir);
        let printed = measure(&run_dir, &[]);
        assert!(printed.contains(&format!("a {signal} of")), "{printed}");
        let frf = ModelArrays::read(&run_dir.join("measurement/frf.npz")).unwrap();
        let (lines, db, degrees) = assert_model_within(&frf, "P", (0.5, 2.0), trusted, &printed);
        eprintln!("{signal}: P within {db:.3} dB and {degrees:.2} deg on {lines} lines");
        let (measured, design) = peaks_db(&frf, "S_i");
        eprintln!("{signal}: peak of |S_i| {measured:.3} dB, the design's {design:.3} dB");
        assert!(
            (measured - design).abs() <= 0.3,
            "{signal}: peak of |S_i| {measured} dB, the design's {design} dB\n{printed}"
        );
    }
}

/// The round in one step on a running loop: measured, fitted, redesigned
/// on the fit (`plant.design_file`, f_bw "auto"), checked, handed over and
/// measured again; the loop ends as it runs, on the laws of the fit.
#[test]
fn a_running_loop_is_measured_fitted_retuned_handed_over_and_measured_again() {
    let dir = temp_dir("measure-round");
    let held = dir.join("held.toml");
    let text = std::fs::read_to_string(scenario("measure-default")).unwrap();
    let (loop_only, _) = text.split_once("[measure]").unwrap();
    std::fs::write(&held, loop_only).unwrap();
    let (up, prefix) = start_file_and_await(&dir, &held, &["--mode", "lockstep"], 2_000);
    let retuned = dir.join("retuned.toml");
    let mut cmd = flexloop();
    cmd.args(["measure", "--running", "--prefix", &prefix])
        .args(AT_PLANT_INPUT)
        .args(["--fit", "4", "--swap", "--retune"])
        .arg(&retuned);
    let out = run_bounded(cmd, Duration::from_secs(600));
    let printed = describe(&out);
    assert!(out.status.success(), "{printed}");
    for words in [
        "fitted mode: 470",
        "retuned scenario:",
        "PID f_bw on the fit:",
        "that design around the plant that runs",
        "swapped the observer",
        "swapped the controller",
        "measuring the retuned loop again",
    ] {
        assert!(printed.contains(words), "{words}: {printed}");
    }
    // Two measurements, the second of the new loop, each its design's: the
    // peak of |S_i| against the design's prediction. ("auto" chose the
    // largest f_bw that meets the rule on the fit, so the new loop sits on
    // the 6 dB line and noise may put it either side.)
    let peaks: Vec<(f64, f64)> = printed
        .lines()
        .filter_map(|l| l.strip_prefix("peak of |S_i|: "))
        .map(|l| {
            let measured = l.split(' ').next().unwrap().parse().unwrap();
            let (_, design) = l.split_once("(the design: ").unwrap();
            (measured, design.split(' ').next().unwrap().parse().unwrap())
        })
        .collect();
    assert_eq!(peaks.len(), 2, "{printed}");
    for (measured, design) in peaks {
        assert!((measured - design).abs() <= 0.3, "{printed}");
    }
    let events = events(&dir);
    let swaps = events
        .iter()
        .filter(|e| matches!(e.kind, EventKind::Swap(_)))
        .count();
    let measured = events
        .iter()
        .filter(|e| matches!(e.kind, EventKind::Measure(_)))
        .count();
    assert_eq!((swaps, measured), (2, 2), "{printed}");
    // The loop runs the retuned file: its design model is the fit.
    let now = std::fs::read_to_string(dir.join("scenario-now.toml")).unwrap();
    assert!(
        now.contains("design_file") && now.contains("plant-fit.npz"),
        "{now}"
    );
    stop(&prefix, up);
    // The retuned file stands on its own: `design` takes it and says so.
    let mut cmd = flexloop();
    cmd.arg("design").arg(&retuned);
    let out = run_bounded(cmd, Duration::from_secs(300));
    let said = describe(&out);
    assert!(
        out.status.success() && said.contains("(plant.design_file)"),
        "{said}"
    );
}

/// The reference as the point (the built-in controller adds the plant's
/// excitation to its set-point): through the processes, the plant and the
/// tracking responses are the design's.
#[test]
fn a_measurement_at_the_reference_gives_the_designs_tracking() {
    let dir = temp_dir("measure-reference");
    let mut table = scenario_table(&scenario("measure-default"));
    table["loop"]["duration_s"] = toml::Value::Float(1.0);
    let mut section = short_measure_at_plant_input(2000.0);
    let fields = section.as_table_mut().unwrap();
    fields.insert("point".into(), "reference".into());
    fields.insert("amplitude".into(), toml::Value::Float(5e-5));
    table.insert("measure".into(), section);
    let file = write_table(&dir, "reference.toml", &table);
    let run_dir = dir.join("run");
    run_lockstep(&file, &run_dir);
    let printed = measure(&run_dir, &[]);
    // The 6 dB rule is read at the plant input or the sensor: with MC,
    // S_r is not the loop's sensitivity.
    assert!(!printed.contains("6 dB rule"), "{printed}");
    let frf = ModelArrays::read(&run_dir.join("measurement/frf.npz")).unwrap();
    for name in ["P", "T_r", "S_r", "CS_r"] {
        let (lines, db, degrees) = assert_model_within(&frf, name, (0.5, 2.0), 20, &printed);
        eprintln!("reference: {name} within {db:.3} dB and {degrees:.2} deg on {lines} lines");
    }
}

/// The measured plant against an independent reference: SciPy's exact ZOH
/// (`cont2discrete`) of the same continuous state space the plant file
/// holds, its frequency response solved by NumPy at the measured lines. A
/// noise-free lockstep loop: the measurement is the plant's response.
#[test]
fn the_measured_plant_is_scipys_zoh_response_of_the_same_state_space() {
    let dir = temp_dir("measure-scipy");
    // Two masses (5 kg driven, 1 kg beyond a 4e5 N/m spring, D = 2e-4 K:
    // its 110 Hz mode at ζ 0.07 settles within the transient periods), the
    // driven one measured: A, B, C, continuous.
    let (m1, m2, k, beta) = (5.0, 1.0, 4e5, 2e-4);
    let a = DMatrix::from_row_slice(
        4,
        4,
        &[
            0.0,
            0.0,
            1.0,
            0.0,
            0.0,
            0.0,
            0.0,
            1.0,
            -k / m1,
            k / m1,
            -beta * k / m1,
            beta * k / m1,
            k / m2,
            -k / m2,
            beta * k / m2,
            -beta * k / m2,
        ],
    );
    let b = DMatrix::from_column_slice(4, 1, &[0.0, 0.0, 1.0 / m1, 0.0]);
    let c = DMatrix::from_row_slice(1, 4, &[1.0, 0.0, 0.0, 0.0]);
    let plant = dir.join("two-mass.npz");
    let arrays = [("A", a), ("B", b), ("C", c)].map(|(n, m)| (n, Array::from_matrix(&m)));
    ModelArrays::write_npz(&plant, &arrays).unwrap();
    let file = dir.join("two-mass.toml");
    std::fs::write(
        &file,
        format!(
            "name = \"two-mass\"\n[loop]\nrate_hz = 10000\nduration_s = 1.0\n\
             [plant]\nmodel = \"state-space\"\nfile = \"{}\"\ninput_limit = 1000\n\
             [observer]\ndesign = \"kalman\"\n[controller]\nfeedback = \"pid\"\n\
             bandwidth_hz = \"auto\"\n\
             [measure]\npoint = \"plant-input\"\nf_min_hz = 10.0\nf_max_hz = 2000.0\n\
             lines = 30\namplitude = 20.0\ntransient_periods = 3\nperiods = 4\nstart_s = 0.05\n",
            plant.display()
        ),
    )
    .unwrap();
    let run_dir = dir.join("run");
    run_lockstep(&file, &run_dir);
    let printed = measure(&run_dir, &[]);
    let frf = run_dir.join("measurement/frf.npz");

    let python = python_with(&["numpy", "scipy"]);
    // SciPy's ZOH; the response C (zI − A_d)⁻¹ B_d solved directly
    // (`dfreqresp` goes through a transfer function's polynomials, which
    // lose 1e-4 on the rigid body's double pole at z = 1).
    let script = "import sys, json, numpy as np\n\
        from scipy.signal import cont2discrete\n\
        m = np.load(sys.argv[1]); f = np.load(sys.argv[2])['frequency_hz']\n\
        ts = 1e-4\n\
        ad, bd, cd, _, _ = cont2discrete((m['A'], m['B'], m['C'], np.zeros((1, 1))), ts, 'zoh')\n\
        z = np.exp(2j * np.pi * f * ts)\n\
        h = [(cd @ np.linalg.solve(zk * np.eye(len(ad)) - ad, bd))[0, 0] for zk in z]\n\
        print(json.dumps([[complex(x).real, complex(x).imag] for x in h]))\n";
    let out = std::process::Command::new(&python)
        .args(["-c", script])
        .arg(&plant)
        .arg(&frf)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let scipy: Vec<[f64; 2]> = serde_json::from_slice(&out.stdout).unwrap();
    let frf = ModelArrays::read(&frf).unwrap();
    let p = response(&frf, "P");
    let model = p.model.unwrap();
    assert_eq!(scipy.len(), p.measured.len());
    let mut checked = 0;
    for (i, [re, im]) in scipy.iter().enumerate() {
        let reference = Complex::new(*re, *im);
        // The design's prediction (the plant it emulates) is SciPy's to
        // rounding.
        let off = (model[i] / reference - 1.0).norm();
        assert!(
            off <= 1e-9,
            "line {i}: the model {} against SciPy's {reference}",
            model[i]
        );
        if p.coherence[i] < 0.999 {
            continue;
        }
        let ratio = p.measured[i] / reference;
        let (db, degrees) = (20.0 * ratio.norm().log10(), ratio.arg().to_degrees());
        assert!(
            db.abs() < 0.01 && degrees.abs() < 0.1,
            "line {i}: {db} dB, {degrees} deg\n{printed}"
        );
        checked += 1;
    }
    assert!(checked >= 25, "{checked} lines\n{printed}");
}
