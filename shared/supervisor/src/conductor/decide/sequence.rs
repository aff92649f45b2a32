//! The swap, restart and standby sequences as states of the decision core.
//!
//! A sequence brings an instance into the running loop: engage it (order an
//! idle spare or start a process), wait until it follows the loop in shadow
//! (handing it a dead predecessor's last state meanwhile), announce the
//! sample from which it owns the loop, and wait until the loop passed that
//! boundary (and the replaced instance left). Each kind takes its own path
//! through those states (docs/architecture.md, "Swapping live"); the core
//! advances it on what the shell saw, and the shell only carries out the
//! commands it returns ([`Command`]) and reports how they went
//! ([`Carried`]). Time comes in with each look, so every timeout is a
//! decision here, and the tests drive whole sequences without a process.
//!
//! One sequence at a time: a second order while one runs is refused
//! ([`Failure::Busy`]) and waits in the request queue; crashes seen meanwhile
//! are settled when it ends (it may be the one that deals with them).

use super::steps::{DrainStep, Engagement, Failure, RestartPlan, Retirement, ShadowStep};
use super::{Action, Core, DRAIN_TIMEOUT, SHADOW_TIMEOUT};
use crate::conductor::switch::Switch;
use flexloop_node::Role;
use flexloop_protocol::{Activation, Handover, Joining};
use flexloop_runfiles::events::{EventKind, Restart, Standby, Swap};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How long a swap or restart waits for a spare that is still starting.
pub const SPARE_START_WAIT: Duration = Duration::from_secs(5);
/// How often a sequence looks at the loop while it waits for it to tick,
/// for a spare, for a shadow, for a boundary. A shadow is looked for every
/// 0.2 ms: a restarted observer waits for the state and the replayed
/// measurements handed on at each look, and a restart's every millisecond is
/// 10 held ticks (the supervisor runs off the loop's CPU, for the few
/// milliseconds a restart takes).
const TICKING_LOOK: Duration = Duration::from_millis(5);
const SPARE_LOOK: Duration = Duration::from_millis(1);
const SHADOW_LOOK: Duration = Duration::from_micros(200);
const DRAIN_LOOK: Duration = Duration::from_millis(2);

/// What a sequence is asked to do.
#[derive(Debug, Clone, PartialEq)]
pub enum Order {
    /// Replace the serving `role` by an instance running `scenario`
    /// (`flexloop swap`, or a set's hand-over).
    Swap { role: Role, scenario: PathBuf },
    /// Bring `role` back after its crash.
    Restart(Role),
    /// Bring up a standby controller ([`Action::StartStandby`]).
    Standby { scenario: PathBuf, generation: u32 },
}

impl Order {
    /// The role it brings an instance of.
    pub fn role(&self) -> Role {
        match self {
            Order::Swap { role, .. } | Order::Restart(role) => *role,
            Order::Standby { .. } => Role::Controller,
        }
    }
}

/// What the shell sees when it looks (the channels and processes are
/// looked at before).
#[derive(Debug, Clone, Copy)]
pub struct Look {
    pub now: Instant,
    /// The supervisor was asked to stop.
    pub shutting_down: bool,
}

/// What the shell is to carry out for a sequence, reporting with
/// [`Core::carried`] before it advances again.
#[derive(Debug, Clone)]
pub enum Command {
    /// Start a process: [`Carried::Launched`] with its pid.
    Launch {
        role: Role,
        scenario: PathBuf,
        generation: u32,
        joining: Joining,
    },
    /// Order the idle spare `pid` to join: [`Carried::Done`].
    Order {
        pid: i32,
        generation: u32,
        joining: Joining,
        scenario: PathBuf,
    },
    /// Publish the activation: [`Carried::Published`] with what went out.
    Publish(Activation),
    /// Publish a dead predecessor's last state for its replacement (and,
    /// to an observer, the measurements since): [`Carried::Done`].
    HandOver {
        role: Role,
        generation: u32,
        state: Box<Handover>,
    },
    /// Order a serving standby to become a spare: [`Carried::Done`], or
    /// [`Carried::Failed`] if the order cannot go out.
    Retire(i32),
    /// Stop a process whose exit is dealt with: [`Carried::Done`].
    Stop(i32),
}

