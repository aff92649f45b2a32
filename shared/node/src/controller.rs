//! The controller process: wakes on y(k), publishes u(k).

use crate::args::{Role, ServiceArgs, realtime_settings, wait_mode};
use crate::handover::{
    ActivationView, HandoverRing, publish_state, raise_priority, shadow_scheduling,
};
use crate::spare::{Served, SpareDuty, leave_the_loop, serve_orders};
use crate::startup::StartupClock;
use crate::{NodeError, await_peers};
use flexloop_components::ControllerCore;
use flexloop_protocol::channels::{COMMAND, CONTROLLER_STATE, ESTIMATE, MEASUREMENT};
use flexloop_protocol::handover::{ACTIVE, FOLLOWING};
use flexloop_protocol::{Activation, Command, Estimate, Handover, MAX_INPUTS, Measurement, flags};
use flexloop_runtime::wait::{WaitMode, wait_for_input, wait_readable};
use flexloop_runtime::{monotonic_ns, realtime, shutdown};
use flexloop_scenario::{LoopDesign, Mode, Scenario};
use flexloop_transport::{Domain, Inlet, LoopNode, Outlet};

/// In lockstep, how long a new instance waits for its predecessor's last
/// state: the loop waits too, and on a loaded machine 100 ms was sometimes
/// too short (a retuned design then starts without continuing the old
/// command: a step).
const HANDOVER_WAIT_LOCKSTEP_NS: u64 = 2_000_000_000;
/// In lockstep, how long to wait for the observer before giving up.
const LOCKSTEP_ESTIMATE_WAIT_NS: u64 = 5_000_000_000;

pub fn run(args: &ServiceArgs) -> Result<(), NodeError> {
    let clock = StartupClock::start();
    let (scenario, design) = args.load_at_start()?;
    // Locked before the ports exist, so their memory is populated now (see plant).
    let rt = realtime_settings(&scenario, Role::Controller);
    let _memory = realtime::apply(Role::Controller.name(), &rt.memory_part());
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node("controller")?;
    let mut ring = EstimateRing::new();
    let Some(mut ports) = Ports::open(&node, args, &scenario, &mut ring)? else {
        return Ok(());
    };
    serve_orders(
        args,
        design.map(|d| (scenario.clone(), d)),
        clock,
        &mut ports,
        |p| {
            let Ports {
                spare,
                measurements,
                ..
            } = p;
            spare.as_mut().map(|d| (d, &*measurements))
        },
        |args, scenario, design, ports, clock| {
            serve(args, scenario, design, ports, &mut ring, clock)
        },
    )
}

/// Every port a controller uses, open for the process's life.
struct Ports {
    measurements: Inlet<Measurement>,
    estimates: Inlet<Estimate>,
    activation: ActivationView,
    states_in: Inlet<Handover>,
    states_out: Outlet<Handover>,
    commands: Outlet<Command>,
    /// With warm spares: orders and idle reports.
    spare: Option<SpareDuty>,
}

