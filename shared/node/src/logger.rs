//! The logger process: polls every channel, records every sample into the
//! MCAP sample file (with the supervisor's events and those the samples
//! show), counts gaps, keeps the latency histograms and publishes telemetry.
//!
//! It polls on its own 2 ms clock instead of waking on events, so the loop
//! processes never pay a notification for it; its queues hold 51 ms. It
//! hands the file a chunk every 100 ms; a write error (a full disk) stops
//! the recording, closes the file at its last complete chunk and is
//! reported, while the counting, the histograms and the loop go on.

use crate::args::{Role, ServiceArgs, realtime_settings};
use crate::run_metadata::run_metadata;
use crate::summary::{run_summary, write_json_atomically};
use crate::{NodeError, await_peers};
use flexloop_components::Recorder;
use flexloop_protocol::channels::{COMMAND, ESTIMATE, MEASUREMENT, TELEMETRY};
use flexloop_protocol::{Command, Estimate, Measurement, Telemetry, flags};
use flexloop_runtime::clock::sleep_until;
use flexloop_runtime::latency::{LoopLatencies, Metric};
use flexloop_runtime::{monotonic_ns, realtime, shutdown, usage};
use flexloop_transport::{Domain, Inlet, Outlet};
use hdrhistogram::serialization::V2DeflateSerializer;
use hdrhistogram::serialization::interval_log::{IntervalLogWriterBuilder, Tag};
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

const POLL_NS: u64 = 2_000_000;
const INTERVAL_NS: u64 = 1_000_000_000;
/// How often the sample file gets a chunk: at most this much is lost when
/// the logger is killed.
const FLUSH_NS: u64 = 100_000_000;
/// How often the supervisor's events file is read.
const EVENTS_POLL_NS: u64 = 50_000_000;
/// After the last measurement, how long to wait for its command and estimate.
const END_GRACE_NS: u64 = 500_000_000;

