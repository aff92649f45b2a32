//! The plant process: owns the clock, applies commands, publishes y(k).

use crate::args::{Role, ServiceArgs, realtime_settings, wait_mode};
use crate::handover::ActivationView;
use crate::{NodeError, await_peers};
use flexloop_components::PlantCore;
use flexloop_protocol::channels::{
    COMMAND, LOGGER_PROGRESS, MEASUREMENT, OBSERVER_WAKEUP, PLANT_SETTINGS, SILENCE_ALARM,
};
use flexloop_protocol::plant_settings::{SAFE_HOLD, SAFE_STANDBY, SAFE_ZERO};
use flexloop_protocol::{Activation, Command, Measurement, PlantSettings, flags};
use flexloop_runtime::clock::{TickGrid, wait_until};
use flexloop_runtime::wait::wait_readable;
use flexloop_runtime::{monotonic_ns, realtime, shutdown};
use flexloop_scenario::Mode;
use flexloop_scenario::schema::SafeAction;
use flexloop_transport::{Domain, Inlet, Outlet, Wakeup};
use std::time::Duration;

/// In lockstep, how long a command may take before the tick goes on without it.
const LOCKSTEP_MISS_AFTER: Duration = Duration::from_secs(1);
/// In lockstep, how long the last tick waits for its command once a stop was asked.
const LOCKSTEP_STOP_WAIT: Duration = Duration::from_millis(100);
/// In lockstep, how long the controller may stay silent before the run fails.
const LOCKSTEP_SILENCE: Duration = Duration::from_secs(10);

