//! The observer process: wakes on y(k), publishes the estimate for tick k+1.

use crate::args::{Role, ServiceArgs, realtime_settings};
use crate::{NodeError, await_peers};
use flexloop_components::ObserverCore;
use flexloop_components::observer::ObserverSizeError;
use flexloop_protocol::channels::{ESTIMATE, MEASUREMENT};
use flexloop_protocol::{Estimate, Measurement, flags};
use flexloop_runtime::wait::wait_readable;
use flexloop_runtime::{monotonic_ns, realtime, shutdown};
use flexloop_transport::{Domain, Inlet, Outlet};

pub fn run(args: &ServiceArgs) -> Result<(), NodeError> {
    let (scenario, design) = args.load()?;
    let mut core = ObserverCore::new(
        &design.observer,
        &design.output_prediction,
        design.n_outputs,
        design.n_inputs,
    )
    .map_err(|e: ObserverSizeError| NodeError::Peer(format!("observer design: {e}")))?;
    // Locked before the ports exist, so their memory is populated now (see plant).
    let _rt = realtime::apply(
        Role::Observer.name(),
        &realtime_settings(&scenario, Role::Observer),
    );
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node("observer")?;
    let measurements =
        Inlet::<Measurement>::open(&node, &MEASUREMENT, MEASUREMENT.qos.loop_buffer_size)?;
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

    let mut expected_seq = 0u64;
    let mut skipped = 0u64;
    let mut done = false;
    while !done && !shutdown::requested() {
        wait_readable(&[measurements.fd()], 100_000_000)
            .map_err(|e| NodeError::Peer(e.to_string()))?;
        measurements.clear_events()?;
        // Every measurement, in order: a Kalman predictor must not skip one.
        while let Some(m) = measurements.receive()? {
            let received_ns = monotonic_ns();
            if m.seq != expected_seq {
                skipped += m.seq.saturating_sub(expected_seq);
            }
            expected_seq = m.seq + 1;
            estimates.publish(|e| {
                core.step(&m, e);
                e.generation = args.generation;
                e.received_ns = received_ns;
                e.published_ns = monotonic_ns();
            })?;
            estimates.notify()?;
            done |= m.flags & flags::END_OF_RUN != 0;
        }
    }
    if skipped > 0 {
        eprintln!("flexloop-observer: {skipped} measurements never arrived");
    }
    Ok(())
}
