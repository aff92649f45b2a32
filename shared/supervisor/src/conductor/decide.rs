//! The conductor's decision core: what to do about what happened, with no
//! IPC, no process, no file and no clock of its own (time comes in with the
//! events). The shell (`shell.rs`) feeds it what it sees, carries out the
//! actions it returns, and asks it at each step of a swap or restart.
//!
//! It keeps the bookkeeping: which instance of each role does what
//! (`roster`), which generation owns which samples (the activation), the
//! restart budgets and their back-off, the restarts pending, the standbys
//! told to retire, and what it has seen of the loop (newest sample, pace,
//! the active instances' last states, shadows following, the inputs the plant applied).

mod events;
mod policy;
mod sequence;
mod silence;
mod steps;

pub use events::{Action, Event, Record, Stage};
pub use policy::{Policy, backoff};
pub use sequence::{Carried, Command, Look, Order, Step};
#[cfg(test)]
pub use silence::SilenceRule;
pub use steps::{DrainStep, Engagement, Failure, Renewal, RestartPlan, Retirement, ShadowStep};

use super::measure::{AppliedHistory, BEFORE_SWITCH, Pace};
use super::per_role::PerRole;
use super::roster::{Duty, Ending, Roster};
use super::switch::Switch;
use crate::children::Outcome;
use crate::process_state::ProcessState;
use flexloop_node::Role;
use flexloop_protocol::Joining;
use flexloop_protocol::handover::ACTIVE;
use flexloop_protocol::{Activation, Handover};
use flexloop_runfiles::events::{Crash, EventKind, Silent, Spare, Standby};
use flexloop_scenario::schema::RestartPolicy;
use silence::SilenceWatch;
use std::path::Path;
use std::time::{Duration, Instant};

/// What the supervisor does with a hung process, as its `silent` event says.
const HUNG_ACTION: &str = "killed, then handled as a crash";

/// How long a replacement may take to start and follow the loop in shadow.
pub const SHADOW_TIMEOUT: Duration = Duration::from_secs(30);
/// How long the replaced instance may take to hand over and exit.
pub const DRAIN_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a standby told to retire may take to become a spare.
const RETIRE_TIMEOUT: Duration = Duration::from_secs(2);
/// The shortest time ahead a swap's boundary is announced: every process
/// must see the announcement before the loop reaches it.
const ANNOUNCE_AHEAD: Duration = Duration::from_millis(50);
const ANNOUNCE_AHEAD_MIN_SAMPLES: u64 = 50;
/// A crash this soon after the role's last restart began (or a failed
/// restart) continues a crash loop, and the back-off grows with each; a crash
/// after its instance ran longer is a fault of its own, restarted at once. A
/// back-off before every first restart held the plant's input 100 ms
/// (docs/benchmarks.md, "Crash hand-over"); a crash loop still cannot spin the supervisor.
const CRASH_LOOP_WINDOW: Duration = Duration::from_millis(250);

struct PendingRestart {
    role: Role,
    due: Instant,
}

pub struct Core {
    policy: Policy,
    roster: Roster,
    /// Which generation of controller and observer owns which samples.
    activation: Activation,
    last_seq: Option<u64>,
    /// The plant published its last sample: no new spare or standby.
    run_ending: bool,
    restarts: PerRole<u32>,
    /// Restarts in a row that ended in a crash loop, and when the role's
    /// last restart was due.
    crash_streak: PerRole<u32>,
    last_restart: PerRole<Option<Instant>>,
    /// Spares that crashed or failed to start, per role (their own budget:
    /// an idle spare's trouble must not use up the active role's restarts).
    spare_failures: PerRole<u32>,
    pending: Vec<PendingRestart>,
    /// Standbys told to retire, and since when: stopped if they have not
    /// become spares within [`RETIRE_TIMEOUT`] (one without spare duty,
    /// started from a file with `warm_spares = false`, never does).
    retiring: Vec<(i32, Instant)>,
    /// The last state each role's active instance published: a restarted
    /// instance gets it from here, since a dead publisher hands nothing over.
    last_active: PerRole<Option<Handover>>,
    /// Shadows seen following, by role and generation.
    shadows_seen: Vec<(Role, u32)>,
    pace: Pace,
    applied: AppliedHistory,
    /// A swap or restart is under way: crashes wait for its end to be
    /// settled (it may be the one that deals with them).
    busy: bool,
    /// That swap, restart or standby's start, where it stands.
    sequence: Option<sequence::Sequence>,
    /// A measurement ordered on the running loop: its first and its end
    /// sample (docs/control.md, "Measuring the loop").
    measuring: Option<(u64, u64)>,
    /// What the loop shows of the controller's and observer's output.
    silence: SilenceWatch,
    /// The generation whose last commands were not finite (the plant
    /// refuses them: a silence of that cause), and how many in a row.
    non_finite: Option<(u32, u64)>,
}

