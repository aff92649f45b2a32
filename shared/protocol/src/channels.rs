//! Service names and QoS of every channel, in one place.
//!
//! iceoryx2 checks QoS on open: every process must ask for the same settings,
//! so nobody else spells them out.

/// A pub-sub service paired with an event service of the same name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Channel {
    pub name: &'static str,
    pub qos: ChannelQos,
}

/// Settings fixed at service creation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelQos {
    /// Active, shadow and standby instances, one rogue or dead slot to spare.
    pub max_publishers: usize,
    pub max_subscribers: usize,
    pub max_nodes: usize,
    /// Samples kept for late joiners (a shadow instance gets the latest at once).
    pub history_size: usize,
    /// Upper bound of any subscriber's queue: the logger's, which polls.
    pub subscriber_max_buffer_size: usize,
    /// Loop subscribers: deep enough to process every sample in order.
    pub loop_buffer_size: usize,
    /// Logger subscribers: 51 ms at 10 kHz, 25 of the logger's 2 ms polls.
    pub logger_buffer_size: usize,
}

// Readers of a measurement: the observer and the controller, a warm spare of
// each, the standby controller, the logger, the supervisor and the live
// server (`flexloop up --live`), and a dead one not yet cleaned. Writers of a command: the controller, its spare, the
// standby, a dead or rogue one.
const LOOP_QOS: ChannelQos = ChannelQos {
    max_publishers: 5,
    max_subscribers: 9,
    max_nodes: 16,
    history_size: 1,
    // Every publisher preallocates max_subscribers x this many samples, and
    // every reader maps (and under mlockall populates) all of it: 2048 made
    // the estimate segment 47 MB.
    subscriber_max_buffer_size: 512,
    loop_buffer_size: 16,
    logger_buffer_size: 512,
};

/// y(k) from the plant.
pub const MEASUREMENT: Channel = Channel {
    name: "flexloop/measurement",
    qos: LOOP_QOS,
};
/// Wakes the observer for y(k), after the measurement's own event has woken
/// the controller: the controller is on the critical path, the observer only
/// has to finish before the next tick (only its event service is used).
pub const OBSERVER_WAKEUP: Channel = Channel {
    name: "flexloop/measurement-observer",
    qos: LOOP_QOS,
};
/// Observer output for the next tick.
pub const ESTIMATE: Channel = Channel {
    name: "flexloop/estimate",
    qos: LOOP_QOS,
};
/// u_c(k) from the controller.
pub const COMMAND: Channel = Channel {
    name: "flexloop/command",
    qos: LOOP_QOS,
};
/// The supervisor's recent measurements, replayed to an observer restarted
/// after a crash, so that it steps through every sample since the last
/// state its predecessor published (paced by the progress it reports: a
/// queue never holds more than `loop_buffer_size` of them).
pub const MEASUREMENT_REPLAY: Channel = Channel {
    name: "flexloop/measurement-replay",
    qos: ChannelQos {
        max_publishers: 2,
        max_subscribers: 4,
        max_nodes: 8,
        history_size: 0,
        subscriber_max_buffer_size: 256,
        loop_buffer_size: 256,
        logger_buffer_size: 256,
    },
};

/// Periodic counters and percentiles (logger) for `flexloop status`.
pub const TELEMETRY: Channel = Channel {
    name: "flexloop/telemetry",
    qos: ChannelQos {
        max_publishers: 4,
        max_subscribers: 8,
        max_nodes: 16,
        history_size: 1,
        subscriber_max_buffer_size: 16,
        loop_buffer_size: 4,
        logger_buffer_size: 16,
    },
};

/// The newest measurement sequence number the logger has drained, a bare
/// `u64`: a lockstep plant paces itself on it, so that a loop running flat
/// out never outruns the recording (a realtime plant never waits for it).
pub const LOGGER_PROGRESS: Channel = Channel {
    name: "flexloop/logger-progress",
    qos: ChannelQos {
        max_publishers: 4,
        max_subscribers: 4,
        max_nodes: 16,
        history_size: 1,
        subscriber_max_buffer_size: 4,
        loop_buffer_size: 4,
        logger_buffer_size: 4,
    },
};

// Active, spare and standby instances and the supervisor, on both ends.
const HANDOVER_QOS: ChannelQos = ChannelQos {
    max_publishers: 6,
    max_subscribers: 8,
    max_nodes: 16,
    history_size: 1,
    subscriber_max_buffer_size: 8,
    loop_buffer_size: 8,
    logger_buffer_size: 8,
};

