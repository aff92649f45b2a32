//! What a live swap may change: every field that would step the actuator
//! or change the loop is named, gains and observer designs pass.

use flexloop_scenario::swap::{Swapped, swap_conflicts};
use flexloop_scenario::{Overrides, Scenario};
use std::path::Path;

fn shipped(name: &str) -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    Scenario::load(&path, &Overrides::default()).unwrap()
}

/// The default scenario with `edit` applied.
fn edited(edit: impl FnOnce(&mut Scenario)) -> Scenario {
    let mut s = shipped("default");
    edit(&mut s);
    s
}

fn conflicts(new: &Scenario, swapped: Swapped) -> Vec<&'static str> {
    swap_conflicts(&shipped("default"), new, swapped)
}

#[test]
fn each_field_that_steps_the_actuator_or_changes_the_loop_is_named() {
    type Edit = fn(&mut Scenario);
    let cases: [(&str, Edit); 14] = [
        ("loop.rate_hz", |s| s.timing.rate_hz = 5_000.0),
        ("loop.mode", |s| {
            s.timing.mode = flexloop_scenario::Mode::Lockstep
        }),
        ("plant.input_limit", |s| s.plant.input_limit = 500.0),
        ("plant.output", |s| s.plant.output = 4),
        ("plant.sensor_noise", |s| s.plant.sensor_noise = 1e-9),
        ("plant.model", |s| s.plant.model = "uniform-chain".into()),
        ("reference.shape", |s| s.reference.shape = "sine".into()),
        ("reference.amplitude", |s| s.reference.amplitude = 0.05),
        ("reference.frequency_hz", |s| s.reference.frequency_hz = 3.0),
        ("reference.repeat_s", |s| s.reference.repeat_s = 0.0),
        ("reference.start_s", |s| s.reference.start_s = 0.02),
        ("reference.direction", |s| {
            s.reference.direction = Some(vec![-1.0])
        }),
        ("controller.extra_delay_samples", |s| {
            s.controller.extra_delay_samples = 1
        }),
        ("plant.seed", |s| s.plant.seed = 7),
    ];
    for (field, edit) in cases {
        let new = edited(edit);
        for swapped in [Swapped::Controller, Swapped::Observer] {
            assert_eq!(conflicts(&new, swapped), vec![field], "{swapped:?}");
        }
    }
}

#[test]
fn the_original_thesis_design_on_the_default_loop_is_refused_for_its_reference() {
    // The reproduction: default (a scan every 0.25 s) against one scan.
    let mut original = shipped("thesis-original");
    original.timing.duration_s = 10.0;
    assert_eq!(
        conflicts(&original, Swapped::Controller),
        vec!["reference.repeat_s"]
    );
}

#[test]
fn gains_bandwidths_notches_feedforward_and_the_observer_may_change() {
    let new = edited(|s| {
        s.controller.bandwidth_hz = flexloop_scenario::PidBandwidth::Hz(35.5);
        s.controller.notches_hz = vec![120.0];
        s.controller.feedforward = None;
        s.controller.feedforward_form = "plain".into();
        s.observer.design = "none".into();
        s.observer.mc = false;
        s.observer.ad = false;
        s.observer.damping_increase = 0.05;
        s.observer.flexible_modes = Some(2);
        s.observer.observer_bandwidth_hz = 300.0;
        // Neither the loop's design nor the set-point.
        s.timing.duration_s = 0.3;
        s.name = "retuned".into();
        s.supervision.estimate_watchdog_ticks = 3;
        s.realtime.controller.cpu = Some(1);
        // The default written out is the default.
        s.reference.direction = Some(vec![1.0]);
    });
    assert_eq!(conflicts(&new, Swapped::Controller), Vec::<&str>::new());
    assert_eq!(conflicts(&new, Swapped::Observer), Vec::<&str>::new());
}

#[test]
fn a_controller_without_feedback_must_keep_the_command_it_replaces() {
    // No PID integrator to continue the old command with.
    let none = edited(|s| s.controller.feedback = "none".into());
    assert_eq!(
        conflicts(&none, Swapped::Controller),
        vec!["controller.feedback"]
    );
    // An observer swap runs no controller from the file.
    assert_eq!(conflicts(&none, Swapped::Observer), Vec::<&str>::new());

    let lecture = shipped("lecture-double-integrator");
    let mut retuned = lecture.clone();
    retuned.controller.feedforward = Some(Default::default());
    assert_eq!(
        swap_conflicts(&lecture, &retuned, Swapped::Controller),
        vec!["controller.feedforward"]
    );
    let mut other_form = lecture.clone();
    other_form.controller.feedforward_form = "modified".into();
    assert_eq!(
        swap_conflicts(&lecture, &other_form, Swapped::Controller),
        vec!["controller.feedforward_form"]
    );
    // Its observer's state feedback may be retuned (the observer's part).
    let mut faster = lecture.clone();
    faster.observer.feedback_bandwidth_hz = 30.0;
    assert_eq!(
        swap_conflicts(&lecture, &faster, Swapped::Controller),
        Vec::<&str>::new()
    );
}

#[test]
fn every_differing_field_is_named_at_once() {
    let new = edited(|s| {
        s.reference.repeat_s = 0.0;
        s.plant.input_limit = 10.0;
        s.controller.extra_delay_samples = 1;
    });
    assert_eq!(
        conflicts(&new, Swapped::Controller),
        vec![
            "plant.input_limit",
            "reference.repeat_s",
            "controller.extra_delay_samples"
        ]
    );
}

