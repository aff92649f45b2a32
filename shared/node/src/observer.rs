//! The observer process: wakes on y(k), publishes the estimate for tick k+1.

use crate::args::{Role, ServiceArgs, realtime_settings, wait_mode};
use crate::handover::{
    ActivationView, HandoverRing, publish_state, raise_priority, shadow_scheduling,
};
use crate::replay::{CatchUp, Replayed};
use crate::spare::{Served, SpareDuty, leave_the_loop, serve_orders};
use crate::startup::StartupClock;
use crate::{NodeError, await_peers};
use flexloop_components::ObserverCore;
use flexloop_components::observer::ObserverSizeError;
use flexloop_protocol::channels::{
    ESTIMATE, MEASUREMENT, MEASUREMENT_REPLAY, OBSERVER_STATE, OBSERVER_WAKEUP,
};
use flexloop_protocol::handover::{ACTIVE, CATCHING_UP, FOLLOWING};
use flexloop_protocol::{Estimate, Handover, Measurement, flags};
use flexloop_runtime::wait::{WaitMode, wait_for_input, wait_readable};
use flexloop_runtime::{monotonic_ns, realtime, shutdown};
use flexloop_scenario::{LoopDesign, Scenario};
use flexloop_transport::{Domain, Inlet, LoopNode, Outlet};
use std::time::{Duration, Instant};

pub fn run(args: &ServiceArgs) -> Result<(), NodeError> {
    let clock = StartupClock::start();
    let (scenario, design) = args.load_at_start()?;
    // Locked before the ports exist, so their memory is populated now (see plant).
    let rt = realtime_settings(&scenario, Role::Observer);
    let _memory = realtime::apply(Role::Observer.name(), &rt.memory_part());
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node("observer")?;
    let Some(mut ports) = Ports::open(&node, args, &scenario)? else {
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
        serve,
    )
}

/// Every port an observer uses, open for the process's life.
struct Ports {
    measurements: Inlet<Measurement>,
    /// Only for a restart (or a spare, which may serve one).
    replay: Option<Inlet<Measurement>>,
    estimates: Outlet<Estimate>,
    activation: ActivationView,
    states_in: Inlet<Handover>,
    states_out: Outlet<Handover>,
    /// With warm spares: orders and idle reports.
    spare: Option<SpareDuty>,
}

impl Ports {
    /// Opens and connects every port. `None`: a shutdown came first.
    fn open(
        node: &LoopNode,
        args: &ServiceArgs,
        scenario: &Scenario,
    ) -> Result<Option<Self>, NodeError> {
        let warm_spares = scenario.supervision.warm_spares;
        // Any instance may end up a spare that serves a restart.
        let may_restart = args.restart || warm_spares;
        // A restart's queue holds what arrives while it catches up (see
        // `catch_up`): 51 ms at 10 kHz.
        let depth = if may_restart {
            MEASUREMENT.qos.logger_buffer_size
        } else {
            MEASUREMENT.qos.loop_buffer_size
        };
        let measurements =
            Inlet::<Measurement>::open_woken_by(node, &MEASUREMENT, &OBSERVER_WAKEUP, depth)?;
        let replay = if may_restart {
            Some(Inlet::<Measurement>::open_polling(
                node,
                &MEASUREMENT_REPLAY,
                MEASUREMENT_REPLAY.qos.loop_buffer_size,
            )?)
        } else {
            None
        };
        let spare = if warm_spares {
            Some(SpareDuty::open(node)?)
        } else {
            None
        };
        if !await_peers(
            || Ok(measurements.publishers() >= 1),
            || "no measurement publisher (plant)".into(),
        )? {
            return Ok(None);
        }
        measurements.connect()?;
        // Opened only now: the controller takes the first estimate as the
        // sign that the observer is connected and ready.
        let estimates = Outlet::<Estimate>::open(node, &ESTIMATE)?;
        let activation = ActivationView::open(node)?;
        let states_in = Inlet::<Handover>::open_polling(
            node,
            &OBSERVER_STATE,
            OBSERVER_STATE.qos.loop_buffer_size,
        )?;
        let states_out = Outlet::<Handover>::open(node, &OBSERVER_STATE)?;
        states_in.connect()?;
        activation.connect()?;
        if let Some(duty) = &spare {
            duty.connect()?;
        }
        Ok(Some(Self {
            measurements,
            replay,
            estimates,
            activation,
            states_in,
            states_out,
            spare,
        }))
    }
}

