//! The controller process: wakes on y(k), publishes u(k). What is its own
//! in the life every loop component shares ([`crate::instance`]).

use crate::args::{Role, ServiceArgs};
use crate::duty::Duty;
use crate::handover::{ActivationView, HandoverRing};
use crate::instance::{Component, Instance, Ports};
use crate::{NodeError, await_peers};
use flexloop_components::control_law::{ControlLaw, ControllerSetup, stamp_command};
use flexloop_design::LoopDesign;
use flexloop_protocol::channels::{COMMAND, CONTROLLER_STATE, ESTIMATE, MEASUREMENT};
use flexloop_protocol::{
    Activation, Channel, Command, Estimate, Handover, Joining, MAX_INPUTS, Measurement, flags,
};
use flexloop_runtime::wait::{wait_for_input, wait_readable};
use flexloop_runtime::{monotonic_ns, shutdown};
use flexloop_scenario::{ProgramRole, Scenario};
use flexloop_transport::{Inlet, LoopNode, Outlet};

/// In lockstep, how long a new instance waits for its predecessor's last
/// state: the loop waits too, and on a loaded machine 100 ms was sometimes
/// too short (a retuned design then starts without continuing the old
/// command: a step).
const HANDOVER_WAIT_LOCKSTEP_NS: u64 = 2_000_000_000;
/// In lockstep, how long to wait for the observer before giving up.
const LOCKSTEP_ESTIMATE_WAIT_NS: u64 = 5_000_000_000;

/// A controller instance's own: its law and how it takes over.
pub(crate) struct Controller<L> {
    core: L,
    n_inputs: usize,
    n_outputs: usize,
    takeover: Takeover,
    backlog: Backlog,
    shadow_command: Command,
    stale_estimates: u64,
}

/// The controller's own ports.
pub(crate) struct Own {
    estimates: Inlet<Estimate>,
    commands: Outlet<Command>,
    /// Estimates by sequence number, kept across services.
    ring: EstimateRing,
}

impl<L: ControlLaw> Component for Controller<L> {
    const ROLE: Role = Role::Controller;
    const STATE: &'static Channel = &CONTROLLER_STATE;
    type Own = Own;

    fn open_measurements(
        node: &LoopNode,
        _args: &ServiceArgs,
        _scenario: &Scenario,
    ) -> Result<Inlet<Measurement>, NodeError> {
        Ok(Inlet::<Measurement>::open(
            node,
            &MEASUREMENT,
            FOLLOW_DEPTH,
        )?)
    }

    /// The first instance also waits for the observer's first estimate
    /// (into the ring).
    fn open_own(
        node: &LoopNode,
        args: &ServiceArgs,
        _scenario: &Scenario,
        measurements: &Inlet<Measurement>,
        activation: &mut ActivationView,
    ) -> Result<Option<Own>, NodeError> {
        let estimates = Inlet::<Estimate>::open(node, &ESTIMATE, FOLLOW_DEPTH)?;
        let mut ring = EstimateRing::new();
        if !await_peers(
            || {
                if estimates.publishers() >= 1 && measurements.publishers() >= 1 {
                    ring.take(&estimates, activation.refresh()?)?;
                }
                // A replacement joins a running loop: the estimates it needs
                // come with the next sample.
                Ok(ring.any() || (args.joining.is_late() && estimates.publishers() >= 1))
            },
            || {
                format!(
                    "{} measurement publishers (plant), {} estimate publishers (observer), no first estimate yet",
                    measurements.publishers(),
                    estimates.publishers()
                )
            },
        )? {
            return Ok(None);
        }
        measurements.connect()?;
        estimates.connect()?;
        // The command port opens last: its appearance tells the plant that
        // the chain is ready for tick 0 (a replacement for a controller that
        // died before tick 0 thereby lets the loop start, and takes over
        // from it; the plant counts a spare's port apart).
        let commands = Outlet::<Command>::open(node, &COMMAND)?;
        commands.connect()?;
        Ok(Some(Own {
            estimates,
            commands,
            ring,
        }))
    }

    fn design(
        design: &LoopDesign,
        scenario: &Scenario,
        args: &ServiceArgs,
    ) -> Result<Self, NodeError> {
        let setup =
            ControllerSetup::new(scenario, design, args.generation, ProgramRole::Controller);
        let core = L::new(&setup).map_err(|e| NodeError::Law(e.to_string()))?;
        crate::program_params::record(&setup, args)?;
        Ok(Self {
            core,
            n_inputs: design.n_inputs,
            n_outputs: design.n_outputs,
            takeover: Takeover::default(),
            backlog: Backlog::default(),
            shadow_command: Command::default(),
            stale_estimates: 0,
        })
    }

