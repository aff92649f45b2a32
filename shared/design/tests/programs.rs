//! A program of one's own serves the controller or the observer on every
//! model and observer flexloop takes (issue: a controller program was
//! refused on every plant but the double integrator, because the design
//! judged the built-in loop that does not run). What is checked is what
//! runs; the closed loop, which needs the program's law, is not claimed.

use flexloop_design::LoopDesign;
use flexloop_scenario::program::served_by_program;
use flexloop_scenario::{Overrides, ProgramRole, Scenario, ScenarioError};
use std::path::{Path, PathBuf};

fn scenarios_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios")
}

/// The scenario at `path` with `roles` served by `sh` (any executable will
/// do: the design does not run it), parsed where the file lies so that its
/// model files resolve.
fn with_programs(path: &Path, roles: &[ProgramRole]) -> Result<LoopDesign, ScenarioError> {
    let mut table: toml::Table = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    for &role in roles {
        served_by_program(&mut table, role, &["sh".to_string()], None, None);
    }
    let text = toml::to_string(&table).unwrap();
    let mut s = Scenario::parse(path, &text)?;
    s.apply(&Overrides::default());
    s.validate()?;
    LoopDesign::from_scenario(&s)
}

fn shipped() -> Vec<PathBuf> {
    let mut all: Vec<PathBuf> = std::fs::read_dir(scenarios_dir())
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    all.sort();
    assert!(all.len() > 20, "{all:?}");
    all
}

#[test]
fn every_shipped_loop_takes_a_program_for_either_role_or_both() {
    for path in shipped() {
        for roles in [
            &[ProgramRole::Controller][..],
            &[ProgramRole::Observer],
            &[ProgramRole::Controller, ProgramRole::Observer],
        ] {
            let d = with_programs(&path, roles)
                .unwrap_or_else(|e| panic!("{} with {roles:?}: {e}", path.display()));
            assert!(d.closed_loop.is_none(), "{}: claimed", path.display());
            // What runs is designed as for the built-in loop: the plant and,
            // when it is built-in, the observer.
            let built_in = with_programs(&path, &[]).unwrap();
            assert_eq!(d.plant, built_in.plant, "{}", path.display());
            assert!(built_in.closed_loop.is_some(), "{}", path.display());
            if !roles.contains(&ProgramRole::Observer) {
                assert_eq!(
                    d.observer.system,
                    built_in.observer.system,
                    "{}",
                    path.display()
                );
            }
            assert_eq!(d.command_deadline_s, built_in.command_deadline_s);
        }
    }
}

/// The cases a review found refused: the thesis chain with its Kalman observer
/// (with and without MC and AD) or none, under a controller program; once
/// refused as "the closed loop is unstable (spectral radius 1.000000)".
#[test]
fn the_thesis_chain_takes_a_controller_program_under_any_observer() {
    let thesis = scenarios_dir().join("thesis-mc-ad.toml");
    let text = std::fs::read_to_string(&thesis).unwrap();
    let dir = std::env::temp_dir().join(format!("flexloop-programs-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (tag, observer) in [
        ("mc-ad", "design = \"kalman\"\nmc = true\nad = true\n"),
        ("mc", "design = \"kalman\"\nmc = true\nad = false\n"),
        ("plain", "design = \"kalman\"\nmc = false\nad = false\n"),
        ("none", "design = \"none\"\n"),
    ] {
        let mut table: toml::Table = toml::from_str(&text).unwrap();
        table.insert(
            "observer".into(),
            toml::Value::Table(toml::from_str(observer).unwrap()),
        );
        let path = dir.join(format!("{tag}.toml"));
        std::fs::write(&path, toml::to_string(&table).unwrap()).unwrap();
        let d = with_programs(&path, &[ProgramRole::Controller])
            .unwrap_or_else(|e| panic!("{tag}: {e}"));
        assert!(d.closed_loop.is_none());
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// With a command deadline a program gets the delayed-input design as the
/// built-in processes do; the deadline is the plant's to enforce.
#[test]
fn a_program_serves_a_loop_with_a_command_deadline() {
    let path = scenarios_dir().join("thesis-mc-ad-deadline-30us.toml");
    let d = with_programs(&path, &[ProgramRole::Controller]).unwrap();
    assert_eq!(d.command_deadline_s, Some(30e-6));
    assert!(d.plant_g_new.is_some());
    let d = with_programs(&path, &[ProgramRole::Observer]).unwrap();
    assert_eq!(d.command_deadline_s, Some(30e-6));
}
