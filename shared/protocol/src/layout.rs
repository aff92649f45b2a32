//! Every message's fields as data: name, type, offset, unit.
//!
//! The messages are `#[repr(C)]` without padding, so their bytes are exactly
//! the ROS1 serialisation of the definitions made here (little-endian
//! scalars, fixed-size arrays without a length prefix). The sample file
//! stores them as they are, under these definitions, and tools such as
//! Foxglove and PlotJuggler decode them without plug-ins; the CSV export
//! names its columns from the same tables. The tests check every offset and
//! size against the structs, so a field added to a message without its line
//! here fails them.

// The sample file stores the messages as they are in memory; ROS1 is
// little-endian.
#[cfg(target_endian = "big")]
compile_error!("the sample file's ROS1 encoding needs a little-endian target");

use crate::handover::{Activation, Handover, MAX_HANDOVER_STATES};
use crate::messages::{
    Command, Estimate, MAX_INPUTS, MAX_OBSERVER_INPUTS, MAX_OBSERVER_OUTPUTS, MAX_OUTPUTS,
    MAX_STATES, Measurement,
};

/// A scalar type of the messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scalar {
    U64,
    U32,
    F64,
}

impl Scalar {
    pub const fn size(self) -> usize {
        match self {
            Scalar::U64 | Scalar::F64 => 8,
            Scalar::U32 => 4,
        }
    }

    /// The ROS1 primitive type.
    pub const fn ros1(self) -> &'static str {
        match self {
            Scalar::U64 => "uint64",
            Scalar::U32 => "uint32",
            Scalar::F64 => "float64",
        }
    }
}

/// How much of a fixed-size array a run uses, by the message's own counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Extent {
    /// A single value.
    One,
    /// `n_outputs` entries.
    Outputs,
    /// `n_inputs` entries.
    Inputs,
    /// `n_states` entries.
    States,
    /// Observer block outputs `[ŷ_flex; u_d]`: at most `n_outputs + n_inputs`.
    ObserverOutputs,
    /// The row-major `MAX_OBSERVER_OUTPUTS × MAX_OBSERVER_INPUTS` feedthrough:
    /// at most `n_outputs + n_inputs` rows of `n_outputs + 2 n_inputs` columns.
    ObserverDirect,
}

/// One field of a message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Field {
    /// The name in the ROS1 definition and the CSV header.
    pub name: &'static str,
    pub scalar: Scalar,
    /// Array length; 0 for a scalar.
    pub len: usize,
    pub offset: usize,
    pub extent: Extent,
    /// Unit of every element; empty for counts, flags and mixed quantities.
    pub unit: &'static str,
    pub doc: &'static str,
}

impl Field {
    pub const fn size(&self) -> usize {
        if self.len == 0 {
            self.scalar.size()
        } else {
            self.scalar.size() * self.len
        }
    }
}

/// A message as the sample file records it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageLayout {
    /// ROS1 type name (`package/Type`), the schema name in the sample file.
    pub type_name: &'static str,
    pub doc: &'static str,
    pub size: usize,
    pub fields: &'static [Field],
}

impl MessageLayout {
    /// The ROS1 message definition (`.msg` text), units and meanings as comments.
    pub fn ros1_definition(&self) -> String {
        let mut text = format!("# {}: {}\n", self.type_name, self.doc);
        for f in self.fields {
            let ty = if f.len == 0 {
                f.scalar.ros1().to_string()
            } else {
                format!("{}[{}]", f.scalar.ros1(), f.len)
            };
            let unit = if f.unit.is_empty() {
                String::new()
            } else {
                format!(" [{}]", f.unit)
            };
            text.push_str(&format!("{ty} {}  # {}{unit}\n", f.name, f.doc));
        }
        text
    }

    pub fn field(&self, name: &str) -> Option<&'static Field> {
        self.fields.iter().find(|f| f.name == name)
    }
}

/// `field!(Type, name: SCALAR; extent, "unit", "doc")`, `field!(Type, name: SCALAR[len]; …)`,
/// and `field!(Type, rust_name as ros_name: …)` where the Rust name is no
/// legal ROS1 field name (a leading underscore).
macro_rules! field {
    ($t:ty, $name:ident $(as $ros:ident)? : $scalar:ident $([$len:expr])?; $extent:ident, $unit:literal, $doc:literal) => {
        Field {
            name: [$(stringify!($ros),)? stringify!($name)][0],
            scalar: Scalar::$scalar,
            len: 0 $(+ $len)?,
            offset: core::mem::offset_of!($t, $name),
            extent: Extent::$extent,
            unit: $unit,
            doc: $doc,
        }
    };
}