impl Core {
    pub fn new(policy: Policy, activation: Activation) -> Self {
        let applied = AppliedHistory::new(policy.n_inputs);
        Self {
            policy,
            roster: Roster::default(),
            activation,
            last_seq: None,
            run_ending: false,
            restarts: PerRole::default(),
            crash_streak: PerRole::default(),
            last_restart: PerRole::default(),
            spare_failures: PerRole::default(),
            pending: Vec::new(),
            retiring: Vec::new(),
            last_active: PerRole::default(),
            shadows_seen: Vec::new(),
            pace: Pace::default(),
            applied,
            busy: false,
            sequence: None,
            measuring: None,
            silence: SilenceWatch::default(),
            non_finite: None,
        }
    }

    pub fn roster(&self) -> &Roster {
        &self.roster
    }

    #[cfg(test)]
    pub fn activation(&self) -> Activation {
        self.activation
    }

    /// The loop's newest sample, once it ticks.
    #[cfg(test)]
    pub fn last_seq(&self) -> Option<u64> {
        self.last_seq
    }

    pub fn ticking(&self) -> bool {
        self.last_seq.is_some()
    }

    pub fn handle(&mut self, event: Event<'_>) -> Vec<Action> {
        match event {
            Event::Launched {
                pid,
                role,
                generation,
                joining,
                scenario,
                program,
            } => {
                self.roster
                    .add(pid, role, generation, joining, scenario, program);
                Vec::new()
            }
            Event::Exited { pid, code, now } => {
                if let Some(m) = self.roster.get_mut(pid) {
                    m.exit = Some(code);
                }
                if self.busy {
                    Vec::new()
                } else {
                    self.settle_crashes(now)
                }
            }
            Event::SpareIdle { pid } => {
                if let Some(m) = self.roster.get_mut(pid).filter(|m| m.alive()) {
                    m.duty = Duty::Spare { idle: true };
                    // A spare's crash is its own event, not the end of the run.
                    m.settled = false;
                }
                Vec::new()
            }
            Event::Command {
                seq,
                generation,
                finite,
            } => {
                self.saw_sample(seq);
                // The owner's commands only: a standby's or a stray's say
                // nothing of the active controller.
                if self.activation.controller_for(seq) == generation {
                    self.non_finite = match self.non_finite {
                        _ if finite => None,
                        Some((g, n)) if g == generation => Some((g, n + 1)),
                        _ => Some((generation, 1)),
                    };
                }
                Vec::new()
            }
            Event::Applied {
                seq,
                command_seq,
                u,
                fresh,
                answered_late,
                stalled,
            } => {
                self.applied.push(seq, command_seq, u);
                // A controller whose commands come late (a command deadline
                // the machine cannot meet) is alive: its misses are counted
                // as misses, and killing it would only add restarts.
                self.silence.tick(seq, fresh || answered_late, stalled);
                Vec::new()
            }
            Event::Estimate { seq } => {
                self.saw_sample(seq.saturating_sub(1));
                self.silence.estimate(seq);
                Vec::new()
            }
            Event::State { role, state } => {
                if let Some(m) = self
                    .roster
                    .iter_mut()
                    .find(|m| m.role == role && m.generation == Some(state.generation) && m.alive())
                {
                    m.followed = true;
                }
                if state.shadow != ACTIVE {
                    if !self.shadows_seen.contains(&(role, state.generation)) {
                        self.shadows_seen.push((role, state.generation));
                    }
                } else {
                    let last = self.last_active.get_mut(role);
                    if last.is_none_or(|l| l.seq <= state.seq) {
                        *last = Some(*state);
                    }
                }
                Vec::new()
            }
            Event::EndOfRun => {
                self.run_ending = true;
                Vec::new()
            }
            Event::Polled { now } => {
                if let Some(seq) = self.last_seq {
                    self.pace.push(now, seq);
                }
                self.silence.polled(now);
                Vec::new()
            }
            Event::ProcessState {
                pid,
                state,
                runqueue_wait_ns,
                now,
            } => {
                self.note_runqueue_wait(pid, runqueue_wait_ns, now);
                self.process_state(pid, state, now)
            }
            Event::Tick { now, stage } => match stage {
                Stage::Silence => self.check_silence(now),
                Stage::Restarts => self.due_restarts(now),
                Stage::Retiring => self.check_retiring(now),
                Stage::Standby => self.keep_standby().into_iter().collect(),
                Stage::Spares => self.keep_spares(),
            },
        }
    }

