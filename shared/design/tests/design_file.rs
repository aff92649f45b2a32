//! `plant.design_file`: the observer and the controller designed on a model
//! file (a fit to a measurement, docs/control.md §14) around the plant the
//! loop emulates. On the plant's own model it changes nothing; on another
//! model the laws are that model's and the plant is still the scenario's,
//! and the loop analysed is the one that runs: the laws on the plant.

use flexloop_design::LoopDesign;
use flexloop_modelfile::{Array, ModelArrays};
use flexloop_scenario::{Overrides, Scenario, ScenarioError};
use nalgebra::{DMatrix, dmatrix};
use std::path::{Path, PathBuf};

/// Two masses on a spring (5 kg driven, 1 kg measured), lightly damped
/// (D = β K), stiffness scaled by `stiffness`: A, B, C of positions and
/// velocities, continuous, as a `state-space` file.
fn two_mass_file(dir: &Path, name: &str, stiffness: f64) -> PathBuf {
    let (m1, m2, k) = (5.0, 1.0, 4e5 * stiffness);
    let beta = 2e-5;
    let minv = dmatrix![1.0 / m1, 0.0; 0.0, 1.0 / m2];
    let kk = dmatrix![k, -k; -k, k];
    let mut a = DMatrix::zeros(4, 4);
    a.view_mut((0, 2), (2, 2))
        .copy_from(&DMatrix::identity(2, 2));
    a.view_mut((2, 0), (2, 2)).copy_from(&(-&minv * &kk));
    a.view_mut((2, 2), (2, 2)).copy_from(&(-&minv * &kk * beta));
    let b = dmatrix![0.0; 0.0; 1.0 / m1; 0.0];
    let c = dmatrix![1.0, 0.0, 0.0, 0.0];
    let path = dir.join(name);
    let arrays = [("A", a), ("B", b), ("C", c)].map(|(n, m)| (n, Array::from_matrix(&m)));
    ModelArrays::write_npz(&path, &arrays).unwrap();
    path
}

fn scenario(dir: &Path, plant_file: &Path, extra: &str) -> Result<Scenario, ScenarioError> {
    let text = format!(
        r#"
name = "design-file"
[loop]
rate_hz = 10000
duration_s = 1
[plant]
model = "state-space"
file = "{}"
input_limit = 1000
{extra}
[observer]
design = "kalman"
[controller]
feedback = "pid"
bandwidth_hz = "auto"
"#,
        plant_file.display()
    );
    let mut s = Scenario::parse(&dir.join("s.toml"), &text)?;
    s.apply(&Overrides::default());
    s.validate()?;
    Ok(s)
}

fn design(dir: &Path, plant_file: &Path, extra: &str) -> Result<LoopDesign, ScenarioError> {
    LoopDesign::from_scenario(&scenario(dir, plant_file, extra)?)
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "flexloop-design-file-{name}-{}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn the_plants_own_model_as_the_design_file_changes_nothing() {
    let dir = temp_dir("same");
    let plant = two_mass_file(&dir, "plant.npz", 1.0);
    let plain = design(&dir, &plant, "").unwrap();
    let same = design(
        &dir,
        &plant,
        &format!("design_file = \"{}\"", plant.display()),
    )
    .unwrap();
    assert_eq!(plain.pid_bandwidth, same.pid_bandwidth);
    assert_eq!(plain.observer, same.observer);
    assert_eq!(plain.plant.a, same.plant.a);
    assert_eq!(
        plain.closed_loop.as_ref().unwrap().a,
        same.closed_loop.as_ref().unwrap().a
    );
}

#[test]
fn another_model_designs_the_laws_and_the_plant_stays_the_scenarios() {
    let dir = temp_dir("other");
    let plant = two_mass_file(&dir, "plant.npz", 1.0);
    let stiffer = two_mass_file(&dir, "stiffer.npz", 1.3);
    let plain = design(&dir, &plant, "").unwrap();
    let on_stiffer = design(&dir, &stiffer, "").unwrap();
    let mixed = design(&dir, &plant, "design_file = \"stiffer.npz\"").unwrap();
    // The laws are the design model's: its observer and its "auto" f_bw.
    assert_eq!(mixed.observer, on_stiffer.observer);
    assert_eq!(mixed.pid_bandwidth, on_stiffer.pid_bandwidth);
    assert_ne!(mixed.observer, plain.observer);
    // The plant emulated is the scenario's, and so is the loop analysed:
    // neither the plain design's nor the design model's.
    assert_eq!(mixed.plant.a, plain.plant.a);
    assert_eq!(mixed.plant.b, plain.plant.b);
    let a = |d: &LoopDesign| d.closed_loop.as_ref().unwrap().a.clone();
    assert_ne!(a(&mixed), a(&plain));
    assert_ne!(a(&mixed), a(&on_stiffer));
}

#[test]
fn a_design_file_that_cannot_design_the_loop_is_refused_naming_it() {
    let dir = temp_dir("refused");
    let plant = two_mass_file(&dir, "plant.npz", 1.0);
    let refused = |extra: &str, words: &str| {
        let e = design(&dir, &plant, extra).unwrap_err();
        assert_eq!(
            e.field.as_deref(),
            Some("plant.design_file"),
            "{extra}: {e}"
        );
        assert!(e.reason.contains(words), "{extra}: {e}");
    };
    refused("design_file = \"missing.npz\"", "missing.npz");
    refused("design_file = \"model.txt\"", ".npz or a .mat");
    // Two outputs where the plant has one.
    let two = dir.join("two-outputs.npz");
    let m = ModelArrays::read(&plant).unwrap();
    let arrays = [
        ("A", m.array("A").unwrap().clone()),
        ("B", m.array("B").unwrap().clone()),
        ("C", Array::from_matrix(&DMatrix::identity(2, 4))),
    ];
    ModelArrays::write_npz(&two, &arrays).unwrap();
    refused(
        "design_file = \"two-outputs.npz\"",
        "has 1 input and 2 outputs; the plant `state-space` has 1 and 1",
    );
}
