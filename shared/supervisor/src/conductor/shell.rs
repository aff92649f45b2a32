//! The conductor's shell: it watches the loop over IPC and feeds what it
//! sees to the decision core (`decide.rs`), carries out the core's actions
//! (orders, announcements, processes started and stopped, the run's files),
//! and waits where a swap or restart must wait, asking the core at each step.

use super::decide::{
    Action, Core, DRAIN_TIMEOUT, DrainStep, Engagement, Event, Failure, Policy, Record,
    RestartPlan, Retirement, SHADOW_TIMEOUT, ShadowStep, Stage,
};
use super::ports::Ports;
use super::record::RunFiles;
use super::replay::Replay;
use super::requests;
use super::switch::Switch;
use super::tuning::Tuning;
use crate::children::{Outcome, RunningLoop};
use anyhow::{Result, anyhow, bail};
use flexloop_design::LoopDesign;
use flexloop_node::Role;
use flexloop_protocol::Joining;
use flexloop_protocol::channels::MEASUREMENT_REPLAY;
use flexloop_protocol::{Activation, SpareOrder};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::{EventKind, Restart, Set, Standby, Stop, Swap};
use flexloop_runfiles::supervision::{SetAnswer, SetOutcome, SwapAnswer};
use flexloop_runtime::shutdown;
use flexloop_scenario::swap::{Swapped, swap_conflicts};
use flexloop_scenario::{Overrides, Scenario};
use std::os::fd::RawFd;
use std::path::Path;
use std::time::{Duration, Instant};

/// How long a swap or restart waits for a spare that is still starting.
const SPARE_START_WAIT: Duration = Duration::from_secs(5);
/// How far back the supervisor keeps measurements for a restarted observer:
/// the crash noticed (20 ms), the back-off (100 ms, doubled per restart), the
/// replacement's start-up (tens of ms), with room to spare.
const REPLAY_SPAN: Duration = Duration::from_secs(2);
const MAX_REPLAY_SAMPLES: usize = 1 << 16;

