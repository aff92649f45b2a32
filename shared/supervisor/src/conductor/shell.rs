//! The conductor's shell: it watches the loop over IPC and feeds what it
//! sees to the decision core (`decide.rs`), carries out the core's actions
//! (orders, announcements, processes started and stopped, the run's files),
//! and runs a swap's, restart's or standby's sequence
//! (`decide/sequence.rs`): it looks when the core says to, carries out the
//! core's commands and reports how they went; the core decides every step.

use super::decide::{
    Action, Carried, Command, Core, Event, Failure, Look, Order, Policy, Record, Stage, Step,
};
use super::ports::Ports;
use super::record::RunFiles;
use super::replay::Replay;
use super::requests;
use super::switch::Switch;
use super::tuning::Tuning;
use crate::children::{Outcome, RunningLoop};
use anyhow::{Context, Result, anyhow, bail};
use flexloop_design::LoopDesign;
use flexloop_node::Role;
use flexloop_protocol::Joining;
use flexloop_protocol::channels::MEASUREMENT_REPLAY;
use flexloop_protocol::{Activation, SpareOrder};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::{EventKind, Measure, Set, Stop, Swap};
use flexloop_runfiles::supervision::{
    MeasureAnswer, MeasureOutcome, SetAnswer, SetOutcome, SwapAnswer,
};
use flexloop_runtime::shutdown;
use flexloop_scenario::swap::{Swapped, swap_conflicts};
use flexloop_scenario::{Overrides, Scenario};
use std::os::fd::RawFd;
use std::path::Path;
use std::time::{Duration, Instant};

/// How far back the supervisor keeps measurements for a restarted observer:
/// the crash noticed (20 ms), the back-off (100 ms, doubled per restart), the
/// replacement's start-up (tens of ms), with room to spare.
const REPLAY_SPAN: Duration = Duration::from_secs(2);
const MAX_REPLAY_SAMPLES: usize = 1 << 16;

pub struct Conductor {
    ports: Ports,
    core: Core,
    replay: Replay,
    files: RunFiles,
    scenario: Scenario,
    overrides: Overrides,
    pub switches: Vec<Switch>,
    /// A process died and its node's shared memory is not cleaned yet.
    dead_nodes: bool,
    /// The scenario as it stands after requested swaps and sets.
    tuning: Tuning,
    /// Who sent the request being served: its `swap` and `set` events name
    /// them.
    sender: Option<requests::Sender>,
}

impl Conductor {
    pub fn open(
        prefix: &str,
        run_dir: &Path,
        scenario: &Scenario,
        overrides: &Overrides,
    ) -> Result<Self> {
        let ports = Ports::open(prefix)?;
        let replay_capacity = ((scenario.timing.rate_hz * REPLAY_SPAN.as_secs_f64()) as usize)
            .clamp(1024, MAX_REPLAY_SAMPLES);
        let activation = ports.publish_activation(Activation::INITIAL)?;
        let design = LoopDesign::from_scenario(scenario);
        let n_inputs = design.as_ref().map(|d| d.n_inputs).unwrap_or(1);
        let mut core = Core::new(Policy::of(scenario, n_inputs), activation);
        // The scenario's own `[measure]` holds changes off as an ordered one
        // does: a swap or a set during it would change the loop it measures.
        if let Some(plan) = design.ok().and_then(|d| d.measurement) {
            core.measurement_ordered(plan.start_tick, plan.end_tick());
        }
        Ok(Self {
            ports,
            core,
            // Replayed measurements in flight at most: the replay queue's depth.
            replay: Replay::new(
                replay_capacity,
                MEASUREMENT_REPLAY.qos.loop_buffer_size as u64,
            ),
            files: RunFiles::new(run_dir),
            scenario: scenario.clone(),
            overrides: overrides.clone(),
            switches: Vec::new(),
            dead_nodes: false,
            tuning: Tuning::default(),
            sender: None,
        })
    }

    fn poll(&mut self) {
        self.ports.poll(&mut self.core, &mut self.replay);
    }