pub fn run(args: &ServiceArgs) -> Result<(), NodeError> {
    let (scenario, design) = args.load()?;
    // Real-time set-up before any port exists: under mlockall every shared
    // memory segment is then populated during start-up, never inside the loop.
    let rt = realtime_settings(&scenario, Role::Plant);
    let _memory = realtime::apply(Role::Plant.name(), &rt.memory_part());
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node("plant")?;
    let measurements = Outlet::<Measurement>::open(&node, &MEASUREMENT)?;
    let observer_wakeup = Wakeup::open(&node, &OBSERVER_WAKEUP)?;
    // Wakes the supervisor when a role falls silent (see `PlantCore::take_alarm`).
    let silence_alarm = Wakeup::open(&node, &SILENCE_ALARM)?;
    let commands = Inlet::<Command>::open(&node, &COMMAND, COMMAND.qos.loop_buffer_size)?;
    // Lockstep only: how far the logger has drained (see `LoggerPace`).
    let logger_progress = Inlet::<u64>::open_polling(
        &node,
        &LOGGER_PROGRESS,
        LOGGER_PROGRESS.qos.loop_buffer_size,
    )?;
    // The safe action and the command watchdog as the supervisor changes them.
    let settings = Inlet::<PlantSettings>::open_polling(
        &node,
        &PLANT_SETTINGS,
        PLANT_SETTINGS.qos.loop_buffer_size,
    )?;

    // Measurements ordered on the running loop (`flexloop measure --running`).
    let mut measure_orders = crate::measure_orders::MeasureOrders::open(&node, &scenario, rt.cpu)?;

    // Start-up handshake: the observer and the logger subscribe once they are
    // connected and locked; the controller opens its command port last, once
    // it holds the observer's first estimate. So when all are there (and the
    // warm spares, whose ports are there from their start, so that a swap
    // opens none), the chain is ready and tick 0 can start.
    // Warm spares open every port at once, so they are counted apart: the
    // controller's own command port still comes last.
    let spares = usize::from(scenario.supervision.warm_spares);
    let expected_readers = 2 + 2 * spares + usize::from(scenario.logger.enabled);
    let expected_writers = 1 + spares;
    let ready = await_peers(
        || {
            Ok(measurements.subscribers() >= expected_readers
                && commands.publishers() >= expected_writers)
        },
        || {
            format!(
                "{} of {expected_readers} measurement readers, {} of {expected_writers} command publishers (warm spares included)",
                measurements.subscribers(),
                commands.publishers()
            )
        },
    )?;
    if !ready {
        return Ok(());
    }
    commands.connect()?;
    measurements.connect()?;
    let mut activation = ActivationView::open(&node)?;
    activation.connect()?;
    // Priority and CPU only now, connected: see `RealtimeSettings::scheduling_part`.
    let scheduling = realtime::apply(Role::Plant.name(), &rt.scheduling_part());

    let mut core = PlantCore::new(&design);
    core.set_watchdog(
        scenario.supervision.command_watchdog_ticks,
        scenario.supervision.safe_action,
    );
    core.set_activation(activation.refresh()?);
    let mut last_command = std::time::Instant::now();
    // The newest command a lockstep tick waited for and got.
    let mut last_served: Option<u64> = None;
    let lockstep = scenario.timing.mode == Mode::Lockstep;
    let period_ns = scenario.period_ns();
    let stall_threshold_ns = period_ns / 2;
    let last_tick = scenario.ticks().map(|n| n.saturating_sub(1));
    let grid = TickGrid::starting_in(period_ns, 2_000_000);
    let waits = wait_mode(&scenario);
    // The tick wait is chosen once the priority is in force (a refused one
    // cannot spin): see `crate::tick`.
    let tick_decision = crate::tick::decide(&scenario, realtime::online_cpus(), &scheduling);
    let mut tick_waiter = crate::tick::waiter(&tick_decision, period_ns);
    let sleeps_for_ticks = scenario.plant_sleeps_for_ticks();
    let mut logger_pace = LoggerPace::new(lockstep && scenario.logger.enabled);

    let mut k: u64 = 0;
    loop {
        while let Some(changed) = settings.receive()? {
            if let Some(action) = safe_action(changed.safe_action) {
                core.set_watchdog(changed.command_watchdog_ticks, action);
            }
        }
        let stopping = shutdown::requested();
        let (tick_ns, woke_ns) = if lockstep {
            if k > 0 {
                // Stopping too: the command for this last tick is on its way.
                wait_for_command(
                    &commands,
                    &mut activation,
                    &mut core,
                    k,
                    &mut last_command,
                    &mut last_served,
                )?;
            }
            logger_pace.wait_for_logger(&logger_progress, k)?;
            let now = monotonic_ns();
            (now, now)
        } else {
            let tick_ns = grid.tick_ns(k);
            if sleeps_for_ticks {
                tick_waiter.wait_for(tick_ns);
            } else {
                wait_until(waits, tick_ns);
            }
            let woke_ns = monotonic_ns();
            core.set_activation(activation.refresh()?);
            while let Some(cmd) = commands.receive()? {
                core.offer(&cmd, k, tick_ns);
            }
            (tick_ns, woke_ns)
        };
        if let Some(excitation) = measure_orders.poll(k)? {
            core.set_excitation(Some(excitation));
        }
        let stalled = woke_ns.saturating_sub(tick_ns) > stall_threshold_ns;
        let last = stopping || Some(k) == last_tick;
        measurements.publish(|m| {
            core.tick(k, tick_ns, woke_ns, stalled, m);
            if last {
                m.flags |= flags::END_OF_RUN;
            }
            if lockstep {
                m.flags |= flags::LOCKSTEP;
            }
            m.published_ns = monotonic_ns();
        })?;
        // The controller first (critical path), then the observer (due
        // before the next tick); the model update after both.
        measurements.notify()?;
        observer_wakeup.wake()?;
        if core.take_alarm() {
            silence_alarm.wake()?;
        }
        core.advance();
        if last {
            break;
        }
        k += 1;
    }
    let c = core.counters;
    eprintln!(
        "flexloop-plant: {} ticks, {} misses, {} late commands, {} stalled ticks ({} misses after stalls)",
        c.ticks, c.misses, c.late_commands, c.stalled_ticks, c.stall_misses
    );
    let path = flexloop_runfiles::RunDir::new(&args.run_dir).plant_latency();
    let tick_wait = sleeps_for_ticks.then(|| crate::tick::report(&tick_decision, &tick_waiter));
    let own = crate::summary::plant_latency(&c, &core.latencies, period_ns, tick_wait);
    if let Err(e) = flexloop_runfiles::json::write_json_atomically(&path, &own) {
        // The loop's work is done; the logger's summary has the same figures.
        eprintln!("flexloop-plant: {e}");
    }
    Ok(())
}

/// Lockstep runs flat out; the logger drains every 2 ms into queues of
/// `logger_buffer_size` samples. Without pacing, a fast loop on a busy
/// machine outruns it and the recording has gaps, so a lockstep plant stays
/// at most [`LoggerPace::LEAD`] samples ahead of what the logger has drained.
/// A logger silent for [`LoggerPace::PATIENCE`] (killed, restarting) is not
/// waited for again until it reports progress.
struct LoggerPace {
    enabled: bool,
    drained: Option<u64>,
    silent: bool,
}

impl LoggerPace {
    /// Half the logger's queue.
    const LEAD: u64 = MEASUREMENT.qos.logger_buffer_size as u64 / 2;
    const PATIENCE: Duration = Duration::from_secs(2);

    fn new(enabled: bool) -> Self {
        Self {
            enabled,
            drained: None,
            silent: false,
        }
    }

    fn take(&mut self, progress: &Inlet<u64>) -> Result<bool, NodeError> {
        let mut moved = false;
        while let Some(seq) = progress.receive()? {
            moved |= self.drained != Some(*seq);
            self.drained = Some(*seq);
        }
        Ok(moved)
    }

