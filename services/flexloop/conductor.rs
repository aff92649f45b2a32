//! The supervisor's side of hand-overs: it owns the activation (which
//! generation of controller and observer owns which samples), swaps a
//! component on request (shadow start, boundary, drain), restarts a crashed
//! one with back-off, and writes every event to the run's `events.jsonl`.

use crate::supervisor::{Outcome, RunningLoop, UNSERVED};
use flexloop_node::Role;
use flexloop_protocol::channels::{
    ACTIVATION, COMMAND, CONTROLLER_STATE, ESTIMATE, MEASUREMENT, MEASUREMENT_REPLAY,
    OBSERVER_STATE, SPARE_ORDER, SPARE_STATUS,
};
use flexloop_protocol::handover::{ACTIVE, CATCHING_UP};
use flexloop_protocol::spare::{JOIN_AS_REPLACEMENT, JOIN_AS_RESTART, JOIN_AS_STANDBY, RETIRE};
use flexloop_protocol::{
    Activation, Command, Estimate, Handover, MAX_INPUTS, Measurement, SpareOrder, SpareStatus,
    flags,
};
use flexloop_scenario::schema::{RestartPolicy, SafeAction};
use flexloop_scenario::{LoopDesign, Overrides, Scenario};
use flexloop_transport::{Domain, Inlet, LoopNode, Outlet, cleanup_dead_nodes};
use serde_json::{Value, json};
use std::collections::VecDeque;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Where `flexloop swap` leaves requests for the supervisor and finds answers.
pub const REQUESTS_DIR: &str = flexloop_runfiles::RunDir::REQUESTS;
pub const EVENTS_FILE: &str = flexloop_runfiles::RunDir::EVENTS;
/// The live processes and what each does (active, standby, spare), rewritten
/// whenever that changes: for `flexloop status` and for tests that must
/// stop one particular instance.
pub const PROCESSES_FILE: &str = flexloop_runfiles::RunDir::PROCESSES;
/// How long a replacement may take to start and follow the loop in shadow.
const SHADOW_TIMEOUT: Duration = Duration::from_secs(30);
/// How long a swap or restart waits for a spare that is still starting.
const SPARE_START_WAIT: Duration = Duration::from_secs(5);
/// How long a standby told to retire may take to become a spare.
const RETIRE_TIMEOUT: Duration = Duration::from_secs(2);
/// How long the replaced instance may take to hand over and exit.
const DRAIN_TIMEOUT: Duration = Duration::from_secs(10);
/// Commands kept for measuring the step at a switch.
const COMMAND_HISTORY: usize = 4096;
/// Ordinary sample-to-sample changes are measured over this many samples
/// before and after the switch.
const BEFORE_SWITCH: u64 = 100;
/// The shortest span the loop's pace is measured over.
const PACE_MIN_SPAN: Duration = Duration::from_millis(100);
/// How far back the supervisor keeps measurements for a restarted observer:
/// the crash noticed (20 ms), the back-off (100 ms, doubled per restart), the
/// replacement's start-up (tens of ms), with room to spare.
const REPLAY_SPAN: Duration = Duration::from_secs(2);
const MAX_REPLAY_SAMPLES: usize = 1 << 16;
/// Replayed measurements in flight at most: the replay queue's depth.
const REPLAY_WINDOW: u64 = MEASUREMENT_REPLAY.qos.loop_buffer_size as u64;

/// The replay to one restarted observer.
struct ReplayFeed {
    generation: u32,
    /// The next measurement to replay.
    next: u64,
    /// The last one the observer reported having stepped.
    progress: u64,
}

/// What one swap or restart did.
#[derive(Debug, Clone)]
pub struct Switch {
    pub role: Role,
    pub generation: u32,
    /// The loop's sample when the replacement was started.
    pub start_seq: u64,
    pub from_seq: u64,
    /// |u(from) − u(from−1)|, the largest over the inputs.
    pub du_switch: f64,
    /// The largest |u(k) − u(k−1)| over the samples before the switch.
    pub du_before: f64,
    /// The same after the switch (the new design's own ordinary steps).
    pub du_after: f64,
    /// Served by a warm spare (no process started or stopped).
    pub warm: bool,
}

impl Switch {
    pub fn json(&self) -> Value {
        json!({
            "role": self.role.name(),
            "generation": self.generation,
            "start_seq": self.start_seq,
            "from_seq": self.from_seq,
            "du_switch": self.du_switch,
            "du_before": self.du_before,
            "du_after": self.du_after,
            "warm": self.warm,
        })
    }
}

/// How a new instance joins the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Joining {
    Replacement,
    Restart,
    Standby,
}

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

struct PendingRestart {
    role: Role,
    due: Instant,
}