    /// Tells the core of processes started and ended since the last look,
    /// and the supervisor which exits are expected. Crash records go out.
    fn track(&mut self, running: &mut RunningLoop) {
        let now = Instant::now();
        let mut events = Vec::new();
        for c in &running.children {
            if !self.core.roster().knows(c.pid) {
                events.push(Event::Launched {
                    pid: c.pid,
                    role: c.role,
                    generation: c.generation,
                    joining: c.joining,
                    scenario: c.scenario.clone(),
                    program: c.program,
                });
            }
            if let Some(exit) = c.exit
                && self
                    .core
                    .roster()
                    .get(c.pid)
                    .is_none_or(|m| m.exit.is_none())
            {
                // Its node is dead now (not before: a process found exiting
                // and dealt with early may still hold its ports).
                self.dead_nodes = true;
                events.push(Event::Exited {
                    pid: c.pid,
                    code: exit.code,
                    now,
                });
            }
        }
        for event in events {
            let actions = self.core.handle(event);
            self.record_all(actions);
        }
        for m in self.core.roster().iter() {
            running.expect_exit(m.pid, m.exit_expected());
        }
    }

    /// One look at everything: processes first, so that the channels' news
    /// (a spare's idle report) finds the process it is about.
    fn observe(&mut self, running: &mut RunningLoop) {
        running.reap();
        self.track(running);
        self.poll();
    }

    /// Writes the records among `actions` (those an exit or an observation
    /// brings: nothing else).
    fn record_all(&mut self, actions: Vec<Action>) {
        for action in actions {
            match action {
                Action::Record(record) => self.record(record),
                other => unreachable!("an exit or observation asked for {other:?}"),
            }
        }
    }

    fn record(&mut self, mut record: Record) {
        self.dead_nodes |= record.clean_dead_nodes;
        match &mut record.kind {
            EventKind::Swap(Swap { sender, .. })
            | EventKind::Set(Set { sender, .. })
            | EventKind::Measure(Measure { sender, .. }) => {
                *sender = self.sender;
            }
            _ => {}
        }
        self.files.append(&record);
    }

    /// The loop is stopping because it was asked to (a signal): the `stop`
    /// event, naming who asked when `flexloop down` left its note.
    pub fn note_stop(&mut self) {
        let sender = requests::take_stop_sender(self.files.run_dir());
        let stop = Stop {
            by: match sender {
                Some(_) => "flexloop down",
                None => "a signal (Ctrl-C, or SIGTERM from elsewhere)",
            }
            .into(),
            sender,
        };
        self.record_action(self.core.note(Role::Plant, None, EventKind::Stop(stop)));
        self.publish_files();
    }

    /// Removes dead nodes' shared memory if a process died since the last
    /// time. Not before a restart: it takes iceoryx2 25 ms, 250 held ticks
    /// at 10 kHz (measured with `flexloop chaos`); but before a new process
    /// opens its ports, which a dead node's ports may still count against.
    fn clean_dead_nodes(&mut self) {
        if std::mem::take(&mut self.dead_nodes) {
            self.ports.clean_dead_nodes();
        }
    }

    /// Carries out the core's actions; returns the run's end if one says so.
    fn execute(&mut self, running: &mut RunningLoop, actions: Vec<Action>) -> Option<Outcome> {
        for action in actions {
            match action {
                Action::Record(record) => self.record(record),
                Action::Stop(pid) => self.stop(running, pid),
                Action::Kill(pid) => running.kill(pid),
                Action::EndRun(outcome) => return Some(outcome),
                Action::Restart(role) => {
                    if let Err(e) = self.conduct(running, Order::Restart(role)) {
                        eprintln!(
                            "flexloop: restart of flexloop-{} failed: {e:#}",
                            role.name()
                        );
                        let then = self.core.restart_failed(
                            role,
                            &e,
                            Instant::now(),
                            shutdown::requested(),
                        );
                        if let Some(outcome) = self.execute(running, then) {
                            return Some(outcome);
                        }
                    }
                }
                Action::StartSpare(role) => {
                    self.clean_dead_nodes();
                    let started = running.start_spare(role);
                    self.track(running);
                    let record = self.core.spare_started(role, &started);
                    self.record_action(record);
                }
                Action::StartStandby {
                    scenario,
                    generation,
                } => {
                    // Its failure is an event of its own (`standby-failed`).
                    let order = Order::Standby {
                        scenario,
                        generation,
                    };
                    if let Err(e) = self.conduct(running, order) {
                        eprintln!("flexloop: the standby controller: {e:#}");
                    }
                }
            }
        }
        None
    }

