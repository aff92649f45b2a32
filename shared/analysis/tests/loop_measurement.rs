//! A scenario's `[measure]` run in one process as lockstep runs it, across
//! the shipped plants, observers and controllers, at both points: without
//! noise every measured response is the design's prediction (so the
//! closed loop's inputs and outputs are read as the analysis says), and an
//! excitation that drives the actuator to its limit leaves its periods out.

use flexloop_analysis::loop_measurement::{LoopMeasurement, LoopSignals};
use flexloop_components::InProcessLoop;
use flexloop_control::excitation::InjectionPoint;
use flexloop_design::LoopDesign;
use flexloop_protocol::Measurement;
use flexloop_scenario::schema::{MeasurePoint, MeasureSection, MeasureSignal, ReferenceSection};
use flexloop_scenario::{Overrides, Scenario};
use std::path::Path;

/// A shipped scenario with its reference held and no noise (the
/// excitation the loop's only input), measuring at `point`.
/// `NAME+delay`: with one more sample of loop delay.
fn measured(name: &str, point: MeasurePoint, amplitude_share: f64) -> (Scenario, LoopDesign) {
    measured_by(name, point, amplitude_share, MeasureSignal::Multisine, 40)
}

/// As [`measured`], by `signal` of at most `lines` lines.
fn measured_by(
    name: &str,
    point: MeasurePoint,
    amplitude_share: f64,
    signal: MeasureSignal,
    lines: usize,
) -> (Scenario, LoopDesign) {
    let (file, delayed) = match name.strip_suffix("+delay") {
        Some(base) => (base, true),
        None => (name, false),
    };
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{file}.toml"));
    let mut s = Scenario::load(&path, &Overrides::default()).unwrap();
    if delayed {
        s.controller.extra_delay_samples = 1;
    }
    s.reference = ReferenceSection::default();
    s.controller.feedforward = None;
    s.controller.feedforward_form = "plain".into();
    s.plant.force_noise = 0.0;
    s.plant.sensor_noise = 0.0;
    s.plant.reference_noise = 0.0;
    s.given.retain(|f| {
        !(f.starts_with("reference.")
            || f.starts_with("controller.feedforward")
            || f.ends_with("_noise")
            || f == "plant.seed")
    });
    let rate = s.timing.rate_hz;
    s.timing.duration_s = 0.0;
    s.measure = Some(MeasureSection {
        point,
        signal,
        f_min_hz: rate / 1000.0,
        f_max_hz: 0.2 * rate,
        lines,
        period_samples: None,
        amplitude: match point {
            MeasurePoint::PlantInput => amplitude_share * s.plant.input_limit,
            MeasurePoint::Sensor | MeasurePoint::Reference => 1e-6,
        },
        phases: None,
        seed: None,
        // The loops' slowest modes (the integrators') settle within these.
        transient_periods: 8,
        periods: 4,
        start_s: 0.02,
    });
    s.validate().unwrap();
    let design = LoopDesign::from_scenario(&s).unwrap();
    (s, design)
}

/// The loop run through its measurement's end: every measurement message.
fn recorded(design: &LoopDesign) -> Vec<Measurement> {
    let plan = design.measurement.as_ref().unwrap();
    let mut l = InProcessLoop::new(design).unwrap();
    (0..plan.end_tick())
        .map(|_| {
            l.tick();
            l.measurement
        })
        .collect()
}

fn run(design: &LoopDesign) -> LoopMeasurement {
    let plan = design.measurement.clone().unwrap();
    let measurements = recorded(design);
    let signals = LoopSignals::from_measurements(&plan, measurements.iter()).unwrap();
    LoopMeasurement::compute(design, &plan, &signals).unwrap()
}

const MATRIX: [&str; 8] = [
    "thesis-mc-ad-deadline-30us",
    "lecture-double-integrator+delay",
    "default",
    "thesis-mc-ad",
    "lecture-double-integrator",
    "drive-train",
    "two-inertia",
    "uniform-chain",
];

#[test]
fn without_noise_every_response_is_the_designs_at_every_point() {
    for name in MATRIX {
        for point in [
            MeasurePoint::PlantInput,
            MeasurePoint::Sensor,
            MeasurePoint::Reference,
        ] {
            let (_, design) = measured(name, point, 0.05);
            let m = run(&design);
            assert_eq!(m.periods_used, 4, "{name} {point:?}");
            is_the_designs(name, point, &m);
        }
    }
}