pub struct Conductor {
    // Ports before the node: they must drop first.
    activation_out: Outlet<Activation>,
    controller_states: Inlet<Handover>,
    observer_states: Inlet<Handover>,
    commands: Inlet<Command>,
    /// Opened once the loop runs: the observer counts its readers at start-up.
    estimates: Option<Inlet<Estimate>>,
    /// Opened once the loop runs too (the plant counts its readers): fills
    /// `recent_measurements`.
    measurements: Option<Inlet<Measurement>>,
    /// The last [`REPLAY_SPAN`] of measurements, oldest first, for an
    /// observer restarted after a crash (see `flexloop_node::replay`).
    recent_measurements: VecDeque<Measurement>,
    replay_out: Outlet<Measurement>,
    replay: Option<ReplayFeed>,
    spare_orders: Outlet<SpareOrder>,
    spare_status: Inlet<SpareStatus>,
    /// Pids that reported themselves idle spares since the last look.
    idle_reports: Vec<u32>,
    /// What [`PROCESSES_FILE`] holds now.
    processes_written: Value,
    /// The plant published its last sample: no new spare or standby.
    run_ending: bool,
    /// Standbys told to retire, and since when: stopped if they have not
    /// become spares within [`RETIRE_TIMEOUT`] (one without spare duty,
    /// started from a file with `warm_spares = false`, never does).
    retiring: Vec<(i32, Instant)>,
    node: LoopNode,
    domain: Domain,
    current: Activation,
    scenario: Scenario,
    overrides: Overrides,
    run_dir: PathBuf,
    started: Instant,
    last_seq: Option<u64>,
    /// (sample, from its owner, u): the owner's commands, and the standby's,
    /// which the plant applies while the owner is silent.
    recent_u: VecDeque<(u64, bool, [f64; MAX_INPUTS])>,
    /// The last state each role's active instance published: a restarted
    /// instance gets it from here, since a dead publisher hands nothing over.
    last_active: [Option<Handover>; 2],
    /// Shadows seen following, by role and generation.
    shadows_seen: Vec<(Role, u32)>,
    /// (when, newest sample) over the last half second: the loop's real pace.
    pace: VecDeque<(Instant, u64)>,
    states_out: [Outlet<Handover>; 2],
    n_inputs: usize,
    restarts: [u32; 4],
    /// Spares that crashed or failed to start, per role (their own budget:
    /// an idle spare's trouble must not use up the active role's restarts).
    spare_failures: [u32; 4],
    pending: Vec<PendingRestart>,
    pub switches: Vec<Switch>,
}

impl Conductor {
    pub fn open(
        prefix: &str,
        run_dir: &Path,
        scenario: &Scenario,
        overrides: &Overrides,
    ) -> Result<Self, String> {
        let err = |e: flexloop_transport::TransportError| e.to_string();
        let domain = Domain::new(prefix).map_err(err)?;
        let node = domain.node("supervisor").map_err(err)?;
        let activation_out = Outlet::<Activation>::open(&node, &ACTIVATION).map_err(err)?;
        let controller_states =
            Inlet::<Handover>::open_polling(&node, &CONTROLLER_STATE, 8).map_err(err)?;
        let observer_states =
            Inlet::<Handover>::open_polling(&node, &OBSERVER_STATE, 8).map_err(err)?;
        let commands =
            Inlet::<Command>::open_polling(&node, &COMMAND, COMMAND.qos.logger_buffer_size)
                .map_err(err)?;
        let states_out = [
            Outlet::<Handover>::open(&node, &CONTROLLER_STATE).map_err(err)?,
            Outlet::<Handover>::open(&node, &OBSERVER_STATE).map_err(err)?,
        ];
        let replay_out = Outlet::<Measurement>::open(&node, &MEASUREMENT_REPLAY).map_err(err)?;
        let spare_orders = Outlet::<SpareOrder>::open(&node, &SPARE_ORDER).map_err(err)?;
        let spare_status = Inlet::<SpareStatus>::open_polling(
            &node,
            &SPARE_STATUS,
            SPARE_STATUS.qos.loop_buffer_size,
        )
        .map_err(err)?;
        let replay_capacity = ((scenario.timing.rate_hz * REPLAY_SPAN.as_secs_f64()) as usize)
            .clamp(1024, MAX_REPLAY_SAMPLES);
        let current = Activation {
            published_ns: flexloop_runtime::monotonic_ns(),
            ..Activation::INITIAL
        };
        activation_out.publish(|a| *a = current).map_err(err)?;
        let n_inputs = LoopDesign::from_scenario(scenario)
            .map(|d| d.n_inputs)
            .unwrap_or(1);
        Ok(Self {
            activation_out,
            controller_states,
            observer_states,
            commands,
            estimates: None,
            measurements: None,
            recent_measurements: VecDeque::with_capacity(replay_capacity),
            replay_out,
            replay: None,
            spare_orders,
            spare_status,
            idle_reports: Vec::new(),
            processes_written: Value::Null,
            run_ending: false,
            retiring: Vec::new(),
            node,
            domain,
            current,
            scenario: scenario.clone(),
            overrides: overrides.clone(),
            run_dir: run_dir.to_path_buf(),
            started: Instant::now(),
            last_seq: None,
            recent_u: VecDeque::with_capacity(COMMAND_HISTORY),
            last_active: [None, None],
            shadows_seen: Vec::new(),
            pace: VecDeque::new(),
            states_out,
            n_inputs,
            restarts: [0; 4],
            spare_failures: [0; 4],
            pending: Vec::new(),
            switches: Vec::new(),
        })
    }

