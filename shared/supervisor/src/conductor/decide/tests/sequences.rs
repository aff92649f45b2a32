//! Whole sequences (swap, restart, promotion, standby and its renewal) driven
//! through the core as the shell drives them, with every failure branch:
//! the shadow never follows, the new instance dies, a command fails, the
//! loop never passes the boundary, a second order arrives, a crash comes in
//! the middle. Time is the test's: each look says when it is.

use super::super::sequence::{SPARE_START_WAIT, SequenceEnd};
use super::*;

/// The pid the tests give each instance they "start".
const NEW: i32 = 50;

pub(super) fn standby_order(generation: u32) -> Order {
    Order::Standby {
        scenario: PathBuf::from("loop.toml"),
        generation,
    }
}

fn swap(role: Role) -> Order {
    Order::Swap {
        role,
        scenario: PathBuf::from("retuned.toml"),
    }
}

impl Fixture {
    fn look(&self, ms: u64) -> Look {
        Look {
            now: self.at(ms),
            shutting_down: false,
        }
    }

    /// `own.toml` names a program of one's own; `unreadable.toml` cannot
    /// be read.
    pub(super) fn begin(&mut self, order: Order) -> Result<(), Failure> {
        let look = self.look(0);
        self.core
            .begin(order, look, &|scenario: &Path| match scenario.to_str() {
                Some("unreadable.toml") => Err("cannot read unreadable.toml".into()),
                other => Ok(other == Some("own.toml")),
            })
    }

    pub(super) fn advance(&mut self, ms: u64) -> Step {
        let look = self.look(ms);
        self.core.advance(look)
    }

    pub(super) fn carried(&mut self, carried: Carried, ms: u64) {
        let now = self.at(ms);
        self.core.carried(carried, now);
    }

    /// The next step is the end.
    pub(super) fn done(&mut self, ms: u64) -> SequenceEnd {
        match self.advance(ms) {
            Step::Done(end) => end,
            other => panic!("expected the end, got {other:?}"),
        }
    }

    /// The next step is a wait.
    fn waits(&mut self, ms: u64) {
        let step = self.advance(ms);
        assert!(
            matches!(step, Step::Wait(_)),
            "expected a wait, got {step:?}"
        );
    }

    /// The next step is this launch: the process starts as [`NEW`].
    fn launches(&mut self, ms: u64, role: Role, generation: u32, joining: Joining) {
        match self.advance(ms) {
            Step::Carry(Command::Launch {
                role: r,
                generation: g,
                joining: j,
                scenario,
            }) => {
                assert_eq!((r, g, j), (role, generation, joining));
                self.launch_with(NEW, role, generation, joining, scenario);
                self.carried(Carried::Launched(NEW), ms);
            }
            other => panic!("expected a launch, got {other:?}"),
        }
    }

    /// The next step publishes an activation: it goes out; its boundary
    /// for `role`.
    fn publishes(&mut self, ms: u64, role: Role) -> u64 {
        match self.advance(ms) {
            Step::Carry(Command::Publish(activation)) => {
                self.carried(Carried::Published(activation), ms);
                match role {
                    Role::Controller => activation.controller_from_seq,
                    _ => activation.observer_from_seq,
                }
            }
            other => panic!("expected an activation, got {other:?}"),
        }
    }

    /// The next step stops `pid`.
    fn stops(&mut self, ms: u64, pid: i32) {
        match self.advance(ms) {
            Step::Carry(Command::Stop(p)) => {
                assert_eq!(p, pid);
                self.carried(Carried::Done, ms);
            }
            other => panic!("expected a stop of {pid}, got {other:?}"),
        }
    }

    /// The loop runs `seqs` on fresh commands, and its newest sample is the last.
    fn runs(&mut self, seqs: std::ops::Range<u64>) {
        let last = seqs.end - 1;
        self.applied(seqs, 0);
        self.sample(last);
    }

    /// A standby controller started as `generation` (pid 23).
    pub(super) fn standby(&mut self, generation: u32) -> SequenceEnd {
        self.begin(standby_order(generation)).unwrap();
        match self.advance(0) {
            Step::Carry(Command::Launch { scenario, .. }) => {
                self.launch_with(23, Role::Controller, generation, Joining::Standby, scenario);
                self.carried(Carried::Launched(23), 0);
            }
            other => panic!("expected a launch, got {other:?}"),
        }
        self.done(0)
    }
}

fn switch_of(end: &SequenceEnd) -> &Switch {
    end.result
        .as_ref()
        .expect("the sequence succeeded")
        .as_ref()
        .expect("it made a switch")
}

// ---- a swap ----

