//! Parsing and validation refuse a bad file with the field to blame.

use flexloop_scenario::{Overrides, Profile, Scenario, ScenarioError};
use std::path::Path;

const LECTURE: &str = r#"
name = "t"
[loop]
rate_hz = 10000
[plant]
model = "double-integrator"
[observer]
design = "state-feedback"
"#;

/// Parsed, overridden and validated, as `Scenario::load` does.
fn validated(text: &str) -> Result<Scenario, ScenarioError> {
    let mut s = Scenario::parse(Path::new("t.toml"), text)?;
    s.apply(&Overrides::default());
    s.validate()?;
    Ok(s)
}

fn shipped_text(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    std::fs::read_to_string(path).unwrap()
}

#[test]
fn unknown_field_is_refused_with_its_name_and_line() {
    let text = LECTURE.replace("[plant]\n", "[plant]\nmas_kg = 2.0\n");
    let err = Scenario::parse(Path::new("t.toml"), &text).unwrap_err();
    assert_eq!(err.field.as_deref(), Some("plant.mas_kg"));
    assert!(err.reason.contains("line 6"), "{}", err.reason);
}

#[test]
fn dedicated_cores_needs_a_cpu_per_loop_process_and_the_machine_for_it() {
    let shared = shipped_text("default");
    let dedicated = shared.replace("[realtime]", "[realtime]\nprofile = \"dedicated-cores\"");
    // The shipped placement shares CPU 0: refused, naming the second process there.
    let e = validated(&dedicated).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.observer.cpu"), "{e}");
    let own_cpus = dedicated
        .replace(
            "controller = { priority = 81, cpu = 0 }",
            "controller = { priority = 81, cpu = 2 }",
        )
        .replace(
            "observer = { priority = 80, cpu = 0 }",
            "observer = { priority = 80, cpu = 1 }",
        );
    let e = validated(&own_cpus).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.logger.cpu"), "{e}");
    let placed = own_cpus.replace(
        "logger = { priority = 10, cpu = 1 }",
        "logger = { priority = 10, cpu = 3 }",
    );
    let mut s = Scenario::parse(Path::new("t.toml"), &placed).unwrap();
    s.apply(&Overrides::default());
    s.validate().unwrap();
    assert_eq!(s.realtime.profile, Profile::DedicatedCores);
    let e = s.check_machine(2).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.profile"));
    assert!(
        e.to_string()
            .contains("needs at least 4 CPUs; this machine has 2"),
        "{e}"
    );
    let e = s.check_machine(3).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("realtime.profile"));
    let e = s.check_machine(4).map(|_| ()).and_then(|_| {
        let mut far = s.clone();
        far.realtime.controller.cpu = Some(7);
        far.check_machine(4)
    });
    assert_eq!(
        e.unwrap_err().field.as_deref(),
        Some("realtime.controller.cpu")
    );
    // Shared cores run anywhere.
    let mut s = Scenario::parse(Path::new("t.toml"), &shared).unwrap();
    s.apply(&Overrides::default());
    assert!(s.check_machine(1).is_ok());
    let e = Scenario::parse(
        Path::new("t.toml"),
        &shared.replace("[realtime]", "[realtime]\nprofile = \"spinning\""),
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("realtime") || e.to_string().contains("profile"),
        "{e}"
    );
}

#[test]
fn out_of_range_values_name_the_field() {
    let mut s = Scenario::parse(Path::new("t.toml"), LECTURE).unwrap();
    s.observer.observer_bandwidth_hz = 6000.0;
    let err = s.validate().unwrap_err();
    assert_eq!(err.field.as_deref(), Some("observer.observer_bandwidth_hz"));
}

/// `validated(text)`'s error: its field and its message.
fn refusal(text: &str) -> (String, String) {
    let e = validated(text).expect_err("accepted");
    let message = e.to_string();
    assert!(message.contains("t.toml"), "{message}");
    (e.field.unwrap_or_default(), message)
}

#[test]
fn a_third_scan_position_is_an_error_not_dropped() {
    let text = shipped_text("thesis-sensor-scan-ad")
        .replace("sensor_scan = [0.0, 7.0]", "sensor_scan = [1.0, 2.0, 3.0]");
    let (field, message) = refusal(&text);
    assert_eq!(field, "plant.sensor_scan", "{message}");
    assert!(message.contains("invalid length 3"), "{message}");
}

