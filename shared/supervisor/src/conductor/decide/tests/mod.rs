//! The decision core, branch by branch, without a process or a channel:
//! each test feeds events and checks the actions and the bookkeeping.

use super::*;
use crate::process_state::ProcessState;
use flexloop_protocol::handover::FOLLOWING;
use flexloop_protocol::{Handover, MAX_INPUTS};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};

const OBSERVER: i32 = 10;
const CONTROLLER: i32 = 20;
const PLANT: i32 = 30;
const LOGGER: i32 = 40;
const SPARE_OBSERVER: i32 = 11;
const SPARE_CONTROLLER: i32 = 21;

fn policy() -> Policy {
    Policy {
        restart: RestartPolicy::OnCrash,
        max_restarts: 3,
        restart_backoff_ms: 100,
        warm_spares: false,
        keep_standby: false,
        rate_hz: 10_000.0,
        n_inputs: 1,
        silence: SilenceRule {
            ticks: 20,
            floor: Duration::ZERO,
            lockstep: false,
        },
    }
}

/// A core with a loop started as `flexloop up` starts it, and the time 0.
struct Fixture {
    core: Core,
    t0: Instant,
}

impl Fixture {
    fn new(policy: Policy) -> Self {
        let warm_spares = policy.warm_spares;
        let mut f = Fixture {
            core: Core::new(policy, Activation::INITIAL),
            t0: Instant::now(),
        };
        f.launch(LOGGER, Role::Logger, 0, Joining::AtStart);
        f.launch(OBSERVER, Role::Observer, 0, Joining::AtStart);
        f.launch(CONTROLLER, Role::Controller, 0, Joining::AtStart);
        if warm_spares {
            f.launch(SPARE_OBSERVER, Role::Observer, 0, Joining::Spare);
            f.launch(SPARE_CONTROLLER, Role::Controller, 0, Joining::Spare);
        }
        f.launch(PLANT, Role::Plant, 0, Joining::AtStart);
        f
    }

    fn at(&self, ms: u64) -> Instant {
        self.t0 + Duration::from_millis(ms)
    }

    fn launch(&mut self, pid: i32, role: Role, generation: u32, joining: Joining) {
        let scenario = PathBuf::from("loop.toml");
        self.launch_with(pid, role, generation, joining, scenario);
    }

    fn launch_with(
        &mut self,
        pid: i32,
        role: Role,
        generation: u32,
        joining: Joining,
        scenario: PathBuf,
    ) {
        self.launch_as(pid, role, generation, joining, scenario, false);
    }

    /// A program of one's own (`exec`) started for `role`.
    fn launch_program(&mut self, pid: i32, role: Role, generation: u32, joining: Joining) {
        self.launch_as(pid, role, generation, joining, "own.toml".into(), true);
    }

    fn launch_as(
        &mut self,
        pid: i32,
        role: Role,
        generation: u32,
        joining: Joining,
        scenario: PathBuf,
        program: bool,
    ) {
        let actions = self.core.handle(Event::Launched {
            pid,
            role,
            generation,
            joining,
            scenario,
            program,
        });
        assert!(actions.is_empty());
    }

    fn exit(&mut self, pid: i32, code: i32, ms: u64) -> Vec<Action> {
        let now = self.at(ms);
        self.core.handle(Event::Exited { pid, code, now })
    }

    /// The loop ticks: sample `seq` seen.
    fn sample(&mut self, seq: u64) {
        self.core.handle(Event::Estimate { seq: seq + 1 });
    }

    fn state(&mut self, role: Role, generation: u32, seq: u64, shadow: u32) {
        let state = Handover {
            generation,
            seq,
            shadow,
            ..Handover::default()
        };
        self.core.handle(Event::State {
            role,
            state: &state,
        });
    }

    fn tick(&mut self, ms: u64) -> Vec<Action> {
        let now = self.at(ms);
        self.core.handle(Event::Tick {
            now,
            stage: Stage::Restarts,
        })
    }

    fn upkeep(&mut self, ms: u64) -> Vec<Action> {
        let now = self.at(ms);
        Stage::IN_ORDER
            .iter()
            .filter(|s| !matches!(s, Stage::Silence | Stage::Restarts))
            .flat_map(|&stage| self.core.handle(Event::Tick { now, stage }))
            .collect()
    }

    fn member(&self, pid: i32) -> &super::super::roster::Member {
        self.core.roster().get(pid).unwrap()
    }
}

/// The records among `actions`, by kind.
fn kinds(actions: &[Action]) -> Vec<&'static str> {
    actions
        .iter()
        .filter_map(|a| match a {
            Action::Record(r) => Some(r.kind.name()),
            _ => None,
        })
        .collect()
}

fn record<'a>(actions: &'a [Action], kind: &str) -> &'a Record {
    actions
        .iter()
        .find_map(|a| match a {
            Action::Record(r) if r.kind.name() == kind => Some(r),
            _ => None,
        })
        .unwrap_or_else(|| panic!("no {kind} record in {actions:?}"))
}

impl Record {
    /// The record's detail as the events file writes it.
    fn detail(&self) -> Value {
        serde_json::to_value(&self.kind).unwrap()["detail"].clone()
    }
}

// ---- restart budget and back-off ----

#[test]
fn a_first_crash_is_settled_and_restarted_at_once() {
    let mut f = Fixture::new(policy());
    let actions = f.exit(OBSERVER, 137, 0);
    let crash = record(&actions, "crash");
    assert_eq!(crash.role, Role::Observer);
    assert_eq!(crash.generation, Some(0));
    assert_eq!(crash.detail()["exit"], 137);
    assert_eq!(crash.detail()["restart_in_ms"], 0);
    assert!(crash.clean_dead_nodes, "the dead node's memory is cleaned");
    assert!(f.member(OBSERVER).exit_expected());
    assert_eq!(f.tick(0), [Action::Restart(Role::Observer)]);
    // Taken once.
    assert!(f.tick(200).is_empty());
}

#[test]
fn a_crash_loop_backs_off_doubling_and_a_later_crash_is_a_fresh_fault() {
    let mut f = Fixture::new(Policy {
        max_restarts: 10,
        ..policy()
    });
    let wait = |actions: &[Action]| record(actions, "crash").detail()["restart_in_ms"].clone();
    assert_eq!(wait(&f.exit(OBSERVER, 1, 0)), 0);
    assert_eq!(f.tick(0), [Action::Restart(Role::Observer)]);
    // The restarted one crashes at once: a crash loop.
    f.launch(12, Role::Observer, 1, Joining::Restart);
    assert_eq!(wait(&f.exit(12, 1, 50)), 100);
    assert!(f.tick(149).is_empty());
    assert_eq!(f.tick(150), [Action::Restart(Role::Observer)]);
    f.launch(13, Role::Observer, 2, Joining::Restart);
    assert_eq!(wait(&f.exit(13, 1, 200)), 200);
    // Another role's first crash is its own.
    assert_eq!(wait(&f.exit(CONTROLLER, 1, 210)), 0);
    // Long after the last restart: at once again.
    f.launch(14, Role::Observer, 3, Joining::Restart);
    assert_eq!(wait(&f.exit(14, 1, 5_000)), 0);
}

