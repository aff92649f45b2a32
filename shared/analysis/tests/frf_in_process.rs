//! A frequency-response measurement of the thesis chain under the default
//! loop, in one process as lockstep runs it (docs/control.md §14): a
//! multisine added to the plant input as a force, the plant P and the input
//! sensitivity S^I estimated from the records in closed loop, against the
//! exact ZOH model and the design's loop report.

use flexloop_analysis::loop_report::loop_check;
use flexloop_components::{InProcessLoop, InjectionPoint, ScheduledExcitation};
use flexloop_control::freq::freq_response_discrete;
use flexloop_control::frf::{Frf, LineSpectra};
use flexloop_control::multisine::{Multisine, MultisineSource, MultisineSpec, Phases};
use flexloop_design::LoopDesign;
use flexloop_scenario::{Overrides, Scenario};
use std::f64::consts::PI;
use std::path::Path;

const TRANSIENT_PERIODS: usize = 3;
const PERIODS: usize = 10;

/// The default scenario (its plant, observer and controller) with the
/// reference held, and with sensor and force noise on if `noise`: the
/// excitation (and the noise) are the only inputs.
fn default_loop(noise: bool) -> (Scenario, LoopDesign) {
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
        .replace("feedforward_form = \"modified\"\n", "");
    // Noise on, as a machine has it: 1 N of force, 1 nm at the sensor.
    let held = if noise {
        held.replace("force_noise = 0.0", "force_noise = 1.0")
            .replace("sensor_noise = 0.0", "sensor_noise = 1e-9")
    } else {
        held
    };
    let mut s = Scenario::parse(&path, &held).unwrap();
    s.apply(&Overrides::default());
    s.validate().unwrap();
    let design = LoopDesign::from_scenario(&s).unwrap();
    (s, design)
}

/// What a measurement of the default loop found: the largest error of the
/// measured P against the exact ZOH model over the lines at coherence ≥
/// 0.99 (dB, degrees), how many lines those were, and the peak of |S^I|
/// and of |S^O|, measured and designed (dB).
struct Found {
    worst_db: f64,
    worst_degrees: f64,
    lines_checked: usize,
    lines: usize,
    si_peak_db: f64,
    si_peak_designed_db: f64,
    si_at_lowest_line_db: f64,
    so_peak_db: f64,
    so_peak_designed_db: f64,
}

/// The loop run with `signal` added at `point` for the transient and the
/// measured periods: the excitation's, the plant input's and the measured
/// output's line spectra.
fn excite(
    design: &LoopDesign,
    signal: &Multisine,
    point: InjectionPoint,
) -> (LineSpectra, LineSpectra, LineSpectra) {
    let n = signal.period_samples();
    let mut l = InProcessLoop::new(design).unwrap();
    l.plant.set_excitation(Some(ScheduledExcitation::from_now(
        point,
        MultisineSource::new(signal.clone(), 0),
    )));
    let ticks = n * (TRANSIENT_PERIODS + PERIODS);
    let (mut d, mut u, mut y) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..ticks {
        l.tick();
        let excitation = l.plant.excitation();
        d.push(excitation);
        // The plant's input over [t_k, t_k+1): the command it held, and the
        // force if the excitation is one.
        let force = if point == InjectionPoint::PlantInput {
            excitation
        } else {
            0.0
        };
        u.push(l.measurement.u_applied[0] + force);
        y.push(l.measurement.y[0]);
    }
    assert_eq!(l.plant.counters.misses, 0);
    let lines = |x: &[f64]| LineSpectra::of(x, signal, TRANSIENT_PERIODS, PERIODS).unwrap();
    (lines(&d), lines(&u), lines(&y))
}

fn multisine(design: &LoopDesign, amplitude: f64) -> Multisine {
    Multisine::design(&MultisineSpec {
        rate_hz: 1.0 / design.ts,
        period_samples: 2_000,
        f_min_hz: 5.0,
        f_max_hz: 2_000.0,
        max_lines: 60,
        amplitude,
        phases: Phases::Schroeder,
    })
    .unwrap()
}