/// How a [`Command`] went.
#[derive(Debug, Clone)]
pub enum Carried {
    Done,
    Launched(i32),
    Published(Activation),
    /// Why it could not be carried out.
    Failed(String),
}

/// Where a sequence stands, as the shell reads it.
#[derive(Debug, Clone)]
pub enum Step {
    /// Carry this out and report ([`Core::carried`]), then advance at once.
    Carry(Command),
    /// Look at the loop again after this long, then advance.
    Wait(Duration),
    /// The sequence is over.
    Done(SequenceEnd),
}

/// How a sequence ended.
#[derive(Debug, Clone, PartialEq)]
pub struct SequenceEnd {
    /// The events to record, then the crashes settled now that it is over.
    pub actions: Vec<Action>,
    /// The switch it made (none for a standby, a logger, or a restart
    /// before tick 0), or why it failed.
    pub result: Result<Option<Switch>, Failure>,
}

/// What the sequence brings in, and what it records when it is done.
#[derive(Debug, Clone)]
enum Purpose {
    Swap {
        scenario: PathBuf,
        old: i32,
    },
    Restart {
        rolled_back_from: Option<PathBuf>,
    },
    Promote,
    Logger,
    Standby,
    /// After a controller swap, a standby of the new design; the swap's
    /// switch is the sequence's result whatever becomes of it.
    Renewal {
        swap: Switch,
        old: Vec<(i32, u32)>,
    },
}

#[derive(Debug, Clone)]
enum Phase {
    AwaitTicking,
    /// A restart's boundary is published before its instance is engaged.
    AnnounceOwnership(u64),
    Engaging,
    /// The command went out; the state after it depends on how it went.
    Ordering(i32),
    Launching,
    /// Engaged before tick 0: it owns every sample from 0 on.
    OwnAll,
    /// Nothing left to wait for: the sequence's events, then its end.
    Finishing,
    Shadowing,
    Announcing,
    Draining {
        from_seq: u64,
    },
    Retiring {
        left: Vec<i32>,
    },
    /// The engaged instance is being stopped; then the sequence fails.
    Abandoning(Failure),
}

/// One sequence under way (the core holds at most one).
#[derive(Debug, Clone)]
pub struct Sequence {
    role: Role,
    generation: u32,
    scenario: PathBuf,
    joining: Joining,
    own_program: bool,
    purpose: Purpose,
    phase: Phase,
    /// When the current phase began (its timeout counts from there).
    since: Instant,
    /// The loop's sample when the instance was started or ordered.
    start_seq: u64,
    /// The instance engaged, and whether it was a warm spare.
    engaged: Option<(i32, bool)>,
    /// The boundary already announced (a restart owns its samples at once).
    announced: Option<u64>,
    /// Events recorded along the way (a swap's before its renewal), and
    /// instances to stop at the end.
    records: Vec<Action>,
    /// A dead predecessor's state went out at this look: the next is a
    /// wait (it is handed over once per look).
    handed_over: bool,
}

