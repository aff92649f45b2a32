//! The plumbing of a hand-over between instances: the supervisor's
//! activation as every process sees it, and the active instance's recent
//! states as a replacement sees them.

use crate::NodeError;
use flexloop_protocol::channels::ACTIVATION;
use flexloop_protocol::{Activation, Handover};
use flexloop_runtime::realtime::{self, RealtimeSettings};
use flexloop_transport::{Inlet, LoopNode, Outlet};

/// The newest activation (polled each sample: no syscall, no wake-up).
pub struct ActivationView {
    inlet: Inlet<Activation>,
    current: Activation,
}

impl ActivationView {
    pub fn open(node: &LoopNode) -> Result<Self, NodeError> {
        Ok(Self {
            inlet: Inlet::open_polling(node, &ACTIVATION, ACTIVATION.qos.loop_buffer_size)?,
            current: Activation::INITIAL,
        })
    }

    /// Takes in anything the supervisor published since the last call.
    pub fn refresh(&mut self) -> Result<&Activation, NodeError> {
        while let Some(a) = self.inlet.receive()? {
            if a.published_ns >= self.current.published_ns {
                self.current = *a;
            }
        }
        Ok(&self.current)
    }

    /// Maps the supervisor's memory now rather than in the loop.
    pub fn connect(&self) -> Result<(), NodeError> {
        Ok(self.inlet.connect()?)
    }

    pub fn current(&self) -> &Activation {
        &self.current
    }
}

const RING: usize = 8;

/// The last few states another generation published, by sequence.
pub struct HandoverRing {
    slots: Box<[Handover; RING]>,
    valid: [bool; RING],
    newest: Option<usize>,
}

impl Default for HandoverRing {
    fn default() -> Self {
        Self {
            slots: Box::new([Handover::default(); RING]),
            valid: [false; RING],
            newest: None,
        }
    }
}

impl HandoverRing {
    /// Drains `inlet`, keeping the active (not shadow) states of other generations.
    pub fn take(&mut self, inlet: &Inlet<Handover>, own_generation: u32) -> Result<(), NodeError> {
        while let Some(h) = inlet.receive()? {
            if h.generation == own_generation || h.shadow != 0 {
                continue;
            }
            let slot = (h.seq % RING as u64) as usize;
            self.slots[slot] = *h;
            self.valid[slot] = true;
            if self.newest.is_none_or(|n| self.slots[n].seq <= h.seq) {
                self.newest = Some(slot);
            }
        }
        Ok(())
    }

    /// The state after measurement `seq`.
    pub fn find(&self, seq: u64) -> Option<&Handover> {
        let slot = (seq % RING as u64) as usize;
        (self.valid[slot] && self.slots[slot].seq == seq).then(|| &self.slots[slot])
    }

    /// The newest state seen (a restart takes over from a dead instance's last).
    pub fn newest(&self) -> Option<&Handover> {
        self.newest.map(|n| &self.slots[n])
    }
}

/// Publishes this instance's state after each sample (no notification);
/// `shadow`: [`flexloop_protocol::handover::ACTIVE`], `FOLLOWING` or `CATCHING_UP`.
pub fn publish_state(
    out: &Outlet<Handover>,
    seq: u64,
    generation: u32,
    shadow: u32,
    u: &[f64],
    save: impl FnOnce(&mut Handover),
) -> Result<(), NodeError> {
    out.publish(|h| {
        save(h);
        h.seq = seq;
        h.generation = generation;
        h.shadow = shadow;
        h.u[..u.len()].copy_from_slice(u);
    })?;
    Ok(())
}

pub fn raise_priority(rt: &RealtimeSettings) {
    if let Some(cpu) = rt.cpu
        && let Err(e) = realtime::pin_to_cpu(cpu)
    {
        eprintln!("flexloop: cpu {cpu} refused ({e}); running on");
    }
    if let Some(priority) = rt.fifo_priority
        && let Err(e) = realtime::set_fifo_priority(priority)
    {
        eprintln!("flexloop: priority {priority} refused ({e}); running on");
    }
}
