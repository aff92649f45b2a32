//! How the cost of one observer sample grows with the number of states n
//! (8 … 128, one output) and with the number of outputs p (1 … 8, 32 states).
//!
//! The systems are synthetic: n/2 lightly damped modes (20 Hz … 2 kHz at
//! 10 kHz, ζ = 0.01, so every |eig| < 1) with seeded random force and sensor
//! gains, a steady-state Kalman predictor, MC on every output and a static
//! active-damping gain, compiled into one observer block as the thesis design
//! is (`compile_observer_block`). Two series:
//!
//! - `observer_block`: one `LtiRunner::step` of the block, ŷ = C s + D·in and
//!   s ← A s + B·in. This is the whole per-sample arithmetic of the observer
//!   and the controller's share of it, with no message around it, so it runs
//!   past the protocol's MAX_STATES.
//! - `observer_core`: `ObserverCore::step` on protocol messages (up to 128
//!   states): the block plus the estimate map, the innovation and filling the
//!   `Estimate` message.
//!
//! Inputs are replayed from a seeded simulation of the plant itself, so the
//! numbers are for realistic, non-zero values.
//!
//! `cargo bench --bench scaling` (docs/benchmarks.md, "The computation of one sample: criterion").

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use flexloop_components::ObserverCore;
use flexloop_components::noise::Gaussian;
use flexloop_control::kalman::{KalmanWeights, steady_state_kalman};
use flexloop_control::lti::{DiscreteStateSpace, LtiRunner};
use flexloop_control::observer_block::{ObserverBlock, ObserverDesign, compile_observer_block};
use flexloop_design::OutputPrediction;
use flexloop_protocol::{Estimate, MAX_STATES, Measurement};
use nalgebra::DMatrix;
use std::f64::consts::PI;
use std::hint::black_box;
use std::time::Duration;

const TS: f64 = 1e-4;
const STATES: [usize; 5] = [8, 16, 32, 64, 128];
const OUTPUTS: [usize; 4] = [1, 2, 4, 8];
/// States of the outputs series.
const STATES_FOR_OUTPUTS: usize = 32;
/// Samples of recorded inputs replayed by every benchmark.
const RECORDED: usize = 1024;

/// n/2 modes as 2×2 blocks r·[[cos θ, sin θ], [−sin θ, cos θ]] (eigenvalues
/// r·e^{±iθ}), one force input, `p` outputs; B and C seeded Gaussian.
fn modal_plant(n: usize, p: usize, seed: u64) -> DiscreteStateSpace {
    assert!(n.is_multiple_of(2));
    let mut rng = Gaussian::new(seed);
    let modes = n / 2;
    let mut a = DMatrix::zeros(n, n);
    for i in 0..modes {
        // Log-spaced natural frequencies from 20 Hz to 2 kHz.
        let f = 20.0 * 100f64.powf(i as f64 / (modes.max(2) - 1) as f64);
        let (w, zeta) = (2.0 * PI * f, 0.01);
        let r = (-zeta * w * TS).exp();
        let theta = w * (1.0 - zeta * zeta).sqrt() * TS;
        let j = 2 * i;
        a[(j, j)] = r * theta.cos();
        a[(j, j + 1)] = r * theta.sin();
        a[(j + 1, j)] = -r * theta.sin();
        a[(j + 1, j + 1)] = r * theta.cos();
    }
    let b = DMatrix::from_fn(n, 1, |_, _| rng.sample());
    let c = DMatrix::from_fn(p, n, |_, _| rng.sample());
    DiscreteStateSpace::new(a, b, c, DMatrix::zeros(p, 1), TS).expect("finite, consistent shapes")
}