impl Core {
    /// Begins a sequence; refused while another runs ([`Failure::Busy`]) and
    /// when there is nothing to swap or restart. `is_program` says which
    /// scenarios name a program of one's own for the role (a spare runs the
    /// built-in law; a crashed program is rolled back), or why a scenario
    /// cannot be read (the sequence then fails at its first step, as an
    /// instance that cannot be started).
    pub fn begin(
        &mut self,
        order: Order,
        look: Look,
        is_program: &dyn Fn(&Path) -> Result<bool, String>,
    ) -> Result<(), Failure> {
        if self.sequence.is_some() {
            return Err(Failure::Busy);
        }
        let start_seq = self.last_seq.unwrap_or(0);
        let sequence = |role, generation, scenario: PathBuf, joining, purpose, phase| {
            // (A promoted standby is engaged already: no scenario to read.)
            let (own_program, phase) = match scenario.as_os_str().is_empty() {
                true => (false, phase),
                false => match is_program(&scenario) {
                    Ok(own) => (own, phase),
                    Err(why) => (false, Phase::Abandoning(Failure::Carrying(why))),
                },
            };
            Sequence {
                role,
                generation,
                scenario,
                joining,
                own_program,
                purpose,
                phase,
                since: look.now,
                start_seq,
                engaged: None,
                announced: None,
                records: Vec::new(),
                handed_over: false,
            }
        };
        let sequence = match order {
            Order::Swap { role, scenario } => {
                let (old, generation) = self.plan_swap(role)?;
                let purpose = Purpose::Swap {
                    scenario: scenario.clone(),
                    old,
                };
                sequence(
                    role,
                    generation,
                    scenario,
                    Joining::Replacement,
                    purpose,
                    Phase::AwaitTicking,
                )
            }
            Order::Standby {
                scenario,
                generation,
            } => sequence(
                Role::Controller,
                generation,
                scenario,
                Joining::Standby,
                Purpose::Standby,
                Phase::Engaging,
            ),
            Order::Restart(role) => {
                match self.plan_restart(role, &|scenario| is_program(scenario).unwrap_or(false))? {
                    RestartPlan::Promote { generation } => sequence(
                        Role::Controller,
                        generation,
                        PathBuf::new(),
                        Joining::Standby,
                        Purpose::Promote,
                        Phase::Announcing,
                    ),
                    // It only listens: started at once, nothing to hand over.
                    RestartPlan::Logger {
                        scenario,
                        generation,
                    } => sequence(
                        role,
                        generation,
                        scenario,
                        Joining::Restart,
                        Purpose::Logger,
                        Phase::Engaging,
                    ),
                    RestartPlan::Fresh {
                        scenario,
                        generation,
                        owns_from,
                        rolled_back_from,
                    } => {
                        let phase = match owns_from {
                            Some(from_seq) => Phase::AnnounceOwnership(from_seq),
                            None => Phase::Engaging,
                        };
                        sequence(
                            role,
                            generation,
                            scenario,
                            Joining::Restart,
                            Purpose::Restart { rolled_back_from },
                            phase,
                        )
                    }
                }
            }
        };
        self.begin_operation();
        self.sequence = Some(sequence);
        Ok(())
    }

    /// Moves the sequence on by what the loop shows now.
    pub fn advance(&mut self, look: Look) -> Step {
        let Some(mut s) = self.sequence.take() else {
            return Step::Done(SequenceEnd {
                actions: Vec::new(),
                result: Err(Failure::NoSequence),
            });
        };
        let step = self.step(&mut s, look);
        if let Step::Done(mut ending) = step {
            ending.actions.extend(self.end_operation(look.now));
            return Step::Done(ending);
        }
        self.sequence = Some(s);
        step
    }

    /// How the last command went.
    pub fn carried(&mut self, carried: Carried, now: Instant) {
        let Some(mut s) = self.sequence.take() else {
            return;
        };
        self.take_report(&mut s, carried, now);
        self.sequence = Some(s);
    }