/// The active controller's state after every sample (for swaps and restarts).
pub const CONTROLLER_STATE: Channel = Channel {
    name: "flexloop/controller-state",
    qos: HANDOVER_QOS,
};
/// The active observer's state after every sample.
pub const OBSERVER_STATE: Channel = Channel {
    name: "flexloop/observer-state",
    qos: HANDOVER_QOS,
};
/// Which generation owns which samples; from the supervisor, kept as history.
pub const ACTIVATION: Channel = Channel {
    name: "flexloop/activation",
    qos: ChannelQos {
        max_publishers: 2,
        max_subscribers: 12,
        max_nodes: 16,
        history_size: 1,
        subscriber_max_buffer_size: 4,
        loop_buffer_size: 4,
        logger_buffer_size: 4,
    },
};

/// The supervisor's orders to idle warm spares (see [`crate::spare`]);
/// polled by the spares, kept as history for one that opens late.
pub const SPARE_ORDER: Channel = Channel {
    name: "flexloop/spare-order",
    qos: SPARE_QOS,
};
/// Spares' reports that they are idle, polled by the supervisor.
pub const SPARE_STATUS: Channel = Channel {
    name: "flexloop/spare-status",
    qos: SPARE_QOS,
};

/// Supervisor → plant: a measurement ordered on the running loop (see
/// [`crate::measure_order`]), polled by the plant at every tick as its
/// settings are; no history (an order is for the plant running now).
pub const MEASURE_ORDER: Channel = Channel {
    name: "flexloop/measure-order",
    qos: ChannelQos {
        max_publishers: 2,
        max_subscribers: 4,
        max_nodes: 8,
        history_size: 0,
        subscriber_max_buffer_size: 4,
        loop_buffer_size: 4,
        logger_buffer_size: 4,
    },
};

/// The plant's safety settings as the supervisor changes them (see
/// [`crate::plant_settings`]); the newest kept for a plant that opens late.
pub const PLANT_SETTINGS: Channel = Channel {
    name: "flexloop/plant-settings",
    qos: ChannelQos {
        max_publishers: 2,
        max_subscribers: 4,
        max_nodes: 8,
        history_size: 1,
        subscriber_max_buffer_size: 4,
        loop_buffer_size: 4,
        logger_buffer_size: 4,
    },
};

/// The plant's silence alarm (only its event service is used): the plant
/// wakes the supervisor the tick its watchdog first applies the safe action
/// (the active controller silent), and the first tick a command says the
/// controller ran without a fresh estimate (the observer silent), so that a
/// dead or stopped process is replaced within ticks, not at the
/// supervisor's next look or the kernel's exit report (docs/architecture.md,
/// "Standby, watchdogs and guards").
pub const SILENCE_ALARM: Channel = Channel {
    name: "flexloop/silence-alarm",
    qos: ChannelQos {
        max_publishers: 2,
        max_subscribers: 2,
        max_nodes: 8,
        history_size: 0,
        subscriber_max_buffer_size: 1,
        loop_buffer_size: 1,
        logger_buffer_size: 1,
    },
};

const SPARE_QOS: ChannelQos = ChannelQos {
    max_publishers: 12,
    max_subscribers: 12,
    max_nodes: 16,
    history_size: 1,
    subscriber_max_buffer_size: 16,
    loop_buffer_size: 16,
    logger_buffer_size: 16,
};

/// Every channel, for tools that list or clean them.
pub const ALL: [Channel; 15] = [
    MEASUREMENT,
    MEASUREMENT_REPLAY,
    OBSERVER_WAKEUP,
    ESTIMATE,
    COMMAND,
    TELEMETRY,
    LOGGER_PROGRESS,
    CONTROLLER_STATE,
    OBSERVER_STATE,
    ACTIVATION,
    SPARE_ORDER,
    SPARE_STATUS,
    PLANT_SETTINGS,
    MEASURE_ORDER,
    SILENCE_ALARM,
];

/// Event ids on the event service paired with each channel.
pub mod events {
    /// A new sample was published.
    pub const SAMPLE: usize = 1;
    /// A notifier's node died (sent by iceoryx2 when it cleans a dead node).
    pub const PUBLISHER_DEAD: usize = 15;
    pub const MAX_EVENT_ID: usize = 15;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_unique_and_queues_fit() {
        for (i, a) in ALL.iter().enumerate() {
            for b in &ALL[i + 1..] {
                assert_ne!(a.name, b.name);
            }
            assert!(a.qos.loop_buffer_size <= a.qos.subscriber_max_buffer_size);
            assert!(a.qos.logger_buffer_size <= a.qos.subscriber_max_buffer_size);
            assert!(a.qos.max_publishers >= 2, "a swap needs two publishers");
        }
    }
}
