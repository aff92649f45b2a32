//! The machine's own floors, measured in the same run as the loop: a
//! cyclictest-like timer probe, a raw iceoryx2 event ping-pong and a polling
//! one (both under the plant's priority and CPU), and the loop's chain by
//! hand over Unix sockets.

use anyhow::{Context, anyhow};
use flexloop_node::Role;
use flexloop_node::args::realtime_settings;
use flexloop_node::summary::floor_histogram;
use flexloop_protocol::channels::events;
use flexloop_runtime::clock::{TickGrid, sleep_until};
use flexloop_runtime::latency::LatencyHistogram;
use flexloop_runtime::monotonic_ns;
use flexloop_runtime::realtime::{self, RealtimeSettings};
use flexloop_runtime::wait::{Readiness, wait_readable};
use flexloop_scenario::Scenario;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Receiver;
use std::thread::JoinHandle;
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
    pub fn measure(scenario: &Scenario, prefix: &str, samples: u64) -> anyhow::Result<Self> {
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

    /// The floors as `bench.json` and `sweep.json` keep them.
    pub fn file(&self) -> flexloop_runfiles::bench::Floors {
        flexloop_runfiles::bench::Floors {
            timer_wakeup: floor_histogram(&self.timer_wakeup),
            iceoryx2_event_ping_pong: floor_histogram(&self.event_ping_pong),
            iceoryx2_polling_ping_pong: floor_histogram(&self.polling_ping_pong),
            unix_socket_ring: floor_histogram(&self.socket_ring),
        }
    }
}

/// The pong side of a ping-pong probe: a thread that set up its own ports
/// and answers until stopped.
struct Pong {
    stop: Arc<AtomicBool>,
    ready: Receiver<()>,
    thread: JoinHandle<anyhow::Result<()>>,
}

impl Pong {
    /// Starts `serve` on a thread of its own; it gets its node, a `ready`
    /// to call once its ports exist, and the flag that stops it.
    fn spawn(
        domain: &flexloop_transport::Domain,
        node_name: &'static str,
        serve: impl FnOnce(Node<ipc::Service>, &dyn Fn(), &AtomicBool) -> anyhow::Result<()>
        + Send
        + 'static,
    ) -> Self {
        let domain = domain.clone();
        let stop = Arc::new(AtomicBool::new(false));
        let stop_pong = stop.clone();
        let (ready_tx, ready) = std::sync::mpsc::channel();
        let thread = std::thread::spawn(move || {
            let node = domain.node(node_name)?;
            serve(
                node,
                &|| {
                    let _ = ready_tx.send(());
                },
                &stop_pong,
            )
        });
        Self {
            stop,
            ready,
            thread,
        }
    }

    /// Waits (bounded) until the pong's ports exist.
    fn await_ready(&self) {
        let _ = self.ready.recv_timeout(Duration::from_secs(5));
    }

    /// Runs the ping over its `ports` on this thread under `settings`,
    /// gives the settings back (threads spawned here later would inherit
    /// them), stops the pong, then closes the ports and removes what the
    /// probe left under `prefix`.
    fn ping<P, T>(
        self,
        name: &str,
        settings: &RealtimeSettings,
        prefix: &str,
        ports: P,
        ping: impl FnOnce(&P) -> T,
    ) -> T {
        let result = {
            let _rt = realtime::apply(name, settings);
            ping(&ports)
        };
        realtime::step_down(settings.cpu);
        self.stop.store(true, Ordering::Relaxed);
        let _ = self.thread.join();
        drop(ports);
        flexloop_transport::remove_leftovers(prefix);
        result
    }
}

/// On the tick grid: for sample k, `round_trip(k)` sends and waits (bounded)
/// for the answer; the span from the send to its answer is recorded, and a
/// failed send or a lost answer (false) records nothing.
fn round_trips(
    period_ns: u64,
    samples: u64,
    mut round_trip: impl FnMut(u64) -> bool,
) -> LatencyHistogram {
    let grid = TickGrid::starting_in(period_ns, 1_000_000);
    let mut h = LatencyHistogram::new();
    for k in 0..samples {
        sleep_until(grid.tick_ns(k));
        let sent = monotonic_ns();
        if round_trip(k) {
            h.record_span(sent, monotonic_ns());
        }
    }
    h
}