    fn step(&mut self, s: &mut Sequence, look: Look) -> Step {
        let waited = look.now.saturating_duration_since(s.since);
        match &s.phase {
            Phase::AwaitTicking => {
                if self.ticking() {
                    s.start_seq = self.last_seq.unwrap_or(0);
                    s.enter(Phase::Engaging, look.now);
                    return self.step(s, look);
                }
                if waited > SHADOW_TIMEOUT || look.shutting_down {
                    return self.fail(s, Failure::LoopNotTicking(SHADOW_TIMEOUT));
                }
                Step::Wait(TICKING_LOOK)
            }
            &Phase::AnnounceOwnership(from_seq) => Step::Carry(Command::Publish(
                self.activation_for(s.role, s.generation, from_seq),
            )),
            Phase::Engaging => {
                if matches!(s.purpose, Purpose::Logger) {
                    s.phase = Phase::Launching;
                    return Step::Carry(s.launch());
                }
                match self.engagement(s.role, waited > SPARE_START_WAIT, s.own_program) {
                    Engagement::WaitForSpare => Step::Wait(SPARE_LOOK),
                    Engagement::Order(pid) => {
                        s.phase = Phase::Ordering(pid);
                        Step::Carry(Command::Order {
                            pid,
                            generation: s.generation,
                            joining: s.joining,
                            scenario: s.scenario.clone(),
                        })
                    }
                    Engagement::Start => {
                        s.phase = Phase::Launching;
                        Step::Carry(s.launch())
                    }
                }
            }
            Phase::Ordering(_) | Phase::Launching => {
                unreachable!("a command's report moves the sequence on")
            }
            Phase::OwnAll => Step::Carry(Command::Publish(self.activation_for(
                s.role,
                s.generation,
                0,
            ))),
            Phase::Shadowing if std::mem::take(&mut s.handed_over) => Step::Wait(SHADOW_LOOK),
            Phase::Shadowing => match self.shadow_step(s.role, s.generation, look.shutting_down) {
                ShadowStep::Following => {
                    if let Purpose::Renewal { old, .. } = &s.purpose {
                        let left = old.iter().map(|&(pid, _)| pid).collect();
                        s.enter(Phase::Retiring { left }, look.now);
                        return self.step(s, look);
                    }
                    match s.announced {
                        Some(from_seq) => s.enter(Phase::Draining { from_seq }, look.now),
                        None => s.enter(Phase::Announcing, look.now),
                    }
                    self.step(s, look)
                }
                ShadowStep::Failed(failure) => self.abandon(s, failure, look),
                ShadowStep::Waiting { .. } if waited > SHADOW_TIMEOUT => {
                    let failure = Failure::NotFollowing {
                        role: s.role,
                        timeout: SHADOW_TIMEOUT,
                    };
                    self.abandon(s, failure, look)
                }
                ShadowStep::Waiting { hand_over } => match hand_over {
                    Some(state) => {
                        s.handed_over = true;
                        Step::Carry(Command::HandOver {
                            role: s.role,
                            generation: s.generation,
                            state,
                        })
                    }
                    None => Step::Wait(SHADOW_LOOK),
                },
            },
            Phase::Announcing => {
                let from_seq = self.boundary_ahead();
                Step::Carry(Command::Publish(self.activation_for(
                    s.role,
                    s.generation,
                    from_seq,
                )))
            }
            &Phase::Draining { from_seq } => {
                let old = s.replaced();
                match self.drain_step(from_seq, old, look.shutting_down) {
                    DrainStep::Passed => self.passed(s, from_seq, look),
                    // A restart's new instance goes with its failure (the
                    // next attempt starts afresh); a swap's is announced and
                    // stays, the old one being the one that did not leave.
                    DrainStep::RunEnded if old.is_none() => {
                        self.abandon(s, Failure::RunEndedBeforeSwitch, look)
                    }
                    DrainStep::RunEnded => self.fail(s, Failure::RunEndedBeforeSwitch),
                    DrainStep::Waiting if waited > DRAIN_TIMEOUT => {
                        let failure = Failure::NotPassed {
                            from_seq,
                            timeout: DRAIN_TIMEOUT,
                        };
                        match old {
                            Some(pid) => {
                                self.settle(pid);
                                s.phase = Phase::Abandoning(failure);
                                Step::Carry(Command::Stop(pid))
                            }
                            None => self.abandon(s, failure, look),
                        }
                    }
                    DrainStep::Waiting => Step::Wait(DRAIN_LOOK),
                }
            }
            Phase::Finishing => self.finish(s),
            Phase::Retiring { left } => {
                let Some(&pid) = left.first() else {
                    return self.finish(s);
                };
                match self.retirement() {
                    Retirement::Order => Step::Carry(Command::Retire(pid)),
                    Retirement::Stop => {
                        self.settle(pid);
                        Step::Carry(Command::Stop(pid))
                    }
                }
            }
            Phase::Abandoning(failure) => {
                let failure = failure.clone();
                self.fail(s, failure)
            }
        }
    }