/// A periodic sweep and a stepped sine measure what the multisine does:
/// any periodic excitation in steady state gives each line's response
/// exactly (on a plant with a rigid body, one with a delay, a flexible
/// chain and a controller at a command deadline).
#[test]
fn a_swept_and_a_stepped_sine_measure_the_designs_responses_too() {
    for name in [
        "lecture-double-integrator+delay",
        "thesis-mc-ad-deadline-30us",
        "uniform-chain",
    ] {
        for point in [MeasurePoint::PlantInput, MeasurePoint::Sensor] {
            let (_, design) = measured_by(name, point, 0.05, MeasureSignal::SweptSine, 40);
            let m = run(&design);
            assert!(m.render_text().contains("a swept-sine of"));
            assert!(m.sensitivity().measured.frequencies_hz.len() > 30);
            is_the_designs(name, point, &m);
            // A stepped sine takes a run per tone: a few, on the cheaper loops.
            if name.starts_with("thesis") {
                continue;
            }
            let (_, design) = measured_by(name, point, 0.05, MeasureSignal::SteppedSine, 4);
            let m = run(&design);
            let plan = design.measurement.as_ref().unwrap();
            assert_eq!(plan.segments.len(), 4);
            assert_eq!(m.periods_used, 4 * 4, "{name} {point:?}");
            assert_eq!(
                m.sensitivity().measured.frequencies_hz,
                plan.frequencies_hz()
            );
            is_the_designs(name, point, &m);
        }
    }
}

/// Every line of every response is the design's where it is measurable.
fn is_the_designs(name: &str, point: MeasurePoint, m: &LoopMeasurement) {
    assert_eq!(m.responses.len(), 5);
    for r in &m.responses {
        let predicted = r.predicted.as_ref().unwrap();
        let largest = predicted.iter().map(|h| h.norm()).fold(0.0, f64::max);
        for (i, f) in r.measured.frequencies_hz.iter().enumerate() {
            // Noise-free, a line is uncertain only where the loop's
            // own slow settling (not periodic) leaks into a response
            // 40 dB below its largest.
            if predicted[i].norm() < 0.01 * largest || r.measured.coherence[i] < 0.999 {
                continue;
            }
            let ratio = r.measured.response[i] / predicted[i];
            let (db, degrees) = (20.0 * ratio.norm().log10(), ratio.arg().to_degrees());
            assert!(
                db.abs() < 0.05 && degrees.abs() < 0.5,
                "{name} {point:?} {} at {f} Hz: {db} dB, {degrees} deg\n{}",
                r.name,
                m.render_text()
            );
        }
    }
    // The rule is read at the plant input and the sensor, not the reference.
    match m.rule() {
        Some((_, _, keeps)) => {
            let designed = m.sensitivity().predicted_peak_db().unwrap().0;
            assert_eq!(keeps, designed <= 6.0, "{name} {point:?}");
        }
        None => assert_eq!(point, MeasurePoint::Reference, "{name}"),
    }
}

#[test]
fn periods_where_the_actuator_reached_its_limit_are_left_out() {
    // Half the input limit from the excitation, and the controller's own
    // answer to it on top: the limit is reached.
    let (_, design) = measured("lecture-double-integrator", MeasurePoint::PlantInput, 0.5);
    let plan = design.measurement.clone().unwrap();
    let mut measurements = recorded(&design);
    // One measured period with a command at the limit.
    let at = plan.measured_ticks(0).start as usize + plan.period_samples() + 7;
    measurements[at].u_applied[0] = design.input_limit;
    let signals = LoopSignals::from_measurements(&plan, measurements.iter()).unwrap();
    let m = LoopMeasurement::compute(&design, &plan, &signals).unwrap();
    assert_eq!(m.periods_saturated, [1]);
    assert_eq!(m.periods_used, 3);
    assert!(m.render_text().contains("left out"), "{}", m.render_text());
    assert_eq!(m.point, InjectionPoint::PlantInput);
}

#[test]
fn a_recording_with_a_hole_or_cut_short_is_refused() {
    let (_, design) = measured("default", MeasurePoint::Sensor, 0.05);
    let plan = design.measurement.clone().unwrap();
    let measurements = recorded(&design);
    let hole = plan.start_tick as usize + 100;
    let holed: Vec<_> = measurements
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != hole)
        .map(|(_, m)| *m)
        .collect();
    let e = LoopSignals::from_measurements(&plan, holed.iter()).unwrap_err();
    assert!(e.to_string().contains("misses 1 samples"), "{e}");
    let short = &measurements[..plan.stop_tick() as usize - 10];
    let e = LoopSignals::from_measurements(&plan, short.iter()).unwrap_err();
    assert!(e.to_string().contains("before the measured periods"), "{e}");
}
