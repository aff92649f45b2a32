//! `[measure]` through the processes and `flexloop measure` on the run
//! directory (docs/control.md §14): the built-in loop's responses against
//! its design and a plant file fitted to them that `design` takes; a
//! program of one's own measured at the sensor, with no model of its law.

use crate::util::*;
use flexloop_modelfile::ModelArrays;
use flexloop_modelfile::VectorAs;
use flexloop_runfiles::events::EventKind;
use nalgebra::{Complex, DVector};
use std::path::Path;
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
        let Response {
            measured,
            model,
            coherence,
        } = response(&frf, name);
        let model = model.unwrap_or_else(|| panic!("{name}: no model"));
        let mut checked = 0;
        for i in 0..measured.len() {
            if coherence[i] < 0.99 {
                continue;
            }
            checked += 1;
            let ratio = measured[i] / model[i];
            let db = 20.0 * ratio.norm().log10();
            assert!(
                db.abs() < 0.5 && ratio.arg().to_degrees().abs() < 3.0,
                "{name} line {i}: {db} dB\n{printed}"
            );
        }
        assert!(checked >= 40, "{name}: {checked} lines trusted\n{printed}");
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
    let mut cmd = flexloop();
    cmd.arg("design").arg(&fitted);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let design = String::from_utf8_lossy(&out.stdout);
    assert!(design.contains("6 dB rule met"), "{design}");
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
    nowhere[0] = "point=\"reference\"";
    refused(&prefix, &nowhere, "unknown variant `reference`");

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
