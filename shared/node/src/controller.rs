//! The controller process: wakes on y(k), publishes u(k).

use crate::args::{Role, ServiceArgs, realtime_settings};
use crate::{NodeError, await_peers};
use flexloop_components::ControllerCore;
use flexloop_protocol::channels::{COMMAND, ESTIMATE, MEASUREMENT};
use flexloop_protocol::{Command, Estimate, Measurement, flags};
use flexloop_runtime::wait::wait_readable;
use flexloop_runtime::{monotonic_ns, realtime, shutdown};
use flexloop_scenario::Mode;
use flexloop_transport::{Domain, Inlet, Outlet};

/// In lockstep, how long to wait for the observer before giving up.
const LOCKSTEP_ESTIMATE_WAIT_NS: u64 = 5_000_000_000;

pub fn run(args: &ServiceArgs) -> Result<(), NodeError> {
    let (scenario, design) = args.load()?;
    let mut core = ControllerCore::new(&design, args.generation);
    // Locked before the ports exist, so their memory is populated now (see plant).
    let _rt = realtime::apply(
        Role::Controller.name(),
        &realtime_settings(&scenario, Role::Controller),
    );
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node("controller")?;
    let measurements =
        Inlet::<Measurement>::open(&node, &MEASUREMENT, MEASUREMENT.qos.loop_buffer_size)?;
    let estimates = Inlet::<Estimate>::open(&node, &ESTIMATE, ESTIMATE.qos.loop_buffer_size)?;
    let mut ring = EstimateRing::new();
    if !await_peers(
        || {
            if estimates.publishers() >= 1 && measurements.publishers() >= 1 {
                ring.take(&estimates)?;
            }
            Ok(ring.any())
        },
        || {
            format!(
                "{} measurement publishers (plant), {} estimate publishers (observer), no first estimate yet",
                measurements.publishers(),
                estimates.publishers()
            )
        },
    )? {
        return Ok(());
    }
    measurements.connect()?;
    // The command port opens last: its appearance tells the plant that the
    // chain is ready for tick 0.
    let commands = Outlet::<Command>::open(&node, &COMMAND)?;
    let lockstep = scenario.timing.mode == Mode::Lockstep;
    let period_ns = scenario.period_ns();
    // In realtime, wait for a late estimate at most half a period after the
    // tick: the wake-up after a timed wait can itself be tens of µs late, and
    // an estimate one tick old (counted) costs less than a missed command.
    let estimate_wait_ns = period_ns / 2;

    let mut stale_estimates = 0u64;
    let mut skipped = 0u64;
    let mut next_seq = 0u64;
    let mut done = false;
    while !done && !shutdown::requested() {
        wait_readable(&[measurements.fd()], 100_000_000)
            .map_err(|e| NodeError::Peer(e.to_string()))?;
        measurements.clear_events()?;
        // Act on the newest measurement only: an older one is already late.
        let mut newest: Option<Measurement> = None;
        while let Some(m) = measurements.receive()? {
            if newest.is_none_or(|n| m.seq > n.seq) {
                newest = Some(*m);
            }
        }
        let Some(m) = newest else { continue };
        let received_ns = monotonic_ns();
        skipped += m.seq.saturating_sub(next_seq);
        next_seq = m.seq + 1;

        ring.take(&estimates)?;
        if ring.find(m.seq).is_none() {
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
                wait_readable(&[estimates.fd()], deadline - now)
                    .map_err(|e| NodeError::Peer(e.to_string()))?;
                ring.take(&estimates)?;
                if ring.find(m.seq).is_some() {
                    break;
                }
                if shutdown::requested() {
                    return Ok(());
                }
            }
            if lockstep && ring.find(m.seq).is_none() {
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
        commands.publish(|c| {
            core.step(&m, estimate, c);
            c.received_ns = received_ns;
            c.published_ns = monotonic_ns();
        })?;
        if lockstep {
            commands.notify()?;
        }
        done = m.flags & flags::END_OF_RUN != 0;
    }
    if stale_estimates + skipped > 0 {
        eprintln!(
            "flexloop-controller: {stale_estimates} stale estimates, {skipped} measurements skipped"
        );
    }
    Ok(())
}

const RING: usize = 8;

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

    /// Drains the inlet into the ring.
    fn take(&mut self, estimates: &Inlet<Estimate>) -> Result<(), NodeError> {
        estimates.clear_events()?;
        while let Some(e) = estimates.receive()? {
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