    fn owner(activation: &Activation, seq: u64) -> u32 {
        activation.controller_for(seq)
    }

    fn named(activation: &Activation) -> u32 {
        activation.controller_generation
    }

    fn drop_stale(own: &mut Own) -> Result<(), NodeError> {
        own.estimates.clear_events()?;
        while own.estimates.receive()?.is_some() {}
        own.ring.clear();
        Ok(())
    }

    fn catch_up(
        &mut self,
        instance: &mut Instance,
        ports: &mut Ports<Own>,
    ) -> Result<bool, NodeError> {
        let generation = instance.generation();
        catch_up_with_loop(
            &mut self.core,
            &ports.measurements,
            &ports.states_in,
            &mut instance.handovers,
            generation,
        )
    }

    fn on_wakeup(
        &mut self,
        instance: &mut Instance,
        ports: &mut Ports<Own>,
    ) -> Result<(), NodeError> {
        let Ports {
            measurements,
            activation,
            states_in,
            states_out,
            spare,
            own:
                Own {
                    estimates,
                    commands,
                    ring,
                },
        } = ports;
        // The active instance acts on the newest measurement only (an older
        // one is already late); a shadow steps through all of them in order,
        // so that a different design's filters see every sample.
        self.backlog.clear();
        while let Some(m) = measurements.receive()? {
            self.backlog.push(&m);
        }
        let Some(m) = self.backlog.newest() else {
            return Ok(());
        };
        let received_ns = monotonic_ns();
        let older = self.backlog.older();
        let step = instance.on_sample::<Self>(
            activation,
            spare.as_ref(),
            m.seq,
            older.first().map_or(m.seq, |oldest| oldest.seq),
            // Named for a coming boundary and caught up (nothing left over
            // from following at low priority).
            older.is_empty(),
        )?;
        let active = step.duty == Duty::Active;
        if step.duty == Duty::Retiring {
            // Replaced at a sample boundary: the new instance owns this one.
            return Ok(());
        }

        ring.take(estimates, activation.current())?;
        // A standby's command may be applied: it waits for the estimate too.
        // So does a shadow of another design: its filters run on their own,
        // and a sample stepped with the estimate before its own (the
        // observer not yet done) leaves them off, and the switch with them
        // (a step 3 times the ordinary ones, now and then, in lockstep).
        if (active || step.duty == Duty::Standby || !self.takeover.copied)
            && ring.find(m.seq).is_none()
            && !self.await_estimate(instance, estimates, activation, ring, &m, received_ns)?
        {
            return Ok(());
        }
        let estimate = ring.find(m.seq).or_else(|| ring.newest_before(m.seq));
        let Some(estimate) = estimate else {
            // No estimate at all yet (observer not started): skip this tick.
            return Ok(());
        };

        instance.take_handovers(states_in)?;
        let generation = instance.generation();
        // A design that copies the active state before each sample needs
        // only the newest; another one steps through every sample it missed.
        if step.was != Duty::Active && !self.takeover.copied {
            for older in self.backlog.older() {
                if activation.current().controller_for(older.seq) == generation {
                    continue;
                }
                if let Some(e) = ring
                    .find(older.seq)
                    .or_else(|| ring.newest_before(older.seq))
                {
                    self.takeover
                        .follow(&mut self.core, &instance.handovers, older.seq, false);
                    self.core.step(older, e, &mut self.shadow_command);
                    self.takeover.shadow_u = law_output(&self.shadow_command, self.n_inputs);
                    self.takeover.shadow_seq = older.seq;
                }
            }
        }
        if !active {
            self.follow(
                instance,
                step.duty,
                commands,
                states_out,
                &m,
                estimate,
                received_ns,
            )?;
            // A shadow ends with the run like everyone else.
            instance.served(m.flags);
            return Ok(());
        }
        if step.takes_over() {
            self.take_over(instance, states_in, &m)?;
        }
        let mut sent_u = [0.0; MAX_INPUTS];
        let (core, n_inputs, n_outputs) = (&mut self.core, self.n_inputs, self.n_outputs);
        commands.publish(|c| {
            core.step(&m, estimate, c);
            stamp_command(c, &m, estimate, generation, n_inputs, n_outputs);
            c.received_ns = received_ns;
            c.published_ns = monotonic_ns();
            sent_u = c.u;
        })?;
        if instance.lockstep {
            commands.notify()?;
        }
        let core = &self.core;
        instance.publish_state(states_out, m.seq, &sent_u[..self.n_inputs], |h| {
            core.save(h)
        })?;
        instance.served(m.flags);
        Ok(())
    }