    /// Runs a swap, restart or standby's start to its end (one at a time,
    /// never one inside another): the core advances it at each look and
    /// says what to carry out; crashes seen meanwhile are settled at its end
    /// (it may be the one that deals with them). Returns its switch.
    fn conduct(&mut self, running: &mut RunningLoop, order: Order) -> Result<Option<Switch>> {
        let role = order.role();
        let is_program = |scenario: &Path| {
            crate::children::own_program(role, scenario)
                .map(|program| program.is_some())
                .map_err(|e| format!("{e:#}"))
        };
        self.core.begin(order, look(), &is_program)?;
        loop {
            match self.core.advance(look()) {
                Step::Carry(command) => {
                    let carried = self.carry_out(running, command);
                    self.core.carried(carried, Instant::now());
                    self.track(running);
                }
                Step::Wait(wait) => {
                    std::thread::sleep(wait);
                    self.observe(running);
                    self.refuse_measurements_meanwhile();
                }
                Step::Done(end) => {
                    for action in end.actions {
                        match action {
                            Action::Record(record) => self.record(record),
                            Action::Stop(pid) => running.terminate(pid),
                            other => unreachable!("a sequence's end asked for {other:?}"),
                        }
                    }
                    self.track(running);
                    return match end.result {
                        Ok(switch) => {
                            self.switches.extend(switch.clone());
                            Ok(switch)
                        }
                        Err(failure) => Err(self.explain(running, failure)),
                    };
                }
            }
        }
    }

    /// A measurement asked for while a sequence changes the loop would span
    /// two loops: it is refused at once (a swap or a set waits its turn).
    fn refuse_measurements_meanwhile(&self) {
        for request in requests::pending(self.files.run_dir()) {
            if !requests::is_measure(&request) {
                continue;
            }
            if let Err(refusal) = self.core.plan_measurement() {
                self.refuse(&request, refusal.to_string());
            }
        }
    }

    /// Carries out one of a sequence's commands.
    fn carry_out(&mut self, running: &mut RunningLoop, command: Command) -> Carried {
        let failed = |e: anyhow::Error| Carried::Failed(format!("{e:#}"));
        match command {
            Command::Launch {
                role,
                scenario,
                generation,
                joining,
            } => {
                self.clean_dead_nodes();
                let launched = running.launch(role, &scenario, generation, joining);
                self.track(running);
                launched.map_or_else(failed, Carried::Launched)
            }
            Command::Order {
                pid,
                generation,
                joining,
                scenario,
            } => self
                .order(pid, generation, joining, &scenario)
                .map_or_else(failed, |()| Carried::Done),
            Command::Publish(activation) => self
                .ports
                .publish_activation(activation)
                .map_or_else(failed, Carried::Published),
            Command::HandOver {
                role,
                generation,
                state,
            } => {
                self.ports.hand_over(role, &state);
                if role == Role::Observer {
                    self.ports
                        .feed_replay(&mut self.replay, generation, state.seq);
                }
                Carried::Done
            }
            Command::Retire(pid) => {
                let order = SpareOrder {
                    pid: pid as u32,
                    // To a serving standby: stop, and idle as a spare.
                    joining: Joining::Spare.wire(),
                    ..SpareOrder::default()
                };
                self.ports
                    .send_order(order)
                    .map_or_else(failed, |()| Carried::Done)
            }
            Command::Stop(pid) => {
                running.terminate(pid);
                Carried::Done
            }
        }
    }

    /// A failure as the user reads it: a new instance that exited points to
    /// its stderr file.
    fn explain(&self, running: &RunningLoop, failure: Failure) -> anyhow::Error {
        if let Failure::NewInstanceExited { pid, .. } = failure {
            let stderr = running
                .children
                .iter()
                .find(|c| c.pid == pid)
                .map(|c| self.files.run_dir().join(&c.stderr_file))
                .unwrap_or_default();
            return anyhow!("{failure}; see {}", stderr.display());
        }
        failure.into()
    }