impl Ports {
    /// Opens and connects every port; the first instance also waits for the
    /// observer's first estimate (into `ring`). `None`: a shutdown came first.
    fn open(
        node: &LoopNode,
        args: &ServiceArgs,
        scenario: &Scenario,
        ring: &mut EstimateRing,
    ) -> Result<Option<Self>, NodeError> {
        let measurements = Inlet::<Measurement>::open(node, &MEASUREMENT, FOLLOW_DEPTH)?;
        let estimates = Inlet::<Estimate>::open(node, &ESTIMATE, FOLLOW_DEPTH)?;
        let mut activation = ActivationView::open(node)?;
        let states_in = Inlet::<Handover>::open_polling(
            node,
            &CONTROLLER_STATE,
            CONTROLLER_STATE.qos.loop_buffer_size,
        )?;
        let states_out = Outlet::<Handover>::open(node, &CONTROLLER_STATE)?;
        let spare = if scenario.supervision.warm_spares {
            Some(SpareDuty::open(node)?)
        } else {
            None
        };
        if !await_peers(
            || {
                if estimates.publishers() >= 1 && measurements.publishers() >= 1 {
                    ring.take(&estimates, activation.refresh()?)?;
                }
                // A replacement joins a running loop: the estimates it needs
                // come with the next sample.
                Ok(ring.any() || (args.join && estimates.publishers() >= 1))
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
        states_in.connect()?;
        activation.connect()?;
        if let Some(duty) = &spare {
            duty.connect()?;
        }
        Ok(Some(Self {
            measurements,
            estimates,
            activation,
            states_in,
            states_out,
            commands,
            spare,
        }))
    }
}

/// What queued up while this process was idle, or before it joined,
/// belongs to nobody now.
fn drop_stale_inputs(
    measurements: &Inlet<Measurement>,
    estimates: &Inlet<Estimate>,
    states_in: &Inlet<Handover>,
    ring: &mut EstimateRing,
) -> Result<(), NodeError> {
    measurements.clear_events()?;
    while measurements.receive()?.is_some() {}
    estimates.clear_events()?;
    while estimates.receive()?.is_some() {}
    while states_in.receive()?.is_some() {}
    *ring = EstimateRing::new();
    Ok(())
}

/// Serves the loop as `args.generation` with `design` until replaced or
/// the run ends.
fn serve(
    args: &ServiceArgs,
    scenario: &Scenario,
    design: &LoopDesign,
    ports: &mut Ports,
    ring: &mut EstimateRing,
    clock: &StartupClock,
) -> Result<Served, NodeError> {
    let Ports {
        measurements,
        estimates,
        activation,
        states_in,
        states_out,
        commands,
        spare,
    } = ports;
    let serve_start_ns = monotonic_ns();
    let mut core = ControllerCore::new(design, args.generation);
    core.set_estimate_watchdog(scenario.supervision.estimate_watchdog_ticks);
    let rt = realtime_settings(scenario, Role::Controller);
    let mut handovers = HandoverRing::default();
    if args.join {
        drop_stale_inputs(measurements, estimates, states_in, ring)?;
        if !catch_up_with_loop(
            &mut core,
            measurements,
            states_in,
            &mut handovers,
            args.generation,
        )? {
            return Ok(Served::Ended);
        }
    }
    // Priority and CPU only now, every port open and connected: creating a
    // port initialises its shared memory, milliseconds of kernel work that
    // must not run at real-time priority on the loop's CPU (measured: each
    // controller swap stalled the plant 1–25 ms). See
    // `RealtimeSettings::scheduling_part`.
    let _scheduling = realtime::apply(Role::Controller.name(), &shadow_scheduling(&rt, args));
    let mut priority_raised = !args.join;
    // A shadow or standby follows on a shared CPU: it waits on events until
    // it is named for the loop's CPU (and, under dedicated-cores, spins there).
    let mut waits = if priority_raised {
        wait_mode(scenario)
    } else {
        WaitMode::Events
    };
    let lockstep = scenario.timing.mode == Mode::Lockstep;
    let period_ns = scenario.period_ns();
    // In realtime, wait for a late estimate at most half a period after the
    // tick: the wake-up after a timed wait can itself be tens of µs late, and
    // an estimate one tick old (counted) costs less than a missed command.
    let estimate_wait_ns = period_ns / 2;

    if args.join {
        clock.report_joined(args.role);
    }
    let mut backlog = Backlog::default();
    let mut takeover = Takeover::default();
    let mut shadow_command = Command::default();
    let mut stale_estimates = 0u64;
    let mut skipped = 0u64;
    let mut next_seq: Option<u64> = None;
    let mut ended = Served::Ended;
    let mut done = false;
    while !done && !shutdown::requested() {
        wait_for_input(waits, &[measurements.fd()], 100_000_000, || {
            measurements.has_samples().unwrap_or(true)
        })
        .map_err(|e| NodeError::Peer(e.to_string()))?;
        measurements.clear_events()?;
        // The active instance acts on the newest measurement only (an older
        // one is already late); a shadow steps through all of them in order,
        // so that a different design's filters see every sample.
        backlog.clear();
        while let Some(m) = measurements.receive()? {
            backlog.push(&m);
        }
        let Some(m) = backlog.newest() else { continue };
        let received_ns = monotonic_ns();
        let owner = activation.refresh()?.controller_for(m.seq);
        let active = owner == args.generation;
        // Measurements never seen (a shadow steps through the older ones of
        // a wake-up; the active instance answers the newest only).
        if let Some(next) = next_seq {
            let first = match backlog.older().first() {
                Some(oldest) if !active => oldest.seq,
                _ => m.seq,
            };
            skipped += first.saturating_sub(next);
        }
        next_seq = Some(m.seq + 1);
        // Named for a coming boundary and caught up (nothing left over from
        // following at low priority), or at the latest at its first sample:
        // the loop's priority from now on.
        let named = activation.current().controller_generation == args.generation;
        if !priority_raised && ((named && backlog.older().is_empty()) || active) {
            raise_priority(&rt);
            priority_raised = true;
            waits = wait_mode(scenario);
        }
        if !active && takeover.was_active {
            // Replaced at a sample boundary: the new instance owns this one.
            ended = Served::Replaced;
            break;
        }
        // A standby of a design no longer active is retired to a spare.
        if args.standby
            && !active
            && let Some(duty) = spare.as_ref()
            && duty.retire_requested(serve_start_ns)?
        {
            ended = Served::Replaced;
            break;
        }

        ring.take(estimates, activation.current())?;
        // A standby's command may be applied: it waits for the estimate too.
        // So does a shadow of another design: its filters run on their own,
        // and a sample stepped with the estimate before its own (the
        // observer not yet done) leaves them off, and the switch with them
        // (a step 3 times the ordinary ones, now and then, in lockstep).
        if (active || args.standby || !takeover.copied) && ring.find(m.seq).is_none() {
            let deadline = if lockstep {
                received_ns + LOCKSTEP_ESTIMATE_WAIT_NS
            } else {
                m.tick_ns + estimate_wait_ns
            };
            loop {
                let now = monotonic_ns();
                if now >= deadline {
                    stale_estimates += 1;
                    break;
                }
                wait_for_input(waits, &[estimates.fd()], deadline - now, || {
                    estimates.has_samples().unwrap_or(true)
                })
                .map_err(|e| NodeError::Peer(e.to_string()))?;
                // Refreshed: a restarted observer's estimates count from
                // a boundary announced while this sample waits for them.
                ring.take(estimates, activation.refresh()?)?;
                if ring.find(m.seq).is_some() {
                    break;
                }
                if shutdown::requested() {
                    return Ok(Served::Ended);
                }
            }
            if lockstep && ring.find(m.seq).is_none() && !args.join {
                return Err(NodeError::Peer(format!(
                    "lockstep: no estimate for tick {} from the observer",
                    m.seq
                )));
            }
        }
        let estimate = ring.find(m.seq).or_else(|| ring.newest_before(m.seq));
        let Some(estimate) = estimate else {
            // No estimate at all yet (observer not started): skip this tick.
            continue;
        };

        handovers.take(states_in, args.generation)?;
        // A design that copies the active state before each sample needs
        // only the newest; another one steps through every sample it missed.
        if !takeover.was_active && !takeover.copied {
            for older in backlog.older() {
                if activation.current().controller_for(older.seq) == args.generation {
                    continue;
                }
                if let Some(e) = ring
                    .find(older.seq)
                    .or_else(|| ring.newest_before(older.seq))
                {
                    takeover.follow(&mut core, &handovers, older.seq, false);
                    core.step(older, e, &mut shadow_command);
                    takeover.shadow_u = shadow_command.u;
                    takeover.shadow_seq = older.seq;
                }
            }
        }
        if !active {
            // Shadow: follow the active instance, compute, publish nothing.
            takeover.follow(&mut core, &handovers, m.seq, true);
            core.step(&m, estimate, &mut shadow_command);
            takeover.shadow_u = shadow_command.u;
            takeover.shadow_seq = m.seq;
            if args.standby {
                commands.publish(|c| {
                    *c = shadow_command;
                    c.flags |= flags::STANDBY;
                    c.received_ns = received_ns;
                    c.published_ns = monotonic_ns();
                })?;
            }
            // Following only once a handed-over state is there (as the
            // observer: after a crash the supervisor hands the dead one's on
            // until it sees this instance follow).
            if handovers.newest().is_some() {
                publish_state(
                    states_out,
                    m.seq,
                    args.generation,
                    FOLLOWING,
                    &shadow_command.u[..design.n_inputs],
                    |h| core.save(h),
                )?;
            }
            // A shadow ends with the run like everyone else.
            done = m.flags & flags::END_OF_RUN != 0;
            continue;
        }
        if !takeover.was_active {
            // The old instance publishes its last state just after its last
            // command, and the plant may already have moved on: wait for it
            // briefly (it carries what a retuned design must continue).
            let deadline = if lockstep {
                monotonic_ns() + HANDOVER_WAIT_LOCKSTEP_NS
            } else {
                m.tick_ns + period_ns / 4
            };
            // (A restart's predecessor is dead: nothing more will come.)
            while !args.restart
                && m.seq > 0
                && handovers.find(m.seq - 1).is_none()
                && monotonic_ns() < deadline
            {
                std::thread::sleep(std::time::Duration::from_micros(20));
                handovers.take(states_in, args.generation)?;
            }
            if !args.restart && m.seq > 0 && handovers.find(m.seq - 1).is_none() {
                // Once, at the switch: a retuned design cannot continue the
                // old command without it (the supervisor measures the step).
                eprintln!(
                    "flexloop-controller: generation {} active from sample {} without its predecessor's state after sample {}",
                    args.generation,
                    m.seq,
                    m.seq - 1
                );
            }
            takeover.activate(&mut core, &handovers, m.seq, design.n_inputs);
            // A restart owns samples at once, before it ever followed: it
            // starts from the newest state its predecessor left.
            if !takeover.copied {
                takeover.follow(&mut core, &handovers, m.seq, true);
            }
        }
        let mut sent_u = [0.0; MAX_INPUTS];
        commands.publish(|c| {
            core.step(&m, estimate, c);
            c.received_ns = received_ns;
            c.published_ns = monotonic_ns();
            sent_u = c.u;
        })?;
        if lockstep {
            commands.notify()?;
        }
        publish_state(
            states_out,
            m.seq,
            args.generation,
            ACTIVE,
            &sent_u[..design.n_inputs],
            |h| core.save(h),
        )?;
        done = m.flags & flags::END_OF_RUN != 0;
    }
    leave_the_loop(rt.cpu, ended, spare.is_some());
    if stale_estimates + skipped > 0 {
        eprintln!(
            "flexloop-controller: generation {}: {stale_estimates} stale estimates, {skipped} measurements skipped",
            args.generation
        );
    }
    Ok(ended)
}

/// A replacement joining a running loop brings its feedforward block to the
/// loop's current sample before it takes its CPU and priority: it takes the
/// block's state from the active instance when both have the same
/// feedforward, and otherwise replays it (design-time work, one block step
/// per sample since the start, that must not run at real-time priority
/// beside the loop). False if a shutdown came first.
fn catch_up_with_loop(
    core: &mut ControllerCore,
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
    was_active: bool,
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
        core: &mut ControllerCore,
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
        core: &mut ControllerCore,
        handovers: &HandoverRing,
        seq: u64,
        n_inputs: usize,
    ) {
        self.was_active = true;
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
