//! The life of a controller or observer process, written once over what
//! each role brings ([`Component`]): the start-up (loading, design, ports,
//! real-time set-up, the handshake), serving one generation after another
//! sample by sample ([`Instance::on_sample`]), and idling as a warm spare
//! in between.

use crate::NodeError;
use crate::args::{Role, ServiceArgs, realtime_settings, wait_mode};
use crate::duty::{Duty, SampleOwnership, Standing, Step};
use crate::handover::{ActivationView, HandoverRing, publish_state, raise_priority};
use crate::prepared::PreparedDesign;
use crate::spare::{Served, SpareDuty, leave_the_loop};
use crate::startup::StartupClock;
use flexloop_design::LoopDesign;
use flexloop_protocol::{Activation, Channel, Handover, Joining, Measurement, flags};
use flexloop_runtime::realtime::{self, RealtimeSettings};
use flexloop_runtime::wait::{WaitMode, wait_for_input};
use flexloop_runtime::{monotonic_ns, shutdown};
use flexloop_scenario::{Mode, Scenario};
use flexloop_transport::{Domain, Inlet, LoopNode, Outlet};

/// What a role brings to the life [`run`] gives it: its ports, its core,
/// and its work on each wake-up. The defaults are for a role with nothing
/// to do at that point.
pub(crate) trait Component: Sized {
    const ROLE: Role;
    /// Where its instances publish their states for a replacement.
    const STATE: &'static Channel;
    /// The role's own ports, beside the ones every instance has.
    type Own;

    /// The loop's measurements, queued as deep as the role reads them.
    fn open_measurements(
        node: &LoopNode,
        args: &ServiceArgs,
        scenario: &Scenario,
    ) -> Result<Inlet<Measurement>, NodeError>;

    /// Opens the role's own ports and waits for its peers: the role's part
    /// of the start-up handshake. `None`: a shutdown came first.
    fn open_own(
        node: &LoopNode,
        args: &ServiceArgs,
        scenario: &Scenario,
        measurements: &Inlet<Measurement>,
        activation: &mut ActivationView,
    ) -> Result<Option<Self::Own>, NodeError>;

    /// The role's core for `design`, serving as the generation `args`
    /// names (a program's law reports its parameters into `args`' run
    /// directory).
    fn design(
        design: &LoopDesign,
        scenario: &Scenario,
        args: &ServiceArgs,
    ) -> Result<Self, NodeError>;

    /// The generation whose output from measurement `seq` counts.
    fn owner(activation: &Activation, seq: u64) -> u32;

    /// The generation named for the role's coming boundary.
    fn named(activation: &Activation) -> u32;

    /// A late joiner drops what queued up on the role's own inputs while
    /// it was idle, or before it joined.
    fn drop_stale(_own: &mut Self::Own) -> Result<(), NodeError> {
        Ok(())
    }

    /// A late joiner's design-time work to reach the loop's present, before
    /// it takes the loop's CPU and priority. False: a shutdown came first.
    fn catch_up(
        &mut self,
        _instance: &mut Instance,
        _ports: &mut Ports<Self::Own>,
    ) -> Result<bool, NodeError> {
        Ok(true)
    }

    /// The rest of the handshake, at the instance's scheduling, before its
    /// start-up is reported. False: a shutdown came first.
    fn enter(
        &mut self,
        _instance: &mut Instance,
        _ports: &mut Ports<Self::Own>,
    ) -> Result<bool, NodeError> {
        Ok(true)
    }

    /// Work owed before the first wake-up (after the start-up report).
    fn resume(
        &mut self,
        _instance: &mut Instance,
        _ports: &mut Ports<Self::Own>,
    ) -> Result<(), NodeError> {
        Ok(())
    }

    /// The measurements of one wake-up: each sample the role serves goes
    /// through [`Instance::on_sample`] first.
    fn on_wakeup(
        &mut self,
        instance: &mut Instance,
        ports: &mut Ports<Self::Own>,
    ) -> Result<(), NodeError>;

    /// What the service counted, once it ended, for the stderr file.
    fn report(&self, instance: &Instance);
}

