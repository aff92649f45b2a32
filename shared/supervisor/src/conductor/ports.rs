//! The conductor's channels: what it reads of the loop (commands, estimates,
//! states, idle spares, measurements) and what it publishes (the activation,
//! a dead instance's last state, orders to spares, replayed measurements, the
//! plant's safety settings).

use super::decide::{Core, Event};
use super::replay::Replay;
use anyhow::Result;
use flexloop_node::Role;
use flexloop_protocol::channels::{
    ACTIVATION, COMMAND, CONTROLLER_STATE, ESTIMATE, LOGGER_PROGRESS, MEASURE_ORDER, MEASUREMENT,
    MEASUREMENT_REPLAY, OBSERVER_STATE, OBSERVER_WAKEUP, PLANT_SETTINGS, SILENCE_ALARM,
    SPARE_ORDER, SPARE_STATUS, TELEMETRY,
};
use flexloop_protocol::handover::CATCHING_UP;
use flexloop_protocol::{
    Activation, Command, Estimate, Handover, MeasureOrder, Measurement, PlantSettings, SpareOrder,
    SpareStatus, Telemetry, flags,
};
use flexloop_transport::{
    ChannelHold, Domain, Inlet, LoopNode, Outlet, WakeupListener, cleanup_dead_nodes,
};
use std::os::fd::RawFd;
use std::time::Instant;

pub struct Ports {
    // Ports before the node: they must drop first.
    activation_out: Outlet<Activation>,
    plant_settings_out: Outlet<PlantSettings>,
    measure_order_out: Outlet<MeasureOrder>,
    controller_states: Inlet<Handover>,
    observer_states: Inlet<Handover>,
    controller_state_out: Outlet<Handover>,
    observer_state_out: Outlet<Handover>,
    commands: Inlet<Command>,
    /// Opened once the loop runs: the observer counts its readers at start-up.
    estimates: Option<Inlet<Estimate>>,
    /// Opened once the loop runs too (the plant counts its readers): fills
    /// the replay's ring.
    measurements: Option<Inlet<Measurement>>,
    replay_out: Outlet<Measurement>,
    spare_orders: Outlet<SpareOrder>,
    spare_status: Inlet<SpareStatus>,
    /// The plant's silence alarm: the supervisor's wait wakes on it.
    silence_alarm: WakeupListener,
    /// Every loop channel, made before any process starts (see `ChannelHold`).
    _holds: Vec<ChannelHold>,
    node: LoopNode,
    domain: Domain,
}

impl Ports {
    pub fn open(prefix: &str) -> Result<Self> {
        let domain = Domain::new(prefix)?;
        let node = domain.node("supervisor")?;
        let mut holds = vec![
            ChannelHold::with_samples::<Measurement>(&node, &MEASUREMENT)?,
            ChannelHold::with_samples::<Estimate>(&node, &ESTIMATE)?,
            ChannelHold::with_samples::<Telemetry>(&node, &TELEMETRY)?,
            ChannelHold::with_samples::<u64>(&node, &LOGGER_PROGRESS)?,
        ];
        // The event services of the channels the supervisor polls, and the
        // observer's own wake-up.
        for channel in [
            &COMMAND,
            &CONTROLLER_STATE,
            &OBSERVER_STATE,
            &SPARE_STATUS,
            &OBSERVER_WAKEUP,
        ] {
            holds.push(ChannelHold::events(&node, channel)?);
        }
        Ok(Self {
            activation_out: Outlet::open(&node, &ACTIVATION)?,
            plant_settings_out: Outlet::open(&node, &PLANT_SETTINGS)?,
            measure_order_out: Outlet::open(&node, &MEASURE_ORDER)?,
            controller_states: Inlet::open_polling(&node, &CONTROLLER_STATE, 8)?,
            observer_states: Inlet::open_polling(&node, &OBSERVER_STATE, 8)?,
            controller_state_out: Outlet::open(&node, &CONTROLLER_STATE)?,
            observer_state_out: Outlet::open(&node, &OBSERVER_STATE)?,
            commands: Inlet::open_polling(&node, &COMMAND, COMMAND.qos.logger_buffer_size)?,
            estimates: None,
            measurements: None,
            replay_out: Outlet::open(&node, &MEASUREMENT_REPLAY)?,
            spare_orders: Outlet::open(&node, &SPARE_ORDER)?,
            spare_status: Inlet::open_polling(
                &node,
                &SPARE_STATUS,
                SPARE_STATUS.qos.loop_buffer_size,
            )?,
            silence_alarm: WakeupListener::open(&node, &SILENCE_ALARM)?,
            _holds: holds,
            node,
            domain,
        })
    }