#[test]
fn past_its_restart_budget_a_crash_is_recorded_fatal_and_left_to_the_supervisor() {
    let mut f = Fixture::new(Policy {
        max_restarts: 1,
        ..policy()
    });
    assert_eq!(kinds(&f.exit(OBSERVER, 1, 0)), ["crash"]);
    f.launch(12, Role::Observer, 1, Joining::Restart);
    let actions = f.exit(12, 1, 500);
    let crash = record(&actions, "crash");
    assert_eq!(crash.detail()["fatal"], "max_restarts spent (1 of 1)");
    assert!(crash.detail().get("restart_in_ms").is_none());
    assert!(
        !f.member(12).exit_expected(),
        "unsettled: the supervisor ends the run"
    );
    // Recorded once, whatever else happens before the run ends.
    assert!(f.exit(CONTROLLER, 0, 600).is_empty());
    assert!(f.core.end_operation(f.at(700)).is_empty());
}

/// A program that fails before its law ever runs on the loop (its
/// parameters, its set-up) would fail the same way again: reported once,
/// not restarted in a loop. One that followed the loop is restarted.
#[test]
fn a_program_that_dies_before_it_ever_followed_the_loop_is_not_restarted() {
    for role in [Role::Controller, Role::Observer] {
        let mut f = Fixture::new(policy());
        f.launch_program(50, role, 1, Joining::Restart);
        let actions = f.exit(50, 1, 0);
        let crash = record(&actions, "crash");
        assert!(
            crash.detail()["fatal"]
                .as_str()
                .unwrap()
                .contains("before it ever followed the loop"),
            "{role:?}: {crash:?}"
        );
        assert!(!f.member(50).exit_expected(), "the supervisor ends the run");
        assert!(f.tick(10_000).is_empty(), "{role:?}: restarted");
        // Recorded once.
        assert!(f.core.end_operation(f.at(20_000)).is_empty());

        // Once it followed (its state, in shadow or serving), a crash is an
        // ordinary one: restarted (rolled back, where a built-in served).
        let mut g = Fixture::new(policy());
        g.launch_program(51, role, 1, Joining::Restart);
        g.state(role, 1, 5, FOLLOWING);
        let crash = g.exit(51, 137, 0);
        assert!(record(&crash, "crash").detail().get("fatal").is_none());
        assert_eq!(g.tick(0), [Action::Restart(role)]);
        // A built-in process is restarted whether or not it followed.
        let mut h = Fixture::new(policy());
        h.launch(52, role, 1, Joining::Restart);
        assert!(
            record(&h.exit(52, 1, 0), "crash")
                .detail()
                .get("fatal")
                .is_none()
        );
    }
}

#[test]
fn with_restarts_off_or_for_the_plant_a_crash_is_fatal() {
    let mut never = Fixture::new(Policy {
        restart: RestartPolicy::Never,
        ..policy()
    });
    let crash = never.exit(CONTROLLER, 1, 0);
    assert_eq!(
        record(&crash, "crash").detail()["fatal"],
        "restart = \"never\""
    );
    assert!(!never.member(CONTROLLER).exit_expected());
    let mut f = Fixture::new(policy());
    let crash = f.exit(PLANT, 137, 0);
    assert_eq!(record(&crash, "crash").role, Role::Plant);
    assert_eq!(record(&crash, "crash").detail()["exit"], 137);
    assert!(!f.member(PLANT).exit_expected());
    assert!(f.tick(10_000).is_empty(), "never restarted");
}

#[test]
fn a_clean_exit_is_no_crash() {
    let mut f = Fixture::new(policy());
    assert!(f.exit(LOGGER, 0, 0).is_empty());
    assert!(f.tick(10_000).is_empty());
}

#[test]
fn a_failed_restart_is_tried_again_after_a_back_off() {
    let mut f = Fixture::new(policy());
    f.exit(CONTROLLER, 1, 0);
    assert_eq!(f.tick(0), [Action::Restart(Role::Controller)]);
    let actions = f.core.restart_failed(
        Role::Controller,
        &anyhow::anyhow!("no luck"),
        f.at(200),
        false,
    );
    assert_eq!(kinds(&actions), ["restart-failed"]);
    assert_eq!(
        record(&actions, "restart-failed").detail(),
        json!("no luck")
    );
    assert!(!actions.iter().any(|a| matches!(a, Action::EndRun(_))));
    // A failed restart continues a crash loop, however long it took.
    assert!(f.tick(299).is_empty());
    assert_eq!(f.tick(300), [Action::Restart(Role::Controller)]);
}

#[test]
fn a_failed_restart_past_the_budget_ends_the_run_and_one_at_a_stop_ends_it_as_asked() {
    let mut f = Fixture::new(Policy {
        max_restarts: 1,
        ..policy()
    });
    f.exit(CONTROLLER, 1, 0);
    let actions = f
        .core
        .restart_failed(Role::Controller, &anyhow::anyhow!("no"), f.at(100), false);
    assert!(actions.contains(&Action::EndRun(Outcome::ChildFailed(Role::Controller, -1))));
    let mut g = Fixture::new(policy());
    g.exit(OBSERVER, 1, 0);
    let actions = g
        .core
        .restart_failed(Role::Observer, &anyhow::anyhow!("no"), g.at(100), true);
    assert!(
        actions.contains(&Action::EndRun(Outcome::Interrupted)),
        "{actions:?}"
    );
    assert_eq!(kinds(&actions), ["restart-failed"]);
    // Past the budget too: the stop was asked first.
    let actions = f
        .core
        .restart_failed(Role::Controller, &anyhow::anyhow!("no"), f.at(200), true);
    assert!(
        actions.contains(&Action::EndRun(Outcome::Interrupted)),
        "{actions:?}"
    );
}

// ---- spares ----

fn warm() -> Policy {
    Policy {
        warm_spares: true,
        ..policy()
    }
}

