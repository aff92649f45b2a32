//! The logger process: polls every channel, records every sample, counts
//! gaps, keeps the latency histograms and publishes telemetry.
//!
//! It polls on its own 2 ms clock instead of waking on events, so the loop
//! processes never pay a notification for it; its queues hold 51 ms.

use crate::args::{Role, ServiceArgs, realtime_settings};
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
use std::path::Path;
use std::time::{Duration, SystemTime};

const POLL_NS: u64 = 2_000_000;
const INTERVAL_NS: u64 = 1_000_000_000;
/// After the last measurement, how long to wait for its command and estimate.
const END_GRACE_NS: u64 = 500_000_000;

pub const SAMPLES_FILE: &str = "samples.flxlog";
pub const HISTOGRAM_LOG: &str = "latency.hlog";
pub const SUMMARY_FILE: &str = "summary.json";

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> NodeError + '_ {
    move |error| NodeError::Io {
        path: path.display().to_string(),
        error,
    }
}

pub fn run(args: &ServiceArgs) -> Result<(), NodeError> {
    let (scenario, _design) = args.load()?;
    let period_ns = scenario.period_ns();
    // Files first: an unwritable run directory fails before the loop starts.
    // A restarted logger (generation > 0) never touches its predecessor's
    // files, which may end in a torn record.
    let samples_path = args
        .run_dir
        .join(generation_file(SAMPLES_FILE, args.generation));
    let hlog_path = args
        .run_dir
        .join(generation_file(HISTOGRAM_LOG, args.generation));
    let metadata = serde_json::json!({
        "scenario": scenario.name,
        "scenario_file": scenario.source.display().to_string(),
        "mode": scenario.timing.mode.as_str(),
        "rate_hz": scenario.timing.rate_hz,
        "prefix": args.prefix,
        "version": env!("CARGO_PKG_VERSION"),
    });
    let mut recorder =
        Recorder::create(&samples_path, &metadata.to_string()).map_err(io_err(&samples_path))?;
    let mut hlog_file = std::fs::File::create(&hlog_path).map_err(io_err(&hlog_path))?;
    let mut serializer = V2DeflateSerializer::new();
    let mut hlog = IntervalLogWriterBuilder::new()
        .add_comment(&format!(
            "flexloop {} latencies in ns, scenario {}",
            env!("CARGO_PKG_VERSION"),
            scenario.name
        ))
        .with_base_time(SystemTime::now())
        .begin_log_with(&mut hlog_file, &mut serializer)
        .map_err(io_err(&hlog_path))?;

    // Locked before the ports exist, so their memory is populated now (see plant).
    let rt = realtime_settings(&scenario, Role::Logger);
    let _memory = realtime::apply(Role::Logger.name(), &rt.memory_part());
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
    let _scheduling = realtime::apply(Role::Logger.name(), &rt.scheduling_part());

    let start_ns = monotonic_ns();
    let mut previous = LoopLatencies::new();
    let mut next_interval_ns = start_ns + INTERVAL_NS;
    let mut interval_start = Duration::ZERO;
    let mut end_seq: Option<u64> = None;
    let mut end_seen_ns = 0u64;
    let mut next_poll = start_ns;
    loop {
        let stopping = shutdown::requested();
        let write = |r: std::io::Result<()>| r.map_err(io_err(&samples_path));
        while let Some(m) = measurements.receive()? {
            write(recorder.measurement(&m))?;
            if m.flags & flags::END_OF_RUN != 0 && end_seq.is_none() {
                end_seq = Some(m.seq);
                end_seen_ns = monotonic_ns();
            }
        }
        while let Some(e) = estimates.receive()? {
            write(recorder.estimate(&e))?;
        }
        while let Some(c) = commands.receive()? {
            write(recorder.command(&c))?;
        }
        let now = monotonic_ns();
        if now >= next_interval_ns || stopping || end_seq.is_some() {
            let elapsed = Duration::from_nanos(now - start_ns);
            write_interval(
                &mut hlog,
                &recorder.latencies,
                &previous,
                interval_start,
                elapsed - interval_start,
            )
            .map_err(io_err(&hlog_path))?;
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
    drop(hlog);
    let summary = run_summary(&recorder, &scenario, period_ns, usage::process_cpu_ns());
    let gaps = recorder.total_gaps();
    recorder.finish().map_err(io_err(&samples_path))?;
    let summary_path = args.run_dir.join(SUMMARY_FILE);
    write_json_atomically(&summary_path, &summary).map_err(io_err(&summary_path))?;
    if gaps > 0 {
        eprintln!("flexloop-logger: {gaps} samples never reached the log (see {SUMMARY_FILE})");
    }
    Ok(())
}

/// `samples.flxlog` for the first logger, `samples.g2.flxlog` for generation 2.
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

fn publish_telemetry<W: std::io::Write>(
    out: &Outlet<Telemetry>,
    recorder: &Recorder<W>,
) -> Result<(), NodeError> {
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