/// Kalman predictor with MC on every output and a static AD gain, compiled
/// into one block: inputs [y (p); u], outputs [ŷ_flex (p); u_d], n states.
fn observer_block(plant: &DiscreteStateSpace, seed: u64) -> ObserverBlock {
    let (n, p) = (plant.states(), plant.outputs());
    let weights = KalmanWeights {
        g: DMatrix::identity(n, n),
        q: DMatrix::identity(n, n) * 1e-2,
        r: DMatrix::identity(p, p),
    };
    let kalman =
        steady_state_kalman(plant, &weights).expect("stable plant: the DARE has a solution");
    let mut rng = Gaussian::new(seed);
    let ad_gain = DMatrix::from_fn(1, n, |_, _| 0.1 * rng.sample());
    let design = ObserverDesign {
        model: plant.clone(),
        gain: kalman.l,
        compensation: Some(plant.c.clone()),
        feedback: Some(DiscreteStateSpace::gain(ad_gain, TS).expect("finite gain")),
    };
    let block = compile_observer_block(&design, 0).expect("consistent design");
    assert_eq!(block.system.states(), n, "a static AD gain adds no states");
    block
}

/// Measurements of the plant driven by seeded white force noise, sensor
/// noise on y.
fn recorded_measurements(plant: &DiscreteStateSpace, seed: u64) -> Vec<Measurement> {
    let p = plant.outputs();
    let mut rng = Gaussian::new(seed);
    let mut run = LtiRunner::new(plant.clone());
    // Past the slowest mode's transient (20 Hz, ζ = 0.01: τ ≈ 80 ms).
    for _ in 0..5000 {
        run.step(&[rng.sample()]);
    }
    (0..RECORDED as u64)
        .map(|seq| {
            let u = rng.sample();
            let y = run.step(&[u]);
            let mut m = Measurement {
                seq,
                n_outputs: p as u32,
                n_inputs: 1,
                ..Measurement::default()
            };
            for (dst, src) in m.y.iter_mut().zip(y) {
                *dst = src + 1e-3 * rng.sample();
            }
            m.u_applied[0] = u;
            m
        })
        .collect()
}

/// The block's input vectors [y; u] of the recorded measurements, flattened.
fn block_inputs(measurements: &[Measurement], p: usize) -> Vec<f64> {
    measurements
        .iter()
        .flat_map(|m| m.y[..p].iter().chain(&m.u_applied[..1]).copied())
        .collect()
}

/// Both series for one (n, p).
fn bench_size(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    n: usize,
    p: usize,
    parameter: usize,
) {
    let seed = (n * 100 + p) as u64;
    let plant = modal_plant(n, p, seed);
    let block = observer_block(&plant, seed + 1);
    let measurements = recorded_measurements(&plant, seed + 2);
    let width = p + 1;
    let inputs = block_inputs(&measurements, p);

    let mut runner = LtiRunner::new(block.system.clone());
    let mut k = 0;
    group.bench_with_input(
        BenchmarkId::new("observer_block", parameter),
        &inputs,
        |b, inputs| {
            b.iter(|| {
                k = (k + 1) % RECORDED;
                black_box(runner.step(black_box(&inputs[k * width..(k + 1) * width])));
            })
        },
    );

    if n <= MAX_STATES {
        let prediction = OutputPrediction {
            c: plant.c.clone(),
            d: plant.d.clone(),
        };
        let mut core =
            ObserverCore::new(&block, &prediction, p, 1).expect("fits the protocol messages");
        let mut estimate = Estimate::default();
        group.bench_with_input(
            BenchmarkId::new("observer_core", parameter),
            &measurements,
            |b, measurements| {
                b.iter(|| {
                    k = (k + 1) % RECORDED;
                    core.step(black_box(&measurements[k]), &mut estimate);
                    black_box(&estimate);
                })
            },
        );
    }
}

fn scaling(c: &mut Criterion) {
    let mut group = c.benchmark_group("states");
    for n in STATES {
        bench_size(&mut group, n, 1, n);
    }
    group.finish();

    let mut group = c.benchmark_group("outputs");
    for p in OUTPUTS {
        bench_size(&mut group, STATES_FOR_OUTPUTS, p, p);
    }
    group.finish();
}

criterion_group! {
    name = benches;
    // Short by default (2-core machine); the command line still overrides.
    config = Criterion::default()
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = scaling
}
criterion_main!(benches);