#[test]
fn a_spare_is_ordered_only_once_it_reported_idle_and_the_loop_ticks() {
    let mut f = Fixture::new(warm());
    // Before tick 0 the plant counts on each spare to stay a spare.
    assert_eq!(
        f.core.engagement(Role::Observer, false, false),
        Engagement::Start
    );
    f.sample(0);
    // Still starting: worth waiting for, until the wait is over.
    assert_eq!(
        f.core.engagement(Role::Observer, false, false),
        Engagement::WaitForSpare
    );
    assert_eq!(
        f.core.engagement(Role::Observer, true, false),
        Engagement::Start
    );
    f.core.handle(Event::SpareIdle {
        pid: SPARE_OBSERVER,
    });
    assert_eq!(
        f.core.engagement(Role::Observer, false, false),
        Engagement::Order(SPARE_OBSERVER)
    );
    // Without warm spares, always a new process.
    let mut cold = Fixture::new(policy());
    cold.sample(0);
    assert_eq!(
        cold.core.engagement(Role::Observer, false, false),
        Engagement::Start
    );
}

#[test]
fn an_ordered_spare_serves_its_generation_and_its_crash_is_a_serving_crash() {
    let mut f = Fixture::new(warm());
    f.sample(0);
    f.core.handle(Event::SpareIdle {
        pid: SPARE_CONTROLLER,
    });
    let (old, generation) = f.core.plan_swap(Role::Controller).unwrap();
    assert_eq!((old, generation), (CONTROLLER, 1));
    f.core.ordered(
        SPARE_CONTROLLER,
        generation,
        Joining::Replacement,
        Path::new("new.toml"),
    );
    let m = f.member(SPARE_CONTROLLER);
    assert_eq!((m.duty, m.generation), (Duty::Active, Some(1)));
    assert_eq!(m.scenario, PathBuf::from("new.toml"));
    assert!(!m.exit_expected());
    assert_eq!(f.core.roster().next_generation(Role::Controller), 2);
    // The replaced one becomes a spare again: it reports itself idle.
    f.core.handle(Event::SpareIdle { pid: CONTROLLER });
    assert_eq!(
        f.core.roster().serving(Role::Controller).unwrap().pid,
        SPARE_CONTROLLER
    );
    let actions = f.exit(SPARE_CONTROLLER, 137, 10);
    assert_eq!(record(&actions, "crash").detail()["restart_in_ms"], 0);
}

#[test]
fn a_spare_crash_costs_the_spare_budget_and_another_spare_starts() {
    let mut f = Fixture::new(Policy {
        max_restarts: 1,
        ..warm()
    });
    f.core.handle(Event::SpareIdle {
        pid: SPARE_CONTROLLER,
    });
    let actions = f.exit(SPARE_CONTROLLER, 137, 0);
    let crash = record(&actions, "crash");
    assert_eq!(crash.detail()["spare"], true);
    assert_eq!(crash.generation, None, "a spare serves no generation yet");
    assert!(crash.detail().get("restart_in_ms").is_none());
    assert!(f.member(SPARE_CONTROLLER).exit_expected());
    // Not a restart: nothing due, and the active role's budget is intact.
    assert!(f.tick(10_000).is_empty());
    assert_eq!(f.upkeep(0), [Action::StartSpare(Role::Controller)]);
    // A second failure (to start, this time) exhausts the spare budget of 1.
    let failed = f
        .core
        .spare_started(Role::Controller, &Err(anyhow::anyhow!("no")));
    assert_eq!(kinds(&[failed]), ["spare-failed"]);
    assert!(f.upkeep(0).is_empty());
    // The controller's own restarts are untouched.
    assert_eq!(kinds(&f.exit(CONTROLLER, 1, 0)), ["crash"]);
}

#[test]
fn spares_are_kept_one_per_role_while_the_plant_runs() {
    let mut f = Fixture::new(warm());
    assert!(f.upkeep(0).is_empty(), "both spares live");
    f.exit(SPARE_OBSERVER, 1, 0);
    assert_eq!(f.upkeep(0), [Action::StartSpare(Role::Observer)]);
    let started = f.core.spare_started(Role::Observer, &Ok(12));
    assert_eq!(kinds(&[started]), ["spare"]);
    f.launch(12, Role::Observer, 0, Joining::Spare);
    assert!(f.upkeep(0).is_empty());
    // Not while the role's restart is pending, nor at the run's end.
    f.exit(12, 1, 0);
    f.exit(OBSERVER, 1, 0);
    assert!(f.upkeep(0).is_empty());
    let mut ending = Fixture::new(warm());
    ending.exit(SPARE_OBSERVER, 1, 0);
    ending.core.handle(Event::EndOfRun);
    assert!(ending.upkeep(0).is_empty());
    let mut no_plant = Fixture::new(warm());
    no_plant.exit(SPARE_OBSERVER, 1, 0);
    no_plant.exit(PLANT, 0, 0);
    assert!(no_plant.upkeep(0).is_empty());
}

// ---- boundaries ----

#[test]
fn a_swaps_boundary_is_50_ms_ahead_at_the_faster_of_rate_and_pace() {
    let mut f = Fixture::new(policy());
    f.sample(1000);
    assert_eq!(f.core.boundary_ahead(), 1000 + 500);
    // Lockstep runs faster than its rate: 20 000 samples in 200 ms.
    f.core.handle(Event::Polled { now: f.at(0) });
    f.sample(21_000);
    f.core.handle(Event::Polled { now: f.at(200) });
    assert_eq!(f.core.boundary_ahead(), 21_000 + 5000);
    // And never fewer than 50 samples ahead.
    let mut slow = Fixture::new(Policy {
        rate_hz: 100.0,
        ..policy()
    });
    slow.sample(7);
    assert_eq!(slow.core.boundary_ahead(), 57);
}

#[test]
fn a_restarts_boundary_is_right_after_the_dead_instances_last_state() {
    let mut f = Fixture::new(policy());
    assert_eq!(
        f.core.restart_boundary(Role::Controller),
        None,
        "before tick 0"
    );
    f.sample(100);
    assert_eq!(
        f.core.restart_boundary(Role::Controller),
        None,
        "never served"
    );
    f.state(Role::Controller, 0, 90, ACTIVE);
    f.state(Role::Observer, 0, 91, ACTIVE);
    // An older state arriving late changes nothing.
    f.state(Role::Controller, 0, 80, ACTIVE);
    // Its last command was for 90; the estimate after measurement 91 is 92's.
    assert_eq!(f.core.restart_boundary(Role::Controller), Some(91));
    assert_eq!(f.core.restart_boundary(Role::Observer), Some(93));
    assert_eq!(f.core.restart_boundary(Role::Logger), None);
    f.exit(CONTROLLER, 1, 0);
    f.tick(100);
    assert_eq!(
        f.core.plan_restart(Role::Controller, &no_program),
        Ok(RestartPlan::Fresh {
            scenario: PathBuf::from("loop.toml"),
            generation: 1,
            owns_from: Some(91),
            rolled_back_from: None,
        })
    );
}

