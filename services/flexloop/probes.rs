//! The machine's own floors, measured in the same run as the loop: a
//! cyclictest-like timer probe, a raw iceoryx2 event ping-pong and a polling
//! one (both under the plant's priority and CPU), and the loop's chain by
//! hand over Unix sockets.

use flexloop_node::Role;
use flexloop_node::args::realtime_settings;
use flexloop_protocol::channels::events;
use flexloop_runtime::clock::{TickGrid, sleep_until};
use flexloop_runtime::latency::LatencyHistogram;
use flexloop_runtime::latency::QUANTILE_LABELS;
use flexloop_runtime::monotonic_ns;
use flexloop_runtime::realtime::{self, RealtimeSettings};
use flexloop_runtime::wait::{Readiness, wait_readable};
use flexloop_scenario::Scenario;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use serde_json::{Value, json};
use std::time::Duration;

/// The four floors, measured one after the other with the scenario's
/// priorities and CPUs at its rate.
pub struct Floors {
    pub timer_wakeup: LatencyHistogram,
    pub event_ping_pong: LatencyHistogram,
    pub polling_ping_pong: LatencyHistogram,
    pub socket_ring: LatencyHistogram,
}

impl Floors {
    /// JSON keys and table labels, in the table's order.
    pub const ROWS: [(&str, &str); 4] = [
        ("timer_wakeup", "probe: timer wake-up"),
        ("iceoryx2_event_ping_pong", "probe: iox2 ping-pong"),
        ("iceoryx2_polling_ping_pong", "probe: iox2 polling"),
        ("unix_socket_ring", "probe: socket ring"),
    ];

    pub fn measure(scenario: &Scenario, prefix: &str, samples: u64) -> Result<Self, String> {
        eprintln!(
            "flexloop bench: measuring the wake-up floor, an iceoryx2 event and a polling ping-pong, and a Unix-socket ring ({:.1} s each)",
            samples as f64 / scenario.timing.rate_hz
        );
        let period_ns = scenario.period_ns();
        let plant = realtime_settings(scenario, Role::Plant);
        let observer = realtime_settings(scenario, Role::Observer);
        let controller = realtime_settings(scenario, Role::Controller);
        Ok(Self {
            timer_wakeup: timer_probe(&plant, period_ns, samples),
            event_ping_pong: event_ping_pong(
                &format!("{prefix}probe_"),
                &plant,
                &controller,
                period_ns,
                samples,
            )?,
            polling_ping_pong: polling_ping_pong(
                &format!("{prefix}poll_"),
                &plant,
                period_ns,
                samples,
            )?,
            socket_ring: socket_ring(&plant, &observer, &controller, period_ns, samples)?,
        })
    }

    /// `{key: {count, p50_ns, …}}` for every floor, keys as in [`Self::ROWS`].
    pub fn json(&self) -> Value {
        let one = |h: &LatencyHistogram| {
            let p = h.percentiles();
            let mut m = serde_json::Map::new();
            m.insert("count".into(), json!(p.count));
            for (label, value) in QUANTILE_LABELS.iter().zip(p.values_ns) {
                m.insert(format!("{label}_ns"), json!(value));
            }
            Value::Object(m)
        };
        json!({
            "timer_wakeup": one(&self.timer_wakeup),
            "iceoryx2_event_ping_pong": one(&self.event_ping_pong),
            "iceoryx2_polling_ping_pong": one(&self.polling_ping_pong),
            "unix_socket_ring": one(&self.socket_ring),
        })
    }
}

/// Lateness of absolute wake-ups on the tick grid.
pub fn timer_probe(settings: &RealtimeSettings, period_ns: u64, samples: u64) -> LatencyHistogram {
    let settings = settings.clone();
    std::thread::spawn(move || {
        let _rt = realtime::apply("bench-probe", &settings);
        let grid = TickGrid::starting_in(period_ns, 1_000_000);
        let mut h = LatencyHistogram::new();
        for k in 0..samples {
            let t = grid.tick_ns(k);
            sleep_until(t);
            h.record_span(t, monotonic_ns());
        }
        h
    })
    .join()
    .unwrap_or_default()
}

