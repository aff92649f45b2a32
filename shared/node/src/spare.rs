//! A loop process's time as a warm spare: every port open, nothing
//! computed, waiting for the supervisor's order (see
//! [`flexloop_protocol::spare`]). A process started as a spare waits here
//! first; an instance replaced at a boundary comes back here instead of
//! exiting, so that a swap neither creates nor drops a port.

use crate::{NodeError, ServiceArgs};
use flexloop_protocol::channels::{SPARE_ORDER, SPARE_STATUS};
use flexloop_protocol::{Joining, Measurement, SpareOrder, SpareStatus};
use flexloop_runtime::wait::wait_readable;
use flexloop_runtime::{monotonic_ns, shutdown};
use flexloop_transport::{Inlet, LoopNode, Outlet};
use std::path::PathBuf;

/// How often an idle spare looks for the end of the run.
const IDLE_CHECK_NS: u64 = 100_000_000;

pub struct SpareDuty {
    orders: Inlet<SpareOrder>,
    status: Outlet<SpareStatus>,
    pid: u32,
    plant_seen: bool,
}

impl SpareDuty {
    pub fn open(node: &LoopNode) -> Result<Self, NodeError> {
        Ok(Self {
            orders: Inlet::open(node, &SPARE_ORDER, SPARE_ORDER.qos.loop_buffer_size)?,
            status: Outlet::open(node, &SPARE_STATUS)?,
            pid: std::process::id(),
            plant_seen: false,
        })
    }

    pub fn connect(&self) -> Result<(), NodeError> {
        self.orders.connect()?;
        self.status.connect()?;
        Ok(())
    }

    /// Reports this process idle (it served `generation` last), then waits
    /// for an order addressed to it and returns the arguments to serve it
    /// with; `None` once the run ended or a shutdown was asked.
    ///
    /// While idle it leaves its loop inputs alone: their queues overwrite
    /// their oldest samples, and their events, not cleared, cost the
    /// publishers no further wake-up. Receiving from them would cost the
    /// plant too: every sample taken and dropped goes back to its publisher,
    /// which takes in all of them at its next loan (draining the 512-sample
    /// queue every 100 ms put a spike into the plant's sample as often).
    /// So the end of the run is the plant's measurement port gone, looked
    /// for every [`IDLE_CHECK_NS`].
    pub fn idle(
        &mut self,
        base: &ServiceArgs,
        generation: u32,
        measurements: &Inlet<Measurement>,
    ) -> Result<Option<ServiceArgs>, NodeError> {
        let since_ns = monotonic_ns();
        self.status.publish(|s| {
            *s = SpareStatus {
                published_ns: since_ns,
                pid: self.pid,
                generation,
            }
        })?;
        loop {
            if shutdown::requested() || self.run_ended(measurements)? {
                return Ok(None);
            }
            wait_readable(&[self.orders.fd()], IDLE_CHECK_NS)
                .map_err(|e| NodeError::Peer(e.to_string()))?;
            self.orders.clear_events()?;
            while let Some(order) = self.orders.receive()? {
                // Another spare's, one from before this idle spell, or a
                // retirement this process is already past.
                if order.pid != self.pid
                    || order.published_ns < since_ns
                    || order.join_as() == Ok(Joining::Spare)
                {
                    continue;
                }
                return args_for(base, &order).map(Some);
            }
        }
    }

    /// Whether an order published since `since_ns` tells this (serving)
    /// process to retire. A polling receive: no system call.
    pub fn retire_requested(&self, since_ns: u64) -> Result<bool, NodeError> {
        let mut retire = false;
        while let Some(order) = self.orders.receive()? {
            retire |= order.pid == self.pid
                && order.join_as() == Ok(Joining::Spare)
                && order.published_ns >= since_ns;
        }
        Ok(retire)
    }

