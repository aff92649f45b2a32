//! `[measure]`: each refusal names its field and says why; what is accepted
//! is the excitation the loop runs (docs/control.md, "Measuring the loop").

use flexloop_control::excitation::{ExcitationShape, InjectionPoint};
use flexloop_scenario::{Overrides, Scenario, ScenarioError};
use std::path::Path;

const LOOP: &str = r#"
name = "t"
[loop]
rate_hz = 10000
duration_s = 4
[plant]
model = "double-integrator"
input_limit = 1000
[observer]
design = "state-feedback"
"#;

const MEASURE: &str = r#"
[measure]
point = "plant-input"
f_min_hz = 5
f_max_hz = 2000
amplitude = 100
"#;

fn validated(text: &str) -> Result<Scenario, ScenarioError> {
    let mut s = Scenario::parse(Path::new("t.toml"), text)?;
    s.apply(&Overrides::default());
    s.validate()?;
    Ok(s)
}

/// The loop with `[measure]` as MEASURE has it, its lines changed
/// (`old => new`) or added, one per line of `change`; validated, and its
/// excitation designed (as `flexloop design` and the start do).
fn with(change: &str) -> Result<Scenario, ScenarioError> {
    let mut measure = MEASURE.to_string();
    for line in change.lines() {
        measure = match line.split_once(" => ") {
            Some((old, new)) => measure.replace(old, new),
            None => format!("{measure}{line}\n"),
        };
    }
    let s = validated(&format!("{LOOP}{measure}"))?;
    s.measurement_plan()?;
    Ok(s)
}

fn refused(change: &str, field: &str, words: &str) {
    let e = with(change).expect_err(change);
    assert_eq!(e.field.as_deref(), Some(field), "{change}: {e}");
    assert!(e.reason.contains(words), "{change}: {e}");
}

#[test]
fn an_accepted_measurement_is_the_excitation_the_plant_runs() {
    let s = with("").unwrap();
    let plan = s.measurement_plan().unwrap().unwrap();
    assert_eq!(plan.point, InjectionPoint::PlantInput);
    // rate / f_min: the lowest line is the period's first bin.
    assert_eq!(plan.period_samples(), 2000);
    assert_eq!(plan.shape, ExcitationShape::Multisine);
    assert_eq!(plan.segments.len(), 1);
    assert_eq!(plan.segments[0].bins[0], 1);
    assert!(*plan.segments[0].bins.last().unwrap() <= 400);
    assert_eq!(plan.start_tick, 1000);
    assert_eq!((plan.transient_periods, plan.periods), (2, 10));
    assert_eq!(plan.end_tick(), 1000 + 13 * 2000);
    let largest = plan.segments[0]
        .period
        .iter()
        .fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!((largest - 100.0).abs() < 1e-9);
    let sensor =
        with("point = \"plant-input\" => point = \"sensor\"\namplitude = 100 => amplitude = 1e-6")
            .unwrap();
    let plan = sensor.measurement_plan().unwrap().unwrap();
    assert_eq!(plan.point, InjectionPoint::Sensor);
    assert!(
        validated(LOOP)
            .unwrap()
            .measurement_plan()
            .unwrap()
            .is_none()
    );
}

#[test]
fn a_band_above_nyquist_or_out_of_order_is_refused() {
    refused(
        "f_max_hz = 2000 => f_max_hz = 5000",
        "measure.f_max_hz",
        "Nyquist",
    );
    refused(
        "f_min_hz = 5 => f_min_hz = 3000",
        "measure.f_min_hz",
        "below",
    );
    refused(
        "f_min_hz = 5 => f_min_hz = -1",
        "measure.f_min_hz",
        "positive",
    );
}

#[test]
fn an_amplitude_that_would_saturate_the_actuator_is_refused() {
    refused(
        "amplitude = 100 => amplitude = 600",
        "measure.amplitude",
        "saturate",
    );
    refused(
        "amplitude = 100 => amplitude = 0",
        "measure.amplitude",
        "positive",
    );
    // At the sensor the amplitude is a position, not a force.
    with("point = \"plant-input\" => point = \"sensor\"\namplitude = 100 => amplitude = 600")
        .unwrap();
}

#[test]
fn a_point_that_does_not_exist_is_refused_naming_the_ones_that_do() {
    let e = with("point = \"plant-input\" => point = \"actuator\"").unwrap_err();
    assert_eq!(e.field.as_deref(), Some("measure.point"), "{e}");
    assert!(
        e.reason.contains("plant-input")
            && e.reason.contains("sensor")
            && e.reason.contains("reference"),
        "{e}"
    );
}