/// Serves the loop as `args.generation` with `design` until replaced or
/// the run ends.
fn serve(
    args: &ServiceArgs,
    scenario: &Scenario,
    design: &LoopDesign,
    ports: &mut Ports,
    clock: &StartupClock,
) -> Result<Served, NodeError> {
    let Ports {
        measurements,
        replay,
        estimates,
        activation,
        states_in,
        states_out,
        spare,
    } = ports;
    let mut core = ObserverCore::for_design(design)
        .map_err(|e: ObserverSizeError| NodeError::Peer(format!("observer design: {e}")))?;
    let rt = realtime_settings(scenario, Role::Observer);
    if args.join {
        // What queued up while idle, or before joining, belongs to nobody now.
        measurements.clear_events()?;
        while measurements.receive()?.is_some() {}
        while states_in.receive()?.is_some() {}
        // Not the replay: the supervisor may have begun it already, and an
        // older one's leftovers are older than the state taken over (the
        // catch-up skips them).
    }
    // Only a restart catches up from the supervisor's replay.
    let replay = replay.as_ref().filter(|_| args.restart);
    // Priority and CPU only now, every port open and connected: see
    // `RealtimeSettings::scheduling_part` and the controller.
    let _scheduling = realtime::apply(Role::Observer.name(), &shadow_scheduling(&rt, args));
    let mut priority_raised = !args.join;
    // A shadow follows on a shared CPU: it waits on events until it is
    // named for the loop's CPU (and, under dedicated-cores, spins there).
    let mut waits = if priority_raised {
        wait_mode(scenario)
    } else {
        WaitMode::Events
    };
    // A replacement for an observer that died before tick 0 must start the
    // loop like the first one did: no wake-up from the plant for 200 ms
    // means the loop has not started (a first estimate that turns out not
    // to be needed is refused by the controller: its generation does not
    // own sample 0).
    // A restart also knows it by the state the supervisor hands on (a
    // lockstep loop waits for this very observer and publishes nothing).
    let mut handovers = HandoverRing::default();
    // A restart waits for that state (the supervisor hands it on every
    // 5 ms) before anything else: it owns samples from the announcement on.
    let loop_running = args.join && {
        let since = Instant::now();
        let mut measured = false;
        loop {
            if args.restart {
                handovers.take(states_in, args.generation)?;
                if handovers.newest().is_some() {
                    break true;
                }
            }
            if measured {
                std::thread::sleep(Duration::from_millis(1));
            } else {
                let wait_ns = if args.restart { 5_000_000 } else { 200_000_000 };
                measured = matches!(
                    wait_readable(&[measurements.fd()], wait_ns),
                    Ok(flexloop_runtime::wait::Readiness::Ready(_))
                );
            }
            let waited = since.elapsed();
            if measured && (!args.restart || waited >= RESTART_STATE_WAIT) {
                break true;
            }
            if (!measured && waited >= Duration::from_millis(200)) || shutdown::requested() {
                break false;
            }
        }
    };
    if !loop_running {
        // The controller, its warm spare and the logger.
        let expected_readers = 1
            + usize::from(scenario.supervision.warm_spares)
            + usize::from(scenario.logger.enabled);
        if !await_peers(
            || Ok(estimates.subscribers() >= expected_readers),
            || {
                format!(
                    "{} of {expected_readers} estimate readers (controller, its spare, logger)",
                    estimates.subscribers()
                )
            },
        )? {
            return Ok(Served::Ended);
        }
        // The estimate for tick 0 is the initial state; history keeps it for a
        // controller that connects later.
        estimates.publish(|e| {
            core.initial(e);
            e.generation = args.generation;
            e.published_ns = monotonic_ns();
        })?;
        estimates.notify()?;
    }

    if args.join {
        clock.report_joined(args.role);
    }
    let lockstep = scenario.timing.mode == flexloop_scenario::Mode::Lockstep;
    let mut shadow_estimate = Box::<Estimate>::default();
    let mut copied = false;
    let mut was_active = false;
    let mut expected_seq: Option<u64> = None;
    let mut skipped = 0u64;
    let mut ended = Served::Ended;
    let mut done = false;
    // A restart owns the estimates its dead predecessor left unserved at
    // once: it takes over the predecessor's last state and steps through
    // the measurements since, without waiting for a live one (in lockstep
    // none comes: the loop waits for the estimate this observer owes). In
    // lockstep it publishes the estimates it owns as it goes.
    if let Some(replay) = replay
        && let Some(h) = handovers.newest().copied()
        && core.load(&h)
    {
        copied = true;
        let generation = args.generation;
        let caught = catch_up(
            &mut core,
            h.seq,
            None,
            replay,
            measurements,
            states_out,
            generation,
            &mut shadow_estimate,
            |m, e| {
                if lockstep && activation.refresh()?.observer_for(m.seq + 1) == generation {
                    let now = monotonic_ns();
                    estimates.publish(|out| {
                        *out = *e;
                        out.generation = generation;
                        out.received_ns = now;
                        out.published_ns = now;
                    })?;
                    estimates.notify()?;
                    was_active = true;
                }
                Ok(())
            },
        )?;
        eprintln!("flexloop-observer: {caught}");
        expected_seq = Some(caught.last_seq + 1);
        publish_state(
            states_out,
            caught.last_seq,
            args.generation,
            if was_active { ACTIVE } else { FOLLOWING },
            &[],
            |h| core.save(h),
        )?;
        done |= caught.end_of_run;
    }
    'samples: while !done && !shutdown::requested() {
        wait_for_input(waits, &[measurements.fd()], 100_000_000, || {
            measurements.has_samples().unwrap_or(true)
        })
        .map_err(|e| NodeError::Peer(e.to_string()))?;
        measurements.clear_events()?;
        // Every measurement, in order: a Kalman predictor must not skip one.
        while let Some(m) = measurements.receive()? {
            let received_ns = monotonic_ns();
            if let Some(expected) = expected_seq {
                skipped += m.seq.saturating_sub(expected);
            }
            expected_seq = Some(m.seq + 1);
            // This measurement yields the estimate for the next tick.
            let owner = activation.refresh()?.observer_for(m.seq + 1);
            // As the controller: once named, at the latest at its first estimate.
            if !priority_raised
                && (activation.current().observer_generation == args.generation
                    || owner == args.generation)
            {
                raise_priority(&rt);
                priority_raised = true;
                waits = wait_mode(scenario);
            }
            if owner != args.generation {
                if was_active {
                    // Replaced: the new instance publishes from here on.
                    ended = Served::Replaced;
                    break 'samples;
                }
                // Shadow: follow the active instance's state, publish nothing.
                handovers.take(states_in, args.generation)?;
                if let Some(h) = m.seq.checked_sub(1).and_then(|s| handovers.find(s)) {
                    copied |= core.load(h);
                } else if !copied
                    && let Some(h) = handovers.newest()
                    && h.seq < m.seq
                    && core.load(h)
                {
                    copied = true;
                    if h.seq + 1 < m.seq
                        && let Some(replay) = replay
                    {
                        // A restart: the dead predecessor's last state is
                        // samples old; step through every one since.
                        let live = *m;
                        let caught = catch_up(
                            &mut core,
                            h.seq,
                            Some(&live),
                            replay,
                            measurements,
                            states_out,
                            args.generation,
                            &mut shadow_estimate,
                            |_, _| Ok(()),
                        )?;
                        eprintln!("flexloop-observer: {caught}");
                        expected_seq = Some(caught.last_seq + 1);
                        publish_state(
                            states_out,
                            caught.last_seq,
                            args.generation,
                            FOLLOWING,
                            &[],
                            |h| core.save(h),
                        )?;
                        done |= caught.end_of_run;
                        continue;
                    }
                }
                core.step(&m, &mut shadow_estimate);
                // Following only once a handed-over state is there: the
                // active instance's (a swap) or, after a crash, the one the
                // supervisor keeps handing on until it sees this instance
                // follow (published before this instance subscribed, it
                // would reach it only with the next one).
                if handovers.newest().is_some() {
                    publish_state(states_out, m.seq, args.generation, FOLLOWING, &[], |h| {
                        core.save(h)
                    })?;
                }
                done |= m.flags & flags::END_OF_RUN != 0;
                continue;
            }
            was_active = true;
            estimates.publish(|e| {
                core.step(&m, e);
                e.generation = args.generation;
                e.received_ns = received_ns;
                e.published_ns = monotonic_ns();
            })?;
            estimates.notify()?;
            publish_state(states_out, m.seq, args.generation, ACTIVE, &[], |h| {
                core.save(h)
            })?;
            done |= m.flags & flags::END_OF_RUN != 0;
        }
    }
    leave_the_loop(rt.cpu, ended, spare.is_some());
    if skipped > 0 {
        eprintln!(
            "flexloop-observer: generation {}: {skipped} measurements never arrived",
            args.generation
        );
    }
    Ok(ended)
}