    fn saw_sample(&mut self, seq: u64) {
        self.last_seq = Some(self.last_seq.map_or(seq, |s| s.max(seq)));
    }

    fn record(&self, role: Role, generation: Option<u32>, kind: EventKind) -> Record {
        Record {
            kind,
            role,
            generation,
            seq: self.last_seq,
            clean_dead_nodes: false,
        }
    }

    /// A line for the events file, stamped with the loop's newest sample.
    pub fn note(&self, role: Role, generation: Option<u32>, kind: EventKind) -> Action {
        Action::Record(self.record(role, generation, kind))
    }

    // ---- crashes and restarts ----

    /// A swap or restart begins: crashes seen meanwhile wait for its end.
    pub fn begin_operation(&mut self) {
        self.busy = true;
    }

    /// It ended: the crashes seen meanwhile are settled now. The roles'
    /// silence is judged afresh from here (a new instance may serve).
    pub fn end_operation(&mut self, now: Instant) -> Vec<Action> {
        self.busy = false;
        self.silence.restart_clock(Role::Controller, now);
        self.silence.restart_clock(Role::Observer, now);
        self.settle_crashes(now)
    }

    /// Deals with the crashes not dealt with yet: a spare's or the
    /// standby's costs its budget and another takes its place (upkeep); a
    /// serving instance's schedules its restart (after a back-off in a
    /// crash loop), within the restart budget; else the crash is recorded as
    /// fatal and left to the supervisor, which ends the run on it.
    fn settle_crashes(&mut self, now: Instant) -> Vec<Action> {
        let crashed: Vec<i32> = self
            .roster
            .iter()
            .filter(|m| !m.settled && !m.fatal_recorded && m.crashed())
            .map(|m| m.pid)
            .collect();
        let mut actions = Vec::new();
        for pid in crashed {
            let Some(m) = self.roster.get(pid) else {
                continue;
            };
            // Unknown while the exit report has not come (found exiting or killed).
            let (role, generation, code, found) = (m.role, m.generation, m.exit, m.found());
            let cause = match (m.cause, m.silenced()) {
                (Some(cause), _) => cause,
                (None, true) => "silent",
                (None, false) => "crashed",
            };
            if m.spare() || m.standby() {
                let spare = m.spare();
                let budget = if spare {
                    &mut self.spare_failures
                } else {
                    &mut self.restarts
                };
                *budget.get_mut(role) += 1;
                self.settle(pid);
                actions.push(self.crash_record(
                    role,
                    generation,
                    Crash {
                        exit: code,
                        found: found.into(),
                        spare,
                        standby: !spare,
                        ..Crash::default()
                    },
                ));
                continue;
            }
            let fatal = if !matches!(role, Role::Observer | Role::Controller | Role::Logger) {
                Some("the plant owns the clock: the run ends with it".to_string())
            } else if m.program && !m.followed {
                // It failed before its law ever ran on the loop (its
                // parameters, its setup, its start): another start would
                // fail the same way, so it is reported once, not restarted.
                Some(
                    "the program exited before it ever followed the loop: not restarted \
                     (its stderr says why)"
                        .to_string(),
                )
            } else if self.policy.restart == RestartPolicy::Never {
                Some("restart = \"never\"".to_string())
            } else if *self.restarts.get(role) >= self.policy.max_restarts {
                Some(format!(
                    "max_restarts spent ({} of {})",
                    self.restarts.get(role),
                    self.policy.max_restarts
                ))
            } else {
                None
            };
            if let Some(reason) = fatal {
                // Left unsettled: the supervisor ends the run on it.
                if let Some(m) = self.roster.get_mut(pid) {
                    m.fatal_recorded = true;
                }
                actions.push(self.crash_record(
                    role,
                    generation,
                    Crash {
                        exit: code,
                        found: found.into(),
                        cause: Some(cause.into()),
                        fatal: Some(reason),
                        ..Crash::default()
                    },
                ));
                continue;
            }
            self.settle(pid);
            let wait = self.count_restart(role, now, false);
            actions.push(self.crash_record(
                role,
                generation,
                Crash {
                    exit: code,
                    found: found.into(),
                    cause: Some(cause.into()),
                    restart_in_ms: Some(wait.as_millis() as u64),
                    ..Crash::default()
                },
            ));
            self.pending.push(PendingRestart {
                role,
                due: now + wait,
            });
        }
        actions
    }