#[test]
fn a_measurement_longer_than_the_run_is_refused() {
    refused("periods = 20", "measure.periods", "loop.duration_s");
    // Until stopped: any length.
    let text = format!(
        "{}{MEASURE}periods = 20\n",
        LOOP.replace("duration_s = 4", "duration_s = 0")
    );
    validated(&text).unwrap();
}

#[test]
fn counts_and_the_seed_are_checked() {
    refused("seed = 3", "measure.seed", "random");
    with("phases = \"random\"\nseed = 3").unwrap();
    refused("periods = 0", "measure.periods", "1..=");
    refused(
        "transient_periods = 0",
        "measure.transient_periods",
        "fade-in",
    );
    refused("lines = 0", "measure.lines", "1..=");
    refused("period_samples = 2", "measure.period_samples", "4..=");
    // A period too short for the band's lowest line.
    refused("period_samples = 100", "measure.period_samples", "lengthen");
    refused("start_s = -1", "measure.start_s", "");
    refused("wobble = 1", "measure.wobble", "");
}

#[test]
fn a_swept_or_stepped_sine_is_the_excitation_asked_for_and_has_no_phases() {
    let plan = |change: &str| with(change).unwrap().measurement_plan().unwrap().unwrap();
    let swept = plan("signal = \"swept-sine\"");
    assert_eq!(swept.shape, ExcitationShape::SweptSine);
    assert_eq!(swept.segments.len(), 1);
    assert!(swept.segments[0].bins.len() > 30);
    // A stepped sine: a tone per line of the multisine's grid, one after
    // another, each for its transient, measured and fade-out periods.
    let stepped = plan("signal = \"stepped-sine\"\nlines = 5\nperiods = 1\ntransient_periods = 1");
    assert_eq!(stepped.shape, ExcitationShape::SteppedSine);
    let multisine = plan("lines = 5");
    assert_eq!(stepped.frequencies_hz(), multisine.frequencies_hz());
    assert_eq!(stepped.segments.len(), 5);
    assert!(stepped.segments.iter().all(|s| s.bins.len() == 1));
    assert_eq!(stepped.end_tick(), 1000 + 5 * 3 * 2000);
    for signal in ["swept-sine", "stepped-sine"] {
        refused(
            &format!("signal = \"{signal}\"\nphases = \"random\""),
            "measure.phases",
            "multisine",
        );
    }
    refused("signal = \"chirp\"", "measure.signal", "");
    // Every tone runs within the run: 60 tones of 13 periods do not.
    refused(
        "signal = \"stepped-sine\"",
        "measure.periods",
        "for each of its",
    );
}

/// An order on a running loop carries the measurement whole: what the
/// plant rebuilds from it is the `[measure]` the supervisor checked.
#[test]
fn an_order_carries_every_signal_and_its_fields() {
    for change in [
        "",
        "phases = \"random\"\nseed = 9",
        "signal = \"swept-sine\"",
        "signal = \"stepped-sine\"\nlines = 3\nperiods = 2\nperiod_samples = 400\nf_min_hz = 5 => f_min_hz = 25",
    ] {
        let s = with(change).unwrap();
        let section = s.measure.clone().unwrap();
        let order = section.order(s.timing.rate_hz, 1000);
        assert_eq!(
            flexloop_scenario::schema::MeasureSection::from_order(&order, s.timing.rate_hz),
            flexloop_scenario::schema::MeasureSection {
                period_samples: Some(section.period_samples_at(s.timing.rate_hz)),
                phases: section.phases.or((section.signal
                    == flexloop_scenario::schema::MeasureSignal::Multisine)
                    .then_some(flexloop_scenario::schema::MeasurePhases::Schroeder)),
                ..section
            },
            "{change}"
        );
    }
}

/// The reference is the built-in controller's set-point: a program of
/// one's own computes its own, so the point is refused for it.
#[test]
fn the_reference_is_a_point_of_the_built_in_controller_only() {
    let plan = with(
        "point = \"plant-input\" => point = \"reference\"\namplitude = 100 => amplitude = 1e-6",
    )
    .unwrap()
    .measurement_plan()
    .unwrap()
    .unwrap();
    assert_eq!(plan.point, InjectionPoint::Reference);
    let text = format!(
        "{LOOP}[controller]\nexec = [\"/bin/sh\"]\n{}",
        MEASURE
            .replace("point = \"plant-input\"", "point = \"reference\"")
            .replace("amplitude = 100", "amplitude = 1e-6")
    );
    let e = validated(&text).unwrap_err();
    assert_eq!(e.field.as_deref(), Some("measure.point"), "{e}");
    assert!(e.reason.contains("program of one's own"), "{e}");
}
