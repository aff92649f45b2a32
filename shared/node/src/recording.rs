//! The logger's writing thread: the sample file (MCAP), the latency log and
//! the supervisor's events, apart from the thread that drains the loop's
//! queues.
//!
//! The draining thread only counts and copies each message into a bounded
//! queue per channel ([`Queue`]); compression, files and the per-second
//! histogram intervals happen here. A slow disk or a busy CPU so delays the
//! files, not the draining, and the loop's 51 ms queues do not overflow
//! while a chunk is compressed. A full queue never blocks the drainer: the
//! message is dropped, counted per channel and written as a `gap` event
//! (cause `logger-queue`) once there is room again. The messages' queues
//! copy each message once and make no system call; the writer polls them.

use flexloop_protocol::{Command, Estimate, Measurement};
use flexloop_recording::event_message::{EventMessage, Gap, GapCause, LoggerEvent};
use flexloop_recording::{RecordSink, SampleWriter};
use flexloop_runfiles::events::SupervisorEvent;
use flexloop_runfiles::summary::{DroppedInLogger, SampleFileState};
use flexloop_runtime::latency::{LoopLatencies, Metric};
use flexloop_runtime::monotonic_ns;
use flexloop_runtime::spsc;
use hdrhistogram::serialization::V2DeflateSerializer;
use hdrhistogram::serialization::interval_log::{IntervalLogWriter, IntervalLogWriterBuilder, Tag};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::PathBuf;
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

/// Messages each channel's queue holds: 400 ms of the loop at 10 kHz (the
/// estimates' take 16 MB).
const QUEUE_CAPACITY: usize = 4096;
/// Events, the metadata and the histogram intervals.
const CONTROL_CAPACITY: usize = 1024;
/// How often the writer looks at the queue.
const WRITER_POLL: Duration = Duration::from_millis(2);
/// How often the sample file gets a chunk: at most this much is lost when
/// the logger is killed.
const FLUSH: Duration = Duration::from_millis(100);
/// How often the supervisor's events file is read.
const EVENTS_POLL: Duration = Duration::from_millis(50);

const CHANNELS: [&str; 3] = ["measurement", "estimate", "command"];

/// What the drainer hands the writer besides the messages.
pub enum Item {
    /// Boxed: the largest event is larger than every other item.
    Event {
        at_ns: u64,
        message: Box<EventMessage>,
    },
    Metadata(BTreeMap<String, String>),
    /// The latency histograms since the start, `elapsed` after it: the
    /// writer logs the difference to the previous ones as one interval.
    Interval {
        totals: Box<LoopLatencies>,
        elapsed: Duration,
    },
    Finish,
}

/// The drainer's end of the queues.
pub struct Queue {
    measurements: spsc::Producer<Measurement>,
    estimates: spsc::Producer<Estimate>,
    commands: spsc::Producer<Command>,
    tx: SyncSender<Item>,
    /// Messages dropped per channel because the queue was full.
    pub dropped: [u64; 3],
    /// Per channel: the dropped run not yet written as an event (first and
    /// last sequence number, count).
    pending: [Option<(u64, u64, u64)>; 3],
    /// Events dropped because the queue was full.
    pub dropped_events: u64,
}

impl Queue {
    /// After a push of a message of `channel` (`pushed`: whether it fitted).
    fn pushed(&mut self, channel: usize, seq: u64, at_ns: u64, pushed: bool) {
        if !pushed {
            self.dropped[channel] += 1;
            self.pending[channel] = Some(match self.pending[channel] {
                Some((first, last, n)) => (first.min(seq), last.max(seq), n + 1),
                None => (seq, seq, 1),
            });
            return;
        }
        if let Some(run) = self.pending[channel]
            && self
                .tx
                .try_send(Item::Event {
                    at_ns,
                    message: Box::new(dropped(CHANNELS[channel], run)),
                })
                .is_ok()
        {
            self.pending[channel] = None;
        }
    }