/// A new instance on its way in.
struct Incoming {
    role: Role,
    generation: u32,
    /// The loop's sample when it was started or ordered.
    start_seq: u64,
    /// A warm spare (or a running standby), not a new process.
    warm: bool,
    /// The instance it replaces, alive (a swap).
    old: Option<i32>,
    /// The boundary, if already announced (a restart owns samples at once).
    announced: Option<u64>,
}

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
        let n_inputs = LoopDesign::from_scenario(scenario)
            .map(|d| d.n_inputs)
            .unwrap_or(1);
        Ok(Self {
            ports,
            core: Core::new(Policy::of(scenario, n_inputs), activation),
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
            EventKind::Swap(Swap { sender, .. }) | EventKind::Set(Set { sender, .. }) => {
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
                    let result = self.operation(running, |c, running| c.restart(running, role));
                    if let Err(e) = result {
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
                    let engaged = self.operation(running, |c, running| {
                        c.engage(
                            running,
                            Role::Controller,
                            &scenario,
                            generation,
                            Joining::Standby,
                        )
                    });
                    let record = self.core.standby_engaged(generation, &engaged);
                    self.record_action(record);
                }
            }
        }
        None
    }

    /// Runs a swap, restart or standby's start (one at a time, never one
    /// inside another): crashes seen meanwhile are settled once it is over
    /// (it may be the one that deals with them).
    fn operation<T>(
        &mut self,
        running: &mut RunningLoop,
        work: impl FnOnce(&mut Self, &mut RunningLoop) -> T,
    ) -> T {
        self.core.begin_operation();
        let result = work(self, running);
        let settled = self.core.end_operation(Instant::now());
        self.record_all(settled);
        self.track(running);
        result
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
                if requests::is_set(&request) {
                    requests::answer(
                        &request,
                        &SetAnswer {
                            outcome: None,
                            error: Some(refusal),
                        },
                    );
                } else {
                    requests::answer(&request, &SwapAnswer::refused(refusal));
                }
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

    /// Replaces the active `role` by an instance running `scenario_path`.
    pub fn swap(
        &mut self,
        running: &mut RunningLoop,
        role: Role,
        scenario_path: &Path,
    ) -> Result<Switch> {
        let switch = self.operation(running, |c, running| {
            c.swap_to(running, role, scenario_path)
        });
        self.publish_files();
        switch
    }

    fn swap_to(
        &mut self,
        running: &mut RunningLoop,
        role: Role,
        scenario_path: &Path,
    ) -> Result<Switch> {
        self.check_compatible(role, scenario_path)?;
        let (old, generation) = self.core.plan_swap(role)?;
        // A replacement follows a ticking loop (and a spare serves only then).
        let since = Instant::now();
        self.poll();
        while !self.core.ticking() {
            if since.elapsed() > SHADOW_TIMEOUT || shutdown::requested() {
                bail!("the loop did not start within {SHADOW_TIMEOUT:?}: nothing to swap into");
            }
            std::thread::sleep(Duration::from_millis(5));
            self.poll();
        }
        let start_seq = self.core.last_seq().unwrap_or(0);
        let (pid, warm) = self.engage(
            running,
            role,
            scenario_path,
            generation,
            Joining::Replacement,
        )?;
        if let Err(e) = self.await_shadow(running, role, generation) {
            self.stop(running, pid);
            return Err(e);
        }
        let switch = self.activate(
            running,
            Incoming {
                role,
                generation,
                start_seq,
                warm,
                old: Some(old),
                announced: None,
            },
        )?;
        self.record_action(self.core.note(
            role,
            Some(generation),
            EventKind::Swap(Swap {
                scenario: scenario_path.display().to_string(),
                switch: switch.record(),
                sender: None,
            }),
        ));
        self.switches.push(switch.clone());
        if role == Role::Controller {
            self.renew_standby(running);
        }
        Ok(switch)
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

    /// Brings up `role` as `generation` running `scenario`, as the core
    /// chooses: an idle warm spare, or a new process. Returns its pid and
    /// whether it was a spare.
    fn engage(
        &mut self,
        running: &mut RunningLoop,
        role: Role,
        scenario: &Path,
        generation: u32,
        joining: Joining,
    ) -> Result<(i32, bool)> {
        let own_program = crate::children::own_program(role, scenario)?.is_some();
        let since = Instant::now();
        // The first decision on what is known already: an idle spare is
        // ordered at once (a restart's every look costs held ticks).
        let mut first = true;
        loop {
            if !std::mem::take(&mut first) {
                self.observe(running);
            }
            match self
                .core
                .engagement(role, since.elapsed() > SPARE_START_WAIT, own_program)
            {
                Engagement::WaitForSpare => std::thread::sleep(Duration::from_millis(1)),
                Engagement::Order(pid) => {
                    self.order(pid, generation, joining, scenario)?;
                    self.core.ordered(pid, generation, joining, scenario);
                    self.track(running);
                    return Ok((pid, true));
                }
                Engagement::Start => {
                    self.clean_dead_nodes();
                    let pid = running.launch(role, scenario, generation, joining)?;
                    self.track(running);
                    return Ok((pid, false));
                }
            }
        }
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

    /// Waits until the new instance follows the loop in shadow, handing it
    /// meanwhile its dead predecessor's last state (and, to an observer, the
    /// measurements since).
    fn await_shadow(
        &mut self,
        running: &mut RunningLoop,
        role: Role,
        generation: u32,
    ) -> Result<()> {
        let since = Instant::now();
        loop {
            self.observe(running);
            match self
                .core
                .shadow_step(role, generation, shutdown::requested())
            {
                ShadowStep::Following => return Ok(()),
                ShadowStep::Failed(failure @ Failure::NewInstanceExited { pid, .. }) => {
                    self.track(running);
                    let stderr = running
                        .children
                        .iter()
                        .find(|c| c.pid == pid)
                        .map(|c| self.files.run_dir().join(&c.stderr_file));
                    let stderr = stderr.unwrap_or_default();
                    bail!("{failure}; see {}", stderr.display());
                }
                ShadowStep::Failed(failure) => return Err(failure.into()),
                ShadowStep::Waiting { hand_over } => {
                    if let Some(last) = hand_over {
                        self.ports.hand_over(role, &last);
                        if role == Role::Observer {
                            self.ports
                                .feed_replay(&mut self.replay, generation, last.seq);
                        }
                    }
                }
            }
            if since.elapsed() > SHADOW_TIMEOUT {
                bail!(
                    "the new flexloop-{} did not follow the loop within {SHADOW_TIMEOUT:?}",
                    role.name()
                );
            }
            // 0.2 ms, not 5: a restarted observer waits for the state and
            // the replayed measurements handed on here, and a restart's every
            // millisecond is 10 held ticks (this runs off the loop's CPU,
            // for the few milliseconds a restart takes).
            std::thread::sleep(Duration::from_micros(200));
        }
    }

    /// Announces the boundary (a swap's, ahead) unless announced already,
    /// waits until the loop passed it (and the old instance, if any, left),
    /// and measures the command's step there.
    fn activate(&mut self, running: &mut RunningLoop, incoming: Incoming) -> Result<Switch> {
        let Incoming {
            role,
            generation,
            start_seq,
            warm,
            old,
            announced,
        } = incoming;
        self.poll();
        let from_seq = match announced {
            Some(from_seq) => from_seq,
            None => {
                let from_seq = self.core.boundary_ahead();
                self.announce(role, generation, from_seq)?;
                from_seq
            }
        };
        if let Some(pid) = old {
            // Its exit (or, with warm spares, its retirement to a spare)
            // after the boundary is the plan, not a crash.
            self.core.settle(pid);
        }
        let since = Instant::now();
        loop {
            self.observe(running);
            match self.core.drain_step(from_seq, old, shutdown::requested()) {
                DrainStep::Passed => break,
                DrainStep::RunEnded => return Err(Failure::RunEndedBeforeSwitch.into()),
                DrainStep::Waiting => {}
            }
            if since.elapsed() > DRAIN_TIMEOUT {
                if let Some(pid) = old {
                    self.stop(running, pid);
                }
                bail!(
                    "the loop did not pass the switch at sample {from_seq} within {DRAIN_TIMEOUT:?}"
                );
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        Ok(self
            .core
            .switch(role, generation, start_seq, from_seq, warm))
    }

    /// Publishes that `generation` of `role` owns the samples from `from_seq` on.
    fn announce(&mut self, role: Role, generation: u32, from_seq: u64) -> Result<()> {
        let next = self.core.activation_for(role, generation, from_seq);
        let published = self.ports.publish_activation(next)?;
        self.core.announced(published);
        Ok(())
    }

    /// Brings `role` back after its crash, as the core plans it.
    fn restart(&mut self, running: &mut RunningLoop, role: Role) -> Result<()> {
        let start_seq = self.core.last_seq().unwrap_or(0);
        let is_program = |scenario: &Path| {
            crate::children::own_program(role, scenario).is_ok_and(|p| p.is_some())
        };
        let (scenario, generation, owns_from, rolled_back_from) = match self
            .core
            .plan_restart(role, &is_program)?
        {
            RestartPlan::Promote { generation } => {
                let incoming = Incoming {
                    role: Role::Controller,
                    generation,
                    start_seq,
                    warm: true,
                    old: None,
                    announced: None,
                };
                let switch = self.activate(running, incoming)?;
                self.record_action(self.core.note(
                    Role::Controller,
                    Some(generation),
                    EventKind::PromoteStandby(switch.record()),
                ));
                self.switches.push(switch);
                return Ok(());
            }
            RestartPlan::Logger {
                scenario,
                generation,
            } => {
                // It only listens: nothing to hand over, no boundary to announce.
                self.clean_dead_nodes();
                running.launch(role, &scenario, generation, Joining::Restart)?;
                self.track(running);
                self.record_action(self.core.note(
                    role,
                    Some(generation),
                    EventKind::Restart(Restart {
                        files: Some(flexloop_runfiles::run_dir::logger_files(generation).into()),
                        ..Restart::default()
                    }),
                ));
                return Ok(());
            }
            RestartPlan::Fresh {
                scenario,
                generation,
                owns_from,
                rolled_back_from,
            } => (scenario, generation, owns_from, rolled_back_from),
        };
        if let Some(from_seq) = owns_from {
            self.announce(role, generation, from_seq)?;
        }
        let (pid, warm) = self.engage(running, role, &scenario, generation, Joining::Restart)?;
        if !self.core.ticking() {
            // Before tick 0 there is nothing to take over: the replacement
            // owns every sample and starts the loop as the first one would.
            if let Err(e) = self.announce(role, generation, 0) {
                self.stop(running, pid);
                return Err(e);
            }
            self.record_action(self.core.note(
                role,
                Some(generation),
                EventKind::Restart(Restart {
                    before_tick_0: true,
                    ..Restart::default()
                }),
            ));
            return Ok(());
        }
        // A failed attempt leaves nothing behind: the next one starts afresh.
        let switch = self.await_shadow(running, role, generation).and_then(|_| {
            let incoming = Incoming {
                role,
                generation,
                start_seq,
                warm,
                old: None,
                announced: owns_from,
            };
            self.activate(running, incoming)
        });
        let switch = match switch {
            Ok(switch) => switch,
            Err(e) => {
                self.stop(running, pid);
                return Err(e);
            }
        };
        let restart = Restart {
            switch: Some(switch.record()),
            scenario: rolled_back_from
                .is_some()
                .then(|| scenario.display().to_string()),
            rolled_back_from: rolled_back_from.map(|p| p.display().to_string()),
            ..Restart::default()
        };
        self.record_action(
            self.core
                .note(role, Some(generation), EventKind::Restart(restart)),
        );
        self.switches.push(switch);
        Ok(())
    }

    /// After a swap of the controller: a standby of the new design, if the
    /// core asks for one; once it follows the loop, the old ones retire.
    fn renew_standby(&mut self, running: &mut RunningLoop) {
        let Some(renewal) = self.core.standby_renewal() else {
            return;
        };
        let generation = renewal.generation;
        let started = self
            .engage(
                running,
                Role::Controller,
                &renewal.scenario,
                generation,
                Joining::Standby,
            )
            .and_then(
                |(pid, _)| match self.await_shadow(running, Role::Controller, generation) {
                    Ok(()) => Ok(pid),
                    Err(e) => {
                        self.stop(running, pid);
                        Err(e)
                    }
                },
            );
        let record = match started {
            Ok(pid) => {
                for &(old, _) in &renewal.old {
                    self.retire(running, old);
                }
                let replaced: Vec<u32> = renewal.old.iter().map(|(_, g)| *g).collect();
                self.core.note(
                    Role::Controller,
                    Some(generation),
                    EventKind::Standby(Standby {
                        pid,
                        scenario: Some(renewal.scenario.display().to_string()),
                        replaces: Some(replaced),
                        ..Standby::default()
                    }),
                )
            }
            // The old standby stays: better one of the old design than none.
            Err(e) => self.core.note(
                Role::Controller,
                Some(generation),
                EventKind::StandbyFailed(format!("{e:#}")),
            ),
        };
        self.record_action(record);
    }

    /// Tells a serving standby to become a spare, or stops it (as the core
    /// says; also if the order cannot go out).
    fn retire(&mut self, running: &mut RunningLoop, pid: i32) {
        if self.core.retirement() == Retirement::Order {
            let order = SpareOrder {
                pid: pid as u32,
                // To a serving standby: stop, and idle as a spare.
                joining: Joining::Spare.wire(),
                ..SpareOrder::default()
            };
            if self.ports.send_order(order).is_ok() {
                self.core.retiring(pid, Instant::now());
                return;
            }
        }
        self.stop(running, pid);
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