    /// A live controller or observer that left the loop without its output
    /// for the policy's ticks (and wall time) is hung: it is killed, and
    /// dealt with at once as crashed (the standby, a restart, a program's
    /// rollback: SIGKILL leaves it no further instruction, so its exit
    /// report need not be waited for), its `crash` event saying
    /// `"cause": "silent"`. Not while a swap or restart is under way, nor
    /// once the run ends.
    fn check_silence(&mut self, now: Instant) -> Vec<Action> {
        if self.busy || self.run_ending {
            return Vec::new();
        }
        let Some(silent) = self.silence.silent(&self.policy.silence, now) else {
            return Vec::new();
        };
        let Some((pid, generation, starved)) = self
            .roster
            .serving(silent.role)
            .filter(|m| m.alive() && !m.silenced())
            .map(|m| (m.pid, m.generation, m.starved))
        else {
            return Vec::new();
        };
        // A controller that sends, but only what the plant refuses (NaN,
        // infinite), is silent for the loop: said so, with how many. It is
        // judged starved or not: it gets the CPU to send.
        let non_finite = self
            .non_finite
            .filter(|&(g, _)| silent.role == Role::Controller && Some(g) == generation)
            .map(|(_, n)| n);
        if starved && non_finite.is_none() {
            return Vec::new();
        }
        let mut detail = Silent {
            pid,
            ticks_without_output: silent.ticks,
            seconds_without_output: Some(silent.since.as_secs_f64()),
            action: HUNG_ACTION.into(),
            ..Silent::default()
        };
        if let Some(n) = non_finite {
            detail.cause = Some("non-finite output".into());
            detail.non_finite_commands_in_a_row = Some(n);
            if let Some(m) = self.roster.get_mut(pid) {
                m.cause = Some("non-finite output");
            }
        }
        self.kill_hung(pid, Ending::Silent, detail, now)
    }

    /// What the kernel shows of a live, unsettled process of the loop (the
    /// shell looks at every supervisor look and whenever the plant's silence
    /// alarm wakes it): one in its exit is dealt with as crashed now, not
    /// milliseconds later when the kernel reports the exit; a stopped one is
    /// hung, killed and dealt with likewise (docs/architecture.md, "Standby,
    /// watchdogs and guards").
    fn process_state(&mut self, pid: i32, state: ProcessState, now: Instant) -> Vec<Action> {
        if self.busy || self.run_ending {
            return Vec::new();
        }
        let Some(m) = self.roster.get_mut(pid).filter(|m| m.alive() && !m.settled) else {
            return Vec::new();
        };
        match state {
            ProcessState::Live => Vec::new(),
            ProcessState::Exiting => {
                m.ending = Some(Ending::Exiting);
                self.settle_crashes(now)
            }
            ProcessState::Stopped => {
                let detail = Silent {
                    pid,
                    stopped: true,
                    ticks_without_output: self.silence.ticks_without(m.role),
                    action: HUNG_ACTION.into(),
                    ..Silent::default()
                };
                self.kill_hung(pid, Ending::Stopped, detail, now)
            }
        }
    }

    /// Whether `pid` waited for a CPU for most of the time since the last
    /// look: starved by a busy machine (no real-time priority), not hung. A
    /// controller so starved for 2 s on a loaded test machine was killed as
    /// silent; a hung process (asleep in its law, deadlocked, stopped)
    /// waits for nothing the scheduler could give it.
    fn note_runqueue_wait(&mut self, pid: i32, waited_ns: Option<u64>, now: Instant) {
        let Some(m) = self.roster.get_mut(pid) else {
            return;
        };
        let (Some(waited), Some((then, before))) = (waited_ns, m.runqueue_wait) else {
            m.runqueue_wait = waited_ns.map(|w| (now, w));
            return;
        };
        let span = now.saturating_duration_since(then).as_nanos() as u64;
        if span > 0 {
            m.starved = waited.saturating_sub(before) * 2 > span;
            m.runqueue_wait = Some((now, waited));
        }
    }

    /// Kills the hung `pid` and deals with it as crashed now.
    fn kill_hung(&mut self, pid: i32, how: Ending, detail: Silent, now: Instant) -> Vec<Action> {
        let Some(m) = self.roster.get_mut(pid) else {
            return Vec::new();
        };
        m.ending = Some(how);
        let (role, generation) = (m.role, m.generation);
        // Its replacement is judged from its own start.
        self.silence.restart_clock(role, now);
        let mut actions = vec![
            self.note(role, generation, EventKind::Silent(detail)),
            Action::Kill(pid),
        ];
        actions.extend(self.settle_crashes(now));
        actions
    }