    /// Ends the writer's work: the drops not yet written, then the end.
    pub fn close(&mut self, at_ns: u64) {
        for (channel, name) in CHANNELS.iter().enumerate() {
            if let Some(run) = self.pending[channel].take() {
                let message = Box::new(dropped(name, run));
                // Blocking is fine now: the loop is over.
                let _ = self.tx.send(Item::Event { at_ns, message });
            }
        }
        let _ = self.tx.send(Item::Finish);
    }

    /// The latency histograms for the writer's interval log.
    pub fn interval(&mut self, totals: Box<LoopLatencies>, elapsed: Duration) {
        let item = Item::Interval { totals, elapsed };
        // A full queue skips this interval; the next one covers it.
        let _ = self.tx.try_send(item);
    }

    /// The last interval and the run's facts must arrive: they wait for room.
    pub fn send_blocking(&mut self, item: Item) {
        let _ = self.tx.send(item);
    }

    pub fn dropped_in_logger(&self) -> DroppedInLogger {
        DroppedInLogger {
            measurement: self.dropped[0],
            estimate: self.dropped[1],
            command: self.dropped[2],
            events: self.dropped_events,
        }
    }
}

/// The gap event of the samples the writer queue had no room for.
fn dropped(channel: &str, (first, last, count): (u64, u64, u64)) -> EventMessage {
    EventMessage::Logger(LoggerEvent::Gap(Gap {
        channel: channel.into(),
        seq: first,
        count,
        cause: Some(GapCause::LoggerQueue),
        last_seq: Some(last),
        after_generation: None,
    }))
}

impl RecordSink for Queue {
    fn measurement(&mut self, m: &Measurement) {
        let pushed = self.measurements.push(m);
        self.pushed(0, m.seq, m.published_ns, pushed);
    }

    fn estimate(&mut self, e: &Estimate) {
        let pushed = self.estimates.push(e);
        self.pushed(1, e.seq, e.published_ns, pushed);
    }

    fn command(&mut self, c: &Command) {
        let pushed = self.commands.push(c);
        self.pushed(2, c.seq, c.published_ns, pushed);
    }

    fn event(&mut self, at_ns: u64, message: EventMessage) {
        let item = Item::Event {
            at_ns,
            message: Box::new(message),
        };
        if self.tx.try_send(item).is_err() {
            self.dropped_events += 1;
        }
    }
}

/// What the writer needs: its files, made by the logger before the loop
/// starts (so that an unwritable run directory fails early).
pub struct Files {
    pub samples: SampleWriter<File>,
    pub samples_path: PathBuf,
    pub hlog: File,
    pub hlog_path: PathBuf,
    pub run_dir: PathBuf,
    pub scenario_name: String,
}

/// How the recording went, for the run summary.
pub struct Outcome {
    pub sample_file: SampleFileState,
    pub latency_log_complete: bool,
}

/// Starts the writer thread.
pub fn spawn(files: Files) -> std::io::Result<(Queue, JoinHandle<Outcome>)> {
    let (tx, rx) = sync_channel(CONTROL_CAPACITY);
    let (measurements, measurements_out) = spsc::channel(QUEUE_CAPACITY);
    let (estimates, estimates_out) = spsc::channel(QUEUE_CAPACITY);
    let (commands, commands_out) = spsc::channel(QUEUE_CAPACITY);
    let queues = Queues {
        measurements: measurements_out,
        estimates: estimates_out,
        commands: commands_out,
        control: rx,
    };
    let handle = std::thread::Builder::new()
        .name("logger-writer".into())
        .spawn(move || write(files, queues))?;
    let queue = Queue {
        measurements,
        estimates,
        commands,
        tx,
        dropped: [0; 3],
        pending: [None; 3],
        dropped_events: 0,
    };
    Ok((queue, handle))
}

/// The writer's ends of the queues.
struct Queues {
    measurements: spsc::Consumer<Measurement>,
    estimates: spsc::Consumer<Estimate>,
    commands: spsc::Consumer<Command>,
    control: Receiver<Item>,
}

impl Queues {
    /// Writes every message waiting, channel by channel.
    fn drain(&mut self, samples: &mut SampleWriter<File>) {
        while self
            .measurements
            .pop_with(|m| samples.measurement(m))
            .is_some()
        {}
        while self.estimates.pop_with(|e| samples.estimate(e)).is_some() {}
        while self.commands.pop_with(|c| samples.command(c)).is_some() {}
    }
}

