//! An observer restarted without its predecessor's state starts from its
//! own initial state mid-scan: its estimates are flagged converging for its
//! settling samples (an error in its block's state shrinks a millionfold
//! by its slowest pole in that many), and the built-in controller leaves their corrections out
//! meanwhile (docs/architecture.md, "Restarts").

use flexloop_components::observer::settling_samples;
use flexloop_components::{EstimationLaw, InProcessLoop, ObserverCore};
use flexloop_design::LoopDesign;
use flexloop_protocol::{Command, Estimate, flags};
use flexloop_scenario::{Overrides, Scenario};
use nalgebra::DMatrix;
use std::path::PathBuf;

fn default_design() -> LoopDesign {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/default.toml");
    LoopDesign::from_scenario(&Scenario::load(&path, &Overrides::default()).unwrap()).unwrap()
}

#[test]
fn settling_samples_follow_the_blocks_slowest_pole() {
    // ρ = 0.5: 0.5^20 < 1e-6 < 0.5^19.
    assert_eq!(
        settling_samples(&DMatrix::from_diagonal_element(3, 3, 0.5), 1000),
        20
    );
    // A pole on the unit circle never settles: the cap.
    assert_eq!(settling_samples(&DMatrix::identity(2, 2), 1000), 1000);
    assert_eq!(settling_samples(&DMatrix::zeros(2, 2), 1000), 1);
}

/// The largest difference between two estimates' corrections (the block's
/// free response and direct part, as the controller uses them).
fn distance(a: &Estimate, b: &Estimate) -> f64 {
    let corrections = |e: &Estimate| {
        e.free
            .iter()
            .chain(e.direct.iter())
            .copied()
            .collect::<Vec<_>>()
    };
    corrections(a)
        .iter()
        .zip(corrections(b))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[test]
fn an_observer_from_its_own_initial_state_meets_the_running_one_within_its_settling_samples() {
    let design = default_design();
    let mut l = InProcessLoop::new(&design).unwrap();
    // Mid-scan, where the loop's estimate is far from the initial state.
    for _ in 0..1200 {
        l.tick();
    }
    let mut fresh = ObserverCore::for_design(&design).unwrap();
    let n = EstimationLaw::settling_samples(&fresh).unwrap();
    assert!(n > 1 && n < 10_000, "{n}");
    let mut own = Estimate::default();
    let mut first = None;
    for _ in 0..n {
        l.tick();
        fresh.step(&l.measurement, &mut own);
        let d = distance(&own, &l.estimate);
        if first.is_none() {
            assert!(d > 0.0, "the fresh observer starts elsewhere");
            first = Some(d);
        }
    }
    let distance_at_end = distance(&own, &l.estimate);
    let first = first.unwrap();
    // A millionfold by the slowest pole; the block's transient (it is not
    // a normal matrix) leaves a little more.
    assert!(
        distance_at_end <= 1e-5 * first,
        "after {n} samples: {distance_at_end} of {first}"
    );
    // Below the loop's ordinary active damping (0.41 N rms on this scan).
    assert!(distance_at_end < 0.1, "{distance_at_end}");
}

#[test]
fn the_controller_leaves_out_a_converging_estimates_corrections() {
    let design = default_design();
    let mut l = InProcessLoop::new(&design).unwrap();
    for _ in 0..1200 {
        l.tick();
    }
    let m = l.measurement;
    let mut estimate = l.estimate;
    let mut with = flexloop_components::ControllerCore::new(&design, 0);
    let mut without = flexloop_components::ControllerCore::new(&design, 0);
    let (mut a, mut b) = (Command::default(), Command::default());
    with.step(&m, &estimate, &mut a);
    estimate.flags |= flags::CONVERGING;
    without.step(&m, &estimate, &mut b);
    assert_eq!(a.flags & flags::OBSERVER_FALLBACK, 0);
    assert_ne!(b.flags & flags::OBSERVER_FALLBACK, 0);
    assert_ne!(a.u_d[0], 0.0, "active damping acts mid-scan");
    assert_eq!(b.u_d[0], 0.0, "not on a converging estimate");
}
