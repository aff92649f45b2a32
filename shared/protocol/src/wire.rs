//! The wire contract as data, for components written in another language.
//!
//! A process that is not built from this crate (the Python package under
//! `python/`) opens the same iceoryx2 services, so it must agree on each
//! message's type name, size, alignment and field offsets, on every
//! channel's QoS (iceoryx2 refuses to open a service with other settings)
//! and on the constants of the protocol. [`description`] gives all of it as
//! one JSON document, made from the structs and tables themselves;
//! `python/flexloop/wire.json` is a copy of it, which a test here keeps
//! current and the Python package checks its own definitions against.

use crate::channels::{self, Channel, events};
use crate::handover::{self, Activation, Handover, MAX_HANDOVER_STATES};
use crate::joining::Joining;
use crate::layout::{self, MessageLayout, Scalar};
use crate::messages::{
    Command, Estimate, MAX_INPUTS, MAX_OBSERVER_INPUTS, MAX_OBSERVER_OUTPUTS, MAX_OUTPUTS,
    MAX_STATES, Measurement, NO_SEQ, flags,
};
use iceoryx2::prelude::ZeroCopySend;
use serde_json::{Value, json};

/// Where the Python package keeps its copy, relative to the repository root.
pub const PYTHON_COPY: &str = "python/flexloop/wire.json";

/// The iceoryx2 type name of `T` (its `#[type_name]`).
fn iceoryx2_name<T: ZeroCopySend>() -> &'static str {
    // SAFETY: only reads the name the derive macro gives the type; the
    // layout promise it stands for is what this module publishes.
    unsafe { <T as ZeroCopySend>::type_name() }
}

fn scalar_name(scalar: Scalar) -> &'static str {
    match scalar {
        Scalar::U64 => "u64",
        Scalar::U32 => "u32",
        Scalar::F64 => "f64",
    }
}

fn message<T: ZeroCopySend>(name: &str, table: &MessageLayout) -> Value {
    let fields: Vec<Value> = table
        .fields
        .iter()
        .map(|f| {
            json!({
                "name": f.name,
                "scalar": scalar_name(f.scalar),
                "len": f.len,
                "offset": f.offset,
                "size": f.size(),
            })
        })
        .collect();
    json!({
        "name": name,
        "iceoryx2_type_name": iceoryx2_name::<T>(),
        "size": core::mem::size_of::<T>(),
        "align": core::mem::align_of::<T>(),
        "fields": fields,
    })
}

fn channel(c: &Channel) -> Value {
    let q = &c.qos;
    json!({
        "name": c.name,
        "max_publishers": q.max_publishers,
        "max_subscribers": q.max_subscribers,
        "max_nodes": q.max_nodes,
        "history_size": q.history_size,
        "subscriber_max_buffer_size": q.subscriber_max_buffer_size,
        "loop_buffer_size": q.loop_buffer_size,
        "logger_buffer_size": q.logger_buffer_size,
    })
}

/// The whole contract as a JSON value.
pub fn description() -> Value {
    let joining: serde_json::Map<String, Value> = Joining::ALL
        .iter()
        .map(|j| (format!("{j:?}"), json!(j.wire())))
        .collect();
    json!({
        "messages": [
            message::<Measurement>("Measurement", &layout::MEASUREMENT),
            message::<Estimate>("Estimate", &layout::ESTIMATE),
            message::<Command>("Command", &layout::COMMAND),
            message::<Handover>("Handover", &layout::HANDOVER),
            message::<Activation>("Activation", &layout::ACTIVATION),
        ],
        "channels": channels::ALL.iter().map(channel).collect::<Vec<_>>(),
        "events": {
            "SAMPLE": events::SAMPLE,
            "PUBLISHER_DEAD": events::PUBLISHER_DEAD,
            "MAX_EVENT_ID": events::MAX_EVENT_ID,
        },
        "constants": {
            "MAX_OUTPUTS": MAX_OUTPUTS,
            "MAX_INPUTS": MAX_INPUTS,
            "MAX_STATES": MAX_STATES,
            "MAX_OBSERVER_OUTPUTS": MAX_OBSERVER_OUTPUTS,
            "MAX_OBSERVER_INPUTS": MAX_OBSERVER_INPUTS,
            "MAX_HANDOVER_STATES": MAX_HANDOVER_STATES,
            "NO_SEQ": NO_SEQ,
        },
        "flags": {
            "END_OF_RUN": flags::END_OF_RUN,
            "HELD_INPUT": flags::HELD_INPUT,
            "STALLED_TICK": flags::STALLED_TICK,
            "STALE_ESTIMATE": flags::STALE_ESTIMATE,
            "LOCKSTEP": flags::LOCKSTEP,
            "CLAMPED": flags::CLAMPED,
            "FALLBACK": flags::FALLBACK,
            "OBSERVER_FALLBACK": flags::OBSERVER_FALLBACK,
            "STANDBY": flags::STANDBY,
            "EXCITING": flags::EXCITING,
            "EXCITING_REFERENCE": flags::EXCITING_REFERENCE,
            "ANSWERED_LATE": flags::ANSWERED_LATE,
        },
        "handover_marks": {
            "ACTIVE": handover::ACTIVE,
            "FOLLOWING": handover::FOLLOWING,
            "CATCHING_UP": handover::CATCHING_UP,
        },
        "joining": joining,
    })
}

/// [`description`] as the text of [`PYTHON_COPY`] (pretty, one trailing newline).
pub fn description_text() -> String {
    let mut text = serde_json::to_string_pretty(&description())
        .expect("a JSON value of strings and numbers always serialises");
    text.push('\n');
    text
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// The Python package's copy is the contract as it is now. Set
    /// `FLEXLOOP_BLESS=1` to rewrite it after a deliberate change (and
    /// bump the type name's version in `messages.rs` with any layout
    /// change).
    #[test]
    fn the_python_copy_is_current() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../..")
            .join(PYTHON_COPY);
        let now = description_text();
        if std::env::var_os("FLEXLOOP_BLESS").is_some() {
            std::fs::write(&path, &now).unwrap();
        }
        let copy =
            std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(
            copy == now,
            "{} is out of date with shared/protocol; rerun with FLEXLOOP_BLESS=1 \
             (cargo test -p flexloop-protocol) and check the Python package's tests",
            path.display()
        );
    }

    #[test]
    fn every_message_names_its_iceoryx2_type_and_fields() {
        let d = description();
        let messages = d["messages"].as_array().unwrap();
        assert_eq!(messages.len(), 5);
        assert_eq!(messages[0]["iceoryx2_type_name"], "flexloop.Measurement.v4");
        for m in messages {
            let fields = m["fields"].as_array().unwrap();
            let last = fields.last().unwrap();
            assert_eq!(
                last["offset"].as_u64().unwrap() + last["size"].as_u64().unwrap(),
                m["size"].as_u64().unwrap(),
                "{}",
                m["name"]
            );
        }
        assert_eq!(d["joining"]["Replacement"], 0);
        assert_eq!(d["channels"].as_array().unwrap().len(), channels::ALL.len());
    }
}
