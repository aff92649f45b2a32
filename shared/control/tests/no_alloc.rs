//! The per-sample paths added for scheduling and the input–output observer
//! allocate nothing, including when they refuse a bad sample. The global
//! allocator aborts the test process on any allocation inside
//! `assert_no_alloc`, in debug and release builds (no_alloc_step.rs in
//! flexloop-components checks that the guard is armed).

use assert_no_alloc::{AllocDisabler, assert_no_alloc};
use flexloop_control::design_error::DesignError;
use flexloop_control::discretise::zoh;
use flexloop_control::io_observer::{IoObserver, observer_based_correction};
use flexloop_control::kalman::KalmanWeights;
use flexloop_control::lti::{DiscreteStateSpace, LtiRunner};
use flexloop_control::modal::ModalModel;
use flexloop_control::models::{TS_10KHZ, flexible_joint, thesis_chain_modal};
use flexloop_control::placement::{robust_place, robust_place_observer};
use flexloop_control::scheduling::{
    InterpolatedKalman, KalmanSchedule, ModelSchedule, PositionGrid, TimeVaryingKalman,
};
use flexloop_control::step_error::StepError;
use nalgebra::Complex;

#[global_allocator]
static ALLOCATOR: AllocDisabler = AllocDisabler;

/// The position-dependent thesis chain on a 5 mm grid (20 mm node pitch).
fn chain_schedule() -> ModelSchedule {
    let modal = thesis_chain_modal().unwrap();
    let base = modal
        .select_outputs(&[0])
        .unwrap()
        .truncate(4, &[])
        .unwrap();
    let disc = zoh(&base.state_space(), TS_10KHZ).unwrap();
    let weights = KalmanWeights::thesis(&disc);
    let grid = PositionGrid::covering(0.0, 0.14, 0.005).unwrap();
    ModelSchedule::new(grid, weights, |pos| {
        let red = modal
            .with_sensor_positions(&[(pos / 0.02).clamp(0.0, 7.0)])?
            .truncate(4, &[4, 5, 6])?;
        let ss = red.state_space();
        Ok::<_, DesignError>(DiscreteStateSpace::new(
            disc.a.clone(),
            disc.b.clone(),
            ss.c,
            ss.d,
            TS_10KHZ,
        )?)
    })
    .unwrap()
}

#[test]
fn scheduled_kalman_filters_do_not_allocate() {
    let schedule = chain_schedule();
    let ks = KalmanSchedule::design(schedule.clone()).unwrap();
    let mut m = ks.matrices();
    let mut ss = InterpolatedKalman::new(ks.clone());
    let mut tv = TimeVaryingKalman::from_steady_state(schedule, 0.0).unwrap();
    let mut sum = 0.0;
    assert_no_alloc(|| {
        for k in 0..2000 {
            let t = k as f64 * TS_10KHZ;
            let pos = 0.07 * (1.0 - (2.0 * std::f64::consts::PI * 5.0 * t).cos());
            let y = [1e-9 * (k as f64 * 0.01).sin()];
            let u = [(k as f64 * 0.02).cos()];
            ks.interpolate(pos, &mut m).unwrap();
            sum += ss.step(pos, &y, &u).unwrap()[0];
            sum += tv.step(pos, &y, &u).unwrap()[0];
        }
        // Refusals do not allocate either.
        assert!(matches!(
            ss.step(0.5, &[0.0], &[0.0]),
            Err(StepError::PositionOutOfRange { .. })
        ));
        assert_eq!(
            tv.step(0.01, &[f64::NAN], &[0.0]),
            Err(StepError::NonFinite("y"))
        );
        assert!(matches!(
            tv.step(0.01, &[0.0, 0.0], &[0.0]),
            Err(StepError::Length { .. })
        ));
    });
    assert!(sum.is_finite());
}

#[test]
fn input_output_observer_does_not_allocate() {
    let modal = ModalModel::from_nodal(&flexible_joint()).unwrap();
    let model = zoh(&modal.state_space(), 1.0 / 200.0).unwrap();
    let poles = |spec: [(f64, f64); 4]| -> Vec<Complex<f64>> {
        spec.iter()
            .flat_map(|&(f_hz, zeta)| {
                let w = 2.0 * std::f64::consts::PI * f_hz;
                let s = Complex::new(-zeta * w, w * (1.0 - zeta * zeta).sqrt());
                let z = (s * model.ts).exp();
                [z, z.conj()]
            })
            .collect()
    };
    let f = robust_place(
        &model.a,
        &model.b,
        &poles([(2.0, 0.7), (2.5, 0.7), (4.88, 0.5), (5.81, 0.5)]),
    )
    .unwrap()
    .gain;
    let l = robust_place_observer(
        &model.a,
        &model.c,
        &poles([(6.0, 0.7), (7.0, 0.7), (8.0, 0.6), (9.0, 0.6)]),
    )
    .unwrap()
    .gain;
    let k = observer_based_correction(&model, &f, &l).unwrap();
    let obs = IoObserver::input_correction(model.clone(), k).unwrap();
    let mut run = obs.runner();
    let mut plant = LtiRunner::new(model);
    plant.set_state(&[0.1, 0.0, -0.05, 0.2, 0.01, 0.0, 0.0, -0.02]);
    let mut y = [0.0; 2];
    assert_no_alloc(|| {
        for k in 0..1000 {
            let u = [0.3 * (k as f64 * 0.01).sin(), -0.2];
            y.copy_from_slice(plant.step(&u));
            run.step(&y, &u).unwrap();
        }
        assert_eq!(
            run.step(&[0.0, f64::INFINITY], &[0.0, 0.0]),
            Err(StepError::NonFinite("y"))
        );
    });
    let err: f64 = plant
        .state()
        .iter()
        .zip(run.estimate())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-9, "{err}");
}

/// The measurement's excitation, sample by sample, through its fade in, its
/// steady periods, a stop and its fade out.
#[test]
fn the_multisine_source_does_not_allocate() {
    use flexloop_control::multisine::{Multisine, MultisineSource, MultisineSpec, Phases};
    let signal = Multisine::design(&MultisineSpec {
        rate_hz: 10_000.0,
        period_samples: 1_000,
        f_min_hz: 10.0,
        f_max_hz: 2_000.0,
        max_lines: 30,
        amplitude: 0.1,
        phases: Phases::Schroeder,
    })
    .unwrap();
    let mut source = MultisineSource::new(signal, 500);
    let mut sum = 0.0;
    assert_no_alloc(|| {
        for k in 0..5_000 {
            if k == 3_000 {
                source.stop();
            }
            sum += source.next_value();
        }
    });
    assert!(sum.is_finite());
}