#[test]
fn an_announced_boundary_keeps_the_owner_of_the_sample_before() {
    let mut f = Fixture::new(policy());
    let first = f.core.activation_for(Role::Controller, 1, 500);
    f.core.announced(first);
    let second = f.core.activation_for(Role::Controller, 2, 900);
    assert_eq!(second.previous_controller_generation, 1);
    assert_eq!(second.controller_generation, 2);
    assert_eq!(second.controller_from_seq, 900);
    // One announced before the first boundary passed keeps generation 0.
    let early = f.core.activation_for(Role::Controller, 2, 400);
    assert_eq!(early.previous_controller_generation, 0);
    let observer = f.core.activation_for(Role::Observer, 1, 300);
    assert_eq!(
        (
            observer.observer_generation,
            observer.previous_observer_generation
        ),
        (1, 0)
    );
    assert_eq!(f.core.activation().controller_generation, 1);
}

// ---- bringing an instance in, and out ----

#[test]
fn a_new_instance_follows_in_shadow_or_by_serving_at_once() {
    let mut f = Fixture::new(policy());
    f.sample(10);
    f.launch(22, Role::Controller, 1, Joining::Replacement);
    assert!(matches!(
        f.core.shadow_step(Role::Controller, 1, false),
        ShadowStep::Waiting { hand_over: None }
    ));
    f.state(Role::Controller, 1, 10, FOLLOWING);
    assert!(matches!(
        f.core.shadow_step(Role::Controller, 1, false),
        ShadowStep::Following
    ));
    // A restart owns samples at once: it is seen active.
    f.launch(12, Role::Observer, 1, Joining::Restart);
    f.state(Role::Observer, 1, 11, ACTIVE);
    assert!(matches!(
        f.core.shadow_step(Role::Observer, 1, false),
        ShadowStep::Following
    ));
}

#[test]
fn a_dead_predecessors_last_state_is_handed_to_its_replacement() {
    let mut f = Fixture::new(policy());
    f.sample(10);
    f.state(Role::Observer, 0, 9, ACTIVE);
    f.launch(12, Role::Observer, 1, Joining::Restart);
    // Alive, it hands over itself.
    assert!(matches!(
        f.core.shadow_step(Role::Observer, 1, false),
        ShadowStep::Waiting { hand_over: None }
    ));
    f.exit(OBSERVER, 137, 0);
    match f.core.shadow_step(Role::Observer, 1, false) {
        ShadowStep::Waiting {
            hand_over: Some(last),
        } => assert_eq!((last.generation, last.seq), (0, 9)),
        other => panic!("{other:?}"),
    }
}

#[test]
fn a_new_instance_that_exits_or_a_run_that_ends_fails_the_wait() {
    let mut f = Fixture::new(policy());
    f.sample(10);
    f.launch(22, Role::Controller, 1, Joining::Replacement);
    f.core.begin_operation();
    f.exit(22, 3, 0);
    match f.core.shadow_step(Role::Controller, 1, false) {
        ShadowStep::Failed(failure) => assert_eq!(
            failure,
            Failure::NewInstanceExited {
                role: Role::Controller,
                generation: 1,
                pid: 22,
                code: 3
            }
        ),
        other => panic!("{other:?}"),
    }
    assert!(
        f.member(22).exit_expected(),
        "its exit is the swap's failure, not the run's"
    );
    assert!(f.core.end_operation(f.at(0)).is_empty());
    assert!(matches!(
        f.core.shadow_step(Role::Observer, 1, true),
        ShadowStep::Failed(Failure::RunEndedBeforeFollowing)
    ));
    f.exit(PLANT, 0, 0);
    assert!(matches!(
        f.core.shadow_step(Role::Observer, 1, false),
        ShadowStep::Failed(Failure::RunEndedBeforeFollowing)
    ));
}

#[test]
fn the_loop_passes_a_boundary_once_measured_past_it_and_the_old_one_left() {
    let mut f = Fixture::new(warm());
    f.sample(1000);
    assert_eq!(
        f.core.drain_step(1000, Some(CONTROLLER), false),
        DrainStep::Waiting
    );
    // The plant applies the new owner's command for 1000 at tick 1001.
    f.applied(990..1102, 0);
    f.sample(1101);
    assert_eq!(
        f.core.drain_step(1000, Some(CONTROLLER), false),
        DrainStep::Waiting,
        "the old one still serves"
    );
    f.applied(1102..1103, 0);
    f.sample(1102);
    // With warm spares it becomes a spare instead of exiting.
    f.core.handle(Event::SpareIdle { pid: CONTROLLER });
    assert_eq!(
        f.core.drain_step(1000, Some(CONTROLLER), false),
        DrainStep::Passed
    );
    assert_eq!(f.core.drain_step(1000, None, false), DrainStep::Passed);
    assert_eq!(f.core.drain_step(2000, None, true), DrainStep::RunEnded);
}

impl Fixture {
    /// The plant's ticks `seqs`, each applying the command for the sample
    /// before, or with `held` > 0 holding the command for `held`; the value
    /// applied is the command's sample number.
    fn applied(&mut self, seqs: std::ops::Range<u64>, held: u64) {
        for seq in seqs {
            let command_seq = if held > 0 { held } else { seq - 1 };
            let mut u = [0.0; MAX_INPUTS];
            u[0] = command_seq as f64;
            self.core.handle(Event::Applied {
                seq,
                command_seq,
                u,
                fresh: command_seq + 1 == seq,
                answered_late: false,
                stalled: false,
            });
        }
    }
}

/// A restart whose replacement comes ticks after its boundary (the plant
/// held meanwhile) is measured where the plant first applied its command,
/// not at the boundary, where nothing of it was applied yet.
#[test]
fn a_restart_after_a_hold_is_measured_where_its_first_command_applied() {
    let mut f = Fixture::new(policy());
    // The dead instance's last command was for 999; held until tick 1300,
    // whose command (for 1299) is the replacement's first.
    f.applied(900..1001, 0);
    f.applied(1001..1300, 999);
    f.sample(1299);
    assert_eq!(f.core.drain_step(1000, None, false), DrainStep::Waiting);
    f.applied(1300..1401, 0);
    f.sample(1400);
    assert_eq!(f.core.drain_step(1000, None, false), DrainStep::Waiting);
    f.applied(1401..1402, 0);
    f.sample(1401);
    assert_eq!(f.core.drain_step(1000, None, false), DrainStep::Passed);
    let switch = f.core.switch(Role::Controller, 1, 1000, 1000, true);
    // From the held 999 to 1299 at tick 1300; 1 per tick before and after.
    assert_eq!(switch.du_switch, 300.0);
    assert_eq!(switch.du_after, 1.0);
}