    fn report(&self, instance: &Instance) {
        let skipped = instance.skipped();
        if self.stale_estimates + skipped > 0 {
            eprintln!(
                "flexloop-controller: generation {}: {} stale estimates, {skipped} measurements skipped",
                instance.generation(),
                self.stale_estimates
            );
        }
    }
}

impl<L: ControlLaw> Controller<L> {
    /// Waits for the estimate of sample `m` (received at `received_ns`):
    /// in lockstep as long as the observer may take, in realtime at most
    /// half a period after the tick (the wake-up after a timed wait can
    /// itself be tens of µs late, and an estimate one tick old, counted
    /// stale, costs less than a missed command). False: a shutdown came.
    fn await_estimate(
        &mut self,
        instance: &Instance,
        estimates: &Inlet<Estimate>,
        activation: &mut ActivationView,
        ring: &mut EstimateRing,
        m: &Measurement,
        received_ns: u64,
    ) -> Result<bool, NodeError> {
        let deadline = if instance.lockstep {
            received_ns + LOCKSTEP_ESTIMATE_WAIT_NS
        } else {
            m.tick_ns + instance.period_ns / 2
        };
        loop {
            let now = monotonic_ns();
            if now >= deadline {
                self.stale_estimates += 1;
                break;
            }
            wait_for_input(instance.waits(), &[estimates.fd()], deadline - now, || {
                estimates.has_samples().unwrap_or(true)
            })
            .map_err(|e| NodeError::Peer(e.to_string()))?;
            // Refreshed: a restarted observer's estimates count from a
            // boundary announced while this sample waits for them.
            ring.take(estimates, activation.refresh()?)?;
            if ring.find(m.seq).is_some() {
                break;
            }
            if shutdown::requested() {
                return Ok(false);
            }
        }
        if instance.lockstep && ring.find(m.seq).is_none() && !instance.joining.is_late() {
            return Err(NodeError::Peer(format!(
                "lockstep: no estimate for tick {} from the observer",
                m.seq
            )));
        }
        Ok(true)
    }

    /// Shadow or standby: follows the active instance through sample `m`
    /// and computes; only a standby publishes its command (for the plant's
    /// safe action).
    #[allow(clippy::too_many_arguments)]
    fn follow(
        &mut self,
        instance: &Instance,
        duty: Duty,
        commands: &Outlet<Command>,
        states_out: &Outlet<Handover>,
        m: &Measurement,
        estimate: &Estimate,
        received_ns: u64,
    ) -> Result<(), NodeError> {
        self.takeover
            .follow(&mut self.core, &instance.handovers, m.seq, true);
        self.core.step(m, estimate, &mut self.shadow_command);
        stamp_command(
            &mut self.shadow_command,
            m,
            estimate,
            instance.generation(),
            self.n_inputs,
            self.n_outputs,
        );
        self.takeover.shadow_u = law_output(&self.shadow_command, self.n_inputs);
        self.takeover.shadow_seq = m.seq;
        if duty == Duty::Standby {
            let shadow_command = &self.shadow_command;
            commands.publish(|c| {
                *c = *shadow_command;
                c.flags |= flags::STANDBY;
                c.received_ns = received_ns;
                c.published_ns = monotonic_ns();
            })?;
        }
        // Following only once a handed-over state is there (as the
        // observer: after a crash the supervisor hands the dead one's on
        // until it sees this instance follow).
        if instance.handovers.newest().is_some() {
            let core = &self.core;
            instance.publish_state(
                states_out,
                m.seq,
                &self.shadow_command.u[..self.n_inputs],
                |h| core.save(h),
            )?;
        }
        Ok(())
    }

