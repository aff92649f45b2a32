//! A controller joining a long run (a restart, a swap to the same design)
//! takes its feedforward block's state from the active instance instead of
//! replaying the whole run; any other feedforward replays. A retuned
//! feedback has another modified feedforward: the block holds a copy of
//! C_fb (thesis App. A).

use flexloop_components::ControllerCore;
use flexloop_design::LoopDesign;
use flexloop_protocol::Handover;
use flexloop_scenario::{Overrides, Scenario};
use std::path::PathBuf;

fn default_scenario() -> Scenario {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/default.toml");
    Scenario::load(&path, &Overrides::default()).unwrap()
}

fn feedforward_state(core: &ControllerCore) -> Vec<f64> {
    let mut h = Handover::default();
    core.save(&mut h);
    let (at, len) = (h.carried_at as usize, h.carried_len as usize);
    h.state[at..at + len].to_vec()
}

/// In the middle of the first scan's motion.
const JOIN_AT: u64 = 1200;

/// The default design's controller run to `JOIN_AT`, and the state it hands over.
fn active_at_join() -> (Scenario, LoopDesign, ControllerCore, Handover) {
    let scenario = default_scenario();
    let design = LoopDesign::from_scenario(&scenario).unwrap();
    let mut active = ControllerCore::new(&design, 0);
    active.fast_forward(JOIN_AT);
    let mut state = Handover::default();
    active.save(&mut state);
    state.seq = JOIN_AT - 1;
    (scenario, design, active, state)
}

#[test]
fn a_joining_controller_takes_the_feedforward_over_and_matches_a_full_replay() {
    let (_, design, mut active, state) = active_at_join();
    assert!(
        state.carried_len > 0,
        "the thesis design has a modified feedforward"
    );

    let mut joiner = ControllerCore::new(&design, 1);
    assert!(
        joiner.load_feedforward(&state),
        "same feedforward: taken over"
    );
    assert_eq!(
        joiner.fast_forward(JOIN_AT + 100),
        100,
        "only the gap is replayed"
    );

    active.fast_forward(JOIN_AT + 100);
    let (a, b) = (feedforward_state(&active), feedforward_state(&joiner));
    assert!(a.iter().any(|v| *v != 0.0), "the block is in motion");
    assert_eq!(a, b, "bit-identical to the instance that ran from sample 0");
}

#[test]
fn another_feedforward_is_not_taken_over() {
    let (scenario, design, _, state) = active_at_join();

    let mut later_scan = scenario.clone();
    later_scan.reference.start_s += 0.01;
    let mut retuned = scenario.clone();
    retuned.controller.bandwidth_hz =
        flexloop_scenario::PidBandwidth::Hz(1.5 * scenario.controller.bandwidth_hz.hz().unwrap());
    for other in [later_scan, retuned] {
        let other = LoopDesign::from_scenario(&other).unwrap();
        let mut joiner = ControllerCore::new(&other, 1);
        assert!(!joiner.load_feedforward(&state));
        assert_eq!(
            joiner.fast_forward(JOIN_AT),
            JOIN_AT,
            "replays from sample 0"
        );
    }

    let mut corrupt = state;
    corrupt.state[corrupt.carried_at as usize] = f64::NAN;
    let mut same = ControllerCore::new(&design, 1);
    assert!(!same.load_feedforward(&corrupt), "non-finite state refused");
}