#[test]
fn a_swap_needs_a_live_instance_to_replace() {
    let mut f = Fixture::new(policy());
    assert_eq!(f.core.plan_swap(Role::Observer), Ok((OBSERVER, 1)));
    f.core.begin_operation();
    f.exit(OBSERVER, 1, 0);
    assert_eq!(
        f.core.plan_swap(Role::Observer),
        Err(Failure::NotRunning(Role::Observer))
    );
}

// ---- crashes during a swap ----

#[test]
fn a_crash_during_a_swap_is_settled_when_the_swap_ends() {
    let mut f = Fixture::new(policy());
    f.core.begin_operation();
    assert!(f.exit(OBSERVER, 137, 0).is_empty());
    assert!(!f.member(OBSERVER).exit_expected(), "not settled yet");
    assert!(f.tick(1000).is_empty(), "no restart scheduled yet");
    let actions = f.core.end_operation(f.at(1000));
    assert_eq!(kinds(&actions), ["crash"]);
    assert!(f.member(OBSERVER).exit_expected());
    assert_eq!(f.tick(1100), [Action::Restart(Role::Observer)]);
}

#[test]
fn the_instance_a_swap_replaces_exits_as_planned() {
    let mut f = Fixture::new(policy());
    f.core.begin_operation();
    f.core.settle(CONTROLLER);
    // Killed at the drain's timeout: no crash, no restart.
    f.exit(CONTROLLER, 143, 0);
    assert!(f.core.end_operation(f.at(0)).is_empty());
    assert!(f.tick(10_000).is_empty());
}

// ---- standby ----

fn standby() -> Policy {
    Policy {
        keep_standby: true,
        ..policy()
    }
}

#[test]
fn a_standby_is_kept_once_the_loop_ticks() {
    let mut f = Fixture::new(standby());
    assert!(f.upkeep(0).is_empty(), "not before tick 0");
    f.sample(0);
    assert_eq!(
        f.upkeep(0),
        [Action::StartStandby {
            scenario: PathBuf::from("loop.toml"),
            generation: 1
        }]
    );
    let standby = f.standby(1);
    assert_eq!(kinds(&standby.actions), ["standby"]);
    assert!(f.upkeep(0).is_empty(), "one is enough");
    assert_eq!(
        f.core.roster().serving(Role::Controller).unwrap().pid,
        CONTROLLER,
        "a standby is not the role's instance"
    );
}

#[test]
fn a_standby_that_fails_to_start_costs_the_restart_budget() {
    let mut f = Fixture::new(Policy {
        max_restarts: 0,
        ..standby()
    });
    f.sample(0);
    assert_eq!(f.upkeep(0).len(), 1);
    f.begin(sequences::standby_order(1)).unwrap();
    assert!(matches!(f.advance(0), Step::Carry(Command::Launch { .. })));
    f.carried(Carried::Failed("no".into()), 0);
    let failed = f.done(0);
    assert_eq!(kinds(&failed.actions), ["standby-failed"]);
    assert_eq!(failed.result, Ok(None), "the loop goes on without");
    assert!(f.upkeep(0).is_empty(), "past the budget");
}

#[test]
fn a_standby_crash_costs_the_restart_budget_and_another_standby_starts() {
    let mut f = Fixture::new(standby());
    f.sample(0);
    f.launch(23, Role::Controller, 1, Joining::Standby);
    let actions = f.exit(23, 137, 0);
    assert_eq!(record(&actions, "crash").detail()["standby"], true);
    assert!(f.member(23).exit_expected());
    assert!(f.tick(10_000).is_empty(), "not restarted as such");
    assert!(matches!(
        f.upkeep(0)[..],
        [Action::StartStandby { generation: 2, .. }]
    ));
}

#[test]
fn a_crashed_controller_promotes_the_standby_that_follows() {
    let mut f = Fixture::new(standby());
    f.sample(100);
    f.launch(23, Role::Controller, 1, Joining::Standby);
    f.exit(CONTROLLER, 137, 0);
    f.tick(100);
    // Not following yet: a new controller instead.
    assert!(matches!(
        f.core.plan_restart(Role::Controller, &no_program),
        Ok(RestartPlan::Fresh { generation: 2, .. })
    ));
    f.state(Role::Controller, 1, 100, FOLLOWING);
    assert_eq!(
        f.core.plan_restart(Role::Controller, &no_program),
        Ok(RestartPlan::Promote { generation: 1 })
    );
    assert_eq!(f.member(23).duty, Duty::Active);
    assert_eq!(f.core.roster().serving(Role::Controller).unwrap().pid, 23);
    // Then another standby follows the promoted one.
    assert!(matches!(
        f.upkeep(200)[..],
        [Action::StartStandby { generation: 2, .. }]
    ));
}

#[test]
fn no_standby_starts_while_the_controllers_restart_is_pending() {
    let mut f = Fixture::new(standby());
    f.sample(0);
    f.exit(CONTROLLER, 1, 0);
    assert!(f.upkeep(0).is_empty());
}

#[test]
fn a_swap_to_another_design_renews_the_standby() {
    let mut f = Fixture::new(Policy {
        warm_spares: true,
        ..standby()
    });
    f.sample(0);
    f.launch(23, Role::Controller, 1, Joining::Standby);
    assert_eq!(f.core.standby_renewal(), None, "same design");
    // The swap: a spare now serves another design.
    f.core.handle(Event::SpareIdle {
        pid: SPARE_CONTROLLER,
    });
    f.core.ordered(
        SPARE_CONTROLLER,
        2,
        Joining::Replacement,
        Path::new("retuned.toml"),
    );
    f.core.handle(Event::SpareIdle { pid: CONTROLLER });
    assert_eq!(
        f.core.standby_renewal(),
        Some(Renewal {
            scenario: PathBuf::from("retuned.toml"),
            generation: 3,
            old: vec![(23, 1)],
        })
    );
}