pub const MEASUREMENT: MessageLayout = MessageLayout {
    type_name: "flexloop/Measurement",
    doc: "y(k) from the plant, published at tick k",
    size: core::mem::size_of::<Measurement>(),
    fields: &[
        field!(Measurement, seq: U64; One, "", "tick k"),
        field!(Measurement, tick_ns: U64; One, "ns", "scheduled time of tick k (CLOCK_MONOTONIC)"),
        field!(Measurement, woke_ns: U64; One, "ns", "when the plant woke for tick k"),
        field!(Measurement, published_ns: U64; One, "ns", "when the plant published y(k)"),
        field!(Measurement, command_seq: U64; One, "", "command applied over [t_k, t_k+1); 2^64-1: none"),
        field!(Measurement, misses: U64; One, "", "cumulative loop misses"),
        field!(Measurement, late_commands: U64; One, "", "cumulative commands dropped as late"),
        field!(Measurement, stalled_ticks: U64; One, "", "cumulative ticks the plant woke too late for"),
        field!(Measurement, stall_misses: U64; One, "", "cumulative misses on stalled ticks"),
        field!(Measurement, fallback_ticks: U64; One, "", "cumulative ticks under the safe action"),
        field!(Measurement, rejected_commands: U64; One, "", "cumulative commands refused"),
        field!(Measurement, flags: U32; One, "", "bits: 1 end of run, 2 held input, 4 stalled tick, 16 lockstep, 64 fallback"),
        field!(Measurement, generation: U32; One, "", "generation whose commands the plant accepts"),
        field!(Measurement, n_outputs: U32; One, "", "outputs in use"),
        field!(Measurement, n_inputs: U32; One, "", "inputs in use"),
        field!(Measurement, y: F64[MAX_OUTPUTS]; Outputs, "m", "measured outputs y(k)"),
        field!(Measurement, y_true: F64[MAX_OUTPUTS]; Outputs, "m", "noise-free outputs"),
        field!(Measurement, u_applied: F64[MAX_INPUTS]; Inputs, "N", "input applied over [t_k, t_k+1)"),
        field!(Measurement, u_pending: F64[MAX_INPUTS]; Inputs, "N", "input accepted for [t_k+1, t_k+2) (extra delay only)"),
        field!(Measurement, excitation: F64; One, "", "measurement excitation added at tick k: N at the plant input, m at the sensor"),
    ],
};

pub const ESTIMATE: MessageLayout = MessageLayout {
    type_name: "flexloop/Estimate",
    doc: "the observer's contribution for tick seq, from measurement seq-1",
    size: core::mem::size_of::<Estimate>(),
    fields: &[
        field!(Estimate, seq: U64; One, "", "tick k this estimate is for"),
        field!(Estimate, source_tick_ns: U64; One, "ns", "tick time of measurement k-1"),
        field!(Estimate, source_published_ns: U64; One, "ns", "when the plant published measurement k-1"),
        field!(Estimate, received_ns: U64; One, "ns", "when the observer received measurement k-1"),
        field!(Estimate, published_ns: U64; One, "ns", "when the observer published this estimate"),
        field!(Estimate, flags: U32; One, "", "flag bits (see Measurement)"),
        field!(Estimate, generation: U32; One, "", "observer generation"),
        field!(Estimate, n_outputs: U32; One, "", "outputs in use"),
        field!(Estimate, n_inputs: U32; One, "", "inputs in use"),
        field!(Estimate, n_states: U32; One, "", "states in x_hat"),
        field!(Estimate, _reserved as reserved: U32; One, "", "unused"),
        field!(Estimate, free: F64[MAX_OBSERVER_OUTPUTS]; ObserverOutputs, "", "free response of [y_flex_hat; u_d] at tick k"),
        field!(Estimate, direct: F64[MAX_OBSERVER_OUTPUTS * MAX_OBSERVER_INPUTS]; ObserverDirect, "", "row-major feedthrough from [y; u_a; u_pending] to [y_flex_hat; u_d], 24 columns"),
        field!(Estimate, x_hat: F64[MAX_STATES]; States, "", "x_hat(k|k-1)"),
        field!(Estimate, innovation: F64[MAX_OUTPUTS]; Outputs, "m", "innovation of measurement k-1"),
    ],
};