    /// Stops one process whose exit is dealt with.
    fn stop(&mut self, running: &mut RunningLoop, pid: i32) {
        self.core.settle(pid);
        running.terminate(pid);
    }

    /// When to look again at the latest: when a silent role's silence is
    /// due to be judged (a law that sleeps is found at its 200th silent
    /// tick, not up to a 20 ms look later).
    pub fn next_look(&self) -> Option<Instant> {
        self.core.silence_due()
    }

    /// What the supervisor's wait also wakes on: the plant's silence alarm.
    pub fn wake_fds(&self) -> Vec<RawFd> {
        vec![self.ports.alarm_fd()]
    }

    /// Called by the supervisor every 20 ms, when a child exits and when the
    /// plant's silence alarm rings: crashes,
    /// restarts, spares,
    /// the standby, requests. The run's files are up to date after it.
    pub fn tick(&mut self, running: &mut RunningLoop) -> Option<Outcome> {
        let outcome = self.tick_stages(running);
        self.clean_dead_nodes();
        if self.core.ticking() && running.ticking_since.is_none() {
            running.ticking_since = Some(Instant::now());
        }
        self.track(running);
        self.publish_files();
        outcome
    }

    fn tick_stages(&mut self, running: &mut RunningLoop) -> Option<Outcome> {
        // The supervisor reaped just now.
        self.track(running);
        self.poll();
        // After the poll: a process that exits because the run ended is
        // then known to (the poll saw the plant's last sample).
        for pid in self.core.watched_processes() {
            let actions = self.core.handle(Event::ProcessState {
                pid,
                state: crate::process_state::of(pid),
                runqueue_wait_ns: crate::process_state::runqueue_wait_ns(pid),
                now: Instant::now(),
            });
            if let Some(outcome) = self.execute(running, actions) {
                return Some(outcome);
            }
        }
        for stage in Stage::IN_ORDER {
            let actions = self.core.handle(Event::Tick {
                now: Instant::now(),
                stage,
            });
            if let Some(outcome) = self.execute(running, actions) {
                return Some(outcome);
            }
        }
        for request in requests::pending(self.files.run_dir()) {
            // A request from another user is refused: the loop is its
            // starter's to change (a foreign swap and stop were seen).
            self.sender = requests::sender(&request);
            let own = self
                .sender
                .is_none_or(|s| s.uid == crate::registry::caller());
            if !own {
                let refusal = format!(
                    "the loop belongs to uid {}; a request from uid {} is refused",
                    crate::registry::caller(),
                    self.sender.map_or(u32::MAX, |s| s.uid)
                );
                self.refuse(&request, refusal);
                continue;
            }
            if requests::is_measure(&request) {
                let answer = match requests::read_measure(&request).and_then(|r| self.measure(&r)) {
                    Ok(outcome) => MeasureAnswer {
                        outcome: Some(outcome),
                        error: None,
                    },
                    Err(e) => MeasureAnswer {
                        outcome: None,
                        error: Some(format!("{e:#}")),
                    },
                };
                self.publish_files();
                requests::answer(&request, &answer);
                continue;
            }
            // A swap or a set changes the loop a measurement measures.
            if let Err(refusal) = self.core.may_change_the_loop() {
                self.refuse(&request, refusal.to_string());
                continue;
            }
            if requests::is_set(&request) {
                let answer = match requests::read_set(&request).and_then(|r| self.set(running, &r))
                {
                    Ok(outcome) => SetAnswer {
                        outcome: Some(outcome),
                        error: None,
                    },
                    Err(e) => SetAnswer {
                        outcome: None,
                        error: Some(format!("{e:#}")),
                    },
                };
                self.publish_files();
                requests::answer(&request, &answer);
                continue;
            }
            let answer = match requests::read(&request).and_then(|r| {
                let switch = self.swap(running, r.role, &r.scenario)?;
                self.note_swapped(r.role, &r.scenario);
                Ok(switch)
            }) {
                Ok(switch) => SwapAnswer::done(switch.record()),
                Err(e) => SwapAnswer::refused(format!("{e:#}")),
            };
            // The files first: who asked may look there next.
            self.publish_files();
            requests::answer(&request, &answer);
        }
        None
    }

