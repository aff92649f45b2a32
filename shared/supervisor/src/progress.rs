//! A line per second on stderr while a loop runs, from the logger's telemetry.

use flexloop_protocol::Telemetry;
use flexloop_protocol::channels::TELEMETRY;
use flexloop_transport::{Domain, Inlet};
use iceoryx2::prelude::{Node, ipc};

/// Reads the run's telemetry channel; silent if it cannot be opened (the
/// loop runs on without a progress display).
pub struct Progress {
    // Field order: the inlet must drop before its node.
    inlet: Option<Inlet<Telemetry>>,
    _node: Option<Node<ipc::Service>>,
    last_published_ns: u64,
}

impl Progress {
    pub fn open(prefix: &str) -> Self {
        let node = Domain::new(prefix).and_then(|d| d.node("progress")).ok();
        let inlet = node.as_ref().and_then(|n| {
            Inlet::<Telemetry>::open_polling(n, &TELEMETRY, TELEMETRY.qos.loop_buffer_size).ok()
        });
        Self {
            inlet,
            _node: node,
            last_published_ns: 0,
        }
    }

    /// Prints the newest telemetry if the logger published since the last call.
    pub fn show(&mut self, rate_hz: f64) {
        let Some(inlet) = &self.inlet else { return };
        let mut newest: Option<Telemetry> = None;
        while let Ok(Some(t)) = inlet.receive() {
            newest = Some(*t);
        }
        let Some(t) = newest.filter(|t| t.published_ns > self.last_published_ns) else {
            return;
        };
        self.last_published_ns = t.published_ns;
        eprintln!(
            "  t {:6.1} s  ticks {:>8}  misses {:>4}  stalled {:>4}  stale estimates {:>4}  log gaps {:>4}  round trip p50 {:5.1} p99.99 {:6.1} µs",
            t.seq as f64 / rate_hz,
            t.samples,
            t.misses,
            t.stalled_ticks,
            t.stale_estimates,
            t.gaps,
            t.round_trip[0] as f64 / 1e3,
            t.round_trip[4] as f64 / 1e3,
        );
    }
}
