//! What a frequency-response measurement's time buys in accuracy: the loop
//! of `scenarios/measure-default.toml` (the thesis chain under the default
//! loop, its 1 N of force and 1 nm of sensor noise kept, the reference
//! held, 200 N at the plant input, 5 Hz – 2 kHz) measured in one process as
//! lockstep runs it, by each signal (multisine, swept sine, stepped sine)
//! at 15, 30 and 60 lines asked and 2, 5, 10 and 20 measured periods.
//!
//! Per measurement: its duration in loop time, the lines of P trusted
//! (coherence ≥ 0.99), the largest error of P on them against the exact
//! ZOH model, the measured peak of |S_i| against the design's, the rms
//! error of S_i, and the wall time of the computation (design and
//! excitation, the loop's ticks, the estimate). One noise realisation
//! moves the errors by a factor of several, so each measurement is made
//! with [`SEEDS`] seeds of the plant's noise and the table gives the
//! median and the worst.
//!
//! The accuracy is the maths' (the loop and its noise are seeded); only
//! the wall time is the machine's.
//!
//! `cargo bench --bench measurement_accuracy [-- SIGNAL...]` (docs/benchmarks.md,
//! "Measurement time against accuracy").

use flexloop_analysis::loop_measurement::{
    LoopMeasurement, LoopSignals, MIN_COHERENCE, MeasuredResponse, predicted,
};
use flexloop_components::InProcessLoop;
use flexloop_control::excitation::InjectionPoint;
use flexloop_design::LoopDesign;
use flexloop_protocol::Measurement;
use flexloop_scenario::schema::{MeasurePoint, MeasureSection, MeasureSignal};
use flexloop_scenario::{Overrides, Scenario};
use std::path::Path;
use std::time::{Duration, Instant};

const SIGNALS: [MeasureSignal; 3] = [
    MeasureSignal::Multisine,
    MeasureSignal::SweptSine,
    MeasureSignal::SteppedSine,
];
const LINES: [usize; 3] = [15, 30, 60];
const PERIODS: [usize; 4] = [2, 5, 10, 20];
/// Noise seeds per measurement: the scenario's (1) and the next ones.
const SEEDS: u64 = 10;
/// The coherence at which a line counts as trusted here (stricter than
/// the verdicts' [`MIN_COHERENCE`]).
const TRUSTED: f64 = 0.99;
/// Where P's error is read apart (Hz, from inclusive, to exclusive): below
/// the loop's bandwidth, around it, and the flexible modes.
const BANDS: [(f64, f64); 3] = [(5.0, 50.0), (50.0, 400.0), (400.0, 2000.5)];
const BAND_NAMES: [&str; 3] = ["5–50 Hz", "50–400 Hz", "400–2000 Hz"];
/// The second table's rows: the lines asked for.
const BAND_LINES: usize = 60;

/// measure-default as shipped (its noise, its held reference), its noise
/// seeded by `seed`, measuring by `signal` with at most `lines` lines and
/// `periods` measured periods.
fn scenario(signal: MeasureSignal, lines: usize, periods: usize, seed: u64) -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/measure-default.toml");
    let mut s = Scenario::load(&path, &Overrides::default()).expect("measure-default loads");
    let shipped = s.measure.clone().expect("measure-default has a [measure]");
    s.measure = Some(MeasureSection {
        point: MeasurePoint::PlantInput,
        signal,
        f_min_hz: shipped.f_min_hz,
        f_max_hz: shipped.f_max_hz,
        lines,
        period_samples: None,
        amplitude: shipped.amplitude,
        phases: None,
        seed: None,
        transient_periods: 2,
        periods,
        start_s: 0.1,
    });
    // Only the realisation changes: the Kalman design reads the noise's σ,
    // not its seed.
    s.plant.seed = seed;
    // No run length to fit in: the loop is ticked to the plan's end.
    s.timing.duration_s = 0.0;
    s.validate().expect("the measurement is a valid [measure]");
    s
}

