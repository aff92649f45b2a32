//! A frequency-response measurement of the thesis chain under the default
//! loop, in one process as lockstep runs it (docs/control.md §14): a
//! multisine added to the plant input as a force, the plant P and the input
//! sensitivity S^I estimated from the records in closed loop, against the
//! exact ZOH model and the design's loop report.

use flexloop_analysis::loop_report::loop_check;
use flexloop_components::InProcessLoop;
use flexloop_control::freq::freq_response_discrete;
use flexloop_control::frf::{Frf, LineSpectra};
use flexloop_control::multisine::{Multisine, MultisineSource, MultisineSpec, Phases};
use flexloop_design::LoopDesign;
use flexloop_scenario::{Overrides, Scenario};
use std::f64::consts::PI;
use std::path::Path;

const TRANSIENT_PERIODS: usize = 3;
const PERIODS: usize = 10;

/// The default scenario (its plant, observer and controller) with sensor
/// and force noise on and the reference held: the excitation and the noise
/// are the only inputs.
fn default_loop() -> (Scenario, LoopDesign) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/default.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let scan = "[reference]\nshape = \"scan\"\nstart_s = 0.01\nrepeat_s = 0.25\n";
    assert!(
        text.contains(scan),
        "the default scenario's reference changed"
    );
    // Held, with no feedforward (it acts on the reference's derivatives).
    let held = text.replace(scan, "[reference]\nshape = \"hold\"\n");
    let held = held
        .split_once("[controller.feedforward]")
        .map_or(held.as_str(), |(before, _)| before)
        .replace("feedforward_form = \"modified\"\n", "")
        // Noise on, as a machine has it: 1 N of force, 1 nm at the sensor.
        .replace("force_noise = 0.0", "force_noise = 1.0")
        .replace("sensor_noise = 0.0", "sensor_noise = 1e-9");
    let mut s = Scenario::parse(&path, &held).unwrap();
    s.apply(&Overrides::default());
    s.validate().unwrap();
    let design = LoopDesign::from_scenario(&s).unwrap();
    (s, design)
}

#[test]
fn the_plant_measured_in_closed_loop_is_the_exact_zoh_model() {
    let (scenario, design) = default_loop();
    assert!(design.sensor_noise > 0.0 && design.force_noise > 0.0);
    let signal = Multisine::design(&MultisineSpec {
        rate_hz: 1.0 / design.ts,
        period_samples: 2_000,
        f_min_hz: 5.0,
        f_max_hz: 2_000.0,
        max_lines: 60,
        // A tenth of the actuator's range.
        amplitude: 0.1 * design.input_limit,
        phases: Phases::Schroeder,
    })
    .unwrap();
    let n = signal.period_samples();
    let mut l = InProcessLoop::new(&design).unwrap();
    l.plant
        .set_input_excitation(Some(MultisineSource::new(signal.clone(), 0)));
    let ticks = n * (TRANSIENT_PERIODS + PERIODS);
    let (mut d, mut u, mut y) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..ticks {
        l.tick();
        let excitation = l.plant.input_excitation();
        d.push(excitation);
        // The plant's input over [t_k, t_k+1): the command it held and the force.
        u.push(l.measurement.u_applied[0] + excitation);
        y.push(l.measurement.y[0]);
    }
    assert_eq!(l.plant.counters.misses, 0);
    let lines = |x: &[f64]| LineSpectra::of(x, &signal, TRANSIENT_PERIODS, PERIODS).unwrap();
    let (d, u, y) = (lines(&d), lines(&u), lines(&y));
    let plant = Frf::between(&signal, &y, &u).unwrap();
    let mut checked = 0;
    for ((f, h), c) in plant
        .frequencies_hz
        .iter()
        .zip(&plant.response)
        .zip(&plant.coherence)
    {
        if *c < 0.99 {
            continue;
        }
        checked += 1;
        let exact = freq_response_discrete(&design.plant, 2.0 * PI * f).unwrap()[(0, 0)];
        let db = 20.0 * (h.norm() / exact.norm()).log10();
        let degrees = (h / exact).arg().to_degrees();
        assert!(
            db.abs() <= 0.5 && degrees.abs() <= 2.0,
            "{f:.1} Hz (coherence {c:.4}): {db:+.3} dB, {degrees:+.2}°"
        );
    }
    assert!(
        checked >= 40,
        "only {checked} of {} lines at coherence ≥ 0.99",
        plant.response.len()
    );
    // The input sensitivity U/D = 1/(1 + L): small well below the loop's
    // bandwidth, and its peak the design's (the 6 dB rule's |S^I|) within
    // 0.3 dB, on lines 5 Hz apart or closer near it.
    let input_sensitivity = Frf::between(&signal, &u, &d).unwrap();
    let db = input_sensitivity.magnitude_db();
    assert!(
        db[0] < -20.0,
        "|S^I| at {} Hz: {} dB",
        signal.frequencies_hz()[0],
        db[0]
    );
    let (peak, at) = input_sensitivity.peak_db(0.99).unwrap();
    let report = loop_check(&scenario, &design).unwrap();
    let axis = &report.axes[0];
    assert!(
        (peak - axis.peak_si_db).abs() <= 0.3,
        "|S^I| measured {peak:.2} dB at {at:.1} Hz, designed {:.2} dB at {:.1} Hz",
        axis.peak_si_db,
        axis.peak_si_hz
    );
}
