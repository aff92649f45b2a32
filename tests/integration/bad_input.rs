//! Bad input: a clear error naming the file and the field, nothing started.

use crate::util::*;
use std::time::Duration;

fn up_with(scenario_path: &std::path::Path, run_dir: &std::path::Path) -> std::process::Output {
    let mut cmd = flexloop();
    cmd.arg("up")
        .arg(scenario_path)
        .args(["--no-realtime", "--duration", "0.1", "--run-dir"])
        .arg(run_dir);
    run_bounded(cmd, Duration::from_secs(30))
}

fn write_variant(dir: &std::path::Path, from: &str, to: &str) -> std::path::PathBuf {
    let lecture = "lecture-double-integrator";
    scenario_variant(dir, lecture, "bad.toml", &[(from, to)], "")
}

#[test]
fn unknown_field_names_file_and_field() {
    let dir = temp_dir("bad-field");
    let path = write_variant(&dir, "mass_kg = 1.0", "mass_kilograms = 1.0");
    let out = up_with(&path, &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("bad.toml") && err.contains("mass_kilograms"),
        "{err}"
    );
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
}

#[test]
fn invalid_value_names_the_field() {
    let dir = temp_dir("bad-value");
    let path = write_variant(
        &dir,
        "observer_bandwidth_hz = 200.0",
        "observer_bandwidth_hz = 9000.0",
    );
    let out = up_with(&path, &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("observer.observer_bandwidth_hz") && err.contains("Nyquist"),
        "{err}"
    );
}

#[test]
fn missing_scenario_file_is_reported() {
    let dir = temp_dir("missing");
    let out = up_with(&dir.join("nope.toml"), &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        err.contains("nope.toml") && err.contains("cannot read"),
        "{err}"
    );
}

#[test]
fn unwritable_run_directory_is_reported_before_anything_starts() {
    let dir = temp_dir("unwritable");
    let out = up_with(
        &scenario("lecture-double-integrator"),
        std::path::Path::new("/proc/flexloop-run"),
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(err.contains("/proc/flexloop-run"), "{err}");
    assert!(processes_mentioning("/proc/flexloop-run").is_empty());
    let _ = dir;
}

#[test]
fn supervision_settings_are_checked() {
    let dir = temp_dir("bad-supervision");
    for (section, field) in [
        (
            "command_watchdog_ticks = 0",
            "supervision.command_watchdog_ticks",
        ),
        ("safe_action = \"explode\"", "safe_action"),
    ] {
        let table = format!("[supervision]\n{section}");
        let path = scenario_variant(&dir, "lecture-double-integrator", "bad.toml", &[], &table);
        let out = up_with(&path, &dir.join("run"));
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
        assert!(err.contains("bad.toml") && err.contains(field), "{err}");
    }
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
}

#[test]
fn a_swap_into_another_plant_is_refused_and_the_loop_runs_on() {
    let dir = temp_dir("bad-swap");
    let (child, prefix) = start(&dir, "lecture-double-integrator", &["--rate", "1000"]);
    wait_for_ticks(&dir, 1);
    let mut swap = flexloop();
    swap.args(["swap", "controller"])
        .arg(scenario("thesis-original"))
        .args(["--prefix", &prefix]);
    let out = run_bounded(swap, Duration::from_secs(60));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains("thesis-original.toml") && err.contains("plant"),
        "{err}"
    );
    stop(&prefix, child);
    assert_clean(&dir);
}

/// A variant of the shipped scenario `name` with `from` replaced by `to`.
fn variant_of(dir: &std::path::Path, name: &str, from: &str, to: &str) -> std::path::PathBuf {
    scenario_variant(dir, name, &format!("bad-{name}.toml"), &[(from, to)], "")
}