/// One measurement's figures.
struct Run {
    lines: usize,
    loop_s: f64,
    p_trusted: usize,
    /// Largest |measured / model| of P over its trusted lines (dB, °), and
    /// the line of the largest in dB.
    p_db: f64,
    p_degrees: f64,
    p_worst_hz: f64,
    /// Measured peak of |S_i| (the rule's, over coherence ≥ 0.9) minus the
    /// design's on the same lines, and minus the design's true peak.
    peak_vs_lines_db: f64,
    peak_vs_design_db: f64,
    /// Rms of |S_i measured / model| (dB) over S_i's lines of coherence ≥
    /// 0.99, and how many.
    s_rms_db: f64,
    s_trusted: usize,
    /// Rms of |P measured / model| (dB) over P's trusted lines in each of
    /// [`BANDS`].
    p_band_rms_db: [f64; 3],
    wall: [Duration; 3],
}

fn db(x: f64) -> f64 {
    20.0 * x.log10()
}

/// The loop ticked through the plan's end, its signals over the measured
/// ticks taken as [`LoopSignals::from_measurements`] takes them (checked
/// against it once, in `main`): a stepped sine runs millions of ticks,
/// whose whole messages would take gigabytes.
fn run_loop(design: &LoopDesign) -> LoopSignals {
    let plan = design.measurement.as_ref().expect("a planned measurement");
    let (start, stop) = (plan.start_tick, plan.stop_tick());
    let len = (stop - start) as usize;
    let mut signals = LoopSignals {
        excitation: Vec::with_capacity(len),
        u: Vec::with_capacity(len),
        y: Vec::with_capacity(len),
        y_true: Vec::with_capacity(len),
    };
    let mut l = InProcessLoop::new(design).expect("the design fits the protocol");
    for k in 0..plan.end_tick() {
        l.tick();
        if (start..stop).contains(&k) {
            let m = &l.measurement;
            signals.excitation.push(m.excitation);
            signals.u.push(m.u_applied[0]);
            signals.y.push(m.y[0]);
            signals.y_true.push(m.y_true[0]);
        }
    }
    signals
}

/// The shortcut above gives what the analysis' own reader gives.
fn check_signals(design: &LoopDesign) {
    let plan = design.measurement.clone().expect("a planned measurement");
    let mut l = InProcessLoop::new(design).expect("the design fits the protocol");
    let recorded: Vec<Measurement> = (0..plan.end_tick())
        .map(|_| {
            l.tick();
            l.measurement
        })
        .collect();
    let read = LoopSignals::from_measurements(&plan, recorded.iter()).expect("a whole record");
    assert_eq!(
        read,
        run_loop(design),
        "the bench reads the loop as the analysis does"
    );
}