    /// The first sample this instance owns, `m`.
    fn take_over(
        &mut self,
        instance: &mut Instance,
        states_in: &Inlet<Handover>,
        m: &Measurement,
    ) -> Result<(), NodeError> {
        // The old instance publishes its last state just after its last
        // command, and the plant may already have moved on: wait for it
        // briefly (it carries what a retuned design must continue).
        let deadline = if instance.lockstep {
            monotonic_ns() + HANDOVER_WAIT_LOCKSTEP_NS
        } else {
            m.tick_ns + instance.period_ns / 4
        };
        // (A restart's predecessor is dead: nothing more will come.)
        let restart = instance.joining == Joining::Restart;
        while !restart
            && m.seq > 0
            && instance.handovers.find(m.seq - 1).is_none()
            && monotonic_ns() < deadline
        {
            std::thread::sleep(std::time::Duration::from_micros(20));
            instance.take_handovers(states_in)?;
        }
        if !restart && m.seq > 0 && instance.handovers.find(m.seq - 1).is_none() {
            // Once, at the switch: a retuned design cannot continue the
            // old command without it (the supervisor measures the step).
            eprintln!(
                "flexloop-controller: generation {} active from sample {} without its predecessor's state after sample {}",
                instance.generation(),
                m.seq,
                m.seq - 1
            );
        }
        self.takeover
            .activate(&mut self.core, &instance.handovers, m.seq, self.n_inputs);
        // A restart owns samples at once, before it ever followed: it
        // starts from the newest state its predecessor left.
        if !self.takeover.copied {
            self.takeover
                .follow(&mut self.core, &instance.handovers, m.seq, true);
        }
        Ok(())
    }
}

/// A replacement joining a running loop brings its feedforward block to the
/// loop's current sample before it takes its CPU and priority: it takes the
/// block's state from the active instance when both have the same
/// feedforward, and otherwise replays it (design-time work, one block step
/// per sample since the start, that must not run at real-time priority
/// beside the loop). False if a shutdown came first.
fn catch_up_with_loop(
    core: &mut impl ControlLaw,
    measurements: &Inlet<Measurement>,
    states_in: &Inlet<Handover>,
    handovers: &mut HandoverRing,
    generation: u32,
) -> Result<bool, NodeError> {
    let mut taken_over = false;
    let since = std::time::Instant::now();
    loop {
        if shutdown::requested() {
            return Ok(false);
        }
        if since.elapsed() > crate::PEER_TIMEOUT {
            return Err(NodeError::Peer(
                "joining: the plant published no measurement".into(),
            ));
        }
        wait_readable(&[measurements.fd()], 100_000_000)
            .map_err(|e| NodeError::Peer(e.to_string()))?;
        measurements.clear_events()?;
        let mut newest = None;
        while let Some(m) = measurements.receive()? {
            newest = Some(m.seq);
        }
        handovers.take(states_in, generation)?;
        if !taken_over && let Some(h) = handovers.newest() {
            taken_over = core.load_feedforward(h);
        }
        // Close the gap until what is left fits the per-sample catch-up.
        if let Some(seq) = newest
            && core.fast_forward(seq) <= 32
        {
            return Ok(true);
        }
    }
}

/// How many samples a shadow may fall behind and still step through every
/// one of them (in lockstep the loop runs flat out beside it, and a shadow
/// of another design that lost samples starts with its filters off: 128
/// was lost now and then on a loaded machine, and the switch stepped).
const FOLLOW_DEPTH: usize = MEASUREMENT.qos.subscriber_max_buffer_size;
const BACKLOG: usize = FOLLOW_DEPTH;

/// The measurements one wake-up drained, in arrival order (preallocated).
struct Backlog {
    items: Box<[Measurement; BACKLOG]>,
    len: usize,
}

impl Default for Backlog {
    fn default() -> Self {
        Self {
            items: Box::new([Measurement::default(); BACKLOG]),
            len: 0,
        }
    }
}

impl Backlog {
    fn clear(&mut self) {
        self.len = 0;
    }

    /// Keeps the last [`BACKLOG`] measurements (the queue holds no more).
    fn push(&mut self, m: &Measurement) {
        if self.len == BACKLOG {
            self.items.copy_within(1.., 0);
            self.len -= 1;
        }
        self.items[self.len] = *m;
        self.len += 1;
    }

    fn newest(&self) -> Option<Measurement> {
        self.len.checked_sub(1).map(|i| self.items[i])
    }

    fn older(&self) -> &[Measurement] {
        &self.items[..self.len.saturating_sub(1)]
    }
}

/// How a replacement takes over: in shadow it copies the active instance's
/// state before each sample (identical design) or runs on its own (another
/// design); at its first active sample it continues the old command.
#[derive(Default)]
struct Takeover {
    /// Whether the state was copied from the active instance.
    copied: bool,
    shadow_u: [f64; MAX_INPUTS],
    shadow_seq: u64,
}

