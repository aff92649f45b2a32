//! The machine's own floors, measured in the same run as the loop:
//! a cyclictest-like timer probe and a raw iceoryx2 event ping-pong, both
//! under the plant's priority and CPU.

use flexloop_protocol::channels::events;
use flexloop_runtime::clock::{TickGrid, sleep_until};
use flexloop_runtime::latency::LatencyHistogram;
use flexloop_runtime::monotonic_ns;
use flexloop_runtime::realtime::{self, RealtimeSettings};
use flexloop_runtime::wait::{Readiness, wait_readable};
use iceoryx2::prelude::*;
use std::time::Duration;

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
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = pong_thread.join();
    drop((listener, notifier, node));
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