pub const SAMPLES_FILE: &str = "samples.mcap";
pub const HISTOGRAM_LOG: &str = "latency.hlog";
pub const SUMMARY_FILE: &str = "summary.json";
/// The supervisor's events (swap, crash, restart, ...), one JSON object a
/// line; the logger copies them into the sample file.
pub const EVENTS_FILE: &str = "events.jsonl";

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
    let samples_name = generation_file(SAMPLES_FILE, args.generation);
    let samples_path = args.run_dir.join(&samples_name);
    let hlog_path = args
        .run_dir
        .join(generation_file(HISTOGRAM_LOG, args.generation));
    let log_time_offset_ns = wall_clock_ns().saturating_sub(monotonic_ns());
    let mut recorder =
        Recorder::create(&samples_path, log_time_offset_ns).map_err(io_err(&samples_path))?;
    let mut hlog_file = std::fs::File::create(&hlog_path).map_err(io_err(&hlog_path))?;
    let mut serializer = V2DeflateSerializer::new();
    let mut hlog = Some(
        IntervalLogWriterBuilder::new()
            .add_comment(&format!(
                "flexloop {} latencies in ns, scenario {}",
                env!("CARGO_PKG_VERSION"),
                scenario.name
            ))
            .with_base_time(SystemTime::now())
            .begin_log_with(&mut hlog_file, &mut serializer)
            .map_err(io_err(&hlog_path))?,
    );

    // Locked before the ports exist, so their memory is populated now (see plant).
    let rt = realtime_settings(&scenario, Role::Logger);
    let memory = realtime::apply(Role::Logger.name(), &rt.memory_part());
    let domain = Domain::new(&args.prefix)?;
    let node = domain.node("logger")?;
    let telemetry = Outlet::<Telemetry>::open(&node, &TELEMETRY)?;
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
        return Ok(());
    }
    estimates.connect()?;
    commands.connect()?;
    // Measurements last: the plant starts once it sees this subscriber, and by
    // then the logger must already hear every other channel.
    let measurements = Inlet::<Measurement>::open_polling(
        &node,
        &MEASUREMENT,
        MEASUREMENT.qos.logger_buffer_size,
    )?;
    measurements.connect()?;
    // Priority and CPU only now, connected: see `RealtimeSettings::scheduling_part`.
    let scheduling = realtime::apply(Role::Logger.name(), &rt.scheduling_part());
    recorder.metadata(run_metadata(
        args,
        &scenario,
        log_time_offset_ns,
        &[&memory, &scheduling],
    ));
    recorder.event(
        monotonic_ns(),
        &format!(
            r#"{{"source":"logger","kind":"recording-start","generation":{},"file":"{samples_name}"}}"#,
            args.generation
        ),
    );
    recorder.flush();
    let mut supervisor_events = EventsTail::new(args.run_dir.join(EVENTS_FILE));

    let start_ns = monotonic_ns();
    let mut previous = LoopLatencies::new();
    let mut next_interval_ns = start_ns + INTERVAL_NS;
    let mut next_flush_ns = start_ns + FLUSH_NS;
    let mut next_events_ns = start_ns;
    let mut interval_start = Duration::ZERO;
    let mut end_seq: Option<u64> = None;
    let mut end_seen_ns = 0u64;
    let mut next_poll = start_ns;
    loop {
        let stopping = shutdown::requested();
        while let Some(m) = measurements.receive()? {
            recorder.measurement(&m);
            if m.flags & flags::END_OF_RUN != 0 && end_seq.is_none() {
                end_seq = Some(m.seq);
                end_seen_ns = monotonic_ns();
            }
        }
        while let Some(e) = estimates.receive()? {
            recorder.estimate(&e);
        }
        while let Some(c) = commands.receive()? {
            recorder.command(&c);
        }
        let now = monotonic_ns();
        let ending = stopping || end_seq.is_some();
        if now >= next_events_ns || ending {
            supervisor_events.read(|line| recorder.event(now, &supervisor_event(line)));
            next_events_ns = now + EVENTS_POLL_NS;
        }
        if now >= next_flush_ns || ending {
            recorder.flush();
            next_flush_ns = now + FLUSH_NS;
        }
        if let Some(failure) = recorder.new_failure() {
            eprintln!(
                "flexloop-logger: {}: {}; recording stopped, the file ends at its last complete chunk ({}); the loop goes on",
                samples_path.display(),
                failure.error,
                match &failure.closed {
                    Ok(c) => format!("{} messages kept", c.messages),
                    Err(e) => format!("could not close it: {e}"),
                }
            );
        }
        if now >= next_interval_ns || ending {
            let elapsed = Duration::from_nanos(now - start_ns);
            if let Some(writer) = &mut hlog
                && let Err(e) = write_interval(
                    writer,
                    &recorder.latencies,
                    &previous,
                    interval_start,
                    elapsed - interval_start,
                )
            {
                eprintln!(
                    "flexloop-logger: {}: {e}; latency log stopped (summary.json keeps the totals); the loop goes on",
                    hlog_path.display()
                );
                hlog = None;
            }
            previous = recorder.latencies.clone();
            interval_start = elapsed;
            next_interval_ns = now + INTERVAL_NS;
            publish_telemetry(&telemetry, &recorder)?;
        }
        if let Some(last) = end_seq {
            let complete = recorder.commands.last_seq.is_some_and(|s| s >= last)
                && recorder.estimates.last_seq.is_some_and(|s| s > last);
            if complete || now - end_seen_ns > END_GRACE_NS {
                break;
            }
        }
        if stopping {
            break;
        }
        next_poll += POLL_NS;
        sleep_until(next_poll.max(monotonic_ns()));
    }
    let hlog_complete = hlog.is_some();
    drop(hlog);
    let now = monotonic_ns();
    supervisor_events.read(|line| recorder.event(now, &supervisor_event(line)));
    let reason = if end_seq.is_some() {
        "end-of-run"
    } else {
        "stopped"
    };
    recorder.event(
        now,
        &format!(
            r#"{{"source":"logger","kind":"recording-end","seq":{},"reason":"{reason}","gaps":{}}}"#,
            recorder.last_measurement.map_or(0, |m| m.seq),
            recorder.total_gaps()
        ),
    );
    let complete = recorder.finish(now).is_some();
    if let (false, Some(failure)) = (complete, recorder.new_failure()) {
        eprintln!(
            "flexloop-logger: {}: {}; the file may lack its end (`flexloop` repairs it when the run ends)",
            samples_path.display(),
            failure.error
        );
    }
    let mut summary = run_summary(&recorder, &scenario, period_ns, usage::process_cpu_ns());
    summary["recording"]["file"] = samples_name.clone().into();
    summary["recording"]["latency_log_complete"] = hlog_complete.into();
    let gaps = recorder.total_gaps();
    let summary_path = args.run_dir.join(SUMMARY_FILE);
    write_json_atomically(&summary_path, &summary).map_err(io_err(&summary_path))?;
    if gaps > 0 {
        eprintln!("flexloop-logger: {gaps} samples never reached the log (see {SUMMARY_FILE})");
    }
    Ok(())
}