impl Takeover {
    /// Before sample `seq`: copy the active state after `seq − 1`. With
    /// `newest_too` (the newest sample of a wake-up only), a restart, which
    /// finds no such state (the old instance is dead), takes the newest there
    /// is, once, and replays its feedforward from there.
    fn follow(
        &mut self,
        core: &mut impl ControlLaw,
        handovers: &HandoverRing,
        seq: u64,
        newest_too: bool,
    ) {
        if let Some(h) = seq.checked_sub(1).and_then(|s| handovers.find(s)) {
            self.copied |= core.load(h);
            return;
        }
        if self.copied || !newest_too {
            return;
        }
        if let Some(h) = handovers.newest()
            && h.seq < seq
            && core.load(h)
        {
            core.fast_forward(seq);
            self.copied = true;
        }
    }

    fn activate(
        &mut self,
        core: &mut impl ControlLaw,
        handovers: &HandoverRing,
        seq: u64,
        n_inputs: usize,
    ) {
        let Some(last) = seq.checked_sub(1).and_then(|s| handovers.find(s)) else {
            return;
        };
        if core.load(last) {
            return;
        }
        // Another design: shift its integrator so that its output continues
        // the old command at the sample both computed.
        if self.shadow_seq == last.seq {
            let mut delta = [0.0; MAX_INPUTS];
            for ((d, old), new) in delta.iter_mut().zip(&last.u).zip(&self.shadow_u) {
                *d = old - new;
            }
            core.shift_output(&delta[..n_inputs]);
        }
    }
}

/// What the law asked for, before any clamp: the sum of its parts when it
/// gives them (`u_fb + u_ff + u_d`, as the built-in controller and the
/// examples do), else its command. The bumpless shift continues the old
/// command from this: a shadow saturated at the actuator's limit would
/// otherwise shift by the wrong amount and step the actuator at the switch
/// by as much as its own output exceeds the limit (seen: 706 N).
fn law_output(command: &Command, n_inputs: usize) -> [f64; MAX_INPUTS] {
    let n = n_inputs.min(MAX_INPUTS);
    let has_parts =
        (0..n).any(|i| command.u_fb[i] != 0.0 || command.u_ff[i] != 0.0 || command.u_d[i] != 0.0);
    let mut out = command.u;
    if has_parts {
        for (i, u) in out.iter_mut().enumerate().take(n) {
            let sum = command.u_fb[i] + command.u_ff[i] + command.u_d[i];
            if sum.is_finite() {
                *u = sum;
            }
        }
    }
    out
}

const RING: usize = FOLLOW_DEPTH;

/// The last few estimates, by sequence number, preallocated: the controller
/// must use the one for its tick, not merely the newest (the observer may
/// already be a tick ahead).
struct EstimateRing {
    slots: Box<[Estimate; RING]>,
    valid: [bool; RING],
}

impl EstimateRing {
    fn new() -> Self {
        Self {
            slots: Box::new([Estimate::default(); RING]),
            valid: [false; RING],
        }
    }

    /// Forgets every estimate, in place: a new ring is 2.2 MB to allocate
    /// and fault in, 0.3 ms of a restart's held ticks (measured with
    /// `flexloop chaos`).
    fn clear(&mut self) {
        self.valid = [false; RING];
    }

    /// Drains the inlet into the ring, keeping only the estimates of the
    /// observer generation that owns their sequence number.
    fn take(
        &mut self,
        estimates: &Inlet<Estimate>,
        activation: &Activation,
    ) -> Result<(), NodeError> {
        estimates.clear_events()?;
        while let Some(e) = estimates.receive()? {
            if e.generation != activation.observer_for(e.seq) {
                continue;
            }
            let slot = (e.seq % RING as u64) as usize;
            self.slots[slot] = *e;
            self.valid[slot] = true;
        }
        Ok(())
    }

    fn any(&self) -> bool {
        self.valid.iter().any(|v| *v)
    }

    fn find(&self, seq: u64) -> Option<&Estimate> {
        let slot = (seq % RING as u64) as usize;
        (self.valid[slot] && self.slots[slot].seq == seq).then(|| &self.slots[slot])
    }

    /// The newest estimate older than `seq` (used, and counted stale, when the
    /// observer is late in realtime mode).
    fn newest_before(&self, seq: u64) -> Option<&Estimate> {
        self.slots
            .iter()
            .zip(&self.valid)
            .filter(|(e, v)| **v && e.seq < seq)
            .map(|(e, _)| e)
            .max_by_key(|e| e.seq)
    }
}
