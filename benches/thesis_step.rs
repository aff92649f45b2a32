//! Per-sample cost of the thesis default design (`scenarios/default.toml`:
//! MC + AD, Kalman observer with noise model, PID, modified feedforward),
//! built exactly as the services build it: the observer step, the controller
//! step, both, and a whole in-process loop tick (plant included).
//!
//! The cores are first run in the in-process loop until the scan is under
//! way, and the benchmarks then replay measurements and estimates recorded
//! from that run, so the numbers are for realistic values, not for a loop at
//! rest (zeros, or states decaying into denormals).
//!
//! `cargo bench --bench thesis_step` (docs/benchmarks.md, "The computation of one sample: criterion").

use criterion::{Criterion, criterion_group, criterion_main};
use flexloop_components::InProcessLoop;
use flexloop_design::LoopDesign;
use flexloop_protocol::{Command, Estimate, Measurement};
use flexloop_scenario::{Overrides, Scenario};
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

/// Ticks before recording: the scan starts at 10 ms (100 ticks), so 1000
/// ticks put the loop in the middle of the motion.
const WARM_UP_TICKS: usize = 1000;
/// Ticks recorded and replayed (6.4 ms of the scan). Few, so that the replayed
/// messages (an `Estimate` is 3.8 KB) stay in cache: this measures the
/// arithmetic, not memory traffic.
const RECORDED_TICKS: usize = 64;

fn default_design() -> LoopDesign {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/default.toml");
    let scenario = Scenario::load(&path, &Overrides::default()).expect("scenarios/default.toml");
    LoopDesign::from_scenario(&scenario).expect("design of the default scenario")
}

/// A warmed-up loop and the (y(k), estimate used at k) pairs it recorded.
fn warmed_up(design: &LoopDesign) -> (InProcessLoop, Vec<Measurement>, Vec<Estimate>) {
    let mut l = InProcessLoop::new(design).expect("default design fits the protocol");
    for _ in 0..WARM_UP_TICKS {
        l.tick();
    }
    let mut measurements = Vec::with_capacity(RECORDED_TICKS);
    let mut estimates = Vec::with_capacity(RECORDED_TICKS);
    for _ in 0..RECORDED_TICKS {
        l.tick();
        measurements.push(l.measurement);
        estimates.push(l.used_estimate);
    }
    let y_max = measurements
        .iter()
        .map(|m| m.y[0].abs())
        .fold(0.0, f64::max);
    assert!(
        y_max > 1e-6,
        "the scan is not moving the plant (|y| ≤ {y_max})"
    );
    (l, measurements, estimates)
}

fn thesis_step(c: &mut Criterion) {
    let design = default_design();
    eprintln!(
        "default design: observer block {} states, {} inputs, {} outputs; feedback {} states; \
         modified feedforward {} states; plant {} states",
        design.observer.system.states(),
        design.observer.system.inputs(),
        design.observer.system.outputs(),
        design.feedback.as_ref().map_or(0, |f| f.states()),
        design
            .modified_feedforward
            .as_ref()
            .map_or(0, |f| f.states()),
        design.plant.states(),
    );
    let (mut l, measurements, estimates) = warmed_up(&design);
    let n = measurements.len();
    let mut group = c.benchmark_group("thesis_default");

    let mut k = 0;
    let mut estimate = l.estimate;
    group.bench_function("observer_step", |b| {
        b.iter(|| {
            k = (k + 1) % n;
            l.observer.step(black_box(&measurements[k]), &mut estimate);
            black_box(&estimate);
        })
    });

    let mut command = Command::default();
    group.bench_function("controller_step", |b| {
        b.iter(|| {
            k = (k + 1) % n;
            l.controller
                .step(black_box(&measurements[k]), &estimates[k], &mut command);
            black_box(&command);
        })
    });

    // Both cores on the same y(k), the estimate double-buffered as the
    // services have it (the observer writes the one for k+1 while the
    // controller reads the one for k), alternating buffers rather than
    // swapping 3.8 KB messages.
    let mut buffers = [estimates[0], estimate];
    let mut flip = false;
    group.bench_function("observer_and_controller_step", |b| {
        b.iter(|| {
            k = (k + 1) % n;
            let m = black_box(&measurements[k]);
            let [first, second] = &mut buffers;
            let (used, next) = if flip {
                (second, first)
            } else {
                (first, second)
            };
            l.controller.step(m, used, &mut command);
            l.observer.step(m, next);
            flip = !flip;
            black_box(&command);
        })
    });

    // Plant, observer and controller, as lockstep runs them (the scan repeats
    // every 0.25 s, so the loop stays in motion however long this runs). This
    // includes `InProcessLoop::tick`'s swap of its two estimate buffers.
    group.bench_function("loop_tick_with_plant", |b| {
        b.iter(|| {
            l.tick();
            black_box(&l.command);
        })
    });
    group.finish();
}

criterion_group! {
    name = benches;
    // Short by default (2-core machine); the command line still overrides.
    config = Criterion::default()
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = thesis_step
}
criterion_main!(benches);