/// Every port a controller or observer uses, open for the process's life.
pub(crate) struct Ports<Own> {
    pub measurements: Inlet<Measurement>,
    pub activation: ActivationView,
    /// Other generations' states (and the supervisor's, for a dead one).
    pub states_in: Inlet<Handover>,
    pub states_out: Outlet<Handover>,
    /// With warm spares: orders and idle reports.
    pub spare: Option<SpareDuty>,
    pub own: Own,
}

impl<Own> Ports<Own> {
    /// Opens and connects every port. `None`: a shutdown came first.
    fn open<C: Component<Own = Own>>(
        node: &LoopNode,
        args: &ServiceArgs,
        scenario: &Scenario,
        spares: Spares,
    ) -> Result<Option<Self>, NodeError> {
        let measurements = C::open_measurements(node, args, scenario)?;
        let mut activation = ActivationView::open(node)?;
        let states_in =
            Inlet::<Handover>::open_polling(node, C::STATE, C::STATE.qos.loop_buffer_size)?;
        let states_out = Outlet::<Handover>::open(node, C::STATE)?;
        let spare = if scenario.supervision.warm_spares && spares == Spares::Serves {
            Some(SpareDuty::open(node)?)
        } else {
            None
        };
        let Some(own) = C::open_own(node, args, scenario, &measurements, &mut activation)? else {
            return Ok(None);
        };
        states_in.connect()?;
        activation.connect()?;
        if let Some(duty) = &spare {
            duty.connect()?;
        }
        Ok(Some(Self {
            measurements,
            activation,
            states_in,
            states_out,
            spare,
            own,
        }))
    }

    /// What queued up while this process was idle, or before it joined,
    /// belongs to nobody now; except, for a restart, the states: the dead
    /// predecessor's last ones are among them, and taking over from them
    /// needs no wait for the supervisor to hand them on (a millisecond or
    /// more of held input, measured with `flexloop chaos`).
    fn drop_stale(&mut self, joining: Joining) -> Result<(), NodeError> {
        self.measurements.clear_events()?;
        while self.measurements.receive()?.is_some() {}
        if joining != Joining::Restart {
            while self.states_in.receive()?.is_some() {}
        }
        Ok(())
    }
}

/// Whether a process can be a warm spare: a spare serves whatever scenario
/// the next order names, which only the built-in processes can (a user's
/// program serves its own law alone, and exits when replaced).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Spares {
    Serves,
    Never,
}

/// A process's life: start-up, then it serves the loop as started (a spare
/// waits for an order first) and, with warm spares, idles after each
/// replacement until the next order.
pub(crate) fn run<C: Component>(args: &ServiceArgs, spares: Spares) -> Result<(), NodeError> {
    if spares == Spares::Never && args.joining == Joining::Spare {
        return Err(NodeError::Usage(format!(
            "--spare: a {} program serves its own law only and is never a spare",
            C::ROLE.name()
        )));
    }
    let clock = StartupClock::start();
    // A spare designs its scenario now too, so that an order to serve it
    // starts at once (see `prepared`).
    let (scenario, design) = args.load()?;
    // Locked before the ports exist, so their memory is populated now (see plant).
    let rt = realtime_settings(&scenario, C::ROLE);
    let _memory = realtime::apply(C::ROLE.name(), &rt.memory_part());
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node(C::ROLE.name())?;
    let Some(mut ports) = Ports::open::<C>(&node, args, &scenario, spares)? else {
        return Ok(());
    };
    let is_spare = Duty::entering(args.joining) == Duty::Spare;
    let prepared = is_spare.then(|| PreparedDesign::new(args, &scenario, &design));
    let mut next = (!is_spare).then(|| (args.clone(), Some((scenario, design)), clock));
    let mut served = args.generation;
    // Whether this process's private memory is populated and locked already
    // (a spare does it before its first idle spell: see `serve`).
    let mut prefaulted = false;
    loop {
        let (serve_args, loaded, clock) = match next.take() {
            Some(order) => order,
            None => {
                let Some(duty) = ports.spare.as_mut() else {
                    return Ok(());
                };
                if !prefaulted && rt.lock_memory {
                    let prefault = RealtimeSettings {
                        prefault_private: true,
                        ..RealtimeSettings::default()
                    };
                    let _ = realtime::apply(C::ROLE.name(), &prefault);
                    prefaulted = true;
                }
                match duty.idle(args, served, &ports.measurements)? {
                    Some(order) => (order, None, StartupClock::start()),
                    None => return Ok(()),
                }
            }
        };
        let (scenario, design) = match loaded {
            Some(loaded) => loaded,
            None => PreparedDesign::for_order(prepared.as_ref(), &serve_args)?,
        };
        served = serve_args.generation;
        let ended = serve::<C>(
            &serve_args,
            &scenario,
            &design,
            &mut ports,
            &clock,
            prefaulted,
        )?;
        if ended == Served::Ended || ports.spare.is_none() {
            return Ok(());
        }
    }
}