fn port_error(e: impl std::fmt::Debug) -> anyhow::Error {
    anyhow!("{e:?}")
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
) -> anyhow::Result<LatencyHistogram> {
    let domain = flexloop_transport::Domain::new(prefix)?;
    fn open(
        node: &Node<ipc::Service>,
        name: &str,
    ) -> anyhow::Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>> {
        let service_name: ServiceName = name.try_into().map_err(port_error)?;
        node.service_builder(&service_name)
            .event()
            .open_or_create()
            .map_err(port_error)
    }
    let pong_settings = pong.clone();
    let pong = Pong::spawn(&domain, "pong", move |node, ready, stop| {
        let listener = open(&node, "probe/ping")?
            .listener_builder()
            .create()
            .map_err(port_error)?;
        let notifier = open(&node, "probe/pong")?
            .notifier_builder()
            .default_event_id(EventId::new(events::SAMPLE))
            .create()
            .map_err(port_error)?;
        let _rt = realtime::apply("bench-pong", &pong_settings);
        ready();
        // SAFETY: the fd stays owned by the listener.
        let fd = unsafe { listener.file_descriptor().native_handle() };
        while !stop.load(Ordering::Relaxed) {
            if let Ok(Readiness::Ready(_)) = wait_readable(&[fd], 50_000_000) {
                let _ = listener.try_wait(|_| {});
                let _ = notifier.notify();
            }
        }
        Ok(())
    });
    let node = domain.node("ping")?;
    let listener = open(&node, "probe/pong")?
        .listener_builder()
        .create()
        .map_err(port_error)?;
    let notifier = open(&node, "probe/ping")?
        .notifier_builder()
        .default_event_id(EventId::new(events::SAMPLE))
        .create()
        .map_err(port_error)?;
    pong.await_ready();
    let ports = (listener, notifier, node);
    let result = pong.ping(
        "bench-ping",
        ping,
        prefix,
        ports,
        |(listener, notifier, _)| {
            // SAFETY: the fd stays owned by the listener.
            let fd = unsafe { listener.file_descriptor().native_handle() };
            round_trips(period_ns, samples, |_| {
                if notifier.notify().is_err() {
                    return false;
                }
                // Bounded: a lost pong costs at most ten periods of waiting.
                let answered = matches!(
                    wait_readable(&[fd], period_ns * 10),
                    Ok(Readiness::Ready(_))
                );
                if answered {
                    let _ = listener.try_wait(|_| {});
                }
                answered
            })
        },
    );
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
) -> anyhow::Result<LatencyHistogram> {
    let domain = flexloop_transport::Domain::new(prefix)?;
    fn open(
        node: &Node<ipc::Service>,
        name: &str,
    ) -> anyhow::Result<
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, u64, ()>,
    > {
        let service_name: ServiceName = name.try_into().map_err(port_error)?;
        node.service_builder(&service_name)
            .publish_subscribe::<u64>()
            .open_or_create()
            .map_err(port_error)
    }
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
    let node = domain.node("poll-ping")?;
    let subscriber = open(&node, "probe/poll-pong")?
        .subscriber_builder()
        .create()
        .map_err(port_error)?;
    let publisher = open(&node, "probe/poll-ping")?
        .publisher_builder()
        .create()
        .map_err(port_error)?;
    let pong = Pong::spawn(&domain, "poll-pong", move |node, ready, stop| {
        let subscriber = open(&node, "probe/poll-ping")?
            .subscriber_builder()
            .create()
            .map_err(port_error)?;
        let publisher = open(&node, "probe/poll-pong")?
            .publisher_builder()
            .create()
            .map_err(port_error)?;
        publisher.update_connections().map_err(port_error)?;
        let _rt = realtime::apply("bench-poll-pong", &pong_settings);
        ready();
        let mut idle_polls = 0u32;
        while !stop.load(Ordering::Relaxed) {
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
    pong.await_ready();
    // The pong's subscriber came after our publisher.
    publisher.update_connections().map_err(port_error)?;
    let ports = (subscriber, publisher, node);
    let result = pong.ping(
        "bench-poll-ping",
        ping,
        prefix,
        ports,
        |(subscriber, publisher, _)| {
            round_trips(period_ns, samples, |k| {
                if publisher.send_copy(k).is_err() {
                    return false;
                }
                let give_up = monotonic_ns() + 10 * period_ns;
                loop {
                    match subscriber.receive() {
                        Ok(Some(sample)) if *sample == k => return true,
                        Ok(Some(_)) => {}
                        Ok(None) if monotonic_ns() < give_up => std::hint::spin_loop(),
                        _ => return false,
                    }
                }
            })
        },
    );
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
) -> anyhow::Result<LatencyHistogram> {
    use flexloop_protocol::{Command, Estimate, Measurement};
    use std::os::unix::net::UnixDatagram;
    let pair = || UnixDatagram::pair().context("socketpair");
    let (plant_out, observer_in) = pair()?;
    let (observer_out, controller_in) = pair()?;
    let (controller_out, plant_in) = pair()?;
    let idle = Some(Duration::from_millis(50));
    for s in [&observer_in, &controller_in] {
        s.set_read_timeout(idle)?;
    }
    plant_in.set_read_timeout(Some(Duration::from_nanos(period_ns * 10)))?;
    let stop = Arc::new(AtomicBool::new(false));
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
            while !stop.load(Ordering::Relaxed) {
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
        round_trips(period_ns, samples, |_| {
            // Bounded by the read timeout: a lost reply costs ten periods.
            plant_out.send(&measurement).is_ok() && plant_in.recv(&mut buffer).is_ok()
        })
    })
    .join()
    .map_err(|_| anyhow!("the socket ring's plant thread panicked"));
    stop.store(true, Ordering::Relaxed);
    let _ = observer_thread.join();
    let _ = controller_thread.join();
    result
}