#[test]
fn fields_that_do_not_apply_are_refused_by_name() {
    let default = shipped_text("default");
    let original = shipped_text("thesis-original");
    let scan = shipped_text("thesis-sensor-scan-ad");
    for (text, field) in [
        // The chain brings its own masses.
        (
            default.replace(
                "model = \"thesis-chain\"",
                "model = \"thesis-chain\"\nmass_kg = 20.0",
            ),
            "plant.mass_kg",
        ),
        // No Kalman observer, no flexible modes to keep.
        (
            original.replace(
                "design = \"none\"",
                "design = \"none\"\nflexible_modes = 100",
            ),
            "observer.flexible_modes",
        ),
        // The double integrator has one output.
        (
            LECTURE.replace("[plant]\n", "[plant]\noutput = 3\n"),
            "plant.output",
        ),
        // Pole bandwidths belong to the state-feedback design.
        (
            default.replace(
                "design = \"kalman\"",
                "design = \"kalman\"\nobserver_bandwidth_hz = 100",
            ),
            "observer.observer_bandwidth_hz",
        ),
        // The noise model is MC's, the band-pass AD's.
        (
            scan.replace("ad = true", "ad = true\nq_nu = 3.0"),
            "observer.q_nu",
        ),
        (
            scan.replace("ad = true", "ad = false"),
            "observer.damping_increase",
        ),
        // No scanned sensor, no scheduling.
        (
            default.replace("mc = true", "mc = true\nscheduling_step = 0.5"),
            "observer.scheduling_step",
        ),
        // A sine's frequency on a scan, a scan's repeat on a sine.
        (
            default.replace("start_s = 0.01", "start_s = 0.01\nfrequency_hz = 3"),
            "reference.frequency_hz",
        ),
        (
            LECTURE.to_string()
                + "[reference]\nshape = \"sine\"\namplitude = 0.001\nrepeat_s = 1\n",
            "reference.repeat_s",
        ),
        // No PID, no PID bandwidth.
        (
            LECTURE.to_string() + "[controller]\nbandwidth_hz = 30\n",
            "controller.bandwidth_hz",
        ),
        // No noise, nothing to seed.
        (
            LECTURE.replace("[plant]\n", "[plant]\nseed = 7\n"),
            "plant.seed",
        ),
        // No motion, no feedforward.
        (
            default
                .replace("shape = \"scan\"", "shape = \"hold\"")
                .replace("start_s = 0.01\n", "")
                .replace("repeat_s = 0.25\n", ""),
            "controller.feedforward.snap",
        ),
        // No restarts, no back-off.
        (
            LECTURE.to_string() + "[supervision]\nrestart = \"never\"\nrestart_backoff_ms = 10\n",
            "supervision.restart_backoff_ms",
        ),
    ] {
        let (got, message) = refusal(&text);
        assert_eq!(got, field, "{message}");
        assert!(message.contains("does not apply"), "{message}");
    }
}

#[test]
fn every_shipped_scenario_gives_only_fields_that_act() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios");
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "toml") {
            let text = std::fs::read_to_string(&path).unwrap();
            if let Err(e) = Scenario::from_text(&path, &text, &Overrides::default()) {
                panic!("{e}");
            }
        }
    }
}

#[test]
fn sizes_that_drive_the_design_cost_are_bounded() {
    let scan = shipped_text("thesis-sensor-scan-ad");
    // A 1e-9 grid was a 280 GB allocation.
    let (field, message) =
        refusal(&scan.replace("scheduling_step = 0.25", "scheduling_step = 1e-9"));
    assert_eq!(field, "observer.scheduling_step", "{message}");
    assert!(
        message.contains("[0.05, 7]") && message.contains("1e-9"),
        "{message}"
    );
    // 1 999 notches hung the design.
    let notches: Vec<String> = (0..1999).map(|i| format!("{}", 100 + i)).collect();
    let text = shipped_text("default").replace(
        "bandwidth_hz = 43.5",
        &format!("bandwidth_hz = 43.5\nnotches_hz = [{}]", notches.join(", ")),
    );
    let (field, message) = refusal(&text);
    assert_eq!(field, "controller.notches_hz", "{message}");
    assert!(message.contains("at most 8 notches, got 1999"), "{message}");
}

#[test]
fn absurd_magnitudes_are_refused_and_printed_readably() {
    let default = shipped_text("default");
    for (from, to, field) in [
        (
            "force_noise = 0.0",
            "force_noise = 1e300",
            "plant.force_noise",
        ),
        (
            "sensor_noise = 0.0",
            "sensor_noise = 1e300",
            "plant.sensor_noise",
        ),
        (
            "snap = 1.6704035112986372e-6",
            "snap = 1e300",
            "controller.feedforward.snap",
        ),
        (
            "input_limit = 2000.0",
            "input_limit = 1e300",
            "plant.input_limit",
        ),
    ] {
        assert!(default.contains(from), "{from}");
        let text = default.replacen(from, to, 1);
        let (got, message) = refusal(&text);
        assert_eq!(got, field, "{message}");
        assert!(
            message.contains("1e300") && !message.contains("00000000"),
            "{message}"
        );
    }
}