/// Serves the loop as `args.generation` with `design` until replaced or
/// the run ends.
fn serve<C: Component>(
    args: &ServiceArgs,
    scenario: &Scenario,
    design: &LoopDesign,
    ports: &mut Ports<C::Own>,
    clock: &StartupClock,
    prefaulted: bool,
) -> Result<Served, NodeError> {
    let mut instance = Instance::new(C::ROLE, args, scenario);
    let mut core = C::design(design, scenario, args)?;
    if args.joining.is_late() {
        ports.drop_stale(args.joining)?;
        C::drop_stale(&mut ports.own)?;
        if !core.catch_up(&mut instance, ports)? {
            return Ok(Served::Ended);
        }
    }
    // Priority and CPU only now, every port open and connected: creating a
    // port initialises its shared memory, milliseconds of kernel work that
    // must not run at real-time priority on the loop's CPU (measured: each
    // controller swap stalled the plant 1–25 ms). See
    // `RealtimeSettings::scheduling_part`.
    // A restart on a spare whose memory was populated while it idled skips
    // it: walking and locking every private mapping again took 1.5–2.5 ms,
    // held ticks every one (measured with `flexloop chaos`). A page the
    // new design touches first in the loop costs a minor fault then.
    let mut scheduling = shadow_scheduling(&instance.rt, args.joining);
    if prefaulted && args.joining == Joining::Restart {
        scheduling.prefault_private = false;
    }
    let _scheduling = realtime::apply(C::ROLE.name(), &scheduling);
    if !core.enter(&mut instance, ports)? {
        return Ok(Served::Ended);
    }
    if args.joining.is_late() {
        clock.report_joined(C::ROLE);
    }
    core.resume(&mut instance, ports)?;
    while instance.serving() && !shutdown::requested() {
        let measurements = &ports.measurements;
        wait_for_input(instance.waits, &[measurements.fd()], 100_000_000, || {
            measurements.has_samples().unwrap_or(true)
        })
        .map_err(|e| NodeError::Peer(e.to_string()))?;
        measurements.clear_events()?;
        core.on_wakeup(&mut instance, ports)?;
    }
    let ended = if instance.duty() == Duty::Retiring {
        Served::Replaced
    } else {
        Served::Ended
    };
    leave_the_loop(instance.rt.cpu, ended, ports.spare.is_some());
    core.report(&instance);
    Ok(ended)
}

/// A replacement follows in shadow off the loop's CPU and without real-time
/// priority, so that stepping through its backlog never competes with the
/// active loop; it moves to the loop's CPU and priority once it is named
/// for a boundary ([`raise_priority`]).
///
/// A standby controller keeps its real-time priority on the other CPU: its
/// commands are the plant's safe action and must be on time.
pub fn shadow_scheduling(rt: &RealtimeSettings, joining: Joining) -> RealtimeSettings {
    let mut scheduling = rt.scheduling_part();
    if joining.is_late() {
        if joining != Joining::Standby {
            scheduling.fifo_priority = None;
        }
        scheduling.avoid_cpu = scheduling.cpu.take();
    }
    scheduling
}