pub const COMMAND: MessageLayout = MessageLayout {
    type_name: "flexloop/Command",
    doc: "u_c(k), computed from y(k), held over [t_k+1, t_k+2)",
    size: core::mem::size_of::<Command>(),
    fields: &[
        field!(Command, seq: U64; One, "", "tick k this command answers"),
        field!(Command, tick_ns: U64; One, "ns", "scheduled time of tick k"),
        field!(Command, measurement_published_ns: U64; One, "ns", "when the plant published measurement k"),
        field!(Command, received_ns: U64; One, "ns", "when the controller received measurement k"),
        field!(Command, published_ns: U64; One, "ns", "when the controller published this command"),
        field!(Command, estimate_seq: U64; One, "", "estimate used (k if fresh)"),
        field!(Command, estimate_published_ns: U64; One, "ns", "when that estimate was published"),
        field!(Command, flags: U32; One, "", "bits: 8 stale estimate, 32 clamped, 128 observer fallback"),
        field!(Command, generation: U32; One, "", "controller generation"),
        field!(Command, n_inputs: U32; One, "", "inputs in use"),
        field!(Command, n_outputs: U32; One, "", "outputs in use"),
        field!(Command, u: F64[MAX_INPUTS]; Inputs, "N", "command u = u_fb + u_ff + u_d after limits"),
        field!(Command, u_fb: F64[MAX_INPUTS]; Inputs, "N", "feedback part"),
        field!(Command, u_ff: F64[MAX_INPUTS]; Inputs, "N", "feedforward part"),
        field!(Command, u_d: F64[MAX_INPUTS]; Inputs, "N", "active damping part"),
        field!(Command, r: F64[MAX_OUTPUTS]; Outputs, "m", "set-point r(k)"),
        field!(Command, e_meas: F64[MAX_OUTPUTS]; Outputs, "m", "measured error r(k) - y_comp(k)"),
    ],
};

/// The recorded messages.
pub const ALL: [MessageLayout; 3] = [MEASUREMENT, ESTIMATE, COMMAND];

// The hand-over messages are not recorded; their tables are here so that a
// component in another language can check its layout of them too (see
// [`crate::wire`]).

pub const HANDOVER: MessageLayout = MessageLayout {
    type_name: "flexloop/Handover",
    doc: "a component's state after it processed measurement seq",
    size: core::mem::size_of::<Handover>(),
    fields: &[
        field!(Handover, seq: U64; One, "", "measurement last processed"),
        field!(Handover, design_hash: U64; One, "", "fingerprint of the design that produced state"),
        field!(Handover, generation: U32; One, "", "generation of the instance"),
        field!(Handover, shadow: U32; One, "", "0 active, 1 following, 2 catching up"),
        field!(Handover, n_states: U32; One, "", "entries of state in use"),
        field!(Handover, n_inputs: U32; One, "", "inputs in use"),
        field!(Handover, carried_hash: U64; One, "", "fingerprint of the part of state another design continues from (feedforward; observer model estimate)"),
        field!(Handover, carried_at: U32; One, "", "where that part lies in state"),
        field!(Handover, carried_len: U32; One, "", "length of that part"),
        field!(Handover, state: F64[MAX_HANDOVER_STATES]; States, "", "the component's state"),
        field!(Handover, u: F64[MAX_INPUTS]; Inputs, "N", "the command for seq (sent or, in shadow, computed)"),
    ],
};

pub const ACTIVATION: MessageLayout = MessageLayout {
    type_name: "flexloop/Activation",
    doc: "which generation owns which sequence numbers",
    size: core::mem::size_of::<Activation>(),
    fields: &[
        field!(Activation, published_ns: U64; One, "ns", "when the supervisor published it"),
        field!(Activation, controller_from_seq: U64; One, "", "first command of controller_generation"),
        field!(Activation, observer_from_seq: U64; One, "", "first estimate of observer_generation"),
        field!(Activation, controller_generation: U32; One, "", "controller generation from the boundary on"),
        field!(Activation, previous_controller_generation: U32; One, "", "controller generation before it"),
        field!(Activation, observer_generation: U32; One, "", "observer generation from the boundary on"),
        field!(Activation, previous_observer_generation: U32; One, "", "observer generation before it"),
    ],
};

/// How many entries of `field` a message with these counts uses (the whole
/// array for `One`).
pub fn used_len(field: &Field, n_outputs: usize, n_inputs: usize, n_states: usize) -> usize {
    let used = match field.extent {
        Extent::One => return 1,
        Extent::Outputs => n_outputs,
        Extent::Inputs => n_inputs,
        Extent::States => n_states,
        Extent::ObserverOutputs => n_outputs + n_inputs,
        Extent::ObserverDirect => {
            // Rows then columns of the packed row-major table.
            return (n_outputs + n_inputs).min(MAX_OBSERVER_OUTPUTS)
                * (n_outputs + 2 * n_inputs).min(MAX_OBSERVER_INPUTS);
        }
    };
    used.min(field.len)
}