    fn run_ended(&mut self, measurements: &Inlet<Measurement>) -> Result<bool, NodeError> {
        let plant_there = measurements.publishers() > 0;
        let gone = self.plant_seen && !plant_there;
        self.plant_seen |= plant_there;
        Ok(gone)
    }
}

/// How one service of the loop (one generation) ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Served {
    /// Another generation owns the samples from here on.
    Replaced,
    /// The run ended, or a shutdown was asked.
    Ended,
}

/// After a service: off the loop's CPU and real-time priority, so that the
/// rest (teardown, or idling as a spare) never delays the loop. A process
/// that stays on as a spare (`stays`) keeps its memory locked.
pub fn leave_the_loop(loop_cpu: Option<usize>, ended: Served, stays: bool) {
    if ended == Served::Replaced && stays {
        flexloop_runtime::realtime::step_aside(loop_cpu);
    } else {
        flexloop_runtime::realtime::step_down(loop_cpu);
    }
}

/// The arguments of the instance an order asks for.
fn args_for(base: &ServiceArgs, order: &SpareOrder) -> Result<ServiceArgs, NodeError> {
    let scenario = order.scenario().ok_or_else(|| {
        NodeError::Order(format!(
            "spare order for generation {}: the scenario path is not UTF-8",
            order.generation
        ))
    })?;
    let joining = match order.join_as() {
        Ok(joining @ (Joining::Replacement | Joining::Restart | Joining::Standby)) => joining,
        Ok(other) => {
            return Err(NodeError::Order(format!(
                "spare order for generation {}: a spare cannot join as {other:?}",
                order.generation
            )));
        }
        Err(e) => {
            return Err(NodeError::Order(format!(
                "spare order for generation {}: {e}",
                order.generation
            )));
        }
    };
    Ok(ServiceArgs {
        scenario: PathBuf::from(scenario),
        generation: order.generation,
        joining,
        ..base.clone()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Role;

    fn base() -> ServiceArgs {
        ServiceArgs::parse(
            Role::Observer,
            [
                "--scenario",
                "run.toml",
                "--prefix",
                "p_",
                "--run-dir",
                "r",
                "--spare",
            ]
            .map(std::ffi::OsString::from),
        )
        .unwrap()
    }

    #[test]
    fn an_order_becomes_a_joining_instance_of_its_scenario() {
        let mut order = SpareOrder {
            generation: 7,
            joining: Joining::Restart.into(),
            ..SpareOrder::default()
        };
        order.set_scenario("/x/retuned.toml").unwrap();
        let a = args_for(&base(), &order).unwrap();
        assert_eq!(a.scenario, PathBuf::from("/x/retuned.toml"));
        assert_eq!(a.generation, 7);
        assert_eq!(a.joining, Joining::Restart);
        assert_eq!(a.prefix, "p_");
        for joining in [Joining::Replacement, Joining::Standby] {
            order.joining = joining.into();
            assert_eq!(args_for(&base(), &order).unwrap().joining, joining);
        }
    }

    #[test]
    fn an_order_to_join_as_no_replacement_is_refused() {
        let mut order = SpareOrder {
            generation: 3,
            ..SpareOrder::default()
        };
        order.set_scenario("/x/s.toml").unwrap();
        for joining in [Joining::AtStart, Joining::Spare] {
            order.joining = joining.into();
            let e = args_for(&base(), &order).unwrap_err();
            assert!(e.to_string().contains("cannot join as"), "{e}");
        }
        order.joining = 42;
        let e = args_for(&base(), &order).unwrap_err();
        assert!(
            e.to_string()
                .contains("unknown way of joining the loop: 42"),
            "{e}"
        );
    }

    #[test]
    fn an_order_with_a_broken_path_is_refused() {
        let mut order = SpareOrder {
            scenario_len: 2,
            ..SpareOrder::default()
        };
        order.scenario[..2].copy_from_slice(&[0xff, 0xfe]);
        let e = args_for(&base(), &order).unwrap_err();
        assert!(e.to_string().contains("not UTF-8"), "{e}");
    }
}