    /// When a silent role's silence is due to be judged, if one is silent
    /// now (see [`SilenceWatch::due`]); none during a swap or restart or
    /// once the run ends.
    pub fn silence_due(&self) -> Option<Instant> {
        if self.busy || self.run_ending {
            return None;
        }
        let period = Duration::from_secs_f64(1.0 / self.policy.rate_hz.max(1.0));
        self.silence.due(&self.policy.silence, period)
    }

    /// The live processes of the loop whose state the shell is to look at
    /// (see [`Core::handle`] with [`Event::ProcessState`]).
    pub fn watched_processes(&self) -> Vec<i32> {
        if self.busy || self.run_ending {
            return Vec::new();
        }
        self.roster
            .iter()
            .filter(|m| m.alive() && !m.settled && m.role != Role::Plant)
            .map(|m| m.pid)
            .collect()
    }

    fn crash_record(&self, role: Role, generation: Option<u32>, crash: Crash) -> Action {
        Action::Record(Record {
            clean_dead_nodes: true,
            ..self.record(role, generation, EventKind::Crash(crash))
        })
    }

    /// Counts one more restart of `role` at `now` and returns its back-off:
    /// none unless it continues a crash loop (`failed`: the last restart
    /// itself failed).
    fn count_restart(&mut self, role: Role, now: Instant, failed: bool) -> Duration {
        let looping = failed
            || self
                .last_restart
                .get(role)
                .is_some_and(|t| now.saturating_duration_since(t) < CRASH_LOOP_WINDOW);
        let streak = self.crash_streak.get_mut(role);
        *streak = if looping { *streak + 1 } else { 0 };
        let wait = backoff(self.policy.restart_backoff_ms, *streak);
        *self.restarts.get_mut(role) += 1;
        *self.last_restart.get_mut(role) = Some(now + wait);
        wait
    }

    fn due_restarts(&mut self, now: Instant) -> Vec<Action> {
        let (due, later) = std::mem::take(&mut self.pending)
            .into_iter()
            .partition(|p| p.due <= now);
        self.pending = later;
        due.into_iter()
            .map(|p| Action::Restart(p.role))
            .collect::<Vec<_>>()
    }

    /// A restart failed: another attempt after the back-off, within the
    /// budget; else the run ends on the failure. If the supervisor is
    /// stopping (the restart's wait gave way to the stop), the run ends as
    /// asked, not as failed: the stop was the user's.
    pub fn restart_failed(
        &mut self,
        role: Role,
        error: &anyhow::Error,
        now: Instant,
        shutting_down: bool,
    ) -> Vec<Action> {
        let error = format!("{error:#}");
        let mut actions = vec![self.note(role, Some(0), EventKind::RestartFailed(error))];
        if shutting_down {
            actions.push(Action::EndRun(Outcome::Interrupted));
            return actions;
        }
        if *self.restarts.get(role) >= self.policy.max_restarts {
            actions.push(Action::EndRun(Outcome::ChildFailed(role, -1)));
            return actions;
        }
        let wait = self.count_restart(role, now, true);
        self.pending.push(PendingRestart {
            role,
            due: now + wait,
        });
        actions
    }

    /// How `role` comes back after its crash (the role's serving instance is
    /// dead). A controller with a standby that follows the loop promotes it.
    /// A program of one's own (`is_program` says which scenario names one
    /// for the role) that dies is rolled back to the newest built-in design
    /// that served before it, if one did: a law that crashed once is likely
    /// to crash again, and the built-in one is known to hold the loop.
    pub fn plan_restart(
        &mut self,
        role: Role,
        is_program: &dyn Fn(&Path) -> bool,
    ) -> Result<RestartPlan, Failure> {
        // The file of the generation that owned the loop (with spares the
        // order of the members is not the order they served in).
        let owner = match role {
            Role::Controller => Some(self.activation.controller_generation),
            Role::Observer => Some(self.activation.observer_generation),
            _ => None,
        };
        let scenario = owner
            .and_then(|g| {
                self.roster
                    .iter()
                    .rev()
                    .find(|m| m.role == role && m.generation == Some(g) && !m.standby())
            })
            .or_else(|| self.roster.serving(role))
            .map(|m| m.scenario.clone())
            .ok_or(Failure::NoInstanceToRestart)?;
        if role == Role::Controller
            && let Some(generation) = self.promote_standby()
        {
            return Ok(RestartPlan::Promote { generation });
        }
        let generation = self.roster.next_generation(role);
        if role == Role::Logger {
            return Ok(RestartPlan::Logger {
                scenario,
                generation,
            });
        }
        let rollback = is_program(&scenario)
            .then(|| {
                self.roster
                    .iter()
                    .rev()
                    // (One that served and was replaced may be a spare now.)
                    .find(|m| m.role == role && m.generation.is_some() && !is_program(&m.scenario))
                    .map(|m| m.scenario.clone())
            })
            .flatten();
        let (scenario, rolled_back_from) = match rollback {
            Some(built_in) => (built_in, Some(scenario)),
            None => (scenario, None),
        };
        Ok(RestartPlan::Fresh {
            scenario,
            generation,
            owns_from: self.restart_boundary(role),
            rolled_back_from,
        })
    }