    /// Hands the core what the channels carry since the last look: the
    /// commands and with them the loop's newest sample number (not from the
    /// measurements: the plant counts their readers to know when the chain
    /// is ready), states, idle spares; and the replay its measurements.
    /// Observations: the core answers them with no action.
    pub fn poll(&mut self, core: &mut Core, replay: &mut Replay) {
        // Whatever woke the supervisor, this look answers it.
        let _ = self.silence_alarm.clear();
        // A publisher hands its history to a new subscriber only when it
        // updates its connections: a replacement must learn the activation.
        let _ = self.activation_out.connect();
        // Estimates too: when the controller is dead they still show the pace.
        if self.estimates.is_none() && core.ticking() {
            self.estimates = Inlet::open_polling(&self.node, &ESTIMATE, 16).ok();
        }
        if self.measurements.is_none() && core.ticking() {
            self.measurements =
                Inlet::open_polling(&self.node, &MEASUREMENT, MEASUREMENT.qos.logger_buffer_size)
                    .ok();
        }
        if let Some(measurements) = &self.measurements {
            while let Ok(Some(m)) = measurements.receive() {
                replay.keep(*m);
                core.handle(Event::Applied {
                    seq: m.seq,
                    command_seq: m.command_seq,
                    u: m.u_applied,
                    fresh: m.flags & (flags::HELD_INPUT | flags::FALLBACK) == 0,
                    // The active controller's command for the due sample,
                    // late: not a stale one, a standby's or a stray's.
                    answered_late: m.flags & flags::ANSWERED_LATE != 0,
                    stalled: m.flags & flags::STALLED_TICK != 0,
                });
                if m.flags & flags::END_OF_RUN != 0 {
                    core.handle(Event::EndOfRun);
                }
            }
        }
        if let Some(estimates) = &self.estimates {
            while let Ok(Some(e)) = estimates.receive() {
                core.handle(Event::Estimate { seq: e.seq });
            }
        }
        for (role, inlet) in [
            (Role::Controller, &self.controller_states),
            (Role::Observer, &self.observer_states),
        ] {
            while let Ok(Some(h)) = inlet.receive() {
                if h.shadow == CATCHING_UP {
                    replay.progress(h.generation, h.seq);
                } else {
                    core.handle(Event::State { role, state: &h });
                }
            }
        }
        while let Ok(Some(status)) = self.spare_status.receive() {
            core.handle(Event::SpareIdle {
                pid: status.pid as i32,
            });
        }
        while let Ok(Some(c)) = self.commands.receive() {
            let n = (c.n_inputs as usize).min(c.u.len());
            core.handle(Event::Command {
                seq: c.seq,
                generation: c.generation,
                finite: c.u[..n].iter().all(|v| v.is_finite()),
            });
        }
        core.handle(Event::Polled {
            now: Instant::now(),
        });
    }

    /// Readable while the plant's silence alarm is pending.
    pub fn alarm_fd(&self) -> RawFd {
        self.silence_alarm.fd()
    }

    /// Publishes the activation, stamped now.
    pub fn publish_activation(&self, mut activation: Activation) -> Result<Activation> {
        activation.published_ns = flexloop_runtime::monotonic_ns();
        self.activation_out.publish(|a| *a = activation)?;
        Ok(activation)
    }

    /// Publishes the plant's safety settings, stamped now (the plant takes
    /// them at its next tick).
    pub fn publish_plant_settings(&self, mut settings: PlantSettings) -> Result<()> {
        settings.published_ns = flexloop_runtime::monotonic_ns();
        self.plant_settings_out.connect()?;
        self.plant_settings_out.publish(|s| *s = settings)?;
        Ok(())
    }

    /// Sends the plant a measurement to run, stamped now.
    pub fn send_measure_order(&self, mut order: MeasureOrder) -> Result<()> {
        order.published_ns = flexloop_runtime::monotonic_ns();
        self.measure_order_out.connect()?;
        self.measure_order_out.publish(|o| *o = order)?;
        Ok(())
    }

    /// Publishes a dead instance's last state for its replacement (best
    /// effort: it is published again at the next look).
    pub fn hand_over(&self, role: Role, last: &Handover) {
        let out = match role {
            Role::Controller => &self.controller_state_out,
            _ => &self.observer_state_out,
        };
        let _ = out.publish(|h| *h = *last);
    }

    /// Publishes `order`, stamped now. Published, it counts: without the
    /// wake-up the spare finds it at its next look (100 ms).
    pub fn send_order(&self, order: SpareOrder) -> Result<()> {
        self.spare_orders.publish(|o| {
            *o = order;
            o.published_ns = flexloop_runtime::monotonic_ns();
        })?;
        let _ = self.spare_orders.notify();
        Ok(())
    }

    /// Replays to the restarted observer `generation` the measurements after
    /// its dead predecessor's last state (see [`Replay::feed`]). Nothing
    /// before that generation says it is catching up, with its reader open
    /// (`poll` hands the replay its reports): the channel keeps no history,
    /// and another reader (an idle warm spare) is no sign that it listens.
    pub fn feed_replay(&self, replay: &mut Replay, generation: u32, state_seq: u64) {
        let out = &self.replay_out;
        replay.feed(generation, state_seq, |m| out.publish(|r| *r = *m).is_ok());
    }

    /// Removes dead nodes' shared memory (now that no live process uses it;
    /// never from inside the loop); returns how many.
    pub fn clean_dead_nodes(&self) -> usize {
        cleanup_dead_nodes(&self.domain).unwrap_or(0)
    }
}