#[test]
fn a_retiring_standby_becomes_a_spare_or_is_stopped_when_late() {
    let mut f = Fixture::new(Policy {
        warm_spares: true,
        ..standby()
    });
    assert_eq!(f.core.retirement(), Retirement::Order);
    f.launch(23, Role::Controller, 1, Joining::Standby);
    f.launch(24, Role::Controller, 2, Joining::Standby);
    f.core.retiring(23, f.at(0));
    f.core.retiring(24, f.at(0));
    assert!(f.upkeep(2000).iter().all(|a| !matches!(a, Action::Stop(_))));
    // 23 became a spare in time; 24 did not.
    f.core.handle(Event::SpareIdle { pid: 23 });
    let actions = f.upkeep(2001);
    assert!(actions.contains(&Action::Stop(24)));
    assert!(!actions.contains(&Action::Stop(23)));
    assert!(f.member(24).exit_expected());
    // Dealt with once.
    assert!(!f.upkeep(5000).contains(&Action::Stop(24)));
    let cold = Fixture::new(standby());
    assert_eq!(cold.core.retirement(), Retirement::Stop);
}

// ---- what a restart brings back ----

/// No scenario names a program of its own.
fn no_program(_: &Path) -> bool {
    false
}

#[test]
fn a_crashed_program_is_rolled_back_to_the_built_in_design_before_it() {
    let mut f = Fixture::new(policy());
    f.sample(10);
    // Generation 1, a program of one's own, took over from the built-in 0.
    f.launch_with(
        22,
        Role::Controller,
        1,
        Joining::Replacement,
        "own.toml".into(),
    );
    let owner = f.core.activation_for(Role::Controller, 1, 50);
    f.core.announced(owner);
    f.exit(CONTROLLER, 0, 0);
    f.exit(22, 137, 0);
    let is_program = |p: &Path| p == Path::new("own.toml");
    assert_eq!(
        f.core.plan_restart(Role::Controller, &is_program),
        Ok(RestartPlan::Fresh {
            scenario: PathBuf::from("loop.toml"),
            generation: 2,
            owns_from: None,
            rolled_back_from: Some(PathBuf::from("own.toml")),
        })
    );
    // A loop that started on the program has nothing to roll back to: the
    // program comes back.
    let mut g = Fixture::new(policy());
    g.sample(10);
    g.exit(CONTROLLER, 137, 0);
    let all_programs = |_: &Path| true;
    assert!(matches!(
        g.core.plan_restart(Role::Controller, &all_programs),
        Ok(RestartPlan::Fresh {
            rolled_back_from: None,
            ..
        })
    ));
}

#[test]
fn a_restart_runs_the_file_of_the_generation_that_owned_the_loop() {
    let mut f = Fixture::new(policy());
    f.sample(10);
    // Generation 1 (another design) took over from generation 0.
    f.launch_with(
        22,
        Role::Controller,
        1,
        Joining::Replacement,
        "retuned.toml".into(),
    );
    let owner = f.core.activation_for(Role::Controller, 1, 50);
    f.core.announced(owner);
    f.exit(CONTROLLER, 0, 0);
    f.exit(22, 137, 0);
    match f.core.plan_restart(Role::Controller, &no_program) {
        Ok(RestartPlan::Fresh {
            scenario,
            generation,
            ..
        }) => assert_eq!((scenario, generation), (PathBuf::from("retuned.toml"), 2)),
        other => panic!("{other:?}"),
    }
    f.exit(LOGGER, 1, 0);
    assert_eq!(
        f.core.plan_restart(Role::Logger, &no_program),
        Ok(RestartPlan::Logger {
            scenario: PathBuf::from("loop.toml"),
            generation: 1
        })
    );
}

// ---- what the core sees ----

#[test]
fn the_step_at_a_switch_is_the_one_the_plant_applied() {
    let mut f = Fixture::new(policy());
    let applied = |seq: u64, command_seq: u64, u0: f64| {
        let mut u = [0.0; MAX_INPUTS];
        u[0] = u0;
        Event::Applied {
            seq,
            command_seq,
            u,
            fresh: true,
            answered_late: false,
            stalled: false,
        }
    };
    for seq in 1..10 {
        f.core.handle(Event::Command {
            seq,
            generation: 0,
            finite: true,
        });
        f.core.handle(applied(seq, seq - 1, 1.0));
    }
    // The new owner's first command (10) acts on sample 11.
    f.core.handle(applied(10, 9, 1.0));
    f.core.handle(Event::Command {
        seq: 10,
        generation: 1,
        finite: true,
    });
    f.core.handle(applied(11, 10, 3.0));
    assert_eq!(f.core.last_seq(), Some(10));
    let switch = f.core.switch(Role::Controller, 1, 5, 10, true);
    assert_eq!((switch.du_switch, switch.du_before), (2.0, 0.0));
}

#[test]
fn the_process_list_shows_live_processes_and_their_duties() {
    let mut f = Fixture::new(warm());
    f.exit(LOGGER, 0, 0);
    let list = f.core.roster().processes();
    let duties: Vec<(&str, &str, Option<u32>)> = list
        .processes
        .iter()
        .map(|p| (p.role.as_str(), p.duty.as_str(), p.generation))
        .collect();
    assert_eq!(
        duties,
        [
            ("observer", "active", Some(0)),
            ("controller", "active", Some(0)),
            ("observer", "spare", None),
            ("controller", "spare", None),
            ("plant", "active", Some(0)),
        ]
    );
}

#[test]
fn a_spare_taken_as_the_standby_is_replaced_at_the_next_stage_of_the_same_tick() {
    let mut f = Fixture::new(Policy {
        warm_spares: true,
        ..standby()
    });
    f.sample(0);
    f.core.handle(Event::SpareIdle {
        pid: SPARE_CONTROLLER,
    });
    let now = f.at(0);
    let standby = f.core.handle(Event::Tick {
        now,
        stage: Stage::Standby,
    });
    assert!(matches!(
        standby[..],
        [Action::StartStandby { generation: 1, .. }]
    ));
    // A scenario with its own controller program never goes to a spare
    // (which runs the built-in law)...
    assert_eq!(
        f.core.engagement(Role::Controller, false, true),
        Engagement::Start
    );
    // The shell orders the spare to stand by...
    assert_eq!(
        f.core.engagement(Role::Controller, false, false),
        Engagement::Order(SPARE_CONTROLLER)
    );
    f.core.ordered(
        SPARE_CONTROLLER,
        1,
        Joining::Standby,
        Path::new("loop.toml"),
    );
    assert_eq!(f.member(SPARE_CONTROLLER).duty, Duty::Standby);
    // ...and the spares' stage, decided after that, starts another spare.
    let spares = f.core.handle(Event::Tick {
        now,
        stage: Stage::Spares,
    });
    assert_eq!(spares, [Action::StartSpare(Role::Controller)]);
}

