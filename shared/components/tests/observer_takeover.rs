//! An observer of another design on the same model (another Q_ν, damping
//! or band-pass: what `flexloop set observer.*` changes) continues the
//! running observer's estimate instead of starting from its own initial
//! state mid-scan; one on another model does not (docs/architecture.md,
//! "Live tuning").

use flexloop_components::{InProcessLoop, ObserverCore};
use flexloop_design::LoopDesign;
use flexloop_protocol::{Estimate, Handover};
use flexloop_scenario::{Overrides, Scenario};
use std::path::PathBuf;

fn default_scenario() -> Scenario {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/default.toml");
    Scenario::load(&path, &Overrides::default()).unwrap()
}

fn retuned(s: &Scenario) -> Scenario {
    let mut r = s.clone();
    r.observer.damping_increase = 0.05;
    r.observer.bandpass_q = 3.0;
    r.observer.q_nu = Some(500.0);
    r
}

/// Mid-scan: the rigid-body estimate is far from the initial state.
const SHADOW_FROM: u64 = 1100;
const BOUNDARY: u64 = 1200;

fn norm_of_difference(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt()
}

#[test]
fn a_retuned_observer_in_shadow_continues_the_running_estimate() {
    let scenario = default_scenario();
    let design = LoopDesign::from_scenario(&scenario).unwrap();
    let other = LoopDesign::from_scenario(&retuned(&scenario)).unwrap();
    let mut l = InProcessLoop::new(&design).unwrap();
    let mut continued = ObserverCore::for_design(&other).unwrap();
    let mut own = ObserverCore::for_design(&other).unwrap();
    assert_ne!(continued.design_hash(), l.observer.design_hash());

    let mut state = Box::<Handover>::default();
    let (mut from_running, mut from_own) = (Box::<Estimate>::default(), Box::<Estimate>::default());
    for _ in 0..BOUNDARY {
        let following = l.next_tick() >= SHADOW_FROM;
        l.tick();
        if following {
            // As a shadow does: the active instance's state after the
            // previous measurement, then this one.
            assert!(continued.load(&state), "same model: continued");
            continued.step(&l.measurement, &mut from_running);
            own.step(&l.measurement, &mut from_own);
        }
        l.observer.save(&mut state);
        state.seq = l.measurement.seq;
    }
    let n = l.estimate.n_states as usize;
    let running = &l.estimate.x_hat[..n];
    assert_eq!(from_running.seq, l.estimate.seq);
    let continued_error = norm_of_difference(&from_running.x_hat[..n], running);
    let own_error = norm_of_difference(&from_own.x_hat[..n], running);
    assert!(
        running.iter().any(|v| *v != 0.0),
        "the loop is in motion at the boundary"
    );
    // One step on another gain apart, against 100 samples from zero.
    assert!(
        continued_error < own_error / 100.0,
        "continued {continued_error:e}, from its own state {own_error:e}"
    );
}

#[test]
fn an_observer_on_another_model_does_not_take_the_estimate() {
    let scenario = default_scenario();
    let design = LoopDesign::from_scenario(&scenario).unwrap();
    let mut l = InProcessLoop::new(&design).unwrap();
    for _ in 0..BOUNDARY {
        l.tick();
    }
    let mut state = Box::<Handover>::default();
    l.observer.save(&mut state);
    state.seq = l.measurement.seq;
    assert!(state.carried_len > 0);

    // Without measurement compensation the noise-model states go: another model.
    let mut no_mc = scenario.clone();
    no_mc.observer.mc = false;
    let mut joiner = ObserverCore::for_design(&LoopDesign::from_scenario(&no_mc).unwrap()).unwrap();
    assert!(!joiner.load(&state));

    // A damaged estimate is not taken either.
    let mut joiner =
        ObserverCore::for_design(&LoopDesign::from_scenario(&retuned(&scenario)).unwrap()).unwrap();
    let mut damaged = state.clone();
    damaged.state[damaged.carried_at as usize] = f64::NAN;
    assert!(!joiner.load(&damaged));
    assert!(joiner.load(&state));
}
