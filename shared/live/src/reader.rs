//! The loop as the live server reads it: one more polling reader of the
//! measurement, estimate and command channels (no notification, so no
//! publisher of the loop waits for it), in the order and with the
//! ownership the logger records them.

use crate::error::LiveError;
use flexloop_node::handover::ActivationView;
use flexloop_node::in_order::{InOrder, STAGED};
use flexloop_protocol::channels::{COMMAND, ESTIMATE, MEASUREMENT};
use flexloop_protocol::{Command, Estimate, Measurement, WireBytes};
use flexloop_transport::{Inlet, LoopNode};

/// The loop's messages as the logger records them: measurements as they
/// come, estimates and commands in sequence order, commands only from the
/// generation that owns their sample (`Activation::counts_command`).
pub struct LoopReader {
    measurements: Inlet<Measurement>,
    estimates: Inlet<Estimate>,
    commands: Inlet<Command>,
    activation: ActivationView,
    estimate_order: InOrder<Estimate>,
    command_order: InOrder<Command>,
}

impl LoopReader {
    pub fn open(node: &LoopNode) -> Result<Self, LiveError> {
        Ok(Self {
            measurements: Inlet::open_polling(
                node,
                &MEASUREMENT,
                MEASUREMENT.qos.logger_buffer_size,
            )?,
            estimates: Inlet::open_polling(node, &ESTIMATE, ESTIMATE.qos.logger_buffer_size)?,
            commands: Inlet::open_polling(node, &COMMAND, COMMAND.qos.logger_buffer_size)?,
            activation: ActivationView::open(node)?,
            estimate_order: InOrder::new(STAGED),
            command_order: InOrder::new(STAGED),
        })
    }

    /// Everything the channels hold now, to `each(channel, seq,
    /// published_ns, bytes)` (channel 0 measurement, 1 estimate, 2
    /// command); each measurement also to `measured` (what
    /// `/measurement/response` collects).
    pub fn drain(
        &mut self,
        each: &mut impl FnMut(usize, u64, u64, &[u8]),
        measured: &mut impl FnMut(&Measurement),
    ) -> Result<(), LiveError> {
        while let Some(m) = self.measurements.receive()? {
            measured(&m);
            each(0, m.seq, m.published_ns, m.wire_bytes());
        }
        self.estimate_order.drain(
            &self.estimates,
            |e| e.seq,
            |e| each(1, e.seq, e.published_ns, e.wire_bytes()),
        )?;
        let activation = *self.activation.refresh()?;
        self.command_order.drain(
            &self.commands,
            |c| c.seq,
            |c| {
                if activation.counts_command(c) {
                    each(2, c.seq, c.published_ns, c.wire_bytes());
                }
            },
        )?;
        Ok(())
    }
}