    /// What the report of the last command means for the sequence.
    fn take_report(&mut self, s: &mut Sequence, carried: Carried, now: Instant) {
        let failed = |why: String| Phase::Abandoning(Failure::Carrying(why));
        match (&s.phase, carried) {
            (&Phase::AnnounceOwnership(from_seq), Carried::Published(activation)) => {
                self.announced(activation);
                s.announced = Some(from_seq);
                s.enter(Phase::Engaging, now);
            }
            (Phase::OwnAll, Carried::Published(activation)) => {
                self.announced(activation);
                s.announced = Some(0);
                s.phase = Phase::Finishing;
            }
            (Phase::OwnAll, Carried::Failed(why)) => {
                // The instance started for nothing: stopped, then the failure.
                s.phase = failed(why);
                if let Some((pid, _)) = s.engaged {
                    self.settle(pid);
                    s.records.push(Action::Stop(pid));
                }
            }
            (Phase::Announcing, Carried::Published(activation)) => {
                let from_seq = activation_boundary(s.role, &activation);
                self.announced(activation);
                s.announced = Some(from_seq);
                if let Some(pid) = s.replaced() {
                    // Its exit (or, with warm spares, its retirement to a
                    // spare) after the boundary is the plan, not a crash.
                    self.settle(pid);
                }
                s.enter(Phase::Draining { from_seq }, now);
            }
            (&Phase::Ordering(pid), Carried::Done) => {
                self.ordered(pid, s.generation, s.joining, &s.scenario);
                s.engaged = Some((pid, true));
                self.engaged(s, now);
            }
            (Phase::Launching, Carried::Launched(pid)) => {
                s.engaged = Some((pid, false));
                self.engaged(s, now);
            }
            (Phase::Shadowing, Carried::Done) => {}
            (Phase::Retiring { left }, report) => {
                let pid = left[0];
                let rest = left[1..].to_vec();
                match report {
                    Carried::Failed(_) if self.retirement() == Retirement::Order => {
                        // The order could not go out: stopped instead.
                        self.settle(pid);
                        s.records.push(Action::Stop(pid));
                    }
                    _ if self.retirement() == Retirement::Order => self.retiring(pid, now),
                    _ => {}
                }
                s.phase = Phase::Retiring { left: rest };
            }
            (Phase::Abandoning(_), _) => {}
            (_, Carried::Failed(why)) => {
                // Nothing engaged yet, or the engaged instance to stop.
                s.phase = failed(why);
                if let Some((pid, _)) = s.engaged {
                    self.settle(pid);
                    s.records.push(Action::Stop(pid));
                }
            }
            (phase, report) => unreachable!("{report:?} reported in {phase:?}"),
        }
    }

    /// The instance is engaged: what follows depends on the sequence and on
    /// whether the loop ticks yet.
    fn engaged(&mut self, s: &mut Sequence, now: Instant) {
        match s.purpose {
            Purpose::Logger => {
                let record = self.note(
                    s.role,
                    Some(s.generation),
                    EventKind::Restart(Restart {
                        files: Some(flexloop_runfiles::run_dir::logger_files(s.generation).into()),
                        ..Restart::default()
                    }),
                );
                s.records.push(record);
                s.phase = Phase::Finishing;
            }
            Purpose::Standby => {
                let Some((pid, warm)) = s.engaged else {
                    return;
                };
                let record = self.standby_started(s.generation, pid, warm);
                s.records.push(record);
                s.phase = Phase::Finishing;
            }
            // Before tick 0 there is nothing to take over: the replacement
            // owns every sample and starts the loop as the first one would.
            Purpose::Restart { .. } if !self.ticking() => s.phase = Phase::OwnAll,
            _ => s.enter(Phase::Shadowing, now),
        }
    }

    /// The loop passed the boundary: the switch is measured and recorded;
    /// after a controller swap the standby is renewed.
    fn passed(&mut self, s: &mut Sequence, from_seq: u64, look: Look) -> Step {
        let warm = s.engaged.is_none_or(|(_, warm)| warm);
        let switch = self.switch(s.role, s.generation, s.start_seq, from_seq, warm);
        let kind = match &s.purpose {
            Purpose::Swap { scenario, .. } => EventKind::Swap(Swap {
                scenario: scenario.display().to_string(),
                switch: switch.record(),
                sender: None,
            }),
            Purpose::Promote => EventKind::PromoteStandby(switch.record()),
            Purpose::Restart { rolled_back_from } => EventKind::Restart(Restart {
                switch: Some(switch.record()),
                scenario: rolled_back_from
                    .is_some()
                    .then(|| s.scenario.display().to_string()),
                rolled_back_from: rolled_back_from.as_ref().map(|p| p.display().to_string()),
                ..Restart::default()
            }),
            Purpose::Logger | Purpose::Standby | Purpose::Renewal { .. } => {
                unreachable!("{:?} has no boundary", s.purpose)
            }
        };
        s.records.push(self.note(s.role, Some(s.generation), kind));
        if matches!(s.purpose, Purpose::Swap { .. })
            && s.role == Role::Controller
            && let Some(renewal) = self.standby_renewal()
        {
            s.generation = renewal.generation;
            s.scenario = renewal.scenario;
            s.joining = Joining::Standby;
            s.own_program = self
                .roster
                .serving(Role::Controller)
                .is_some_and(|m| m.program);
            s.engaged = None;
            s.announced = None;
            s.purpose = Purpose::Renewal {
                swap: switch,
                old: renewal.old,
            };
            s.enter(Phase::Engaging, look.now);
            return self.step(s, look);
        }
        Step::Done(SequenceEnd {
            actions: std::mem::take(&mut s.records),
            result: Ok(Some(switch)),
        })
    }

