//! The observer process: wakes on y(k), publishes the estimate for tick k+1.

use crate::NodeError;
use crate::args::{Role, ServiceArgs, realtime_settings};
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
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node("observer")?;
    let measurements =
        Inlet::<Measurement>::open(&node, &MEASUREMENT, MEASUREMENT.qos.loop_buffer_size)?;
    let estimates = Outlet::<Estimate>::open(&node, &ESTIMATE)?;
    let _rt = realtime::apply(
        Role::Observer.name(),
        &realtime_settings(&scenario, Role::Observer),
    );

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