    fn wait_for_logger(&mut self, progress: &Inlet<u64>, k: u64) -> Result<(), NodeError> {
        if !self.enabled {
            return Ok(());
        }
        if self.take(progress)? {
            self.silent = false;
        }
        let ahead = |drained: Option<u64>| k > drained.map_or(0, |d| d + 1) + Self::LEAD;
        if self.silent || !ahead(self.drained) {
            return Ok(());
        }
        let since = std::time::Instant::now();
        while ahead(self.drained) && !shutdown::requested() {
            if since.elapsed() > Self::PATIENCE {
                eprintln!(
                    "flexloop-plant: the logger has drained nothing for {:?} (at tick {k}); not waiting for it",
                    Self::PATIENCE
                );
                self.silent = true;
                return Ok(());
            }
            std::thread::sleep(Duration::from_micros(200));
            self.take(progress)?;
        }
        Ok(())
    }
}

/// Lockstep: block until the command for tick `k` arrived (or shutdown). A
/// controller silent for [`LOCKSTEP_MISS_AFTER`] costs the tick (a miss, then
/// the watchdog's safe action), so that a crashed controller does not stop
/// the plant; silent for [`LOCKSTEP_SILENCE`] in a row, the run fails.
/// Except while a replaced observer generation owns samples no command has
/// served yet (a restart replaying its way back, a swap's boundary): the
/// controller is alive and waits for that observer, however long a loaded
/// machine makes it take, so the tick is not given away; only the silence
/// fails the run.
fn wait_for_command(
    commands: &Inlet<Command>,
    activation: &mut ActivationView,
    core: &mut PlantCore,
    k: u64,
    last_command: &mut std::time::Instant,
    last_served: &mut Option<u64>,
) -> Result<(), NodeError> {
    let since = std::time::Instant::now();
    loop {
        commands.clear_events()?;
        core.set_activation(activation.refresh()?);
        while let Some(cmd) = commands.receive()? {
            core.offer(&cmd, k, u64::MAX);
        }
        if core.has_command_for(k) {
            *last_command = std::time::Instant::now();
            *last_served = Some(k - 1);
            return Ok(());
        }
        let patience = if shutdown::requested() {
            LOCKSTEP_STOP_WAIT
        } else if awaits_new_observer(activation.current(), k, *last_served) {
            LOCKSTEP_SILENCE
        } else {
            LOCKSTEP_MISS_AFTER
        };
        if since.elapsed() > patience {
            break;
        }
        wait_readable(&[commands.fd()], 10_000_000).map_err(|e| NodeError::Peer(e.to_string()))?;
    }
    if last_command.elapsed() > LOCKSTEP_SILENCE {
        return Err(NodeError::Peer(format!(
            "lockstep: no command since {LOCKSTEP_SILENCE:?} before tick {k}: controller silent"
        )));
    }
    Ok(())
}

/// Whether the command due for tick `k` (command `k - 1`, from estimate
/// `k - 1`) waits on an observer generation that replaced another and owns
/// estimates from which no command has been served yet (`last_served`: the
/// newest command applied).
fn awaits_new_observer(a: &Activation, k: u64, last_served: Option<u64>) -> bool {
    a.observer_generation != a.previous_observer_generation
        && a.observer_from_seq < k
        && last_served.is_none_or(|s| s < a.observer_from_seq)
}

/// The safe action a [`PlantSettings`] names; None for a value no
/// supervisor sends (the plant keeps what it has).
fn safe_action(wire: u32) -> Option<SafeAction> {
    match wire {
        SAFE_HOLD => Some(SafeAction::Hold),
        SAFE_ZERO => Some(SafeAction::Zero),
        SAFE_STANDBY => Some(SafeAction::Standby),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tick_waits_on_a_restarted_observer_until_a_command_passed_its_boundary() {
        // Observer generation 1 owns the estimates from 390 on (a restart).
        let a = Activation {
            observer_from_seq: 390,
            observer_generation: 1,
            ..Activation::INITIAL
        };
        // Tick 390 takes command 389: the dead observer's estimate.
        assert!(!awaits_new_observer(&a, 390, Some(388)));
        // Tick 391 takes command 390: the new observer's first.
        assert!(awaits_new_observer(&a, 391, Some(389)));
        // Once a command from its estimates came, the loop has passed it.
        assert!(!awaits_new_observer(&a, 392, Some(390)));
        // Without a replaced observer, nothing to wait for.
        assert!(!awaits_new_observer(&Activation::INITIAL, 391, Some(389)));
    }

    #[test]
    fn the_settings_name_a_safe_action_or_change_nothing() {
        assert_eq!(safe_action(SAFE_HOLD), Some(SafeAction::Hold));
        assert_eq!(safe_action(SAFE_ZERO), Some(SafeAction::Zero));
        assert_eq!(safe_action(SAFE_STANDBY), Some(SafeAction::Standby));
        assert_eq!(safe_action(7), None);
    }
}
