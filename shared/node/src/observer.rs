//! The observer process: wakes on y(k), publishes the estimate for tick k+1.

use crate::args::{Role, ServiceArgs, realtime_settings};
use crate::handover::{
    ActivationView, HandoverRing, publish_state, raise_priority, shadow_scheduling,
};
use crate::startup::StartupClock;
use crate::{NodeError, await_peers};
use flexloop_components::ObserverCore;
use flexloop_components::observer::ObserverSizeError;
use flexloop_protocol::channels::{ESTIMATE, MEASUREMENT, OBSERVER_STATE, OBSERVER_WAKEUP};
use flexloop_protocol::{Estimate, Handover, Measurement, flags};
use flexloop_runtime::wait::wait_readable;
use flexloop_runtime::{monotonic_ns, realtime, shutdown};
use flexloop_transport::{Domain, Inlet, Outlet};

pub fn run(args: &ServiceArgs) -> Result<(), NodeError> {
    let clock = StartupClock::start();
    let (scenario, design) = args.load()?;
    let mut core = ObserverCore::for_design(&design)
        .map_err(|e: ObserverSizeError| NodeError::Peer(format!("observer design: {e}")))?;
    // Locked before the ports exist, so their memory is populated now (see plant).
    let rt = realtime_settings(&scenario, Role::Observer);
    let _memory = realtime::apply(Role::Observer.name(), &rt.memory_part());
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node("observer")?;
    let measurements = Inlet::<Measurement>::open_woken_by(
        &node,
        &MEASUREMENT,
        &OBSERVER_WAKEUP,
        MEASUREMENT.qos.loop_buffer_size,
    )?;
    if !await_peers(
        || Ok(measurements.publishers() >= 1),
        || "no measurement publisher (plant)".into(),
    )? {
        return Ok(());
    }
    measurements.connect()?;
    // Opened only now: the controller takes the first estimate as the sign
    // that the observer is connected and ready.
    let estimates = Outlet::<Estimate>::open(&node, &ESTIMATE)?;
    // A publisher hands its history to late subscribers only when it sends
    // again, and the next send waits for tick 0: so the first estimate goes
    // out once its readers (controller, logger) are there.
    let mut activation = ActivationView::open(&node)?;
    let states_in = Inlet::<Handover>::open_polling(
        &node,
        &OBSERVER_STATE,
        OBSERVER_STATE.qos.loop_buffer_size,
    )?;
    let states_out = Outlet::<Handover>::open(&node, &OBSERVER_STATE)?;
    states_in.connect()?;
    activation.connect()?;
    // Priority and CPU only now, every port open and connected: see
    // `RealtimeSettings::scheduling_part` and the controller.
    let _scheduling = realtime::apply(Role::Observer.name(), &shadow_scheduling(&rt, args));
    let mut priority_raised = !args.join;
    // A replacement for an observer that died before tick 0 must start the
    // loop like the first one did: no wake-up from the plant for 200 ms
    // means the loop has not started (a first estimate that turns out not
    // to be needed is refused by the controller: its generation does not
    // own sample 0).
    let loop_running = args.join
        && matches!(
            wait_readable(&[measurements.fd()], 200_000_000),
            Ok(flexloop_runtime::wait::Readiness::Ready(_))
        );
    if !loop_running {
        let expected_readers = 1 + usize::from(scenario.logger.enabled);
        if !await_peers(
            || Ok(estimates.subscribers() >= expected_readers),
            || {
                format!(
                    "{} of {expected_readers} estimate readers (controller, logger)",
                    estimates.subscribers()
                )
            },
        )? {
            return Ok(());
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
    let mut handovers = HandoverRing::default();
    let mut shadow_estimate = Box::<Estimate>::default();
    let mut copied = false;
    let mut was_active = false;
    let mut expected_seq: Option<u64> = None;
    let mut skipped = 0u64;
    let mut done = false;
    'samples: while !done && !shutdown::requested() {
        wait_readable(&[measurements.fd()], 100_000_000)
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
            }
            if owner != args.generation {
                if was_active {
                    // Replaced: the new instance publishes from here on.
                    break 'samples;
                }
                // Shadow: follow the active instance's state, publish nothing.
                handovers.take(&states_in, args.generation)?;
                let before = m.seq.checked_sub(1).and_then(|s| handovers.find(s));
                let from = before.or(if copied { None } else { handovers.newest() });
                if let Some(h) = from
                    && core.load(h)
                {
                    copied = true;
                }
                core.step(&m, &mut shadow_estimate);
                publish_state(&states_out, m.seq, args.generation, true, &[], |h| {
                    core.save(h)
                })?;
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
            publish_state(&states_out, m.seq, args.generation, false, &[], |h| {
                core.save(h)
            })?;
            done |= m.flags & flags::END_OF_RUN != 0;
        }
    }
    // Replaced or done: the teardown must not run at real-time priority.
    realtime::step_down(rt.cpu);
    if skipped > 0 {
        eprintln!("flexloop-observer: {skipped} measurements never arrived");
    }
    Ok(())
}