    /// Takes in the recent commands and with them the loop's newest sample
    /// number. (Not from the measurements: the plant counts their readers to
    /// know when the chain is ready.)
    fn poll(&mut self) {
        // A publisher hands its history to a new subscriber only when it
        // updates its connections: a replacement must learn the activation.
        let _ = self.activation_out.connect();
        // Estimates too: when the controller is dead they still show the pace.
        if self.estimates.is_none() && self.last_seq.is_some() {
            self.estimates = Inlet::<Estimate>::open_polling(&self.node, &ESTIMATE, 16).ok();
        }
        if self.measurements.is_none() && self.last_seq.is_some() {
            self.measurements = Inlet::<Measurement>::open_polling(
                &self.node,
                &MEASUREMENT,
                MEASUREMENT.qos.logger_buffer_size,
            )
            .ok();
        }
        if let Some(measurements) = &self.measurements {
            while let Ok(Some(m)) = measurements.receive() {
                if self.recent_measurements.len() == self.recent_measurements.capacity() {
                    self.recent_measurements.pop_front();
                }
                self.recent_measurements.push_back(*m);
                self.run_ending |= m.flags & flags::END_OF_RUN != 0;
            }
        }
        if let Some(estimates) = &self.estimates {
            while let Ok(Some(e)) = estimates.receive() {
                let seq = e.seq.saturating_sub(1);
                self.last_seq = Some(self.last_seq.map_or(seq, |s| s.max(seq)));
            }
        }
        for (slot, role) in [(0, Role::Controller), (1, Role::Observer)] {
            let inlet = match role {
                Role::Controller => &self.controller_states,
                _ => &self.observer_states,
            };
            while let Ok(Some(h)) = inlet.receive() {
                if h.shadow == CATCHING_UP {
                    if let Some(feed) = &mut self.replay
                        && feed.generation == h.generation
                    {
                        feed.progress = feed.progress.max(h.seq);
                    }
                } else if h.shadow != ACTIVE {
                    if !self.shadows_seen.contains(&(role, h.generation)) {
                        self.shadows_seen.push((role, h.generation));
                    }
                } else if self.last_active[slot].is_none_or(|l| l.seq <= h.seq) {
                    self.last_active[slot] = Some(*h);
                }
            }
        }
        if let Some(seq) = self.last_seq {
            let now = Instant::now();
            self.pace.push_back((now, seq));
            while self
                .pace
                .front()
                .is_some_and(|(t, _)| now.duration_since(*t) > Duration::from_millis(500))
            {
                self.pace.pop_front();
            }
        }
        while let Ok(Some(status)) = self.spare_status.receive() {
            self.idle_reports.push(status.pid);
        }
        while let Ok(Some(c)) = self.commands.receive() {
            self.last_seq = Some(self.last_seq.map_or(c.seq, |s| s.max(c.seq)));
            let owner = c.generation == self.current.controller_for(c.seq);
            if !owner && c.flags & flags::STANDBY == 0 {
                continue;
            }
            if self.recent_u.len() == COMMAND_HISTORY {
                self.recent_u.pop_front();
            }
            self.recent_u.push_back((c.seq, owner, c.u));
        }
    }