    /// The standby controller that follows the loop becomes the active one.
    fn promote_standby(&mut self) -> Option<u32> {
        let shadows = &self.shadows_seen;
        let standby = self.roster.iter_mut().find(|m| {
            m.standby()
                && m.alive()
                && m.generation
                    .is_some_and(|g| shadows.contains(&(Role::Controller, g)))
        })?;
        standby.duty = Duty::Active;
        standby.generation
    }

    /// A restart's boundary: the dead predecessor's replacement owns at once
    /// the samples it left unserved, from the first after its last state
    /// (its last command; the estimate after its last measurement). A
    /// boundary ahead, as a swap has, would never come in lockstep: the
    /// loop waits for the dead one's output. None before tick 0 or if the
    /// predecessor never served.
    pub fn restart_boundary(&self, role: Role) -> Option<u64> {
        self.last_seq?;
        let last = (*self.last_active.get(role))?;
        match role {
            Role::Controller => Some(last.seq + 1),
            Role::Observer => Some(last.seq + 2),
            _ => None,
        }
    }

    // ---- swaps ----

    /// The live instance a swap of `role` replaces, and the new generation.
    pub fn plan_swap(&self, role: Role) -> Result<(i32, u32), Failure> {
        let old = self
            .roster
            .serving(role)
            .filter(|m| m.alive())
            .map(|m| m.pid)
            .ok_or(Failure::NotRunning(role))?;
        Ok((old, self.roster.next_generation(role)))
    }

    /// A swap's boundary: far enough ahead that every process sees the
    /// announcement first, at the loop's real pace (lockstep runs faster
    /// than its rate).
    pub fn boundary_ahead(&self) -> u64 {
        let now_seq = self.last_seq.unwrap_or(0);
        let observed = self.pace.observed().unwrap_or(0.0);
        let margin = ((self.policy.rate_hz.max(observed) * ANNOUNCE_AHEAD.as_secs_f64()) as u64)
            .max(ANNOUNCE_AHEAD_MIN_SAMPLES);
        now_seq + margin
    }

    /// The activation in which `generation` of `role` owns the samples from
    /// `from_seq` on (the shell publishes it, then calls [`Core::announced`]).
    pub fn activation_for(&self, role: Role, generation: u32, from_seq: u64) -> Activation {
        let mut next = self.activation;
        match role {
            Role::Controller => {
                next.previous_controller_generation =
                    next.controller_for(from_seq.saturating_sub(1));
                next.controller_generation = generation;
                next.controller_from_seq = from_seq;
            }
            _ => {
                next.previous_observer_generation = next.observer_for(from_seq.saturating_sub(1));
                next.observer_generation = generation;
                next.observer_from_seq = from_seq;
            }
        }
        next
    }

    pub fn announced(&mut self, activation: Activation) {
        self.activation = activation;
    }

    // ---- measurements ordered on the running loop ----

    /// The end sample of the measurement that runs now, if one does.
    pub fn measurement_under_way(&self) -> Option<u64> {
        let (_, end) = self.measuring?;
        self.last_seq.is_none_or(|s| s < end).then_some(end)
    }

    /// Where a measurement ordered now starts (a boundary ahead, as a
    /// swap's: the plant designs it meanwhile), or why none can: the loop
    /// does not tick yet, or one runs.
    pub fn plan_measurement(&self) -> Result<u64, Failure> {
        if !self.ticking() {
            return Err(Failure::NotTickingYet);
        }
        if let Some(until) = self.measurement_under_way() {
            return Err(Failure::Measuring { until });
        }
        if self.sequence.is_some() {
            return Err(Failure::Changing);
        }
        Ok(self.boundary_ahead())
    }

    pub fn measurement_ordered(&mut self, start_seq: u64, end_seq: u64) {
        self.measuring = Some((start_seq, end_seq));
    }