/// Round trip of one iceoryx2 event each way between two threads, paced on
/// the tick grid: two process wake-ups, the floor of an event-driven hop.
pub fn event_ping_pong(
    prefix: &str,
    ping: &RealtimeSettings,
    pong: &RealtimeSettings,
    period_ns: u64,
    samples: u64,
) -> Result<LatencyHistogram, String> {
    let domain = flexloop_transport::Domain::new(prefix).map_err(|e| e.to_string())?;
    let open = |node: &Node<ipc::Service>, name: &str| {
        let service_name: ServiceName = name.try_into().map_err(|e| format!("{e:?}"))?;
        node.service_builder(&service_name)
            .event()
            .open_or_create()
            .map_err(|e| format!("{e:?}"))
    };
    let pong_settings = pong.clone();
    let pong_domain = domain.clone();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop_pong = stop.clone();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let pong_thread = std::thread::spawn(move || -> Result<(), String> {
        let node = pong_domain.node("pong").map_err(|e| e.to_string())?;
        let listener = open(&node, "probe/ping")?
            .listener_builder()
            .create()
            .map_err(|e| format!("{e:?}"))?;
        let notifier = open(&node, "probe/pong")?
            .notifier_builder()
            .default_event_id(EventId::new(events::SAMPLE))
            .create()
            .map_err(|e| format!("{e:?}"))?;
        let _rt = realtime::apply("bench-pong", &pong_settings);
        let _ = ready_tx.send(());
        // SAFETY: the fd stays owned by the listener.
        let fd = unsafe { listener.file_descriptor().native_handle() };
        while !stop_pong.load(std::sync::atomic::Ordering::Relaxed) {
            if let Ok(Readiness::Ready(_)) = wait_readable(&[fd], 50_000_000) {
                let _ = listener.try_wait(|_| {});
                let _ = notifier.notify();
            }
        }
        Ok(())
    });
    let node = domain.node("ping").map_err(|e| e.to_string())?;
    let listener = open(&node, "probe/pong")?
        .listener_builder()
        .create()
        .map_err(|e| format!("{e:?}"))?;
    let notifier = open(&node, "probe/ping")?
        .notifier_builder()
        .default_event_id(EventId::new(events::SAMPLE))
        .create()
        .map_err(|e| format!("{e:?}"))?;
    let _ = ready_rx.recv_timeout(Duration::from_secs(5));
    let result = std::thread::scope(|_| {
        let _rt = realtime::apply("bench-ping", ping);
        // SAFETY: the fd stays owned by the listener.
        let fd = unsafe { listener.file_descriptor().native_handle() };
        let grid = TickGrid::starting_in(period_ns, 1_000_000);
        let mut h = LatencyHistogram::new();
        for k in 0..samples {
            sleep_until(grid.tick_ns(k));
            let sent = monotonic_ns();
            if notifier.notify().is_err() {
                continue;
            }
            // Bounded: a lost pong costs at most one period of waiting.
            if let Ok(Readiness::Ready(_)) = wait_readable(&[fd], period_ns * 10) {
                let _ = listener.try_wait(|_| {});
                h.record_span(sent, monotonic_ns());
            }
        }
        h
    });
    // The ping ran on this thread: give its real-time settings back before
    // anything else runs here (threads spawned later would inherit them).
    realtime::step_down(ping.cpu);
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = pong_thread.join();
    drop((listener, notifier, node));
    flexloop_transport::remove_leftovers(prefix);
    Ok(result)
}

/// Round trip of one iceoryx2 sample each way between two threads that
/// poll their subscribers instead of waiting for an event: the shared-memory
/// floor without any wake-up, what a spinning (`dedicated-cores`) loop could
/// reach. The ping thread runs with `ping`'s settings on the tick grid and
/// spins only until its pong arrives (at most ten periods); the pong thread
/// spins for the whole probe, so it runs without real-time priority on
/// another CPU than the ping's (on a 2-CPU machine: the logger's).
pub fn polling_ping_pong(
    prefix: &str,
    ping: &RealtimeSettings,
    period_ns: u64,
    samples: u64,
) -> Result<LatencyHistogram, String> {
    let domain = flexloop_transport::Domain::new(prefix).map_err(|e| e.to_string())?;
    let open = |node: &Node<ipc::Service>, name: &str| {
        let service_name: ServiceName = name.try_into().map_err(|e| format!("{e:?}"))?;
        node.service_builder(&service_name)
            .publish_subscribe::<u64>()
            .open_or_create()
            .map_err(|e| format!("{e:?}"))
    };
    let ping_cpu = ping.cpu.unwrap_or(0);
    let pong_cpu = (0..realtime::online_cpus())
        .find(|cpu| *cpu != ping_cpu)
        .unwrap_or(ping_cpu);
    let pong_settings = RealtimeSettings {
        fifo_priority: None,
        cpu: Some(pong_cpu),
        ..ping.clone()
    };
    // Our ports first, so that the pong's publisher finds our subscriber.
    let node = domain.node("poll-ping").map_err(|e| e.to_string())?;
    let subscriber = open(&node, "probe/poll-pong")?
        .subscriber_builder()
        .create()
        .map_err(|e| format!("{e:?}"))?;
    let publisher = open(&node, "probe/poll-ping")?
        .publisher_builder()
        .create()
        .map_err(|e| format!("{e:?}"))?;
    let pong_domain = domain.clone();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop_pong = stop.clone();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel();
    let pong_thread = std::thread::spawn(move || -> Result<(), String> {
        let node = pong_domain.node("poll-pong").map_err(|e| e.to_string())?;
        let subscriber = open(&node, "probe/poll-ping")?
            .subscriber_builder()
            .create()
            .map_err(|e| format!("{e:?}"))?;
        let publisher = open(&node, "probe/poll-pong")?
            .publisher_builder()
            .create()
            .map_err(|e| format!("{e:?}"))?;
        publisher
            .update_connections()
            .map_err(|e| format!("{e:?}"))?;
        let _rt = realtime::apply("bench-poll-pong", &pong_settings);
        let _ = ready_tx.send(());
        let mut idle_polls = 0u32;
        while !stop_pong.load(std::sync::atomic::Ordering::Relaxed) {
            match subscriber.receive() {
                Ok(Some(sample)) => {
                    let _ = publisher.send_copy(*sample);
                }
                _ => {
                    // Checking the stop flag every poll would cost an atomic
                    // load per spin; every 4096th is plenty.
                    idle_polls = idle_polls.wrapping_add(1);
                    if idle_polls.is_multiple_of(4096) {
                        std::thread::yield_now();
                    }
                    std::hint::spin_loop();
                }
            }
        }
        Ok(())
    });
    let _ = ready_rx.recv_timeout(Duration::from_secs(5));
    // The pong's subscriber came after our publisher.
    publisher
        .update_connections()
        .map_err(|e| format!("{e:?}"))?;
    let result = std::thread::scope(|_| {
        let _rt = realtime::apply("bench-poll-ping", ping);
        let grid = TickGrid::starting_in(period_ns, 1_000_000);
        let mut h = LatencyHistogram::new();
        for k in 0..samples {
            sleep_until(grid.tick_ns(k));
            let sent = monotonic_ns();
            if publisher.send_copy(k).is_err() {
                continue;
            }
            let give_up = sent + 10 * period_ns;
            loop {
                match subscriber.receive() {
                    Ok(Some(sample)) if *sample == k => {
                        h.record_span(sent, monotonic_ns());
                        break;
                    }
                    Ok(Some(_)) => {}
                    Ok(None) if monotonic_ns() < give_up => std::hint::spin_loop(),
                    _ => break,
                }
            }
        }
        h
    });
    // The ping ran on this thread: give its real-time settings back before
    // anything else runs here (threads spawned later would inherit them).
    realtime::step_down(ping.cpu);
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = pong_thread.join();
    drop((subscriber, publisher, node));
    flexloop_transport::remove_leftovers(prefix);
    Ok(result)
}