/// One generation's service of the loop: its duty and what every role
/// keeps alike while it serves.
pub(crate) struct Instance {
    standing: Standing,
    pub joining: Joining,
    pub rt: RealtimeSettings,
    /// How it waits now: on events while it follows on a shared CPU, as the
    /// scenario says ([`Instance::loop_waits`]) once at the loop's priority.
    waits: WaitMode,
    loop_waits: WaitMode,
    pub lockstep: bool,
    pub period_ns: u64,
    /// The states other generations hand over.
    pub handovers: HandoverRing,
    serve_start_ns: u64,
    end_of_run: bool,
}

impl Instance {
    fn new(role: Role, args: &ServiceArgs, scenario: &Scenario) -> Self {
        let standing = Standing::new(args.generation, args.joining);
        let loop_waits = wait_mode(scenario);
        Self {
            joining: args.joining,
            rt: realtime_settings(scenario, role),
            // A shadow or standby follows on a shared CPU: it waits on events
            // until it is named for the loop's CPU (and, under
            // dedicated-cores, spins there).
            waits: if standing.priority_raised() {
                loop_waits
            } else {
                WaitMode::Events
            },
            loop_waits,
            lockstep: scenario.timing.mode == Mode::Lockstep,
            period_ns: scenario.period_ns(),
            handovers: HandoverRing::default(),
            serve_start_ns: monotonic_ns(),
            end_of_run: false,
            standing,
        }
    }

    pub fn generation(&self) -> u32 {
        self.standing.generation()
    }

    pub fn duty(&self) -> Duty {
        self.standing.duty()
    }

    pub fn waits(&self) -> WaitMode {
        self.waits
    }

    /// Measurements this instance never saw.
    pub fn skipped(&self) -> u64 {
        self.standing.skipped()
    }

    fn serving(&self) -> bool {
        !self.end_of_run && self.duty().serves()
    }

    /// Before the role serves measurement `seq` (the oldest of its wake-up
    /// `oldest_seq`; `caught_up`: nothing left over from following at low
    /// priority): its duty for it, from the activation. Takes the loop's
    /// priority when due, and retires a standby the supervisor retired (a
    /// polling receive: no system call).
    pub fn on_sample<C: Component>(
        &mut self,
        activation: &mut ActivationView,
        spare: Option<&SpareDuty>,
        seq: u64,
        oldest_seq: u64,
        caught_up: bool,
    ) -> Result<Step, NodeError> {
        let current = activation.refresh()?;
        let step = self.standing.on_sample(&SampleOwnership {
            seq,
            oldest_seq,
            owner: C::owner(current, seq),
            named: C::named(current),
            caught_up,
        });
        if step.raise_priority {
            raise_priority(&self.rt);
            self.waits = self.loop_waits;
        }
        // A standby of a design no longer active is retired to a spare.
        if step.duty == Duty::Standby
            && let Some(duty) = spare
            && duty.retire_requested(self.serve_start_ns)?
        {
            self.standing.retire();
            return Ok(Step {
                duty: Duty::Retiring,
                ..step
            });
        }
        Ok(step)
    }

    /// After a sample the role served: the run ends with the plant's last.
    pub fn served(&mut self, measurement_flags: u32) {
        self.end_of_run |= measurement_flags & flags::END_OF_RUN != 0;
    }

    /// Drains the states other generations handed over.
    pub fn take_handovers(&mut self, states_in: &Inlet<Handover>) -> Result<(), NodeError> {
        self.handovers.take(states_in, self.generation())
    }

    /// Publishes this instance's state after sample `seq`, marked by its
    /// duty; `u`: the command it sent or would have sent.
    pub fn publish_state(
        &self,
        out: &Outlet<Handover>,
        seq: u64,
        u: &[f64],
        save: impl FnOnce(&mut Handover),
    ) -> Result<(), NodeError> {
        publish_state(
            out,
            seq,
            self.generation(),
            self.duty().handover_mark(),
            u,
            save,
        )
    }

    /// A restart's replay is under way.
    pub fn replaying(&mut self) {
        self.standing.replaying();
    }

    /// The replay ended after measurement `last_seq`, into `duty`.
    pub fn replayed(&mut self, last_seq: u64, duty: Duty, end_of_run: bool) {
        self.standing.replayed(last_seq, duty);
        self.end_of_run |= end_of_run;
    }
}