    /// Answers a request with a refusal, in the answer type of its kind.
    fn refuse(&self, request: &Path, refusal: String) {
        if requests::is_set(request) {
            let answer = SetAnswer {
                outcome: None,
                error: Some(refusal),
            };
            requests::answer(request, &answer);
        } else if requests::is_measure(request) {
            let answer = MeasureAnswer {
                outcome: None,
                error: Some(refusal),
            };
            requests::answer(request, &answer);
        } else {
            requests::answer(request, &SwapAnswer::refused(refusal));
        }
    }

    /// `flexloop measure --running`: the measurement checked against the
    /// loop's scenario, ordered from a sample ahead, and recorded.
    fn measure(
        &mut self,
        request: &flexloop_runfiles::supervision::MeasureRequest,
    ) -> Result<MeasureOutcome> {
        let start_seq = self.core.plan_measurement()?;
        // The loop it measures, as it stands now (after swaps and sets): it
        // is checked against it, and judged against its design whatever
        // swaps come after.
        let run_dir = RunDir::new(self.files.run_dir());
        let snapshot = run_dir.measured_scenario(start_seq);
        self.tuning
            .snapshot(&run_dir, &self.scenario, &snapshot)
            .context("the scenario the measurement measures")?;
        let planned = Scenario::load(&snapshot, &self.overrides)
            .map_err(anyhow::Error::from)
            .and_then(|now| super::measuring::plan(&now, request, start_seq));
        let planned = match planned {
            Ok(planned) => planned,
            Err(e) => {
                // Refused: nothing of it is left in the run directory.
                let _ = std::fs::remove_dir_all(run_dir.ordered_measurement(start_seq));
                return Err(e);
            }
        };
        self.ports.send_measure_order(planned.order)?;
        let outcome = planned.outcome;
        self.core
            .measurement_ordered(outcome.start_seq, outcome.end_seq);
        self.record_action(self.core.note(
            Role::Plant,
            None,
            EventKind::Measure(Measure {
                outcome: outcome.clone(),
                sender: None,
            }),
        ));
        Ok(outcome)
    }

    /// `role` runs `scenario` now: the scenario as it stands follows (a
    /// file that cannot be written is said, the swap stands).
    fn note_swapped(&mut self, role: Role, scenario: &Path) {
        let run_dir = RunDir::new(self.files.run_dir());
        if let Err(e) = self
            .tuning
            .swapped(&run_dir, &self.scenario, role, scenario)
        {
            eprintln!("flexloop: the scenario as it stands: {e:#}");
        }
    }

    /// `flexloop set`: the changed scenario checked and written (refused
    /// with the reason, the loop untouched), then handed to the controller
    /// through the swap path; one `set` event after the swap's names the
    /// fields, their old and new values, the file and the switch.
    fn set(
        &mut self,
        running: &mut RunningLoop,
        request: &flexloop_runfiles::supervision::SetRequest,
    ) -> Result<SetOutcome> {
        let since = Instant::now();
        let run_dir = RunDir::new(self.files.run_dir());
        let plan = self
            .tuning
            .plan(&run_dir, &self.scenario, &self.overrides, request)?;
        let check_s = since.elapsed().as_secs_f64();
        let Some(plan) = plan else {
            return Ok(SetOutcome {
                fields: Vec::new(),
                file: None,
                switches: Vec::new(),
                check_s,
                handover_s: 0.0,
            });
        };
        // An observer set hands the controller over second, when its
        // feedforward follows the observer (`tuning::observer_roles`).
        let mut switches = Vec::new();
        let mut first = None;
        for &role in &plan.roles {
            let switch = self.swap(running, role, &plan.file).map_err(|e| {
                let taken = switches
                    .iter()
                    .map(|s: &Switch| format!("the {} took it; ", s.role.name()))
                    .collect::<String>();
                e.context(format!(
                    "{taken}the {} did not take {}",
                    role.name(),
                    plan.file.display()
                ))
            })?;
            self.note_swapped(role, &plan.file);
            first.get_or_insert((role, switch.generation));
            switches.push(switch);
        }
        if let Some(settings) = plan.plant {
            self.ports.publish_plant_settings(settings)?;
            self.note_swapped(Role::Plant, &plan.file);
            first.get_or_insert((Role::Plant, 0));
        }
        let (role, generation) = first.expect("a set plan names a role or the plant's settings");
        let outcome = SetOutcome {
            fields: plan.fields,
            file: Some(plan.file.display().to_string()),
            switches: switches.iter().map(Switch::record).collect(),
            check_s,
            handover_s: since.elapsed().as_secs_f64() - check_s,
        };
        // The plant has no generation: it is never swapped.
        let generation = (role != Role::Plant).then_some(generation);
        self.record_action(self.core.note(
            role,
            generation,
            EventKind::Set(Set {
                outcome: outcome.clone(),
                sender: None,
            }),
        ));
        self.publish_files();
        Ok(outcome)
    }