/// |measured / model| in dB at each line of coherence ≥ `min` in `band`
/// (Hz): the rms, and the count.
fn rms_db(r: &MeasuredResponse, min: f64, band: (f64, f64)) -> (f64, usize) {
    let predicted = r.predicted.as_ref().expect("the design predicts it");
    let errors: Vec<f64> = (0..r.measured.response.len())
        .filter(|&i| {
            r.measured.coherence[i] >= min
                && (band.0..band.1).contains(&r.measured.frequencies_hz[i])
        })
        .map(|i| db((r.measured.response[i] / predicted[i]).norm()))
        .collect();
    let n = errors.len();
    if n == 0 {
        return (f64::NAN, 0);
    }
    (
        (errors.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt(),
        n,
    )
}

/// The line of `r`'s largest |measured / model| in dB among its lines of
/// coherence ≥ `min`.
fn worst_line_hz(r: &MeasuredResponse, min: f64) -> f64 {
    let predicted = r.predicted.as_ref().expect("the design predicts it");
    (0..r.measured.response.len())
        .filter(|&i| r.measured.coherence[i] >= min)
        .map(|i| {
            let error = db((r.measured.response[i] / predicted[i]).norm()).abs();
            (error, r.measured.frequencies_hz[i])
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map_or(f64::NAN, |(_, hz)| hz)
}

/// The design's peak of |S_i| over the band on a dense grid (dB, Hz):
/// what the lines may miss between them.
fn design_peak_db(design: &LoopDesign, band: (f64, f64)) -> (f64, f64) {
    let points = 8000;
    let grid: Vec<f64> = (0..=points)
        .map(|i| band.0 * (band.1 / band.0).powf(i as f64 / points as f64))
        .collect();
    let s = predicted(design, InjectionPoint::PlantInput, "S_i", &grid).expect("S_i predicted");
    s.iter()
        .zip(&grid)
        .map(|(h, f)| (db(h.norm()), *f))
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .expect("a grid")
}

fn measure(
    signal: MeasureSignal,
    lines: usize,
    periods: usize,
    seed: u64,
    design_peak: f64,
) -> Run {
    let s = scenario(signal, lines, periods, seed);
    let t0 = Instant::now();
    let design = LoopDesign::from_scenario(&s).expect("measure-default designs");
    let t1 = Instant::now();
    let signals = run_loop(&design);
    let t2 = Instant::now();
    let plan = design.measurement.clone().expect("a planned measurement");
    let m = LoopMeasurement::compute(&design, &plan, &signals).expect("the measurement");
    let t3 = Instant::now();
    // 200 N and the controller's answer stay within the 2000 N limit: every
    // period is averaged, so the rows compare like with like.
    assert!(
        m.periods_saturated.is_empty(),
        "{} {lines} lines {periods} periods seed {seed}: the actuator reached its limit",
        signal.name()
    );
    let p = m.response("P").expect("P");
    let dev = p
        .deviation((0.0, f64::INFINITY), TRUSTED)
        .unwrap_or_default();
    let si = m.sensitivity();
    let (peak, _, _) = m.rule().expect("a trusted line of S_i");
    let (on_lines, _) = si.predicted_peak_db().expect("S_i predicted");
    let (s_rms_db, s_trusted) = rms_db(si, TRUSTED, (0.0, f64::INFINITY));
    Run {
        lines: plan.frequencies_hz().len(),
        loop_s: (plan.end_tick() - plan.start_tick) as f64 / s.timing.rate_hz,
        p_trusted: dev.lines,
        p_db: dev.max_db,
        p_degrees: dev.max_degrees,
        p_worst_hz: worst_line_hz(p, TRUSTED),
        peak_vs_lines_db: peak - on_lines,
        peak_vs_design_db: peak - design_peak,
        s_rms_db,
        s_trusted,
        p_band_rms_db: BANDS.map(|band| rms_db(p, TRUSTED, band).0),
        wall: [t1 - t0, t2 - t1, t3 - t2],
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn largest(v: impl Iterator<Item = f64>) -> f64 {
    v.fold(0.0, f64::max)
}

/// `median (worst)` of one figure over the seeds.
fn spread(runs: &[Run], figure: fn(&Run) -> f64, digits: usize) -> String {
    let values: Vec<f64> = runs.iter().map(figure).collect();
    let worst = largest(values.iter().map(|v| v.abs()));
    format!("{:.digits$} ({:.digits$})", median(values), worst)
}

/// The signed value of largest magnitude.
fn extreme(runs: &[Run], figure: fn(&Run) -> f64) -> f64 {
    runs.iter()
        .map(figure)
        .max_by(|a, b| a.abs().total_cmp(&b.abs()))
        .unwrap_or(f64::NAN)
}

/// The line most often the worst of P, and in how many seeds.
fn usual_worst(runs: &[Run]) -> String {
    let mut counts: Vec<(f64, usize)> = Vec::new();
    for r in runs {
        match counts.iter_mut().find(|(hz, _)| *hz == r.p_worst_hz) {
            Some((_, n)) => *n += 1,
            None => counts.push((r.p_worst_hz, 1)),
        }
    }
    let (hz, n) = counts
        .into_iter()
        .max_by_key(|(_, n)| *n)
        .unwrap_or((f64::NAN, 0));
    format!("{hz:.0} ({n}/{})", runs.len())
}

fn row(signal: MeasureSignal, lines_asked: usize, periods: usize, runs: &[Run]) -> String {
    let first = &runs[0];
    let trusted = |f: fn(&Run) -> usize| {
        let (lo, hi) = (
            runs.iter().map(f).min().unwrap_or(0),
            runs.iter().map(f).max().unwrap_or(0),
        );
        if lo == hi {
            format!("{lo}")
        } else {
            format!("{lo}–{hi}")
        }
    };
    let wall = |i: usize| median(runs.iter().map(|r| r.wall[i].as_secs_f64()).collect());
    format!(
        "| {} | {} ({}) | {} | {:.1} | {}/{} | {} | {} | {} | {:+.3} / {:+.3} | {:+.3} | {} | {} | \
         {:.2} ({:.2} + {:.2} + {:.2}) |",
        signal.name(),
        first.lines,
        lines_asked,
        periods,
        first.loop_s,
        trusted(|r| r.p_trusted),
        first.lines,
        spread(runs, |r| r.p_db, 3),
        spread(runs, |r| r.p_degrees, 2),
        usual_worst(runs),
        median(runs.iter().map(|r| r.peak_vs_lines_db).collect()),
        extreme(runs, |r| r.peak_vs_lines_db),
        median(runs.iter().map(|r| r.peak_vs_design_db).collect()),
        spread(runs, |r| r.s_rms_db, 3),
        trusted(|r| r.s_trusted),
        wall(0) + wall(1) + wall(2),
        wall(0),
        wall(1),
        wall(2),
    )
}

fn main() {
    // `cargo bench` passes `--bench`; other words pick signals by name.
    let picked: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let signals: Vec<MeasureSignal> = SIGNALS
        .into_iter()
        .filter(|s| picked.is_empty() || picked.iter().any(|p| p == s.name()))
        .collect();

    let reference = scenario(MeasureSignal::Multisine, 15, 2, 1);
    let design = LoopDesign::from_scenario(&reference).expect("measure-default designs");
    check_signals(&design);
    let band = {
        let m = reference.measure.as_ref().expect("a [measure]");
        (m.f_min_hz, m.f_max_hz)
    };
    let (peak, at) = design_peak_db(&design, band);
    println!(
        "measure-default at the plant input: 200 N, 5 Hz - 2 kHz, periods of 0.2 s after 2 \
         transient ones; the design's peak of |S_i| {peak:.3} dB at {at:.1} Hz (dense grid)."
    );
    println!(
        "Each row: {SEEDS} seeds of the plant's noise, median (worst). P trusted: coherence >= \
         {TRUSTED}. S_i peak over coherence >= {MIN_COHERENCE} (the rule's), minus the design's \
         on the same lines (median / most extreme), and minus its dense-grid peak; S_i rms over \
         its own lines of coherence >= {TRUSTED}. Wall: median s, design + ticks + estimate.\n"
    );
    println!(
        "| signal | lines (asked) | periods | loop s | P trusted | P max dB | P max ° | \
         P worst at Hz (seeds) | S_i peak − design, same lines dB | S_i peak − design dB | \
         S_i rms dB | S_i trusted | wall s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let started = Instant::now();
    let mut by_band = Vec::new();
    for &signal in &signals {
        for lines in LINES {
            for periods in PERIODS {
                let runs: Vec<Run> = (1..=SEEDS)
                    .map(|seed| measure(signal, lines, periods, seed, peak))
                    .collect();
                println!("{}", row(signal, lines, periods, &runs));
                if lines == BAND_LINES {
                    by_band.push((signal, periods, runs));
                }
            }
        }
    }
    println!(
        "\nP against the model by band, {BAND_LINES} lines asked: rms over the trusted lines of \
         |P measured / model| in dB, median (worst) over the seeds\n"
    );
    println!("| signal | periods | loop s | {} |", BAND_NAMES.join(" | "));
    println!("|---|---|---|---|---|---|");
    for (signal, periods, runs) in &by_band {
        let cells: Vec<String> = (0..BANDS.len())
            .map(|b| {
                let values: Vec<f64> = runs.iter().map(|r| r.p_band_rms_db[b]).collect();
                let worst = largest(values.iter().copied());
                format!("{:.3} ({worst:.3})", median(values))
            })
            .collect();
        println!(
            "| {} | {periods} | {:.1} | {} |",
            signal.name(),
            runs[0].loop_s,
            cells.join(" | ")
        );
    }
    println!("\ntotal {:.1} s", started.elapsed().as_secs_f64());
}