fn wall_clock_ns() -> u64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// A line of the supervisor's events file as a `/events` message.
fn supervisor_event(line: &str) -> String {
    match serde_json::from_str::<serde_json::Value>(line) {
        Ok(serde_json::Value::Object(mut map)) => {
            map.insert("source".into(), "supervisor".into());
            serde_json::Value::Object(map).to_string()
        }
        _ => serde_json::json!({"source": "supervisor", "kind": "unreadable", "detail": line})
            .to_string(),
    }
}

/// Reads the lines appended to a file since the last read (complete lines
/// only: the writer may be in the middle of one).
struct EventsTail {
    path: PathBuf,
    offset: u64,
    partial: Vec<u8>,
}

impl EventsTail {
    fn new(path: PathBuf) -> Self {
        Self {
            path,
            offset: 0,
            partial: Vec::new(),
        }
    }

    fn read(&mut self, mut each: impl FnMut(&str)) {
        // No file yet: no events yet.
        let Ok(mut file) = std::fs::File::open(&self.path) else {
            return;
        };
        if file.seek(SeekFrom::Start(self.offset)).is_err() {
            return;
        }
        let Ok(n) = file.read_to_end(&mut self.partial) else {
            return;
        };
        self.offset += n as u64;
        let Some(end) = self.partial.iter().rposition(|b| *b == b'\n') else {
            return;
        };
        for line in String::from_utf8_lossy(&self.partial[..end]).lines() {
            if !line.trim().is_empty() {
                each(line);
            }
        }
        self.partial.drain(..=end);
    }
}

/// `samples.mcap` for the first logger, `samples.g2.mcap` for generation 2.
pub fn generation_file(name: &str, generation: u32) -> String {
    match (generation, name.rsplit_once('.')) {
        (0, _) | (_, None) => name.to_string(),
        (g, Some((stem, ext))) => format!("{stem}.g{g}.{ext}"),
    }
}

fn write_interval<W: std::io::Write>(
    hlog: &mut hdrhistogram::serialization::interval_log::IntervalLogWriter<
        '_,
        '_,
        W,
        V2DeflateSerializer,
    >,
    current: &LoopLatencies,
    previous: &LoopLatencies,
    start: Duration,
    duration: Duration,
) -> std::io::Result<()> {
    for metric in Metric::ALL {
        let mut interval = current.get(metric).histogram().clone();
        interval
            .subtract(previous.get(metric).histogram())
            .map_err(|e| std::io::Error::other(format!("{e:?}")))?;
        if interval.is_empty() {
            continue;
        }
        hlog.write_histogram(&interval, start, duration, Tag::new(metric.name()))
            .map_err(|e| std::io::Error::other(format!("{e:?}")))?;
    }
    Ok(())
}

fn publish_telemetry(out: &Outlet<Telemetry>, recorder: &Recorder) -> Result<(), NodeError> {
    let m = recorder.last_measurement.unwrap_or_default();
    out.publish(|t| {
        t.published_ns = monotonic_ns();
        t.seq = m.seq;
        t.samples = recorder.measurements.samples;
        t.misses = m.misses;
        t.late_commands = m.late_commands;
        t.stalled_ticks = m.stalled_ticks;
        t.stall_misses = m.stall_misses;
        t.gaps = recorder.total_gaps();
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