// ---- hung components ----

impl Fixture {
    /// The loop's ticks `from..to` as the plant reports them, with a fresh
    /// command or not, and the observer's estimates or not; then a poll at `ms`.
    fn ticks(&mut self, from: u64, to: u64, commands: bool, estimates: bool, ms: u64) {
        self.ticks_answered(from, to, commands, false, estimates, ms);
    }

    /// As [`Fixture::ticks`]; `late`: the controller's commands came, each
    /// too late to apply (the plant held its input).
    fn ticks_answered(
        &mut self,
        from: u64,
        to: u64,
        commands: bool,
        late: bool,
        estimates: bool,
        ms: u64,
    ) {
        for seq in from..to {
            self.core.handle(Event::Applied {
                seq,
                command_seq: if commands { seq - 1 } else { from - 1 },
                u: [0.0; MAX_INPUTS],
                fresh: commands,
                answered_late: late,
                stalled: false,
            });
            if estimates {
                self.core.handle(Event::Estimate { seq: seq + 1 });
            }
        }
        let now = self.at(ms);
        self.core.handle(Event::Polled { now });
    }

    fn silence_stage(&mut self, ms: u64) -> Vec<Action> {
        let now = self.at(ms);
        self.core.handle(Event::Tick {
            now,
            stage: Stage::Silence,
        })
    }
}

/// A hung controller (alive, no command: stopped, deadlocked, a law that
/// sleeps) is found from the plant's held ticks, killed, and its exit
/// dealt with as a crash whose cause is its silence: restarted.
#[test]
fn a_hung_controller_is_killed_and_restarted_as_after_a_crash() {
    let mut f = Fixture::new(policy());
    f.ticks(1, 100, true, true, 0);
    assert!(f.silence_stage(0).is_empty());
    // Held ticks, fewer than the rule's 20: nothing yet.
    f.ticks(100, 115, false, true, 2);
    assert!(f.silence_stage(2).is_empty());
    f.ticks(115, 130, false, true, 4);
    let actions = f.silence_stage(4);
    let silent = record(&actions, "silent");
    assert_eq!(silent.role, Role::Controller);
    assert_eq!(silent.detail()["pid"], CONTROLLER);
    assert_eq!(silent.detail()["ticks_without_output"], 30);
    assert!(actions.contains(&Action::Kill(CONTROLLER)));
    // Dealt with at once as a crash of cause "silent" (SIGKILL leaves it no
    // instruction to run: its exit report is not waited for): a restart.
    let crash = record(&actions, "crash");
    assert_eq!(crash.detail()["cause"], "silent");
    assert_eq!(crash.detail()["found"], "silent");
    assert_eq!(crash.detail()["exit"], Value::Null);
    assert_eq!(crash.detail()["restart_in_ms"], 0);
    assert!(!f.member(CONTROLLER).alive());
    assert_eq!(f.tick(4), [Action::Restart(Role::Controller)]);
    // Judged once; its exit report, when it comes, changes nothing.
    f.ticks(130, 200, false, true, 6);
    assert!(f.silence_stage(6).is_empty());
    assert!(f.exit(CONTROLLER, 137, 7).is_empty());
    assert_eq!(f.member(CONTROLLER).exit, Some(137));
    assert!(f.tick(8).is_empty());
}

/// A controller whose every command comes too late to apply (a command
/// deadline the machine cannot meet) is alive: the plant holds its input
/// and counts the misses, and the supervisor does not kill it as hung.
#[test]
fn a_controller_whose_commands_come_late_is_not_silent() {
    let mut f = Fixture::new(policy());
    f.ticks(1, 100, true, true, 0);
    f.ticks_answered(100, 400, false, true, true, 30);
    assert!(f.silence_stage(30).is_empty());
    assert!(f.member(CONTROLLER).alive());
    // When they stop coming, it is silent.
    f.ticks(400, 430, false, true, 33);
    assert_eq!(
        record(&f.silence_stage(33), "silent").role,
        Role::Controller
    );
}

impl Fixture {
    fn process_state(&mut self, pid: i32, state: ProcessState, ms: u64) -> Vec<Action> {
        self.process_waited(pid, state, None, ms)
    }

    fn process_waited(
        &mut self,
        pid: i32,
        state: ProcessState,
        runqueue_wait_ns: Option<u64>,
        ms: u64,
    ) -> Vec<Action> {
        let now = self.at(ms);
        self.core.handle(Event::ProcessState {
            pid,
            state,
            runqueue_wait_ns,
            now,
        })
    }
}

/// The kernel shows a killed or crashed process in its exit milliseconds
/// before it reports the exit: it is dealt with as crashed from there.
#[test]
fn a_process_seen_exiting_is_a_crash_before_its_exit_report() {
    let mut f = Fixture::new(policy());
    f.ticks(1, 100, true, true, 0);
    assert!(
        f.process_state(CONTROLLER, ProcessState::Live, 1)
            .is_empty()
    );
    let actions = f.process_state(CONTROLLER, ProcessState::Exiting, 2);
    assert!(!actions.contains(&Action::Kill(CONTROLLER)), "{actions:?}");
    let crash = record(&actions, "crash");
    assert_eq!(crash.detail()["cause"], "crashed");
    assert_eq!(crash.detail()["found"], "exiting");
    assert_eq!(crash.detail()["exit"], Value::Null);
    assert_eq!(f.tick(2), [Action::Restart(Role::Controller)]);
    // Seen again, then reported: once only.
    assert!(
        f.process_state(CONTROLLER, ProcessState::Exiting, 3)
            .is_empty()
    );
    assert!(f.exit(CONTROLLER, 137, 4).is_empty());
    assert!(f.tick(5).is_empty());
    // Watched: the live, unsettled processes but the plant.
    let mut watched = f.core.watched_processes();
    watched.sort();
    assert_eq!(watched, [OBSERVER, LOGGER]);
}

/// A stopped process (SIGSTOP, a debugger) is hung whatever the loop's
/// ticks say yet: killed and dealt with at once.
#[test]
fn a_stopped_process_is_killed_and_restarted_at_once() {
    for (pid, role) in [
        (OBSERVER, Role::Observer),
        (CONTROLLER, Role::Controller),
        (LOGGER, Role::Logger),
    ] {
        let mut f = Fixture::new(policy());
        f.ticks(1, 100, true, true, 0);
        f.ticks(100, 103, false, true, 1);
        let actions = f.process_state(pid, ProcessState::Stopped, 1);
        assert!(actions.contains(&Action::Kill(pid)), "{actions:?}");
        let silent = record(&actions, "silent");
        assert_eq!(silent.role, role);
        assert_eq!(silent.detail()["stopped"], true);
        let crash = record(&actions, "crash");
        assert_eq!(crash.detail()["cause"], "silent");
        assert_eq!(crash.detail()["found"], "stopped");
        assert_eq!(f.tick(1), [Action::Restart(role)]);
    }
}