    /// A swap or a set changes the loop: not while a measurement of it runs.
    pub fn may_change_the_loop(&self) -> Result<(), Failure> {
        match self.measurement_under_way() {
            Some(until) => Err(Failure::Measuring { until }),
            None => Ok(()),
        }
    }

    // ---- bringing an instance in ----

    /// How to bring in an instance of `role`: an idle warm spare if there is
    /// one, else a new process. Not before tick 0: until then the plant
    /// counts on each spare to be there as a spare. `waited_out`: the wait
    /// for a spare still starting is over.
    /// A scenario with its `own_program` for the role is always a new
    /// process: a spare runs the built-in law.
    pub fn engagement(&self, role: Role, waited_out: bool, own_program: bool) -> Engagement {
        if !self.policy.warm_spares || !self.ticking() || own_program {
            return Engagement::Start;
        }
        if let Some(pid) = self.roster.idle_spare(role) {
            return Engagement::Order(pid);
        }
        if self.roster.spare_starting(role) && !waited_out {
            return Engagement::WaitForSpare;
        }
        Engagement::Start
    }

    /// The spare `pid` took the order: it serves `generation` as `joining` says.
    pub fn ordered(&mut self, pid: i32, generation: u32, joining: Joining, scenario: &Path) {
        if let Some(m) = self.roster.get_mut(pid) {
            m.duty = if joining == Joining::Standby {
                Duty::Standby
            } else {
                Duty::Active
            };
            m.settled = false;
            m.generation = Some(generation);
            m.scenario = scenario.to_path_buf();
        }
    }

    /// One look at a new instance on its way in.
    pub fn shadow_step(&mut self, role: Role, generation: u32, shutting_down: bool) -> ShadowStep {
        let last = *self.last_active.get(role);
        if self.shadows_seen.contains(&(role, generation))
            || last.is_some_and(|l| l.generation == generation)
        {
            return ShadowStep::Following;
        }
        let plant_ended = self.roster.serving(Role::Plant).is_some_and(|p| !p.alive());
        if shutting_down || plant_ended {
            return ShadowStep::Failed(Failure::RunEndedBeforeFollowing);
        }
        if let Some(new) = self.roster.of_generation(role, generation)
            && let Some(code) = new.exit
        {
            let pid = new.pid;
            self.settle(pid);
            return ShadowStep::Failed(Failure::NewInstanceExited {
                role,
                generation,
                pid,
                code,
            });
        }
        let hand_over = last
            .filter(|l| self.roster.generation_gone(role, l.generation))
            .map(Box::new);
        ShadowStep::Waiting { hand_over }
    }

    /// One look at the loop on its way past `from_seq` (and the samples
    /// measured after it), with `old` the instance it replaces.
    pub fn drain_step(&self, from_seq: u64, old: Option<i32>, shutting_down: bool) -> DrainStep {
        // Measured once the plant applied the new owner's first command and
        // the ticks after it (a restart after a hold applies it ticks past
        // its boundary: measured at the boundary, its step was unknown);
        // a second's samples without one are measured as they are.
        let first = self
            .applied
            .first_applied_from(from_seq)
            .unwrap_or(from_seq + self.policy.rate_hz.ceil() as u64);
        let passed = self.last_seq.is_some_and(|s| s > first + BEFORE_SWITCH);
        let old_gone =
            old.is_none_or(|pid| self.roster.get(pid).is_none_or(|m| !m.alive() || m.spare()));
        if passed && old_gone {
            return DrainStep::Passed;
        }
        let plant_ended = self.roster.serving(Role::Plant).is_some_and(|p| !p.alive());
        if plant_ended || shutting_down {
            return DrainStep::RunEnded;
        }
        DrainStep::Waiting
    }

    /// What one swap or restart did, measured once the loop passed it.
    pub fn switch(
        &self,
        role: Role,
        generation: u32,
        start_seq: u64,
        from_seq: u64,
        warm: bool,
    ) -> Switch {
        let steps = self.applied.steps_at(from_seq);
        Switch {
            role,
            generation,
            start_seq,
            from_seq,
            du_switch: steps.at_switch,
            du_before: steps.before,
            du_after: steps.after,
            warm,
        }
    }

    /// The exit of `pid` is dealt with (replaced, stopped, restarted).
    pub fn settle(&mut self, pid: i32) {
        if let Some(m) = self.roster.get_mut(pid) {
            m.settled = true;
        }
    }

    // ---- standby and spares ----