/// How long a restart waits for its dead predecessor's state while the
/// loop runs (the supervisor hands it on every 5 ms; without it the
/// replacement goes on from its own initial state).
const RESTART_STATE_WAIT: Duration = Duration::from_secs(1);

/// How long a restarted observer may take to replay its way to the live
/// samples before it goes on from where it got (the supervisor's ring holds
/// two seconds).
const CATCH_UP_TIMEOUT: Duration = Duration::from_secs(1);

/// What a catch-up did, for the observer's stderr file.
struct CaughtUp {
    state_seq: u64,
    replayed: u64,
    /// The last measurement stepped (the newest live one held).
    last_seq: u64,
    /// Why the sequence has a hole, if it has one.
    incomplete: Option<String>,
    end_of_run: bool,
}

impl std::fmt::Display for CaughtUp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.incomplete {
            None => write!(
                f,
                "took over the state after sample {} and replayed {} measurements up to the live sample {}",
                self.state_seq, self.replayed, self.last_seq
            ),
            Some(why) => write!(
                f,
                "took over the state after sample {}, replayed {} measurements, then {why}: going on from sample {} with a hole in between",
                self.state_seq, self.replayed, self.last_seq
            ),
        }
    }
}

/// A restarted observer holds the state its dead predecessor last published
/// (after measurement `state_seq`) and has just received `first_live`: it
/// steps through the supervisor's replay of the measurements in between,
/// reporting its progress (which paces the replay), while the live queue
/// fills, and then through the live samples held meanwhile. Design-time
/// work in shadow, off the loop's CPU; bounded by [`CATCH_UP_TIMEOUT`].
#[allow(clippy::too_many_arguments)]
fn catch_up(
    core: &mut ObserverCore,
    state_seq: u64,
    first_live: Option<&Measurement>,
    replay: &Inlet<Measurement>,
    live: &Inlet<Measurement>,
    states_out: &Outlet<Handover>,
    generation: u32,
    scratch: &mut Estimate,
    mut stepped: impl FnMut(&Measurement, &Estimate) -> Result<(), NodeError>,
) -> Result<CaughtUp, NodeError> {
    let mut merge = CatchUp::after(state_seq);
    if let Some(m) = first_live {
        merge.hold_live(m);
    }
    let since = Instant::now();
    let (mut replayed, mut reported) = (0u64, state_seq);
    let mut incomplete = None;
    'replay: loop {
        while let Some(r) = replay.receive()? {
            match merge.replayed(&r) {
                Replayed::Step => {
                    core.step(&r, scratch);
                    stepped(&r, scratch)?;
                    replayed += 1;
                }
                Replayed::Skip => {}
                Replayed::Gap { missing_from, got } => {
                    incomplete = Some(format!(
                        "the replay had lost samples {missing_from} to {}",
                        got - 1
                    ));
                    break 'replay;
                }
            }
        }
        if merge.next_seq() - 1 > reported {
            reported = merge.next_seq() - 1;
            publish_state(states_out, reported, generation, CATCHING_UP, &[], |h| {
                core.save(h)
            })?;
        }
        while let Some(m) = live.receive()? {
            merge.hold_live(&m);
        }
        if merge.reached_live() {
            break;
        }
        if merge.overflowed() {
            incomplete = Some("the live queue outran the replay".into());
            break;
        }
        if since.elapsed() > CATCH_UP_TIMEOUT || shutdown::requested() {
            incomplete = Some(format!(
                "no replay past sample {} within {CATCH_UP_TIMEOUT:?}",
                merge.next_seq() - 1
            ));
            break;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    // Drops held samples the replay already covered.
    merge.reached_live();
    let (mut last_seq, mut end_of_run) = (merge.next_seq() - 1, false);
    while let Some(m) = merge.take_held() {
        core.step(&m, scratch);
        stepped(&m, scratch)?;
        last_seq = m.seq;
        end_of_run |= m.flags & flags::END_OF_RUN != 0;
    }
    Ok(CaughtUp {
        state_seq,
        replayed,
        last_seq,
        incomplete,
        end_of_run,
    })
}