/// `flexloop up` refuses the file with exit status 2 and a message naming the
/// file, the field and every fragment of the reason; nothing starts.
fn refused(dir: &std::path::Path, path: &std::path::Path, field: &str, reason: &[&str]) {
    let out = up_with(path, &dir.join("run"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    let file = path.file_name().unwrap().to_string_lossy();
    assert!(
        err.contains(file.as_ref()) && err.contains(field),
        "{field}: {err}"
    );
    for r in reason {
        assert!(err.contains(r), "{field}: no `{r}` in {err}");
    }
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
    assert!(
        !dir.join("run")
            .join(flexloop_runfiles::RunDir::SAMPLES)
            .exists()
    );
}

#[test]
fn mimo_settings_on_a_siso_plant_are_refused_before_anything_starts() {
    let dir = temp_dir("bad-mimo-on-siso");
    // A reference direction for two outputs on the one-output thesis chain.
    let path = variant_of(
        &dir,
        "thesis-original",
        "shape = \"scan\"",
        "shape = \"scan\"\ndirection = [1.0, 0.0]",
    );
    refused(
        &dir,
        &path,
        "reference.direction",
        &["2 entries", "1 output"],
    );
    // Encoder selection belongs to the OAT-like model.
    let path = variant_of(
        &dir,
        "lecture-double-integrator",
        "mass_kg = 1.0",
        "mass_kg = 1.0\nencoders = [1, 2, 4]",
    );
    refused(&dir, &path, "plant.encoders", &["OAT"]);
    // The MIMO models measure every sensor: one `output` is a mistake.
    let path = variant_of(
        &dir,
        "mimo-example",
        "input_limit",
        "output = 1\ninput_limit",
    );
    refused(&dir, &path, "plant.output", &["reference.direction"]);
}

#[test]
fn an_observer_model_larger_than_the_plant_is_refused() {
    let dir = temp_dir("bad-observer-model");
    // The two-inertia setup has one flexible mode; the observer cannot keep three.
    let path = variant_of(
        &dir,
        "two-inertia",
        "design = \"kalman\"",
        "design = \"kalman\"\nflexible_modes = 3",
    );
    refused(
        &dir,
        &path,
        "observer.flexible_modes",
        &["1 flexible mode", "3"],
    );
    // Nor can the MIMO example's observer keep four of its three.
    let path = variant_of(
        &dir,
        "mimo-example",
        "design = \"kalman\"",
        "design = \"kalman\"\nflexible_modes = 4",
    );
    refused(
        &dir,
        &path,
        "observer.flexible_modes",
        &["3 flexible modes"],
    );
}

#[test]
fn an_unstable_mimo_design_is_refused() {
    let dir = temp_dir("bad-unstable-mimo");
    let path = variant_of(
        &dir,
        "mimo-example",
        "bandwidth_hz = 37.0",
        "bandwidth_hz = 400.0",
    );
    refused(&dir, &path, "controller.bandwidth_hz", &["unstable"]);
    let path = variant_of(
        &dir,
        "oat-like",
        "bandwidth_hz = 26.0",
        "bandwidth_hz = 400.0",
    );
    refused(&dir, &path, "controller.bandwidth_hz", &["unstable"]);
}

#[test]
fn a_mimo_trajectory_beyond_an_actuator_is_refused() {
    let dir = temp_dir("bad-limit-mimo");
    let path = variant_of(
        &dir,
        "mimo-example",
        "input_limit = 2000.0",
        "input_limit = 100.0",
    );
    refused(&dir, &path, "plant.input_limit", &["on input", "100 N"]);
    let path = variant_of(
        &dir,
        "two-inertia",
        "input_limit = 1.0",
        "input_limit = 0.001",
    );
    refused(&dir, &path, "plant.input_limit", &["0.001 A"]);
}

/// `flexloop design` accepts exactly what `flexloop up` accepts: the files
/// design printed a report for and up refused, and a name that would have
/// put the run outside runs/, are refused by both with the same message.
#[test]
fn design_and_up_refuse_the_same_files_with_the_same_message() {
    let dir = temp_dir("design-up");
    for (from, to, field) in [
        (
            "design = \"kalman\"",
            "design = \"magic\"",
            "observer.design",
        ),
        ("shape = \"scan\"", "shape = \"square\"", "reference.shape"),
        (
            "bandwidth_hz = 43.5",
            "bandwidth_hz = 4999",
            "controller.bandwidth_hz",
        ),
        (
            "name = \"default\"",
            "name = \"x/../../../escaped\"",
            "name",
        ),
    ] {
        let path = variant_of(&dir, "default", from, to);
        let mut design = flexloop();
        design.arg("design").arg(&path);
        let design = run_bounded(design, Duration::from_secs(60));
        // Without --run-dir: the name would choose the directory.
        let mut up = flexloop();
        up.arg("up")
            .arg(&path)
            .args(["--no-realtime", "--duration", "0.1"]);
        let up = run_bounded(up, Duration::from_secs(60));
        for out in [&design, &up] {
            assert_eq!(out.status.code(), Some(2), "{field}: {}", describe(out));
        }
        let (design_err, up_err) = (
            String::from_utf8_lossy(&design.stderr),
            String::from_utf8_lossy(&up.stderr),
        );
        assert_eq!(design_err, up_err);
        assert!(
            design_err.contains("bad-default.toml") && design_err.contains(field),
            "{field}: {design_err}"
        );
    }
    // runs/<stamp>-x/../../../escaped-<pid> is beside the checkout.
    let beside = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let escaped: Vec<_> = std::fs::read_dir(beside)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("escaped-"))
        .map(|e| e.path())
        .collect();
    assert!(escaped.is_empty(), "{escaped:?}");
}

/// `thesis-original` with its plant replaced by `plant`, in `dir`.
fn own_plant_variant(dir: &std::path::Path, plant: &str) -> std::path::PathBuf {
    scenario_variant(
        dir,
        "thesis-original",
        "bad-own.toml",
        &[("model = \"thesis-chain\"\noutput = 5\n", plant)],
        "",
    )
}

/// `flexloop up` and `flexloop design` refuse the scenario alike, naming
/// the scenario, the field and every fragment; nothing starts or remains.
fn both_refuse(dir: &std::path::Path, path: &std::path::Path, field: &str, reason: &[&str]) {
    refused(dir, path, field, reason);
    let mut design = flexloop();
    design.arg("design").arg(path);
    let out = run_bounded(design, Duration::from_secs(60));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(err.contains("bad-own.toml") && err.contains(field), "{err}");
    for r in reason {
        assert!(err.contains(r), "design: no `{r}` in {err}");
    }
    assert!(processes_mentioning(&dir.display().to_string()).is_empty());
}

#[test]
fn a_matlab_v7_3_model_file_is_refused_with_the_advice_to_save_with_v7() {
    let dir = temp_dir("bad-mat-v73");
    // MATLAB's v7.3 is HDF5: the 128-byte text header, the HDF5 signature
    // at byte 512.
    let mut v73 =
        b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan 13 2025 HDF5 schema 1.00 ."
            .to_vec();
    v73.resize(116, b' ');
    v73.extend_from_slice(&[0; 8]);
    v73.extend_from_slice(&[0x00, 0x02, b'I', b'M']);
    v73.resize(512, 0);
    v73.extend_from_slice(b"\x89HDF\r\n\x1a\n");
    v73.resize(4096, 0);
    std::fs::write(dir.join("plant.mat"), &v73).unwrap();
    let path = own_plant_variant(&dir, "model = \"state-space\"\nfile = \"plant.mat\"\n");
    both_refuse(&dir, &path, "plant.file", &["plant.mat", "v7.3", "-v7"]);
}

#[test]
fn a_numpy_model_with_a_non_symmetric_k_is_refused_naming_the_file_and_k() {
    let dir = temp_dir("bad-npz-k");
    let mut cmd = std::process::Command::new(python_with(&["numpy"]));
    cmd.arg("-c")
        .arg(
            "import sys, numpy as np\n\
             np.savez(sys.argv[1], M=np.diag([2.5, 10.0]), \
             K=np.array([[1e8, -1e8], [-0.9e8, 1e8]]), B=np.array([1.0, 0.0]), \
             C=np.array([0.0, 1.0]))",
        )
        .arg(dir.join("plant.npz"));
    let out = run_bounded(cmd, Duration::from_secs(60));
    assert!(out.status.success(), "{}", describe(&out));
    let path = own_plant_variant(
        &dir,
        "model = \"second-order\"\nfile = \"plant.npz\"\nzeta = 0.01\n",
    );
    both_refuse(
        &dir,
        &path,
        "plant.file",
        &["plant.npz", "K: is not symmetric"],
    );
}
