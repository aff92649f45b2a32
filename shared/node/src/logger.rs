//! The logger process: polls every channel, records every sample into the
//! MCAP sample file (with the supervisor's events and those the samples
//! show), counts gaps, keeps the latency histograms and publishes telemetry.
//!
//! It polls on its own 2 ms clock instead of waking on events, so the loop
//! processes never pay a notification for it; its queues hold 51 ms. The
//! files are written by a thread of their own ([`crate::recording`]): a
//! chunk every 100 ms; a write error (a full disk) stops the recording,
//! closes the file at its last complete chunk and is reported, while the
//! counting, the histograms and the loop go on.

use crate::args::{Role, ServiceArgs, realtime_settings};
use crate::handover::ActivationView;
use crate::in_order::{InOrder, STAGED};
use crate::recording::{self, Files, Item, Queue};
use crate::run_metadata::run_metadata;
use crate::summary::run_summary;
use crate::{NodeError, await_peers};
use flexloop_protocol::channels::{COMMAND, ESTIMATE, LOGGER_PROGRESS, MEASUREMENT, TELEMETRY};
use flexloop_protocol::{Command, Estimate, Measurement, Telemetry, flags};
use flexloop_recording::event_message::{EventMessage, LoggerEvent};
use flexloop_recording::{Recorder, SampleWriter};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::json::write_json_atomically;
use flexloop_runfiles::run_dir::generation_file;
use flexloop_runfiles::summary::Recording;
use flexloop_runtime::clock::sleep_until;
use flexloop_runtime::latency::Metric;
use flexloop_runtime::{monotonic_ns, realtime, shutdown, usage};
use flexloop_transport::{Domain, Inlet, Outlet};
use std::path::Path;
use std::time::{Duration, SystemTime};

const POLL_NS: u64 = 2_000_000;
const INTERVAL_NS: u64 = 1_000_000_000;
/// After the last measurement, how long to wait for its command and estimate.
const END_GRACE_NS: u64 = 500_000_000;

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> NodeError + '_ {
    move |error| NodeError::Io {
        path: path.display().to_string(),
        error,
    }
}