/// Element `i` of the used part of `field` as an index into the whole array
/// (only `ObserverDirect` skips: it walks rows of the packed table).
pub fn element_index(field: &Field, i: usize, n_outputs: usize, n_inputs: usize) -> usize {
    match field.extent {
        Extent::ObserverDirect => {
            let cols = (n_outputs + 2 * n_inputs).clamp(1, MAX_OBSERVER_INPUTS);
            (i / cols) * MAX_OBSERVER_INPUTS + i % cols
        }
        _ => i,
    }
}

/// The name of element `i` (as [`element_index`] counts) in a CSV header.
pub fn element_name(field: &Field, i: usize, n_outputs: usize, n_inputs: usize) -> String {
    match field.extent {
        Extent::One => field.name.to_string(),
        Extent::ObserverDirect => {
            let index = element_index(field, i, n_outputs, n_inputs);
            format!(
                "{}[{}][{}]",
                field.name,
                index / MAX_OBSERVER_INPUTS,
                index % MAX_OBSERVER_INPUTS
            )
        }
        _ => format!("{}[{i}]", field.name),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_cover_every_byte_in_order() {
        for layout in ALL.into_iter().chain([HANDOVER, ACTIVATION]) {
            let mut next = 0;
            for f in layout.fields {
                assert_eq!(
                    f.offset, next,
                    "{}.{}: padding or a missing field before it",
                    layout.type_name, f.name
                );
                next += f.size();
            }
            assert_eq!(
                next, layout.size,
                "{}: fields after the last one listed",
                layout.type_name
            );
        }
    }

    #[test]
    fn field_types_match_the_structs() {
        // Spot checks of values at the offsets the tables give.
        let m = Measurement {
            seq: 7,
            flags: 3,
            y_true: [2.5; MAX_OUTPUTS],
            ..Default::default()
        };
        // SAFETY: Measurement is plain data of the table's size.
        let bytes = unsafe {
            core::slice::from_raw_parts((&m as *const Measurement).cast::<u8>(), MEASUREMENT.size)
        };
        let at = |name: &str| MEASUREMENT.field(name).unwrap().offset;
        assert_eq!(
            u64::from_le_bytes(bytes[at("seq")..][..8].try_into().unwrap()),
            7
        );
        assert_eq!(
            u32::from_le_bytes(bytes[at("flags")..][..4].try_into().unwrap()),
            3
        );
        let y_true = at("y_true") + 8 * (MAX_OUTPUTS - 1);
        assert_eq!(
            f64::from_le_bytes(bytes[y_true..][..8].try_into().unwrap()),
            2.5
        );
    }

    #[test]
    fn definitions_are_legal_ros1() {
        for layout in ALL {
            let text = layout.ros1_definition();
            for line in text.lines().filter(|l| !l.starts_with('#')) {
                let (ty, rest) = line.split_once(' ').unwrap();
                let name = rest.split_whitespace().next().unwrap();
                assert!(
                    name.starts_with(|c: char| c.is_ascii_alphabetic())
                        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'),
                    "{name}"
                );
                assert!(
                    ["uint64", "uint32", "float64"]
                        .iter()
                        .any(|t| ty.starts_with(t)),
                    "{ty}"
                );
            }
        }
        assert!(
            MEASUREMENT
                .ros1_definition()
                .contains("\nfloat64[8] y  # measured outputs y(k) [m]\n")
        );
        assert!(ESTIMATE.ros1_definition().contains("uint32 reserved"));
    }

    #[test]
    fn used_extents_follow_the_counts() {
        let direct = ESTIMATE.field("direct").unwrap();
        // One output, one input: 2 rows of 3 columns.
        assert_eq!(used_len(direct, 1, 1, 15), 6);
        assert_eq!(element_index(direct, 4, 1, 1), MAX_OBSERVER_INPUTS + 1);
        assert_eq!(element_name(direct, 4, 1, 1), "direct[1][1]");
        let x_hat = ESTIMATE.field("x_hat").unwrap();
        assert_eq!(used_len(x_hat, 1, 1, 15), 15);
        assert_eq!(used_len(x_hat, 1, 1, 500), MAX_STATES);
        assert_eq!(element_name(x_hat, 3, 1, 1), "x_hat[3]");
    }
}