fn write(mut files: Files, mut queues: Queues) -> Outcome {
    let mut serializer = V2DeflateSerializer::new();
    let hlog_path = files.hlog_path.clone();
    let hlog_failed = |e: &dyn std::fmt::Display| {
        eprintln!(
            "flexloop-logger: {}: {e}; latency log stopped (summary.json keeps the totals); the loop goes on",
            hlog_path.display()
        );
    };
    let mut hlog = IntervalLogWriterBuilder::new()
        .add_comment(&format!(
            "flexloop {} latencies in ns, scenario {}",
            env!("CARGO_PKG_VERSION"),
            files.scenario_name
        ))
        .with_base_time(SystemTime::now())
        .begin_log_with(&mut files.hlog, &mut serializer)
        .map_err(|e| hlog_failed(&e))
        .ok();
    let samples = &mut files.samples;
    let mut previous = LoopLatencies::new();
    let mut interval_start = Duration::ZERO;
    let mut supervisor_events =
        EventsTail::new(files.run_dir.join(flexloop_runfiles::RunDir::EVENTS));
    let mut next_flush = Instant::now() + FLUSH;
    let mut next_events = Instant::now();
    let mut finished = false;
    while !finished {
        queues.drain(samples);
        loop {
            match queues.control.try_recv() {
                Ok(Item::Event { at_ns, message }) => samples.event(at_ns, &message),
                Ok(Item::Metadata(entries)) => samples.metadata(entries),
                Ok(Item::Interval { totals, elapsed }) => {
                    if let Some(writer) = &mut hlog
                        && let Err(e) = write_interval(
                            writer,
                            &totals,
                            &previous,
                            interval_start,
                            elapsed.saturating_sub(interval_start),
                        )
                    {
                        hlog_failed(&e);
                        hlog = None;
                    }
                    previous = *totals;
                    interval_start = elapsed;
                }
                Ok(Item::Finish) | Err(TryRecvError::Disconnected) => {
                    // Everything the drainer queued before it sent this.
                    queues.drain(samples);
                    finished = true;
                    break;
                }
                Err(TryRecvError::Empty) => break,
            }
        }
        let now = Instant::now();
        if now >= next_events || finished {
            let at_ns = monotonic_ns();
            supervisor_events.read(|line| samples.event(at_ns, &supervisor_event(line)));
            next_events = now + EVENTS_POLL;
        }
        if now >= next_flush {
            samples.flush();
            report_failure(samples, &files.samples_path);
            next_flush = now + FLUSH;
        }
        if !finished {
            std::thread::sleep(WRITER_POLL);
        }
    }
    let latency_log_complete = hlog.is_some();
    drop(hlog);
    samples.finish();
    report_failure(samples, &files.samples_path);
    Outcome {
        // The writer reports as JSON (components knows no run files).
        sample_file: serde_json::from_value(samples.recording_json()).unwrap_or_default(),
        latency_log_complete,
    }
}

/// Says once on stderr that writing stopped and how the file was closed.
fn report_failure(samples: &mut SampleWriter<File>, path: &std::path::Path) {
    if let Some(failure) = samples.new_failure() {
        eprintln!(
            "flexloop-logger: {}: {}; recording stopped, the file ends at its last complete chunk ({}); the loop goes on",
            path.display(),
            failure.error,
            match &failure.closed {
                Ok(c) => format!("{} messages kept", c.messages),
                Err(e) => format!("could not close it: {e}"),
            }
        );
    }
}

fn write_interval(
    hlog: &mut IntervalLogWriter<'_, '_, File, V2DeflateSerializer>,
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

/// A line of the supervisor's events file as a `/events` message.
fn supervisor_event(line: &str) -> EventMessage {
    match serde_json::from_str::<SupervisorEvent>(line) {
        Ok(event) => EventMessage::Supervisor(event),
        Err(_) => EventMessage::Logger(LoggerEvent::UnreadableSupervisorLine { line: line.into() }),
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
        let Ok(mut file) = File::open(&self.path) else {
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