    /// The renewed standby follows and the old ones are retired (or a
    /// standby or logger engaged, a restart before tick 0 done).
    fn finish(&mut self, s: &mut Sequence) -> Step {
        let result = match &s.purpose {
            Purpose::Renewal { swap, old } => {
                let (pid, _) = s.engaged.expect("a renewed standby was engaged");
                let record = self.note(
                    Role::Controller,
                    Some(s.generation),
                    EventKind::Standby(Standby {
                        pid,
                        scenario: Some(s.scenario.display().to_string()),
                        replaces: Some(old.iter().map(|&(_, g)| g).collect()),
                        ..Standby::default()
                    }),
                );
                s.records.push(record);
                Some(swap.clone())
            }
            Purpose::Restart { .. } => {
                let record = self.note(
                    s.role,
                    Some(s.generation),
                    EventKind::Restart(Restart {
                        before_tick_0: true,
                        ..Restart::default()
                    }),
                );
                s.records.push(record);
                None
            }
            _ => None,
        };
        Step::Done(SequenceEnd {
            actions: std::mem::take(&mut s.records),
            result: Ok(result),
        })
    }

    /// The engaged instance failed to follow (or the run ended): it is
    /// stopped first, then the sequence fails.
    fn abandon(&mut self, s: &mut Sequence, failure: Failure, look: Look) -> Step {
        match s.engaged {
            Some((pid, _)) if !matches!(failure, Failure::NewInstanceExited { .. }) => {
                self.settle(pid);
                s.phase = Phase::Abandoning(failure);
                Step::Carry(Command::Stop(pid))
            }
            _ => {
                s.phase = Phase::Abandoning(failure);
                self.step(s, look)
            }
        }
    }
    /// It failed: a standby's or a renewal's failure is an event of its
    /// own (a swap stands without its renewed standby, the old standby
    /// covering; a standby's costs the restart budget); the others fail
    /// the order.
    fn fail(&mut self, s: &mut Sequence, failure: Failure) -> Step {
        let mut actions = std::mem::take(&mut s.records);
        let result = match &s.purpose {
            Purpose::Renewal { swap, .. } => {
                actions.push(self.note(
                    Role::Controller,
                    Some(s.generation),
                    EventKind::StandbyFailed(failure.to_string()),
                ));
                Ok(Some(swap.clone()))
            }
            Purpose::Standby => {
                actions.push(self.standby_failed(s.generation, failure.to_string()));
                Ok(None)
            }
            _ => Err(failure),
        };
        Step::Done(SequenceEnd { actions, result })
    }
}

impl Sequence {
    fn enter(&mut self, phase: Phase, now: Instant) {
        self.phase = phase;
        self.since = now;
    }

    fn launch(&self) -> Command {
        Command::Launch {
            role: self.role,
            scenario: self.scenario.clone(),
            generation: self.generation,
            joining: self.joining,
        }
    }

    /// The live instance a swap replaces.
    fn replaced(&self) -> Option<i32> {
        match self.purpose {
            Purpose::Swap { old, .. } => Some(old),
            _ => None,
        }
    }
}

/// The boundary an activation announces for `role`.
fn activation_boundary(role: Role, activation: &Activation) -> u64 {
    match role {
        Role::Controller => activation.controller_from_seq,
        _ => activation.observer_from_seq,
    }
}