/// An own plant's scenario text, read as if from `path` (not validated:
/// the swap rule compares what the files say).
fn own(path: &Path, plant: &str) -> Scenario {
    let text = format!(
        "name = \"own\"\n[loop]\nrate_hz = 10000\n[observer]\ndesign = \"kalman\"\n\
         [controller]\nfeedback = \"pid\"\n[plant]\n{plant}\n"
    );
    Scenario::parse(path, &text).unwrap()
}

#[test]
fn a_model_file_is_the_same_plant_only_when_it_is_the_same_file() {
    let file = "model = \"state-space\"\nfile = \"plant.npz\"";
    let a = own(Path::new("/runs/a/own.toml"), file);
    // The same name beside another scenario is another file.
    let elsewhere = own(Path::new("/runs/b/own.toml"), file);
    // The same file, named from another directory.
    let same = own(
        Path::new("/runs/b/own.toml"),
        "model = \"state-space\"\nfile = \"../a/plant.npz\"",
    );
    let absolute = own(
        Path::new("/elsewhere/own.toml"),
        "model = \"state-space\"\nfile = \"/runs/a/plant.npz\"",
    );
    for swapped in [Swapped::Controller, Swapped::Observer] {
        assert_eq!(swap_conflicts(&a, &elsewhere, swapped), vec!["plant.file"]);
        assert_eq!(swap_conflicts(&a, &a.clone(), swapped), Vec::<&str>::new());
        assert_eq!(swap_conflicts(&a, &absolute, swapped), Vec::<&str>::new());
        // These files do not exist, so they cannot be resolved: a path
        // spelled otherwise is refused rather than taken for the same file.
        assert_eq!(swap_conflicts(&a, &same, swapped), vec!["plant.file"]);
    }
}

#[test]
fn inline_arrays_and_lumped_fields_are_the_plant() {
    let at = Path::new("/runs/a/own.toml");
    let arrays = |k: &str| {
        own(
            at,
            &format!(
                "model = \"second-order\"\nzeta = 0.01\n[plant.arrays]\n\
                 M = [[2.5, 0.0], [0.0, 10.0]]\nK = [[{k}, -1e8], [-1e8, 1e8]]\n\
                 B = [1.0, 0.0]\nC = [0.0, 1.0]"
            ),
        )
    };
    assert_eq!(
        swap_conflicts(&arrays("1e8"), &arrays("1e8"), Swapped::Controller),
        Vec::<&str>::new()
    );
    assert_eq!(
        swap_conflicts(&arrays("1e8"), &arrays("2e8"), Swapped::Controller),
        vec!["plant.arrays"]
    );
    let lumped = |lines: &str| {
        own(
            at,
            &format!(
                "model = \"lumped\"\nmasses_kg = [2.5, 10.0]\n\
                 springs = [{{ between = [0, 1], stiffness = 1e8 }}]\n\
                 forces = [{{ at = 0 }}]\npositions = [{{ at = 1 }}]\n{lines}"
            ),
        )
    };
    let base = lumped("zeta = 0.01");
    for (lines, field) in [
        ("zeta = 0.02", "plant.zeta"),
        ("zeta = [0.01]", "plant.zeta"),
        ("rayleigh = { beta = 1e-6 }", "plant.zeta"),
        (
            "dampers = [{ between = [0, 1], damping = 10.0 }]",
            "plant.dampers",
        ),
    ] {
        let new = lumped(lines);
        let conflicts = swap_conflicts(&base, &new, Swapped::Observer);
        assert!(conflicts.contains(&field), "{lines}: {conflicts:?}");
    }
    let edits: [(&str, &str, &str); 4] = [
        (
            "masses_kg = [2.5, 10.0]",
            "masses_kg = [2.5, 12.0]",
            "plant.masses_kg",
        ),
        ("stiffness = 1e8", "stiffness = 2e8", "plant.springs"),
        (
            "forces = [{ at = 0 }]",
            "forces = [{ at = 1 }]",
            "plant.forces",
        ),
        (
            "positions = [{ at = 1 }]",
            "positions = [{ between = [0, 1] }]",
            "plant.positions",
        ),
    ];
    for (from, to, field) in edits {
        let text = "model = \"lumped\"\nmasses_kg = [2.5, 10.0]\n\
             springs = [{ between = [0, 1], stiffness = 1e8 }]\n\
             forces = [{ at = 0 }]\npositions = [{ at = 1 }]\nzeta = 0.01"
            .replace(from, to);
        let new = own(at, &text);
        assert_eq!(
            swap_conflicts(&base, &new, Swapped::Controller),
            vec![field],
            "{to}"
        );
    }
}

#[test]
fn the_model_file_is_the_same_by_any_path_and_another_by_another() {
    let dir = std::env::temp_dir().join(format!("flexloop-swap-file-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("other")).unwrap();
    std::fs::write(dir.join("model.npz"), b"").unwrap();
    std::fs::write(dir.join("other/model.npz"), b"").unwrap();
    let with_file = |source: &Path, file: &str| {
        let mut s = shipped("default");
        s.source = source.to_path_buf();
        s.plant.file = Some(file.into());
        s
    };
    // A scenario in `dir` (reached by a detour, as a relative path from
    // another directory is) naming its model relatively; a tuned copy
    // elsewhere naming the same file absolutely (`flexloop set` does).
    let running = with_file(&dir.join("other/../a.toml"), "model.npz");
    let absolute = dir.join("model.npz").display().to_string();
    let tuned = with_file(&dir.join("other/tuned.toml"), &absolute);
    assert!(swap_conflicts(&running, &tuned, Swapped::Controller).is_empty());
    let elsewhere = with_file(&dir.join("other/b.toml"), "model.npz");
    assert_eq!(
        swap_conflicts(&running, &elsewhere, Swapped::Controller),
        vec!["plant.file"]
    );
    let _ = std::fs::remove_dir_all(&dir);
}