/// Not during a swap or restart (it may be the one that deals with it),
/// nor once the run ends (its processes exit then), nor for a process whose
/// exit is planned (replaced, stopped).
#[test]
fn process_states_are_not_judged_when_an_exit_is_expected() {
    let mut f = Fixture::new(policy());
    f.ticks(1, 100, true, true, 0);
    f.core.begin_operation();
    assert!(f.core.watched_processes().is_empty());
    assert!(
        f.process_state(CONTROLLER, ProcessState::Exiting, 1)
            .is_empty()
    );
    assert!(f.core.end_operation(f.at(2)).is_empty());
    f.core.settle(OBSERVER);
    assert!(
        f.process_state(OBSERVER, ProcessState::Exiting, 3)
            .is_empty()
    );
    assert!(
        f.process_state(OBSERVER, ProcessState::Stopped, 3)
            .is_empty()
    );
    f.core.handle(Event::EndOfRun);
    assert!(f.core.watched_processes().is_empty());
    assert!(
        f.process_state(CONTROLLER, ProcessState::Exiting, 4)
            .is_empty()
    );
}

/// A controller whose every command is NaN sends, but the plant refuses
/// all of it: silent for the loop, and its silence's cause is said.
#[test]
fn a_controller_sending_only_non_finite_commands_is_silent_of_that_cause() {
    let mut f = Fixture::new(policy());
    f.ticks(1, 100, true, true, 0);
    for seq in 100..130 {
        f.core.handle(Event::Command {
            seq,
            generation: 0,
            finite: false,
        });
        // A standby's (or a stray's) finite commands say nothing of the owner.
        f.core.handle(Event::Command {
            seq,
            generation: 1,
            finite: true,
        });
    }
    f.ticks(100, 130, false, true, 4);
    // Starved or not: it gets the CPU to send.
    f.process_waited(CONTROLLER, ProcessState::Live, Some(0), 2);
    f.process_waited(CONTROLLER, ProcessState::Live, Some(2_000_000), 4);
    let actions = f.silence_stage(4);
    let silent = record(&actions, "silent");
    assert_eq!(silent.detail()["cause"], "non-finite output");
    assert_eq!(silent.detail()["non_finite_commands_in_a_row"], 30);
    assert_eq!(
        record(&actions, "crash").detail()["cause"],
        "non-finite output"
    );
    assert_eq!(f.tick(4), [Action::Restart(Role::Controller)]);
    // A finite command in between resets it: a plain silence.
    let mut g = Fixture::new(policy());
    g.ticks(1, 100, true, true, 0);
    for (seq, finite) in [(100, false), (101, true)] {
        g.core.handle(Event::Command {
            seq,
            generation: 0,
            finite,
        });
    }
    g.ticks(100, 130, false, true, 4);
    let actions = g.silence_stage(4);
    assert_eq!(record(&actions, "crash").detail()["cause"], "silent");
}

/// A controller silent because a busy machine gives it no CPU (it waited
/// on a runqueue for most of the last look) is starved, not hung: not
/// judged until it gets the CPU and still sends nothing.
#[test]
fn a_starved_controller_is_not_judged_silent() {
    let mut f = Fixture::new(policy());
    f.ticks(1, 100, true, true, 0);
    f.process_waited(CONTROLLER, ProcessState::Live, Some(0), 0);
    f.ticks(100, 130, false, true, 20);
    // 15 of the 20 ms waiting for a CPU.
    f.process_waited(CONTROLLER, ProcessState::Live, Some(15_000_000), 20);
    assert!(f.silence_stage(20).is_empty());
    // 2 of the next 20 ms: it had the CPU, and sent nothing.
    f.ticks(130, 160, false, true, 40);
    f.process_waited(CONTROLLER, ProcessState::Live, Some(17_000_000), 40);
    let actions = f.silence_stage(40);
    assert!(actions.contains(&Action::Kill(CONTROLLER)), "{actions:?}");
}

#[test]
fn a_hung_observer_is_judged_first_and_a_crash_is_a_crash() {
    let mut f = Fixture::new(policy());
    f.ticks(1, 100, true, true, 0);
    // In realtime the controller runs on without estimates: only the
    // observer falls behind.
    f.ticks(100, 150, true, false, 5);
    let actions = f.silence_stage(5);
    assert_eq!(record(&actions, "silent").role, Role::Observer);
    assert!(actions.contains(&Action::Kill(OBSERVER)));
    // A process that dies of itself is a crash of cause "crashed".
    let mut g = Fixture::new(policy());
    g.ticks(1, 100, true, true, 0);
    let crash = g.exit(CONTROLLER, 139, 1);
    assert_eq!(record(&crash, "crash").detail()["cause"], "crashed");
}

#[test]
fn no_silence_is_judged_during_a_swap_or_restart_and_a_new_instance_has_its_own_clock() {
    let mut f = Fixture::new(policy());
    f.ticks(1, 100, true, true, 0);
    f.core.begin_operation();
    f.ticks(100, 200, false, true, 10);
    assert!(f.silence_stage(10).is_empty(), "busy");
    assert!(f.core.end_operation(f.at(11)).is_empty());
    // From the end of the operation on: only further silent ticks count.
    f.ticks(200, 210, false, true, 12);
    assert!(f.silence_stage(12).is_empty());
    f.ticks(210, 230, false, true, 14);
    assert!(!f.silence_stage(14).is_empty());
}

#[test]
fn a_hung_controller_with_a_standby_hands_the_loop_to_it() {
    let mut f = Fixture::new(standby());
    f.launch(25, Role::Controller, 1, Joining::Standby);
    f.state(Role::Controller, 1, 50, FOLLOWING);
    f.ticks(1, 100, true, true, 0);
    f.ticks(100, 130, false, true, 3);
    let actions = f.silence_stage(3);
    assert!(actions.contains(&Action::Kill(CONTROLLER)), "{actions:?}");
    assert_eq!(f.tick(3), [Action::Restart(Role::Controller)]);
    let is_program = |_: &Path| false;
    assert_eq!(
        f.core.plan_restart(Role::Controller, &is_program),
        Ok(RestartPlan::Promote { generation: 1 })
    );
}

mod sequences;