/// The loop's chain by hand over Unix datagram sockets, as a program without
/// iceoryx2 would write it: three threads with the loop's CPU and priorities,
/// each blocking in `recv`; the plant sends a measurement-sized datagram on
/// the tick grid, the observer an estimate-sized one to the controller, the
/// controller a command-sized one back. Round trip as the loop's: from the
/// plant's send to the plant holding the command.
pub fn socket_ring(
    plant: &RealtimeSettings,
    observer: &RealtimeSettings,
    controller: &RealtimeSettings,
    period_ns: u64,
    samples: u64,
) -> Result<LatencyHistogram, String> {
    use flexloop_protocol::{Command, Estimate, Measurement};
    use std::os::unix::net::UnixDatagram;
    let pair = || UnixDatagram::pair().map_err(|e| format!("socketpair: {e}"));
    let (plant_out, observer_in) = pair()?;
    let (observer_out, controller_in) = pair()?;
    let (controller_out, plant_in) = pair()?;
    let idle = Some(Duration::from_millis(50));
    for s in [&observer_in, &controller_in] {
        s.set_read_timeout(idle).map_err(|e| e.to_string())?;
    }
    plant_in
        .set_read_timeout(Some(Duration::from_nanos(period_ns * 10)))
        .map_err(|e| e.to_string())?;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    // One stage: receive what the one before sent, send `reply` bytes on.
    let stage = |name: &'static str,
                 settings: &RealtimeSettings,
                 input: UnixDatagram,
                 output: UnixDatagram,
                 reply: usize| {
        let settings = settings.clone();
        let stop = stop.clone();
        std::thread::spawn(move || {
            let _rt = realtime::apply(name, &settings);
            let mut buffer = vec![0u8; 8192];
            let message = vec![1u8; reply];
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if input.recv(&mut buffer).is_ok() {
                    let _ = output.send(&message);
                }
            }
        })
    };
    let observer_thread = stage(
        "bench-socket-observer",
        observer,
        observer_in,
        observer_out,
        size_of::<Estimate>(),
    );
    let controller_thread = stage(
        "bench-socket-controller",
        controller,
        controller_in,
        controller_out,
        size_of::<Command>(),
    );
    let plant = plant.clone();
    let result = std::thread::spawn(move || {
        let _rt = realtime::apply("bench-socket-plant", &plant);
        let measurement = vec![1u8; size_of::<Measurement>()];
        let mut buffer = vec![0u8; 8192];
        let grid = TickGrid::starting_in(period_ns, 1_000_000);
        let mut h = LatencyHistogram::new();
        for k in 0..samples {
            sleep_until(grid.tick_ns(k));
            let sent = monotonic_ns();
            if plant_out.send(&measurement).is_err() {
                continue;
            }
            // Bounded by the read timeout: a lost reply costs ten periods.
            if plant_in.recv(&mut buffer).is_ok() {
                h.record_span(sent, monotonic_ns());
            }
        }
        h
    })
    .join()
    .map_err(|_| "the socket ring's plant thread panicked".to_string());
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = observer_thread.join();
    let _ = controller_thread.join();
    result
}