fn measure(noise: bool) -> Found {
    let (scenario, design) = default_loop(noise);
    // A tenth of the actuator's range.
    let signal = multisine(&design, 0.1 * design.input_limit);
    let (d, u, y) = excite(&design, &signal, InjectionPoint::PlantInput);
    let plant = Frf::between(&signal, &y, &u).unwrap();
    let (mut checked, mut worst_db, mut worst_degrees) = (0, 0.0_f64, 0.0_f64);
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
        worst_db = worst_db.max(db.abs());
        worst_degrees = worst_degrees.max(degrees.abs());
    }
    // The input sensitivity U/D = 1/(1 + L), and the design's peak of it
    // (the 6 dB rule's |S^I|).
    let input_sensitivity = Frf::between(&signal, &u, &d).unwrap();
    // At the sensor (10 µm): the measured output over the excitation is the
    // output sensitivity 1/(1 + L_o), the 6 dB rule's |S^O|.
    let sensor_signal = multisine(&design, 1e-5);
    let (n, _, y_measured) = excite(&design, &sensor_signal, InjectionPoint::Sensor);
    let output_sensitivity = Frf::between(&sensor_signal, &y_measured, &n).unwrap();
    let report = loop_check(&scenario, &design).unwrap();
    Found {
        worst_db,
        worst_degrees,
        lines_checked: checked,
        lines: plant.response.len(),
        si_peak_db: input_sensitivity.peak_db(0.99).unwrap().0,
        si_peak_designed_db: report.axes[0].peak_si_db,
        si_at_lowest_line_db: input_sensitivity.magnitude_db()[0],
        so_peak_db: output_sensitivity.peak_db(0.99).unwrap().0,
        so_peak_designed_db: report.axes[0].peak_so_db,
    }
}

/// Without noise the measurement is the model's: P to 0.01 dB and 0.1°,
/// the |S^I| and |S^O| peaks to 0.01 dB of the design's (lines 5 Hz apart
/// near them).
#[test]
fn without_noise_the_measured_loop_is_the_designed_one() {
    let found = measure(false);
    assert_eq!(found.lines_checked, found.lines, "every line is coherent");
    assert!(
        found.worst_db <= 0.01 && found.worst_degrees <= 0.1,
        "P off by {} dB, {}°",
        found.worst_db,
        found.worst_degrees
    );
    assert!(
        (found.si_peak_db - found.si_peak_designed_db).abs() <= 0.01,
        "|S^I| peak measured {} dB, designed {} dB",
        found.si_peak_db,
        found.si_peak_designed_db
    );
    assert!(
        (found.so_peak_db - found.so_peak_designed_db).abs() <= 0.01,
        "|S^O| peak measured {} dB, designed {} dB",
        found.so_peak_db,
        found.so_peak_designed_db
    );
}

/// With a machine's noise: P within 0.5 dB and 2° wherever coherence ≥ 0.99
/// (most lines), the |S^I| and |S^O| peaks within 0.3 dB of the design's, and a loop
/// that rejects an input disturbance well below its bandwidth.
#[test]
fn with_noise_the_plant_and_the_input_sensitivity_are_measured_closely() {
    let found = measure(true);
    assert!(
        found.lines_checked >= 40,
        "only {} of {} lines at coherence ≥ 0.99",
        found.lines_checked,
        found.lines
    );
    assert!(
        found.worst_db <= 0.5 && found.worst_degrees <= 2.0,
        "P off by {} dB, {}°",
        found.worst_db,
        found.worst_degrees
    );
    assert!(
        (found.si_peak_db - found.si_peak_designed_db).abs() <= 0.3,
        "|S^I| peak measured {} dB, designed {} dB",
        found.si_peak_db,
        found.si_peak_designed_db
    );
    assert!(
        (found.so_peak_db - found.so_peak_designed_db).abs() <= 0.3,
        "|S^O| peak measured {} dB, designed {} dB",
        found.so_peak_db,
        found.so_peak_designed_db
    );
    assert!(
        found.si_at_lowest_line_db < -20.0,
        "{}",
        found.si_at_lowest_line_db
    );
}