    fn publish_files(&mut self) {
        let list = self.core.roster().processes();
        self.files.publish(list);
    }

    /// Replaces the active `role` by an instance running `scenario`.
    pub fn swap(
        &mut self,
        running: &mut RunningLoop,
        role: Role,
        scenario_path: &Path,
    ) -> Result<Switch> {
        self.check_compatible(role, scenario_path)?;
        // The loop's newest sample: a replacement follows a ticking loop.
        self.poll();
        let order = Order::Swap {
            role,
            scenario: scenario_path.to_path_buf(),
        };
        let switch = self.conduct(running, order);
        self.publish_files();
        switch?.ok_or_else(|| anyhow!("the swap of flexloop-{} made no switch", role.name()))
    }

    fn record_action(&mut self, action: Action) {
        self.record_all(vec![action]);
    }

    /// The replacement must fit the running loop: what no design change can
    /// make bumpless stays as it is (`flexloop_scenario::swap`), and the
    /// design passes its own checks.
    fn check_compatible(&self, role: Role, path: &Path) -> Result<()> {
        let new = Scenario::load(path, &self.overrides)?;
        let swapped = match role {
            Role::Observer => Swapped::Observer,
            _ => Swapped::Controller,
        };
        let fields = swap_conflicts(&self.scenario, &new, swapped);
        if !fields.is_empty() {
            bail!(
                "{}: {} differ{} from the running loop's ({}); a swap may retune the controller \
                 and the observer, not the loop's rate, plant, set-point or loop delay (docs/architecture.md#what-a-swap-may-change)",
                path.display(),
                fields.join(", "),
                if fields.len() == 1 { "s" } else { "" },
                self.scenario.source.display()
            );
        }
        LoopDesign::from_scenario(&new)?;
        Ok(())
    }

    /// Orders the idle spare `pid` to join as `generation` running `scenario`.
    fn order(&self, pid: i32, generation: u32, joining: Joining, scenario: &Path) -> Result<()> {
        let path = scenario
            .to_str()
            .ok_or_else(|| anyhow!("{}: the path is not UTF-8", scenario.display()))?;
        let mut order = SpareOrder {
            pid: pid as u32,
            generation,
            joining: ordered_joining(joining)?.wire(),
            ..SpareOrder::default()
        };
        order
            .set_scenario(path)
            .map_err(|e| anyhow!("{}: {e}", scenario.display()))?;
        self.ports.send_order(order)
    }
}

/// What the shell sees of the supervisor itself at a look.
fn look() -> Look {
    Look {
        now: Instant::now(),
        shutting_down: shutdown::requested(),
    }
}

/// A spare is ordered to replace, restart or stand by (retiring is an order
/// of its own, to a standby).
fn ordered_joining(joining: Joining) -> Result<Joining> {
    match joining {
        Joining::Replacement | Joining::Restart | Joining::Standby => Ok(joining),
        Joining::AtStart | Joining::Spare => {
            bail!("a spare cannot be ordered to join as {joining:?}")
        }
    }
}