#[test]
fn vague_errors_name_the_field_and_line() {
    let default = shipped_text("default");
    // An array of tables where the format has one table.
    let e = Scenario::parse(
        Path::new("t.toml"),
        &default.replacen("[loop]", "[[loop]]", 1),
    )
    .unwrap_err();
    assert_eq!(e.field.as_deref(), Some("loop"), "{e}");
    assert!(
        e.reason.contains("[[loop]]") && e.reason.contains("one `[loop]` table"),
        "{e}"
    );
    // Tables nested beyond the parser's limit: the line and the key.
    let deep = format!("{default}\n[{}]\n", vec!["a"; 300].join("."));
    let e = Scenario::parse(Path::new("t.toml"), &deep).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("a"), "{e}");
    assert!(
        e.reason.contains("nested too deeply") && !e.reason.contains("line 0"),
        "{e}"
    );
    // A rate too small to be a rate names the rate, not a bandwidth above its Nyquist.
    let (field, message) = refusal(&default.replacen("rate_hz = 10000", "rate_hz = 5e-324", 1));
    assert_eq!(field, "loop.rate_hz", "{message}");
    assert!(message.contains("5e-324"), "{message}");
}

#[test]
fn a_name_that_is_not_one_plain_path_component_is_refused() {
    for name in ["x/../../../escaped", "..", ".", "", "a\\b", "tab\there"] {
        let text = LECTURE.replace("name = \"t\"", &format!("name = {name:?}"));
        let (field, message) = refusal(&text);
        assert_eq!(field, "name", "{message}");
    }
    assert!(validated(&LECTURE.replace("name = \"t\"", "name = \"my run-2\"")).is_ok());
}

#[test]
fn an_io_observer_takes_exactly_one_correction_filter() {
    let default = shipped_text("default");
    let io =
        |extra: &str| default.replace("design = \"kalman\"", &format!("design = \"io\"\n{extra}"));
    // The Kalman gain as K: the Kalman observer's fields all act.
    validated(&io("correction = \"observer-based\"")).unwrap();
    // A K of one's own: no Kalman weights, no noise model.
    let file = io("correction_file = \"k.npz\"").replace("q_nu = 1000.0\n", "");
    validated(&file).unwrap();
    let cases = [
        (
            io("").replace("q_nu = 1000.0\n", ""),
            "observer.correction",
            "needs its correction filter",
        ),
        (
            io("correction = \"observer-based\"\ncorrection_file = \"k.npz\""),
            "observer.correction_file",
            "not several",
        ),
        (
            io("correction = \"luenberger\""),
            "observer.correction",
            "expected one of observer-based",
        ),
        (
            io("correction_file = \"k.npz\""),
            "observer.q_nu",
            "does not apply",
        ),
        (
            file.replace("bandpass_q = 2.0", "bandpass_q = 2.0\nprocess_noise = 0.01"),
            "observer.process_noise",
            "does not apply",
        ),
        (
            default.replace(
                "q_nu = 1000.0",
                "q_nu = 1000.0\ncorrection_file = \"k.npz\"",
            ),
            "observer.correction_file",
            "does not apply",
        ),
        (
            default.replace(
                "q_nu = 1000.0",
                "q_nu = 1000.0\n[observer.correction_arrays]\nD_K = 1.0",
            ),
            "observer.correction_arrays",
            "does not apply",
        ),
        (
            shipped_text("thesis-sensor-scan-ad").replace(
                "design = \"kalman\"",
                "design = \"io\"\ncorrection = \"observer-based\"",
            ),
            "observer.design",
            "scanned sensor",
        ),
    ];
    for (text, field, words) in cases {
        let (got, message) = refusal(&text);
        assert_eq!(got, field, "{message}");
        assert!(message.contains(words), "{message}");
    }
}

/// Smaller refusals a review found: each names the field at fault.
#[test]
fn a_negative_rate_is_the_rates_fault_and_ad_needs_a_mode() {
    let thesis = include_str!("../../../scenarios/thesis-mc-ad.toml");
    let with_deadline = thesis.replace(
        "rate_hz = 10000\n",
        "rate_hz = -10000\ncommand_deadline_us = 30.0\n",
    );
    assert_ne!(with_deadline, thesis);
    let e = Scenario::from_text(
        std::path::Path::new("t.toml"),
        &with_deadline,
        &Overrides::default(),
    )
    .unwrap_err();
    assert_eq!(e.field.as_deref(), Some("loop.rate_hz"), "{e}");
    let no_modes = thesis.replace("ad = true\n", "ad = true\nflexible_modes = 0\n");
    assert_ne!(no_modes, thesis);
    let e = Scenario::from_text(
        std::path::Path::new("t.toml"),
        &no_modes,
        &Overrides::default(),
    )
    .unwrap_err();
    assert_eq!(e.field.as_deref(), Some("observer.flexible_modes"), "{e}");
}