#[test]
fn a_swap_starts_the_new_instance_awaits_its_shadow_announces_ahead_and_drains() {
    let mut f = Fixture::new(policy());
    f.runs(1..101);
    f.begin(swap(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 1, Joining::Replacement);
    f.waits(1);
    f.state(Role::Controller, 1, 100, FOLLOWING);
    // 50 ms ahead at 10 kHz.
    let from_seq = f.publishes(2, Role::Controller);
    assert_eq!(from_seq, 600);
    assert!(f.member(CONTROLLER).exit_expected(), "its exit is the plan");
    f.waits(3);
    f.runs(101..800);
    f.waits(4);
    // The old one leaves at the boundary: no crash.
    assert!(f.exit(CONTROLLER, 0, 5).is_empty());
    let end = f.done(5);
    assert_eq!(kinds(&end.actions), ["swap"]);
    let switch = switch_of(&end);
    assert_eq!((switch.from_seq, switch.start_seq), (600, 100));
    assert!(!switch.warm);
    assert_eq!(
        record(&end.actions, "swap").detail()["scenario"],
        "retuned.toml"
    );
    assert!(f.tick(1000).is_empty(), "nothing to restart");
}

#[test]
fn a_swap_waits_for_the_loop_to_tick_and_gives_up_on_a_loop_that_never_does() {
    let mut f = Fixture::new(policy());
    f.begin(swap(Role::Observer)).unwrap();
    f.waits(0);
    f.waits(29_000);
    let end = f.done(30_001);
    assert_eq!(
        end.result,
        Err(Failure::LoopNotTicking(SHADOW_TIMEOUT)),
        "nothing started, nothing to stop"
    );
    // A stop asked meanwhile ends the wait at once.
    let mut f = Fixture::new(policy());
    f.begin(swap(Role::Observer)).unwrap();
    let look = Look {
        now: f.at(1),
        shutting_down: true,
    };
    assert!(matches!(f.core.advance(look), Step::Done(_)));
}

#[test]
fn a_shadow_that_never_follows_is_stopped_and_the_swap_refused() {
    let mut f = Fixture::new(policy());
    f.sample(10);
    f.begin(swap(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 1, Joining::Replacement);
    f.waits(29_999);
    f.stops(30_001, NEW);
    let end = f.done(30_001);
    assert_eq!(
        end.result,
        Err(Failure::NotFollowing {
            role: Role::Controller,
            timeout: SHADOW_TIMEOUT
        })
    );
    // The stopped one's exit is the plan; the old one serves on.
    assert!(f.exit(NEW, 143, 30_002).is_empty());
    assert!(f.tick(40_000).is_empty());
    assert_eq!(
        f.core.roster().serving(Role::Controller).unwrap().pid,
        CONTROLLER
    );
}

#[test]
fn a_new_instance_that_dies_before_it_follows_fails_the_swap_without_a_restart() {
    let mut f = Fixture::new(policy());
    f.sample(10);
    f.begin(swap(Role::Observer)).unwrap();
    f.launches(0, Role::Observer, 1, Joining::Replacement);
    f.waits(1);
    f.exit(NEW, 1, 2);
    let end = f.done(3);
    assert!(matches!(
        end.result,
        Err(Failure::NewInstanceExited {
            pid: NEW,
            code: 1,
            ..
        })
    ));
    assert!(kinds(&end.actions).is_empty(), "its exit is no crash");
    assert!(f.tick(1000).is_empty());
}

#[test]
fn a_launch_or_an_order_that_fails_fails_the_swap() {
    let mut f = Fixture::new(policy());
    f.sample(10);
    f.begin(swap(Role::Controller)).unwrap();
    assert!(matches!(f.advance(0), Step::Carry(Command::Launch { .. })));
    f.carried(Carried::Failed("no such file".into()), 0);
    let end = f.done(0);
    assert_eq!(end.result, Err(Failure::Carrying("no such file".into())));
    // A scenario that cannot be read fails at the first step.
    f.begin(Order::Swap {
        role: Role::Controller,
        scenario: "unreadable.toml".into(),
    })
    .unwrap();
    let end = f.done(1);
    assert_eq!(
        end.result,
        Err(Failure::Carrying("cannot read unreadable.toml".into()))
    );
}

#[test]
fn a_loop_that_does_not_pass_the_boundary_stops_the_old_instance_and_fails() {
    let mut f = Fixture::new(policy());
    f.runs(1..101);
    f.begin(swap(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 1, Joining::Replacement);
    f.waits(1);
    f.state(Role::Controller, 1, 100, FOLLOWING);
    f.publishes(2, Role::Controller);
    f.waits(9_000);
    f.stops(10_003, CONTROLLER);
    let end = f.done(10_003);
    assert!(matches!(
        end.result,
        Err(Failure::NotPassed { from_seq: 600, .. })
    ));
}

#[test]
fn a_swap_takes_an_idle_spare_waits_for_a_starting_one_and_then_starts_a_process() {
    let mut f = Fixture::new(warm());
    f.sample(10);
    // Neither spare reported idle yet: the swap waits for one.
    f.begin(swap(Role::Controller)).unwrap();
    f.waits(0);
    f.core.handle(Event::SpareIdle {
        pid: SPARE_CONTROLLER,
    });
    match f.advance(1) {
        Step::Carry(Command::Order {
            pid,
            generation,
            joining,
            scenario,
        }) => {
            assert_eq!(
                (pid, generation, joining),
                (SPARE_CONTROLLER, 1, Joining::Replacement)
            );
            assert_eq!(scenario, Path::new("retuned.toml"));
        }
        other => panic!("expected an order, got {other:?}"),
    }
    f.carried(Carried::Done, 1);
    assert_eq!(f.member(SPARE_CONTROLLER).generation, Some(1));
    // The observer's spare never reports: after the wait, a new process.
    f.exit(SPARE_CONTROLLER, 9, 2);
    let mut f = Fixture::new(warm());
    f.sample(10);
    f.begin(swap(Role::Observer)).unwrap();
    f.waits(0);
    let waited_out = SPARE_START_WAIT.as_millis() as u64 + 1;
    f.launches(waited_out, Role::Observer, 1, Joining::Replacement);
}

// ---- one sequence at a time, and crashes meanwhile ----

#[test]
fn a_second_order_during_a_swap_is_refused_and_the_swap_goes_on() {
    let mut f = Fixture::new(policy());
    f.runs(1..101);
    f.begin(swap(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 1, Joining::Replacement);
    assert_eq!(f.begin(swap(Role::Observer)), Err(Failure::Busy));
    assert_eq!(f.begin(Order::Restart(Role::Observer)), Err(Failure::Busy));
    assert_eq!(f.begin(standby_order(2)), Err(Failure::Busy));
    // A measurement would span the old loop and the new one.
    assert_eq!(f.core.plan_measurement(), Err(Failure::Changing));
    f.state(Role::Controller, 1, 100, FOLLOWING);
    f.publishes(1, Role::Controller);
    f.runs(101..800);
    f.exit(CONTROLLER, 0, 2);
    assert_eq!(switch_of(&f.done(2)).generation, 1);
    // Once it is over, the next one begins, and a measurement may.
    assert!(f.core.plan_measurement().is_ok());
    assert_eq!(f.begin(swap(Role::Observer)), Ok(()));
}

#[test]
fn a_crash_of_another_role_during_a_swap_is_settled_at_its_end_and_restarted() {
    let mut f = Fixture::new(policy());
    f.runs(1..101);
    f.begin(swap(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 1, Joining::Replacement);
    assert!(
        f.exit(OBSERVER, 137, 1).is_empty(),
        "not while the swap runs"
    );
    f.state(Role::Controller, 1, 100, FOLLOWING);
    f.publishes(2, Role::Controller);
    f.runs(101..800);
    f.exit(CONTROLLER, 0, 3);
    let end = f.done(3);
    assert_eq!(kinds(&end.actions), ["swap", "crash"]);
    assert_eq!(f.tick(4), [Action::Restart(Role::Observer)]);
}

#[test]
fn the_instance_a_swap_replaces_that_dies_meanwhile_hands_its_last_state_over() {
    let mut f = Fixture::new(policy());
    f.runs(1..101);
    f.state(Role::Controller, 0, 100, ACTIVE);
    f.begin(swap(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 1, Joining::Replacement);
    f.exit(CONTROLLER, 137, 1);
    match f.advance(1) {
        Step::Carry(Command::HandOver { role, state, .. }) => {
            assert_eq!(
                (role, state.seq, state.generation),
                (Role::Controller, 100, 0)
            );
        }
        other => panic!("expected a hand-over, got {other:?}"),
    }
    f.carried(Carried::Done, 1);
    f.waits(1);
    f.state(Role::Controller, 1, 101, FOLLOWING);
    f.publishes(2, Role::Controller);
    f.runs(101..800);
    let end = f.done(3);
    assert_eq!(kinds(&end.actions), ["swap"], "replaced, not restarted");
    assert!(f.tick(1000).is_empty());
}

#[test]
fn the_new_instance_that_dies_after_the_boundary_is_a_crash_settled_at_the_end() {
    let mut f = Fixture::new(policy());
    f.runs(1..101);
    f.begin(swap(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 1, Joining::Replacement);
    f.state(Role::Controller, 1, 100, FOLLOWING);
    f.publishes(1, Role::Controller);
    f.exit(CONTROLLER, 0, 2);
    f.runs(101..650);
    // It serves from 600 on, and dies.
    f.exit(NEW, 139, 3);
    f.runs(650..1700);
    let end = f.done(4);
    assert_eq!(kinds(&end.actions), ["swap", "crash"]);
    assert_eq!(f.tick(5), [Action::Restart(Role::Controller)]);
}

// ---- restarts ----

#[test]
fn a_restart_owns_the_dead_ones_samples_at_once_then_follows_without_a_new_boundary() {
    let mut f = Fixture::new(policy());
    f.runs(1..101);
    f.state(Role::Observer, 0, 99, ACTIVE);
    f.exit(OBSERVER, 137, 0);
    assert_eq!(f.tick(0), [Action::Restart(Role::Observer)]);
    f.begin(Order::Restart(Role::Observer)).unwrap();
    // The estimate after its last measurement: sample 101.
    assert_eq!(f.publishes(0, Role::Observer), 101);
    f.launches(0, Role::Observer, 1, Joining::Restart);
    f.state(Role::Observer, 1, 101, ACTIVE);
    f.runs(101..1300);
    let end = f.done(2);
    assert_eq!(kinds(&end.actions), ["restart"]);
    assert_eq!(switch_of(&end).from_seq, 101);
}

#[test]
fn a_restart_before_tick_0_owns_every_sample_and_a_failed_announcement_stops_it() {
    let mut f = Fixture::new(policy());
    f.exit(CONTROLLER, 1, 0);
    f.begin(Order::Restart(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 1, Joining::Restart);
    assert_eq!(f.publishes(0, Role::Controller), 0);
    let end = f.done(0);
    assert_eq!(kinds(&end.actions), ["restart"]);
    assert_eq!(
        record(&end.actions, "restart").detail()["before_tick_0"],
        true
    );
    assert_eq!(end.result, Ok(None));

    let mut f = Fixture::new(policy());
    f.exit(CONTROLLER, 1, 0);
    f.begin(Order::Restart(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 1, Joining::Restart);
    assert!(matches!(f.advance(0), Step::Carry(Command::Publish(_))));
    f.carried(Carried::Failed("the activation did not go out".into()), 0);
    let end = f.done(0);
    assert!(end.actions.contains(&Action::Stop(NEW)));
    assert!(end.result.is_err());
}

#[test]
fn a_program_that_dies_during_its_restart_fails_it_and_another_attempt_follows() {
    let mut f = Fixture::new(policy());
    f.runs(1..101);
    f.state(Role::Controller, 0, 100, ACTIVE);
    f.exit(CONTROLLER, 137, 0);
    f.tick(0);
    f.begin(Order::Restart(Role::Controller)).unwrap();
    f.publishes(0, Role::Controller);
    f.launches(0, Role::Controller, 1, Joining::Restart);
    f.exit(NEW, 1, 1);
    let end = f.done(1);
    let error = anyhow::Error::from(end.result.unwrap_err());
    let then = f
        .core
        .restart_failed(Role::Controller, &error, f.at(1), false);
    assert_eq!(kinds(&then), ["restart-failed"]);
    assert_eq!(f.tick(1000), [Action::Restart(Role::Controller)]);
}

#[test]
fn a_crashed_logger_is_started_again_with_its_own_files() {
    let mut f = Fixture::new(policy());
    f.sample(10);
    f.exit(LOGGER, 137, 0);
    f.tick(0);
    f.begin(Order::Restart(Role::Logger)).unwrap();
    f.launches(0, Role::Logger, 1, Joining::Restart);
    let end = f.done(0);
    assert_eq!(kinds(&end.actions), ["restart"]);
    assert!(!record(&end.actions, "restart").detail()["files"].is_null());
}

#[test]
fn a_crashed_controller_with_a_following_standby_promotes_it_at_a_boundary_ahead() {
    let mut f = Fixture::new(standby());
    f.runs(1..101);
    f.standby(1);
    f.state(Role::Controller, 1, 100, FOLLOWING);
    f.exit(CONTROLLER, 137, 0);
    f.tick(0);
    f.begin(Order::Restart(Role::Controller)).unwrap();
    assert_eq!(f.publishes(0, Role::Controller), 600);
    f.runs(101..800);
    let end = f.done(1);
    assert_eq!(kinds(&end.actions), ["promote-standby"]);
    let switch = switch_of(&end);
    assert!(switch.warm, "nothing started");
    assert_eq!(switch.generation, 1);
}

// ---- the standby ----

/// A loop with a standby (generation 1, pid 23) whose controller is swapped
/// to `retuned.toml` as generation 2, up to the renewed standby's start
/// (generation 3, pid NEW + 1).
fn swapped_with_a_standby() -> Fixture {
    let mut f = Fixture::new(Policy {
        warm_spares: false,
        ..standby()
    });
    f.runs(1..101);
    f.standby(1);
    f.begin(swap(Role::Controller)).unwrap();
    f.launches(0, Role::Controller, 2, Joining::Replacement);
    f.state(Role::Controller, 2, 100, FOLLOWING);
    f.publishes(1, Role::Controller);
    f.exit(CONTROLLER, 0, 2);
    f.runs(101..800);
    // Passed: a standby of the new design.
    match f.advance(3) {
        Step::Carry(Command::Launch {
            generation,
            joining,
            scenario,
            ..
        }) => {
            assert_eq!((generation, joining), (3, Joining::Standby));
            assert_eq!(scenario, Path::new("retuned.toml"));
            f.launch_with(NEW + 1, Role::Controller, 3, Joining::Standby, scenario);
            f.carried(Carried::Launched(NEW + 1), 3);
        }
        other => panic!("expected the renewed standby, got {other:?}"),
    }
    f
}

#[test]
fn a_controller_swap_renews_the_standby_and_retires_the_old_one() {
    let mut f = swapped_with_a_standby();
    f.waits(4);
    f.state(Role::Controller, 3, 800, FOLLOWING);
    // Without warm spares, the old standby is stopped.
    f.stops(5, 23);
    let end = f.done(5);
    assert_eq!(kinds(&end.actions), ["swap", "standby"]);
    assert_eq!(switch_of(&end).generation, 2);
    assert_eq!(
        record(&end.actions, "standby").detail()["replaces"],
        json!([1])
    );
}

#[test]
fn a_renewed_standby_that_never_follows_leaves_the_old_one_and_the_swap_stands() {
    let mut f = swapped_with_a_standby();
    f.stops(30_010, NEW + 1);
    let end = f.done(30_010);
    assert_eq!(kinds(&end.actions), ["swap", "standby-failed"]);
    assert_eq!(switch_of(&end).generation, 2, "the swap stands");
    assert!(f.member(23).alive(), "the old standby covers");
}

// ---- a measurement ordered on the running loop ----

#[test]
fn a_measurement_starts_ahead_once_the_loop_ticks_and_holds_off_changes_until_its_end() {
    let mut f = Fixture::new(policy());
    assert_eq!(f.core.plan_measurement(), Err(Failure::NotTickingYet));
    assert_eq!(f.core.may_change_the_loop(), Ok(()));
    f.runs(1..101);
    // 50 ms ahead at 10 kHz, as a swap's boundary.
    assert_eq!(f.core.plan_measurement(), Ok(600));
    f.core.measurement_ordered(600, 5_000);
    assert_eq!(
        f.core.plan_measurement(),
        Err(Failure::Measuring { until: 5_000 })
    );
    assert_eq!(
        f.core.may_change_the_loop(),
        Err(Failure::Measuring { until: 5_000 })
    );
    f.runs(101..5_000);
    assert!(
        f.core.may_change_the_loop().is_err(),
        "its last sample is yet to come"
    );
    f.runs(5_000..5_002);
    assert_eq!(f.core.may_change_the_loop(), Ok(()));
    assert_eq!(f.core.plan_measurement(), Ok(5_001 + 500));
}

#[test]
fn a_restart_whose_loop_never_passes_its_boundary_stops_its_instance_and_fails() {
    let mut f = Fixture::new(policy());
    f.runs(1..101);
    f.state(Role::Controller, 0, 100, ACTIVE);
    f.exit(CONTROLLER, 137, 0);
    f.tick(0);
    f.begin(Order::Restart(Role::Controller)).unwrap();
    f.publishes(0, Role::Controller);
    f.launches(0, Role::Controller, 1, Joining::Restart);
    f.state(Role::Controller, 1, 101, ACTIVE);
    f.waits(1);
    // No sample past the boundary within the drain's time: the new
    // instance goes, so that the next attempt starts afresh.
    f.stops(10_002, NEW);
    let end = f.done(10_002);
    assert!(matches!(
        end.result,
        Err(Failure::NotPassed { from_seq: 101, .. })
    ));
    assert!(f.member(NEW).exit_expected());
}
