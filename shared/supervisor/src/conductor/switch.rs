//! What one swap or restart did: where the new instance took over and the
//! command's step there.

use flexloop_node::Role;
use flexloop_runfiles::supervision::SwitchRecord;

#[derive(Debug, Clone, PartialEq)]
pub struct Switch {
    pub role: Role,
    pub generation: u32,
    /// The loop's sample when the replacement was started.
    pub start_seq: u64,
    pub from_seq: u64,
    /// |u(from) − u(from−1)|, the largest over the inputs.
    pub du_switch: f64,
    /// The largest |u(k) − u(k−1)| over the samples before the switch.
    pub du_before: f64,
    /// The same after the switch (the new design's own ordinary steps).
    pub du_after: f64,
    /// Served by a warm spare (no process started or stopped).
    pub warm: bool,
}

impl Switch {
    /// The switch as the run files record it (events, swap answer, `bench.json`).
    pub fn record(&self) -> SwitchRecord {
        SwitchRecord {
            role: self.role.name().to_string(),
            generation: self.generation,
            start_seq: self.start_seq,
            from_seq: self.from_seq,
            du_switch: self.du_switch,
            du_before: self.du_before,
            du_after: self.du_after,
            warm: self.warm,
        }
    }
}