pub fn run(args: &ServiceArgs) -> Result<(), NodeError> {
    let (scenario, _design) = args.load()?;
    let period_ns = scenario.period_ns();
    // A file-size limit then fails a write (handled like a full disk)
    // instead of killing the logger.
    // SAFETY: ignoring a signal has no preconditions.
    unsafe { libc::signal(libc::SIGXFSZ, libc::SIG_IGN) };
    // Files first: an unwritable run directory fails before the loop starts.
    // A restarted logger (generation > 0) never touches its predecessor's
    // files, which may end in a torn chunk.
    let run_dir = RunDir::new(&args.run_dir);
    let samples_name = generation_file(RunDir::SAMPLES, args.generation);
    let samples_path = run_dir.samples(args.generation);
    let hlog_path = run_dir.histogram_log(args.generation);
    let log_time_offset_ns = wall_clock_ns().saturating_sub(monotonic_ns());
    let samples =
        SampleWriter::create(&samples_path, log_time_offset_ns).map_err(io_err(&samples_path))?;
    let hlog = std::fs::File::create(&hlog_path).map_err(io_err(&hlog_path))?;

    // Locked before the ports exist, so their memory is populated now (see plant).
    let rt = realtime_settings(&scenario, Role::Logger);
    let memory = realtime::apply(Role::Logger.name(), &rt.memory_part());
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node("logger")?;
    let telemetry = Outlet::<Telemetry>::open(&node, &TELEMETRY)?;
    let progress = Outlet::<u64>::open(&node, &LOGGER_PROGRESS)?;
    let estimates =
        Inlet::<Estimate>::open_polling(&node, &ESTIMATE, ESTIMATE.qos.logger_buffer_size)?;
    let commands = Inlet::<Command>::open_polling(&node, &COMMAND, COMMAND.qos.logger_buffer_size)?;
    if !await_peers(
        || Ok(estimates.publishers() >= 1 && commands.publishers() >= 1),
        || {
            format!(
                "{} estimate publishers (observer), {} command publishers (controller)",
                estimates.publishers(),
                commands.publishers()
            )
        },
    )? {
        // Stopped before the loop started: the sample file finishes empty.
        return Ok(());
    }
    estimates.connect()?;
    commands.connect()?;
    let mut activation = ActivationView::open(&node)?;
    activation.connect()?;
    // Measurements last: the plant starts once it sees this subscriber, and by
    // then the logger must already hear every other channel.
    let measurements = Inlet::<Measurement>::open_polling(
        &node,
        &MEASUREMENT,
        MEASUREMENT.qos.logger_buffer_size,
    )?;
    measurements.connect()?;
    // The writer starts before this thread takes its priority: it stays a
    // normal thread (off the loop's CPU, as this one was started), which
    // this one preempts whenever it wakes to drain.
    let (queue, writer) = recording::spawn(Files {
        samples,
        samples_path: samples_path.clone(),
        hlog,
        hlog_path,
        run_dir: args.run_dir.clone(),
        scenario_name: scenario.name.clone(),
    })
    .map_err(io_err(&samples_path))?;
    let mut recorder = Recorder::new(queue);
    // Priority and CPU only now, connected: see `RealtimeSettings::scheduling_part`.
    let scheduling = realtime::apply(Role::Logger.name(), &rt.scheduling_part());
    recorder.sink().send_blocking(Item::Metadata(run_metadata(
        args,
        &scenario,
        log_time_offset_ns,
        &[&memory, &scheduling],
    )));
    recorder.event(
        monotonic_ns(),
        EventMessage::Logger(LoggerEvent::RecordingStart {
            generation: args.generation,
            file: samples_name.clone(),
        }),
    );
    let start_ns = monotonic_ns();
    let mut inlets = Inlets {
        measurements: &measurements,
        estimates: &estimates,
        commands: &commands,
        activation: &mut activation,
        telemetry: &telemetry,
        progress: &progress,
    };
    let drained = drain(&mut recorder, &mut inlets, start_ns);

    // Whatever ended the draining, the files are finished.
    let now = monotonic_ns();
    recorder.finish(now);
    let reason = match &drained {
        Ok(Some(_)) => "end-of-run".to_string(),
        Ok(None) => "stopped".to_string(),
        Err(e) => format!("error: {e}"),
    };
    let end = LoggerEvent::RecordingEnd {
        seq: recorder.last_measurement.map_or(0, |m| m.seq),
        reason,
        gaps: recorder.total_gaps(),
    };
    recorder.event(now, EventMessage::Logger(end));
    let totals = Box::new(recorder.latencies.clone());
    let queue = recorder.sink();
    queue.send_blocking(Item::Interval {
        totals,
        elapsed: Duration::from_nanos(now - start_ns),
    });
    queue.close(now);
    let dropped_in_logger = queue.dropped_in_logger();
    let outcome = writer
        .join()
        .map_err(|_| NodeError::Peer("the logger's writer thread panicked".into()))?;
    let recording = Recording {
        sample_file: outcome.sample_file,
        file: samples_name,
        latency_log_complete: outcome.latency_log_complete,
        dropped_in_logger,
    };
    let mut summary = run_summary(
        &recorder,
        &scenario,
        period_ns,
        usage::process_cpu_ns(),
        recording,
    );
    // Gaps: everything the file lacks, also what the writer had no room for.
    for (gaps, dropped) in summary.gaps.iter_mut().zip(recorder.sink_ref().dropped) {
        *gaps += dropped;
    }
    let gaps = missing(&recorder);
    // A restarted logger accounts for its own share; `flexloop` joins the
    // generations into summary.json once the run is over.
    let summary_path = run_dir.generation_summary(args.generation);
    write_json_atomically(&summary_path, &summary)?;
    if gaps > 0 {
        eprintln!(
            "flexloop-logger: {gaps} samples never reached the log (see {})",
            summary_path.display()
        );
    }
    drained.map(|_| ())
}