    /// With `safe_action = "standby"`, one standby controller follows the
    /// running loop: started once the loop ticks, again after a promotion
    /// or a crash of the standby, within the restart budget.
    fn keep_standby(&self) -> Option<Action> {
        if !self.policy.keep_standby
            || !self.ticking()
            || self.run_ending
            || self.pending.iter().any(|p| p.role == Role::Controller)
            || *self.restarts.get(Role::Controller) > self.policy.max_restarts
            || self.roster.has_live_standby()
        {
            return None;
        }
        let scenario = self.roster.serving(Role::Controller)?.scenario.clone();
        Some(Action::StartStandby {
            scenario,
            generation: self.roster.next_generation(Role::Controller),
        })
    }

    /// The standby `generation` was engaged: `pid`, a warm spare or not.
    fn standby_started(&mut self, generation: u32, pid: i32, warm: bool) -> Action {
        self.note(
            Role::Controller,
            Some(generation),
            EventKind::Standby(Standby {
                pid,
                warm: Some(warm),
                ..Standby::default()
            }),
        )
    }

    /// The standby `generation` could not be engaged: it costs the restart
    /// budget (a standby that never starts must not be retried forever).
    fn standby_failed(&mut self, generation: u32, why: String) -> Action {
        *self.restarts.get_mut(Role::Controller) += 1;
        self.note(
            Role::Controller,
            Some(generation),
            EventKind::StandbyFailed(why),
        )
    }

    /// With warm spares, one spare controller and one spare observer, before
    /// tick 0 too (the plant waits for a spare of each; the first ones start
    /// with the loop; another after a spare crashed or served), within each
    /// role's spare budget.
    fn keep_spares(&self) -> Vec<Action> {
        let plant_running = self.roster.serving(Role::Plant).is_some_and(|p| p.alive());
        if !self.policy.warm_spares || self.run_ending || !plant_running {
            return Vec::new();
        }
        [Role::Controller, Role::Observer]
            .into_iter()
            .filter(|&role| {
                !self.pending.iter().any(|p| p.role == role)
                    && *self.spare_failures.get(role) <= self.policy.max_restarts
                    && !self.roster.has_live_spare(role)
            })
            .map(Action::StartSpare)
            .collect()
    }

    /// What became of [`Action::StartSpare`].
    pub fn spare_started(&mut self, role: Role, result: &anyhow::Result<i32>) -> Action {
        match result {
            Ok(pid) => self.note(role, None, EventKind::Spare(Spare { pid: *pid })),
            Err(e) => {
                *self.spare_failures.get_mut(role) += 1;
                self.note(role, None, EventKind::SpareFailed(format!("{e:#}")))
            }
        }
    }

    /// After a swap to another controller design the standby must follow
    /// the new one: with the old design it can neither copy the active
    /// state nor compute the command the active one would have sent, and a
    /// promotion would step. A standby of the new design starts; once it
    /// follows the loop, the old ones retire (until then they cover).
    pub fn standby_renewal(&self) -> Option<Renewal> {
        if !self.policy.keep_standby {
            return None;
        }
        let active = self.roster.serving(Role::Controller)?.scenario.clone();
        let old: Vec<(i32, u32)> = self
            .roster
            .iter()
            .filter(|m| m.standby() && m.alive() && m.scenario != active)
            .map(|m| (m.pid, m.generation.unwrap_or(0)))
            .collect();
        if old.is_empty() {
            return None;
        }
        Some(Renewal {
            scenario: active,
            generation: self.roster.next_generation(Role::Controller),
            old,
        })
    }

    /// A serving standby no longer needed: told to become a spare (it
    /// reports itself idle then) with warm spares, else stopped.
    pub fn retirement(&self) -> Retirement {
        if self.policy.warm_spares {
            Retirement::Order
        } else {
            Retirement::Stop
        }
    }

    /// The order to retire went out to `pid`.
    pub fn retiring(&mut self, pid: i32, now: Instant) {
        self.retiring.push((pid, now));
    }

    /// Stops a standby told to retire that did not become a spare in time.
    fn check_retiring(&mut self, now: Instant) -> Vec<Action> {
        let mut late = Vec::new();
        let roster = &self.roster;
        self.retiring.retain(|&(pid, since)| {
            let Some(m) = roster.get(pid) else {
                return false;
            };
            if m.spare() || !m.alive() {
                return false;
            }
            if now.duration_since(since) > RETIRE_TIMEOUT {
                late.push(pid);
                return false;
            }
            true
        });
        for &pid in &late {
            self.settle(pid);
        }
        late.into_iter().map(Action::Stop).collect()
    }
}

#[cfg(test)]
mod tests;
