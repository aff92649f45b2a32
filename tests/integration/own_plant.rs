//! A plant of the user's own, through the real processes in lockstep: the
//! thesis chain entered every way a user would bring it (a lumped network in
//! the scenario; M, K, D, B, C and a physical A, B, C, D in .npz and .mat
//! files written by NumPy and SciPy) must run Table 3.7's loops as the
//! built-in chain does (docs/own-plant.md).

use crate::util::*;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The scan rms of e_true (nm) of a lockstep run of `scenario`.
fn scan_rms_nm(scenario: &Path, run_dir: &Path) -> f64 {
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(scenario)
        .args(["--mode", "lockstep", "--no-realtime", "--run-dir"])
        .arg(run_dir);
    let out = run_bounded(cmd, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    let metrics = metrics(run_dir);
    assert!(metrics.valid, "{:?}", metrics.invalid_reasons);
    assert_clean(run_dir);
    metrics.control["rms_e_true_scan"].as_f64().unwrap() * 1e9
}

/// The thesis chain's sensor line in the Table 3.7 scenarios.
const BUILT_IN_PLANT: &str = "model = \"thesis-chain\"\noutput = 5\n";

/// `case` (a Table 3.7 scenario) with its plant replaced by `plant`, in `dir`.
fn with_plant(dir: &Path, case: &str, tag: &str, plant: &str) -> PathBuf {
    scenario_variant(
        dir,
        case,
        &format!("{case}-{tag}.toml"),
        &[(BUILT_IN_PLANT, plant)],
        "",
    )
}

/// The chain of Table 3.2 as a lumped network: ma and m1..m7 in a row, the
/// force on ma, the sensor on m5.
fn lumped_chain() -> String {
    let mut springs = vec!["{ between = [0, 1], stiffness = 1e8 }".to_string()];
    springs.extend((1..7).map(|i| format!("{{ between = [{i}, {}], stiffness = 9.6e7 }}", i + 1)));
    format!(
        "model = \"lumped\"\n\
         masses_kg = [2.5, {m}, {m}, {m}, {m}, {m}, {m}, {m}]\n\
         springs = [{}]\n\
         zeta = 0.005\n\
         forces = [{{ at = 0 }}]\n\
         positions = [{{ at = 5 }}]\n",
        springs.join(", "),
        m = 10.0_f64 / 7.0
    )
}

/// The largest f_bw meeting the 6 dB rule that `flexloop design` finds for
/// the scenario's own loop (its observer, its delay).
fn largest_bandwidth_hz(scenario: &Path) -> f64 {
    let mut cmd = flexloop();
    cmd.arg("design").arg(scenario).arg("--json");
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    report["loop"]["largest_bandwidth_hz"]
        .as_f64()
        .unwrap_or_else(|| panic!("no largest f_bw: {}", report["loop"]))
}

/// Within 1 % of the built-in chain's figure.
fn assert_close(what: &str, own: f64, built_in: f64) {
    let off = (own - built_in).abs() / built_in;
    assert!(
        off < 0.01,
        "{what}: {own} nm against the built-in chain's {built_in} nm ({:.3} %)",
        off * 100.0
    );
}

#[test]
fn the_chain_as_a_lumped_network_runs_table_3_7_as_the_built_in_chain() {
    let dir = temp_dir("own-plant-lumped");
    for case in ["thesis-original", "thesis-mc-ad"] {
        let built_in = scan_rms_nm(&scenario(case), &dir.join(format!("{case}-built-in")));
        let lumped = with_plant(&dir, case, "lumped", &lumped_chain());
        let own = scan_rms_nm(&lumped, &dir.join(format!("{case}-lumped")));
        assert_close(&format!("{case} as a lumped network"), own, built_in);
        if case == "thesis-mc-ad" {
            assert_eq!(
                largest_bandwidth_hz(&lumped),
                largest_bandwidth_hz(&scenario(case))
            );
        }
    }
}

#[test]
fn the_chain_from_numpy_and_matlab_files_runs_table_3_7_as_the_built_in_chain() {
    let dir = temp_dir("own-plant-files");
    write_chain_models(&dir);
    let built_in_bandwidth = largest_bandwidth_hz(&scenario("thesis-mc-ad"));
    for case in ["thesis-original", "thesis-mc-ad"] {
        let built_in = scan_rms_nm(&scenario(case), &dir.join(format!("{case}-built-in")));
        for (model, file) in [
            ("second-order", "chain_mkd.npz"),
            ("second-order", "chain_mkd.mat"),
            ("state-space", "chain_abcd.npz"),
            ("state-space", "chain_abcd.mat"),
        ] {
            let tag = file.replace('.', "-");
            let plant = format!("model = \"{model}\"\nfile = \"{file}\"\n");
            let own_scenario = with_plant(&dir, case, &tag, &plant);
            let own = scan_rms_nm(&own_scenario, &dir.join(format!("{case}-{tag}")));
            assert_close(&format!("{case} from {file}"), own, built_in);
            if case == "thesis-mc-ad" {
                assert_eq!(
                    largest_bandwidth_hz(&own_scenario),
                    built_in_bandwidth,
                    "{file}"
                );
            }
        }
    }
}

#[test]
fn a_drive_train_of_its_own_runs_and_tracks_with_the_bandwidth_it_chose() {
    let dir = temp_dir("own-plant-drive-train");
    let path = scenario("drive-train");
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(&path)
        .args(["--mode", "lockstep", "--no-realtime", "--run-dir"])
        .arg(dir.join("run"));
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
    let text =
        String::from_utf8_lossy(&out.stderr).to_string() + &String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("(auto)"), "{text}");
    assert!(!text.contains("warning"), "{text}");
    let metrics = metrics(&dir.join("run"));
    assert!(metrics.valid, "{:?}", metrics.invalid_reasons);
    // A 50 mm scan followed to tens of nanometres; without the loop the
    // feedforward alone leaves micrometres (the modes ring at 212–700 Hz).
    let rms = metrics.control["rms_e_true_scan"].as_f64().unwrap() * 1e9;
    assert!(rms < 50.0, "{rms} nm");
    assert_clean(&dir.join("run"));
}

/// A model file outside the scenario's directory (`../chain_mkd.npz`) is
/// read where it is, and the run's copy of the scenario names it by its
/// absolute path, so that `report` (which designs the loop again from the
/// copy in the run directory) finds it.
#[test]
fn a_model_file_outside_the_scenarios_directory_is_found_again_by_report() {
    let dir = temp_dir("own-plant-outside");
    write_chain_models(&dir);
    let sub = dir.join("scenarios");
    std::fs::create_dir_all(&sub).unwrap();
    let own = with_plant(
        &sub,
        "thesis-mc-ad",
        "outside",
        "model = \"second-order\"\nfile = \"../chain_mkd.npz\"\n",
    );
    let run = dir.join("run");
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(&own)
        .args(["--mode", "lockstep", "--no-realtime", "--run-dir"])
        .arg(&run);
    let out = run_bounded(cmd, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    let copy: toml::Table =
        toml::from_str(&std::fs::read_to_string(run.join("scenario.toml")).unwrap()).unwrap();
    let named = Path::new(copy["plant"]["file"].as_str().unwrap());
    assert!(named.is_absolute(), "{named:?}");
    assert_eq!(
        std::fs::canonicalize(named).unwrap(),
        std::fs::canonicalize(dir.join("chain_mkd.npz")).unwrap()
    );
    let mut report = flexloop();
    report.arg("report").arg(&run);
    let out = run_bounded(report, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    assert_clean(&run);
}