/// The ports the draining reads from and publishes to.
struct Inlets<'a> {
    measurements: &'a Inlet<Measurement>,
    estimates: &'a Inlet<Estimate>,
    commands: &'a Inlet<Command>,
    /// Which generation owns which sample: the commands of others are foreign.
    activation: &'a mut ActivationView,
    telemetry: &'a Outlet<Telemetry>,
    progress: &'a Outlet<u64>,
}

/// Drains every channel every 2 ms until the run ends (returns the last
/// tick) or a stop is requested (`None`).
fn drain(
    recorder: &mut Recorder<Queue>,
    ports: &mut Inlets<'_>,
    start_ns: u64,
) -> Result<Option<u64>, NodeError> {
    let mut next_interval_ns = start_ns + INTERVAL_NS;
    let mut end_seq: Option<u64> = None;
    let mut end_seen_ns = 0u64;
    let mut next_poll = start_ns;
    let mut estimates = InOrder::<Estimate>::new(STAGED);
    let mut commands = InOrder::<Command>::new(STAGED);
    let mut progress_sent: Option<u64> = None;
    loop {
        let stopping = shutdown::requested();
        while let Some(m) = ports.measurements.receive()? {
            recorder.measurement(&m);
            if m.flags & flags::END_OF_RUN != 0 && end_seq.is_none() {
                end_seq = Some(m.seq);
                end_seen_ns = monotonic_ns();
            }
        }
        // Two publishers during a hand-over: in sequence order (see `InOrder`).
        estimates.drain(ports.estimates, |e| e.seq, |e| recorder.estimate(e))?;
        let activation = ports.activation.refresh()?;
        commands.drain(
            ports.commands,
            |c| c.seq,
            |c| {
                if activation.counts_command(c) {
                    recorder.command(c);
                } else {
                    recorder.foreign_command();
                }
            },
        )?;
        if let Some(m) = recorder.last_measurement
            && Some(m.seq) != progress_sent
        {
            ports.progress.publish(|p| *p = m.seq)?;
            progress_sent = Some(m.seq);
        }
        let now = monotonic_ns();
        if now >= next_interval_ns {
            // Once a second: the histograms' copy is the only allocation here.
            let totals = Box::new(recorder.latencies.clone());
            recorder
                .sink()
                .interval(totals, Duration::from_nanos(now - start_ns));
            next_interval_ns = now + INTERVAL_NS;
            publish_telemetry(ports.telemetry, recorder)?;
        }
        if let Some(last) = end_seq {
            let complete = recorder.commands.last_seq.is_some_and(|s| s >= last)
                && recorder.estimates.last_seq.is_some_and(|s| s > last);
            if complete || now - end_seen_ns > END_GRACE_NS {
                publish_telemetry(ports.telemetry, recorder)?;
                return Ok(end_seq);
            }
        }
        if stopping {
            publish_telemetry(ports.telemetry, recorder)?;
            return Ok(None);
        }
        next_poll += POLL_NS;
        sleep_until(next_poll.max(monotonic_ns()));
    }
}

/// Samples the file lacks: never received, or no room in the writer's queue.
fn missing(recorder: &Recorder<Queue>) -> u64 {
    recorder.total_gaps() + recorder.sink_ref().dropped.iter().sum::<u64>()
}

fn wall_clock_ns() -> u64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

fn publish_telemetry(out: &Outlet<Telemetry>, recorder: &Recorder<Queue>) -> Result<(), NodeError> {
    let m = recorder.last_measurement.unwrap_or_default();
    out.publish(|t| {
        t.published_ns = monotonic_ns();
        t.seq = m.seq;
        t.samples = recorder.measurements.samples;
        t.misses = m.misses;
        t.late_commands = m.late_commands;
        t.stalled_ticks = m.stalled_ticks;
        t.stall_misses = m.stall_misses;
        t.gaps = missing(recorder);
        t.stale_estimates = recorder.stale_estimates;
        t.round_trip = recorder
            .latencies
            .get(Metric::RoundTrip)
            .percentiles()
            .values_ns;
        t.tick_lateness = recorder
            .latencies
            .get(Metric::TickLateness)
            .percentiles()
            .values_ns;
        t.role = 4;
        t.pid = std::process::id();
    })?;
    Ok(())
}