    /// Appends one event to the run's events file (best effort: an event
    /// that cannot be written is printed instead).
    pub fn event(&self, kind: &str, role: Role, generation: impl Into<Option<u32>>, detail: Value) {
        let generation = generation.into().filter(|g| *g != UNSERVED);
        let line = json!({
            "t_s": self.started.elapsed().as_secs_f64(),
            "kind": kind,
            "role": role.name(),
            "generation": generation,
            "seq": self.last_seq,
            "detail": detail,
        });
        let written = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.run_dir.join(EVENTS_FILE))
            // One write of the whole line: with O_APPEND a reader never sees
            // half of it (`writeln!` writes the pieces of its format apart).
            .and_then(|mut f| f.write_all(format!("{line}\n").as_bytes()));
        if written.is_err() {
            eprintln!("flexloop: event {line}");
        }
    }

    /// Called by the supervisor every 20 ms: crashes, restarts, requests.
    pub fn tick(&mut self, running: &mut RunningLoop) -> Option<Outcome> {
        self.poll();
        self.take_idle_reports(running);
        self.settle_crashes(running);
        let now = Instant::now();
        let (due, later): (Vec<PendingRestart>, Vec<PendingRestart>) =
            std::mem::take(&mut self.pending)
                .into_iter()
                .partition(|p| p.due <= now);
        self.pending = later;
        let due: Vec<Role> = due.into_iter().map(|p| p.role).collect();
        for role in due {
            if let Err(e) = self.restart(running, role) {
                self.event("restart-failed", role, 0, json!(e));
                eprintln!("flexloop: restart of flexloop-{} failed: {e}", role.name());
                let slot = role as usize;
                if self.restarts[slot] >= self.scenario.supervision.max_restarts
                    || flexloop_runtime::shutdown::requested()
                {
                    return Some(Outcome::ChildFailed(role, -1));
                }
                let backoff = self.next_backoff(slot);
                self.pending.push(PendingRestart {
                    role,
                    due: Instant::now() + backoff,
                });
            }
        }
        self.check_retiring(running);
        self.keep_standby(running);
        self.keep_spares(running);
        for request in pending_requests(&self.run_dir) {
            let answer = match self.handle_request(running, &request) {
                Ok(switch) => json!({"ok": true, "switch": switch.json()}),
                Err(e) => json!({"ok": false, "error": e}),
            };
            let _ = std::fs::remove_file(&request);
            // The process list first: who asked may look there next.
            self.write_processes(running);
            write_answer(&request, &answer);
        }
        // Crashes reaped inside a swap or restart above, settled now,
        // before the supervisor judges exits.
        self.settle_crashes(running);
        self.write_processes(running);
        None
    }

    /// Rewrites [`PROCESSES_FILE`] if the processes or their duties changed
    /// (atomically: a reader sees the old list or the new one).
    fn write_processes(&mut self, running: &RunningLoop) {
        let list: Vec<Value> = running
            .children
            .iter()
            .filter(|c| c.exit.is_none())
            .map(|c| {
                let duty = if c.spare {
                    "spare"
                } else if c.standby {
                    "standby"
                } else {
                    "active"
                };
                json!({
                    "role": c.role.name(),
                    "pid": c.pid,
                    "duty": duty,
                    "generation": (c.generation != UNSERVED).then_some(c.generation),
                    "scenario": c.scenario.display().to_string(),
                })
            })
            .collect();
        let now = json!({ "processes": list });
        if now == self.processes_written {
            return;
        }
        let path = self.run_dir.join(PROCESSES_FILE);
        if flexloop_runfiles::json::write_json_atomically(&path, &now).is_ok() {
            self.processes_written = now;
        }
    }

    /// With `safe_action = "standby"`, keeps one standby controller following
    /// the running loop (started once the loop ticks, again after a promotion
    /// or a crash of the standby, within the restart limit).
    fn keep_standby(&mut self, running: &mut RunningLoop) {
        let slot = Role::Controller as usize;
        if self.scenario.supervision.safe_action != SafeAction::Standby
            || self.last_seq.is_none()
            || self.run_ending
            || self.pending.iter().any(|p| p.role == Role::Controller)
            || self.restarts[slot] > self.scenario.supervision.max_restarts
            || running
                .children
                .iter()
                .any(|c| c.standby && c.exit.is_none())
        {
            return;
        }
        let Some(scenario) = running.child(Role::Controller).map(|c| c.scenario.clone()) else {
            return;
        };
        let generation = self.next_generation(running, Role::Controller);
        match self.engage(
            running,
            Role::Controller,
            &scenario,
            generation,
            Joining::Standby,
        ) {
            Ok((pid, warm)) => self.event(
                "standby",
                Role::Controller,
                generation,
                json!({"pid": pid, "warm": warm}),
            ),
            Err(e) => {
                self.restarts[slot] += 1;
                self.event("standby-failed", Role::Controller, generation, json!(e));
            }
        }
    }

    /// Brings up `role` as `generation` running `scenario`: an idle warm
    /// spare if there is one, else a new process. Returns its pid and
    /// whether it was a spare. Not before tick 0: until then the plant
    /// counts on each spare to be there as a spare.
    fn engage(
        &mut self,
        running: &mut RunningLoop,
        role: Role,
        scenario: &Path,
        generation: u32,
        joining: Joining,
    ) -> Result<(i32, bool), String> {
        if self.scenario.supervision.warm_spares && self.last_seq.is_some() {
            // A spare still starting up is worth waiting for: a new process
            // would open ports while the loop runs.
            let since = Instant::now();
            loop {
                self.poll();
                self.take_idle_reports(running);
                running.reap();
                let starting = running
                    .children
                    .iter()
                    .any(|c| c.role == role && c.spare && !c.idle && c.exit.is_none());
                let idle = running
                    .children
                    .iter()
                    .any(|c| c.role == role && c.spare && c.idle && c.exit.is_none());
                if idle || !starting || since.elapsed() > SPARE_START_WAIT {
                    break;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            if let Some(spare) = running
                .children
                .iter_mut()
                .find(|c| c.role == role && c.spare && c.idle && c.exit.is_none())
            {
                let path = scenario
                    .to_str()
                    .ok_or_else(|| format!("{}: the path is not UTF-8", scenario.display()))?;
                let mut order = SpareOrder {
                    pid: spare.pid as u32,
                    generation,
                    joining: match joining {
                        Joining::Replacement => JOIN_AS_REPLACEMENT,
                        Joining::Restart => JOIN_AS_RESTART,
                        Joining::Standby => JOIN_AS_STANDBY,
                    },
                    ..SpareOrder::default()
                };
                order
                    .set_scenario(path)
                    .map_err(|e| format!("{}: {e}", scenario.display()))?;
                send_order(&self.spare_orders, order)?;
                spare.spare = false;
                spare.idle = false;
                spare.settled = false;
                spare.standby = joining == Joining::Standby;
                spare.generation = generation;
                spare.scenario = scenario.to_path_buf();
                return Ok((spare.pid, true));
            }
        }
        let pid = match joining {
            Joining::Replacement => running.start_replacement(role, scenario, generation),
            Joining::Restart => running.start_restart(role, scenario, generation),
            Joining::Standby => running.start_standby(scenario, generation),
        }?;
        Ok((pid, false))
    }

    /// Stops a standby told to retire that did not become a spare in time.
    fn check_retiring(&mut self, running: &mut RunningLoop) {
        let mut late = Vec::new();
        self.retiring.retain(|&(pid, since)| {
            let Some(c) = running.children.iter().find(|c| c.pid == pid) else {
                return false;
            };
            if c.spare || c.exit.is_some() {
                return false;
            }
            if since.elapsed() > RETIRE_TIMEOUT {
                late.push(pid);
                return false;
            }
            true
        });
        for pid in late {
            running.terminate(pid);
        }
    }

    /// Tells a serving standby to become a spare (it reports itself idle
    /// then); without warm spares, or if the order cannot go out, stops it.
    fn retire(&mut self, running: &mut RunningLoop, pid: i32) {
        if self.scenario.supervision.warm_spares {
            let order = SpareOrder {
                pid: pid as u32,
                joining: RETIRE,
                ..SpareOrder::default()
            };
            if send_order(&self.spare_orders, order).is_ok() {
                self.retiring.push((pid, Instant::now()));
                return;
            }
        }
        running.terminate(pid);
    }

    /// Marks the processes that reported themselves idle as spares that
    /// take orders (a new spare, or an instance replaced at a boundary).
    fn take_idle_reports(&mut self, running: &mut RunningLoop) {
        for pid in self.idle_reports.drain(..) {
            if let Some(c) = running
                .children
                .iter_mut()
                .find(|c| c.pid as u32 == pid && c.exit.is_none())
            {
                c.spare = true;
                c.idle = true;
                c.standby = false;
                // A spare's crash is its own event, not the end of the run.
                c.settled = false;
            }
        }
    }

    /// With warm spares, keeps one spare controller and one spare observer
    /// once the loop ticks (the first ones start with the loop; another
    /// after a spare crashed or served a restart), within the restart limit.
    fn keep_spares(&mut self, running: &mut RunningLoop) {
        // Before tick 0 too: the plant waits for a spare of each.
        if !self.scenario.supervision.warm_spares
            || self.run_ending
            || running.child(Role::Plant).is_none_or(|p| p.exit.is_some())
        {
            return;
        }
        for role in [Role::Controller, Role::Observer] {
            let slot = role as usize;
            if self.pending.iter().any(|p| p.role == role)
                || self.spare_failures[slot] > self.scenario.supervision.max_restarts
                || running
                    .children
                    .iter()
                    .any(|c| c.role == role && c.spare && c.exit.is_none())
            {
                continue;
            }
            match running.start_spare(role) {
                Ok(pid) => self.event("spare", role, None, json!({"pid": pid})),
                Err(e) => {
                    self.spare_failures[slot] += 1;
                    self.event("spare-failed", role, None, json!(e));
                }
            }
        }
    }

    /// Hands the loop to the standby controller, if one follows it.
    fn promote_standby(
        &mut self,
        running: &mut RunningLoop,
        start_seq: u64,
    ) -> Option<Result<(), String>> {
        let generation = running
            .children
            .iter()
            .find(|c| {
                c.standby
                    && c.exit.is_none()
                    && self
                        .shadows_seen
                        .contains(&(Role::Controller, c.generation))
            })?
            .generation;
        if let Some(c) = running
            .children
            .iter_mut()
            .find(|c| c.standby && c.generation == generation)
        {
            c.standby = false;
        }
        let incoming = Incoming {
            role: Role::Controller,
            generation,
            start_seq,
            warm: true,
            old: None,
            announced: None,
        };
        let switch = match self.activate_and_measure(running, incoming) {
            Ok(switch) => switch,
            Err(e) => return Some(Err(e)),
        };
        self.event(
            "promote-standby",
            Role::Controller,
            generation,
            switch.json(),
        );
        self.switches.push(switch);
        Some(Ok(()))
    }

    fn settle_crashes(&mut self, running: &mut RunningLoop) {
        let policy = self.scenario.supervision.restart;
        let crashed: Vec<(i32, Role, u32, i32, bool, bool)> = running
            .children
            .iter()
            .filter(|c| !c.settled && c.exit.is_some_and(|e| e.code != 0))
            .map(|c| {
                let code = c.exit.map_or(-1, |e| e.code);
                (c.pid, c.role, c.generation, code, c.standby, c.spare)
            })
            .collect();
        for (pid, role, generation, code, standby, spare) in crashed {
            if spare || standby {
                // The active loop is untouched; `keep_spares` or
                // `keep_standby` starts another (a spare has its own budget).
                if let Some(c) = running.children.iter_mut().find(|c| c.pid == pid) {
                    c.settled = true;
                }
                let budget = if spare {
                    &mut self.spare_failures
                } else {
                    &mut self.restarts
                };
                budget[role as usize] += 1;
                let cleaned = cleanup_dead_nodes(&self.domain).unwrap_or(0);
                let duty = if spare { "spare" } else { "standby" };
                self.event(
                    "crash",
                    role,
                    generation,
                    json!({"exit": code, duty: true, "cleaned_nodes": cleaned}),
                );
                continue;
            }
            let restartable = matches!(role, Role::Observer | Role::Controller | Role::Logger);
            let slot = role as usize;
            if !restartable
                || policy == RestartPolicy::Never
                || self.restarts[slot] >= self.scenario.supervision.max_restarts
            {
                continue;
            }
            if let Some(c) = running.children.iter_mut().find(|c| c.pid == pid) {
                c.settled = true;
            }
            // The dead node's shared memory, now that no live process uses
            // it; never from inside the loop.
            let cleaned = cleanup_dead_nodes(&self.domain).unwrap_or(0);
            let backoff = self.next_backoff(slot);
            self.event(
                "crash",
                role,
                generation,
                json!({"exit": code, "cleaned_nodes": cleaned, "restart_in_ms": backoff.as_millis() as u64}),
            );
            self.pending.push(PendingRestart {
                role,
                due: Instant::now() + backoff,
            });
        }
    }

    /// Counts one more restart of the role in `slot` and returns its wait:
    /// the configured back-off, doubled for each restart before.
    fn next_backoff(&mut self, slot: usize) -> Duration {
        let wait = self.scenario.supervision.restart_backoff_ms << self.restarts[slot].min(10);
        self.restarts[slot] += 1;
        Duration::from_millis(wait)
    }

    fn next_generation(&self, running: &RunningLoop, role: Role) -> u32 {
        running
            .children
            .iter()
            .filter(|c| c.role == role && c.generation != UNSERVED)
            .map(|c| c.generation + 1)
            .max()
            .unwrap_or(1)
    }

    fn restart(&mut self, running: &mut RunningLoop, role: Role) -> Result<(), String> {
        // The file of the generation that owned the loop (with spares the
        // order of the children is not the order they served in).
        let owner = match role {
            Role::Controller => Some(self.current.controller_generation),
            Role::Observer => Some(self.current.observer_generation),
            _ => None,
        };
        let scenario = owner
            .and_then(|g| {
                running
                    .children
                    .iter()
                    .rev()
                    .find(|c| c.role == role && c.generation == g && !c.standby)
            })
            .or_else(|| running.child(role))
            .map(|c| c.scenario.clone())
            .ok_or("no instance to restart")?;
        let start_seq = self.last_seq.unwrap_or(0);
        if role == Role::Controller
            && let Some(promoted) = self.promote_standby(running, start_seq)
        {
            return promoted;
        }
        let generation = self.next_generation(running, role);
        // The predecessor is dead: its replacement owns at once the samples
        // it left unserved, from the first after its last state (its last
        // command; the estimate after its last measurement). A boundary
        // ahead, as a swap has, would never come in lockstep: the loop
        // waits for the dead one's output.
        let slot = usize::from(role != Role::Controller);
        let owns_from = match (role, self.last_active[slot], self.last_seq) {
            (Role::Controller, Some(last), Some(_)) => Some(last.seq + 1),
            (Role::Observer, Some(last), Some(_)) => Some(last.seq + 2),
            _ => None,
        };
        if let Some(from_seq) = owns_from {
            self.announce(role, generation, from_seq)?;
        }
        let (pid, warm) = if role == Role::Logger {
            (running.start_restart(role, &scenario, generation)?, false)
        } else {
            self.engage(running, role, &scenario, generation, Joining::Restart)?
        };
        if self.last_seq.is_none() && role != Role::Logger {
            // Before tick 0 there is nothing to take over: the replacement
            // owns every sample and starts the loop as the first one would.
            if let Err(e) = self.announce(role, generation, 0) {
                running.terminate(pid);
                return Err(e);
            }
            self.event("restart", role, generation, json!({"before_tick_0": true}));
            return Ok(());
        }
        if role == Role::Logger {
            // It only listens: nothing to hand over, no boundary to announce.
            self.event(
                "restart",
                role,
                generation,
                json!({"files": flexloop_runfiles::run_dir::logger_files(generation)}),
            );
            return Ok(());
        }
        // A failed attempt leaves nothing behind: the next one starts afresh.
        let switch = match self.await_shadow(running, role, generation).and_then(|_| {
            let incoming = Incoming {
                role,
                generation,
                start_seq,
                warm,
                old: None,
                announced: owns_from,
            };
            self.activate_and_measure(running, incoming)
        }) {
            Ok(switch) => switch,
            Err(e) => {
                running.terminate(pid);
                return Err(e);
            }
        };
        self.event("restart", role, generation, switch.json());
        self.switches.push(switch);
        Ok(())
    }

    fn handle_request(&mut self, running: &mut RunningLoop, path: &Path) -> Result<Switch, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let request: Value =
            serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        let role = match request["role"].as_str() {
            Some("controller") => Role::Controller,
            Some("observer") => Role::Observer,
            other => {
                return Err(format!(
                    "cannot swap {other:?}: only controller or observer"
                ));
            }
        };
        let scenario = PathBuf::from(
            request["scenario"]
                .as_str()
                .ok_or("request has no scenario")?,
        );
        self.swap(running, role, &scenario)
    }

    /// Replaces the active `role` by an instance running `scenario`.
    pub fn swap(
        &mut self,
        running: &mut RunningLoop,
        role: Role,
        scenario_path: &Path,
    ) -> Result<Switch, String> {
        let result = self.swap_to(running, role, scenario_path);
        // Crashes reaped while it waited, settled before the supervisor
        // judges exits (a swap may run outside `tick`).
        self.settle_crashes(running);
        result
    }

    fn swap_to(
        &mut self,
        running: &mut RunningLoop,
        role: Role,
        scenario_path: &Path,
    ) -> Result<Switch, String> {
        self.check_compatible(scenario_path)?;
        let old = running
            .child(role)
            .filter(|c| c.exit.is_none())
            .map(|c| c.pid)
            .ok_or_else(|| format!("no running flexloop-{}", role.name()))?;
        let generation = self.next_generation(running, role);
        // A replacement follows a ticking loop (and a spare serves only then).
        let since = Instant::now();
        self.poll();
        while self.last_seq.is_none() {
            if since.elapsed() > SHADOW_TIMEOUT || flexloop_runtime::shutdown::requested() {
                return Err(format!(
                    "the loop did not start within {SHADOW_TIMEOUT:?}: nothing to swap into"
                ));
            }
            std::thread::sleep(Duration::from_millis(5));
            self.poll();
        }
        let start_seq = self.last_seq.unwrap_or(0);
        let (pid, warm) = self.engage(
            running,
            role,
            scenario_path,
            generation,
            Joining::Replacement,
        )?;
        if let Err(e) = self.await_shadow(running, role, generation) {
            running.terminate(pid);
            return Err(e);
        }
        let switch = self.activate_and_measure(
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
        self.event(
            "swap",
            role,
            generation,
            json!({"scenario": scenario_path.display().to_string(), "switch": switch.json()}),
        );
        self.switches.push(switch.clone());
        if role == Role::Controller {
            self.renew_standby(running);
        }
        Ok(switch)
    }

    /// After a swap to another controller design the standby must follow
    /// the new one: with the old design it can neither copy the active
    /// state nor compute the command the active one would have sent, and a
    /// promotion would step. A standby of the new design starts; once it
    /// follows the loop, the old one is stopped (until then it covers).
    fn renew_standby(&mut self, running: &mut RunningLoop) {
        if self.scenario.supervision.safe_action != SafeAction::Standby {
            return;
        }
        let Some(active) = running.child(Role::Controller).map(|c| c.scenario.clone()) else {
            return;
        };
        let old: Vec<(i32, u32)> = running
            .children
            .iter()
            .filter(|c| c.standby && c.exit.is_none() && c.scenario != active)
            .map(|c| (c.pid, c.generation))
            .collect();
        if old.is_empty() {
            return;
        }
        let generation = self.next_generation(running, Role::Controller);
        let started = self
            .engage(
                running,
                Role::Controller,
                &active,
                generation,
                Joining::Standby,
            )
            .and_then(|(pid, _)| {
                self.await_shadow(running, Role::Controller, generation)
                    .inspect_err(|_| running.terminate(pid))
                    .map(|_| pid)
            });
        match started {
            Ok(pid) => {
                for (pid, _) in &old {
                    self.retire(running, *pid);
                }
                let replaced: Vec<u32> = old.iter().map(|(_, g)| *g).collect();
                self.event(
                    "standby",
                    Role::Controller,
                    generation,
                    json!({"pid": pid, "scenario": active.display().to_string(), "replaces": replaced}),
                );
            }
            Err(e) => {
                // The old standby stays: better one of the old design than none.
                self.event("standby-failed", Role::Controller, generation, json!(e));
            }
        }
    }

    /// The replacement must fit the running loop: same rate, mode and plant,
    /// same loop delay, and a design that passes its own checks.
    fn check_compatible(&self, path: &Path) -> Result<(), String> {
        let new = Scenario::load(path, &self.overrides).map_err(|e| e.to_string())?;
        let run = &self.scenario;
        let field = |name: &str| {
            format!(
                "{}: field {name} differs from the running loop's ({}); a swap replaces only [controller] or [observer]",
                path.display(),
                run.source.display()
            )
        };
        if new.timing != run.timing {
            return Err(field("loop"));
        }
        if new.plant != run.plant {
            return Err(field("plant"));
        }
        if new.controller.extra_delay_samples != run.controller.extra_delay_samples {
            return Err(field("controller.extra_delay_samples"));
        }
        LoopDesign::from_scenario(&new)
            .map(|_| ())
            .map_err(|e| e.to_string())
    }

    /// Waits until the new instance follows the loop in shadow.
    fn await_shadow(
        &mut self,
        running: &mut RunningLoop,
        role: Role,
        generation: u32,
    ) -> Result<(), String> {
        let since = Instant::now();
        let slot = usize::from(role != Role::Controller);
        loop {
            self.poll();
            self.take_idle_reports(running);
            // Following in shadow, or (a restart, which owns samples at
            // once) already serving them.
            if self.shadows_seen.contains(&(role, generation))
                || self.last_active[slot].is_some_and(|l| l.generation == generation)
            {
                return Ok(());
            }
            // A replacement for a dead instance takes over its last state,
            // which the dead publisher can no longer hand over itself.
            if let Some(last) = self.last_active[slot]
                && running
                    .children
                    .iter()
                    .filter(|c| c.role == role && c.generation == last.generation)
                    .all(|c| c.exit.is_some() || c.spare)
            {
                let _ = self.states_out[slot].publish(|h| *h = last);
                if role == Role::Observer {
                    self.feed_replay(generation, last.seq);
                }
            }
            if flexloop_runtime::shutdown::requested()
                || running.child(Role::Plant).is_some_and(|p| p.exit.is_some())
            {
                return Err("the run ended before the replacement followed it".into());
            }
            running.reap();
            if let Some(c) = running
                .children
                .iter_mut()
                .find(|c| c.role == role && c.generation == generation)
                && let Some(exit) = c.exit
            {
                c.settled = true;
                return Err(format!(
                    "the new flexloop-{} (generation {generation}) exited with {} before it followed the loop; see {}",
                    role.name(),
                    exit.code,
                    self.run_dir.join(&c.stderr_file).display()
                ));
            }
            if since.elapsed() > SHADOW_TIMEOUT {
                return Err(format!(
                    "the new flexloop-{} did not follow the loop within {SHADOW_TIMEOUT:?}",
                    role.name()
                ));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Replays to the restarted observer `generation` the measurements after
    /// the dead predecessor's last state (after `state_seq`), no further
    /// than [`REPLAY_WINDOW`] past the progress it reported, so that its
    /// queue never overflows. A ring that no longer holds the first of them
    /// replays from its oldest: the observer sees the hole and says so.
    fn feed_replay(&mut self, generation: u32, state_seq: u64) {
        // Nothing before the observer listens: the channel keeps no history.
        if self.replay_out.subscribers() == 0 {
            return;
        }
        let feed = match &mut self.replay {
            Some(feed) if feed.generation == generation => feed,
            _ => self.replay.insert(ReplayFeed {
                generation,
                next: state_seq + 1,
                progress: state_seq,
            }),
        };
        let limit = feed.progress + REPLAY_WINDOW;
        let first = self
            .recent_measurements
            .partition_point(|m| m.seq < feed.next);
        for m in self.recent_measurements.range(first..) {
            if m.seq > limit || self.replay_out.publish(|r| *r = *m).is_err() {
                break;
            }
            feed.next = m.seq + 1;
        }
    }

    /// Announces the boundary, waits until the loop passed it (and the old
    /// instance, if any, exited), and measures the command's step there.
    fn activate_and_measure(
        &mut self,
        running: &mut RunningLoop,
        incoming: Incoming,
    ) -> Result<Switch, String> {
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
                // Far enough ahead that every process sees the announcement
                // first: 50 ms at the loop's real pace (lockstep runs faster
                // than its rate).
                let now_seq = self.last_seq.unwrap_or(0);
                let observed = observed_pace(&self.pace).unwrap_or(0.0);
                let margin = ((self.scenario.timing.rate_hz.max(observed) * 0.05) as u64).max(50);
                let from_seq = now_seq + margin;
                self.announce(role, generation, from_seq)?;
                from_seq
            }
        };
        if let Some(pid) = old
            && let Some(c) = running.children.iter_mut().find(|c| c.pid == pid)
        {
            // Its exit (or, with warm spares, its retirement to a spare)
            // after the boundary is the plan, not a crash.
            c.settled = true;
        }
        let since = Instant::now();
        loop {
            self.poll();
            running.reap();
            self.take_idle_reports(running);
            let passed = self.last_seq.is_some_and(|s| s > from_seq + BEFORE_SWITCH);
            let old_gone = old.is_none_or(|pid| {
                running
                    .children
                    .iter()
                    .find(|c| c.pid == pid)
                    .is_none_or(|c| c.exit.is_some() || c.spare)
            });
            if passed && old_gone {
                break;
            }
            if running.child(Role::Plant).is_some_and(|p| p.exit.is_some())
                || flexloop_runtime::shutdown::requested()
            {
                return Err("the run ended before the switch".into());
            }
            if since.elapsed() > DRAIN_TIMEOUT {
                if let Some(pid) = old {
                    running.terminate(pid);
                }
                return Err(format!(
                    "the loop did not pass the switch at sample {from_seq} within {DRAIN_TIMEOUT:?}"
                ));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        let (du_switch, du_before, du_after) = self.step_at(from_seq);
        Ok(Switch {
            role,
            generation,
            start_seq,
            from_seq,
            du_switch,
            du_before,
            du_after,
            warm,
        })
    }

    /// Publishes that `generation` of `role` owns the samples from `from_seq` on.
    fn announce(&mut self, role: Role, generation: u32, from_seq: u64) -> Result<(), String> {
        let mut next = self.current;
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
        next.published_ns = flexloop_runtime::monotonic_ns();
        self.activation_out
            .publish(|a| *a = next)
            .map_err(|e| e.to_string())?;
        self.current = next;
        Ok(())
    }

    /// The command's step at `from_seq` and the largest ordinary steps
    /// before and after it.
    fn step_at(&self, from_seq: u64) -> (f64, f64, f64) {
        // What the plant applied: the owner's command, else the standby's,
        // else (neither seen: late or lost on a busy machine) the input it
        // held, if that was the sample before's; older is not known.
        let u_of = |seq: u64| {
            let of = |owner: bool| {
                self.recent_u
                    .iter()
                    .rev()
                    .find(|(s, o, _)| *s == seq && *o == owner)
                    .map(|(_, _, u)| *u)
            };
            of(true).or_else(|| of(false)).or_else(|| {
                self.recent_u
                    .iter()
                    .filter(|(s, _, _)| s.saturating_add(1) == seq)
                    .max_by_key(|(s, o, _)| (*s, *o))
                    .map(|(_, _, u)| *u)
            })
        };
        let step = |seq: u64| -> Option<f64> {
            let (a, b) = (u_of(seq.checked_sub(1)?)?, u_of(seq)?);
            Some(
                (0..self.n_inputs)
                    .map(|i| (b[i] - a[i]).abs())
                    .fold(0.0, f64::max),
            )
        };
        let du_switch = step(from_seq).unwrap_or(f64::NAN);
        let largest = |range: std::ops::Range<u64>| range.filter_map(step).fold(0.0, f64::max);
        let du_before = largest(from_seq.saturating_sub(BEFORE_SWITCH)..from_seq);
        let du_after = largest(from_seq + 1..from_seq + 1 + BEFORE_SWITCH);
        (du_switch, du_before, du_after)
    }
}

/// Samples per second over the (when, newest sample) points, once they
/// span [`PACE_MIN_SPAN`]: over a shorter span one poll that drains a
/// backlog reads as a burst (two polls 70 µs apart at the loop's start once
/// gave 2.3 MHz, and a boundary 11 s away that the run never reached).
fn observed_pace(pace: &VecDeque<(Instant, u64)>) -> Option<f64> {
    let ((t0, s0), (t1, s1)) = (pace.front()?, pace.back()?);
    let span = t1.checked_duration_since(*t0)?;
    (span >= PACE_MIN_SPAN).then(|| s1.saturating_sub(*s0) as f64 / span.as_secs_f64())
}

/// Publishes `order`, stamped now. Published, it counts: without the
/// wake-up the spare finds it at its next look (100 ms).
fn send_order(out: &Outlet<SpareOrder>, order: SpareOrder) -> Result<(), String> {
    out.publish(|o| {
        *o = order;
        o.published_ns = flexloop_runtime::monotonic_ns();
    })
    .map_err(|e| e.to_string())?;
    let _ = out.notify();
    Ok(())
}

/// Request files waiting for the supervisor, oldest first.
fn pending_requests(run_dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(run_dir.join(REQUESTS_DIR)) else {
        return Vec::new();
    };
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "request"))
        .collect();
    found.sort();
    found
}

fn answer_path(request: &Path) -> PathBuf {
    request.with_extension("answer")
}

fn write_answer(request: &Path, answer: &Value) {
    let path = answer_path(request);
    let tmp = path.with_extension("answer.tmp");
    if std::fs::write(&tmp, answer.to_string()).is_ok() {
        let _ = std::fs::rename(&tmp, &path);
    }
}

/// `flexloop swap`: leaves a request in the loop's run directory and waits
/// for the supervisor's answer.
pub fn request_swap(run_dir: &Path, role: &str, scenario: &Path) -> Result<Value, String> {
    let dir = run_dir.join(REQUESTS_DIR);
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let scenario =
        std::fs::canonicalize(scenario).map_err(|e| format!("{}: {e}", scenario.display()))?;
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let request = dir.join(format!("{stamp}-{}.request", std::process::id()));
    let tmp = request.with_extension("tmp");
    let body = json!({"role": role, "scenario": scenario.display().to_string()});
    std::fs::write(&tmp, body.to_string()).map_err(|e| format!("{}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, &request).map_err(|e| format!("{}: {e}", request.display()))?;
    let answer = answer_path(&request);
    let since = Instant::now();
    while since.elapsed() < SHADOW_TIMEOUT + DRAIN_TIMEOUT + Duration::from_secs(10) {
        if let Ok(text) = std::fs::read_to_string(&answer) {
            let _ = std::fs::remove_file(&answer);
            return serde_json::from_str(&text).map_err(|e| format!("{}: {e}", answer.display()));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = std::fs::remove_file(&request);
    Err("the supervisor did not answer the swap request".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pace_needs_a_long_enough_span() {
        let t0 = Instant::now();
        // A backlog drained by two polls 70 µs apart is no pace at all.
        let burst = VecDeque::from([(t0, 94), (t0 + Duration::from_micros(70), 258)]);
        assert_eq!(observed_pace(&burst), None);
        assert_eq!(observed_pace(&VecDeque::new()), None);
        let steady = VecDeque::from([
            (t0, 1000),
            (t0 + Duration::from_millis(50), 1500),
            (t0 + Duration::from_millis(200), 3000),
        ]);
        let pace = observed_pace(&steady).unwrap();
        assert!((pace - 10_000.0).abs() < 1e-6, "{pace}");
    }
}
