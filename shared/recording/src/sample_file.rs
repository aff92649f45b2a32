//! The run's sample file (`samples.mcap`): every message of the loop as it
//! was sent, in MCAP.
//!
//! - `/measurement`, `/estimate`, `/command`: schema encoding `ros1msg`,
//!   message encoding `ros1`. The `#[repr(C)]` bytes are the ROS1
//!   serialisation of the definitions in [`flexloop_protocol::layout`], so a
//!   message is written as it came and read back with a size check; Foxglove,
//!   PlotJuggler and the `mcap` Python package with its ROS1 support decode
//!   them as they are.
//! - `/events`: JSON messages with a JSON Schema (swaps, crashes, restarts
//!   from the supervisor; misses, stalls, fallbacks, clamping and log gaps
//!   seen by the logger).
//! - A Metadata record `flexloop`: scenario, rates, versions, host,
//!   real-time settings.
//!
//! Log and publish time of a message are its own `published_ns`
//! (CLOCK_MONOTONIC) moved onto the wall clock by the offset in the metadata
//! (`log_time_offset_ns`), so that viewers show the date of the run.
//!
//! Chunks are LZ4-compressed in memory and written whole at every
//! [`SampleWriter::flush`] (the logger flushes every 100 ms): a killed writer
//! leaves complete chunks and at most one torn one, which
//! [`crate::mcap_repair`] cuts off before it writes the missing index.

use crate::event_message::EventMessage;
use crate::mcap_repair::{self, Closed};
use crate::storage::Storage;
use flexloop_protocol::layout::{self, MessageLayout};
use flexloop_protocol::{Command, Estimate, Measurement, WireBytes};
use mcap::records::MessageHeader;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::write::NoSeek;
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read};
use std::path::Path;

pub const MEASUREMENT_TOPIC: &str = "/measurement";
pub const ESTIMATE_TOPIC: &str = "/estimate";
pub const COMMAND_TOPIC: &str = "/command";
pub const EVENTS_TOPIC: &str = "/events";
/// Name of the Metadata record holding the run's facts.
pub const METADATA_NAME: &str = "flexloop";
pub const EVENT_SCHEMA_NAME: &str = "flexloop/Event";

/// JSON Schema of the `/events` messages.
pub const EVENT_SCHEMA: &str = r#"{
  "title": "flexloop/Event",
  "description": "Something that happened in the loop: from the supervisor (swap, crash, restart, ...) or seen by the logger in the samples (miss, stall, fallback, observer-fallback, clamped, stale-estimate, late-command, rejected-command, gap, recording-start, recording-end)",
  "type": "object",
  "properties": {
    "source": {"type": "string", "enum": ["supervisor", "logger"]},
    "kind": {"type": "string"},
    "phase": {"type": "string", "enum": ["begin", "end"], "description": "for conditions that last: begin at the first tick, end at the first tick without"},
    "seq": {"type": ["integer", "null"], "description": "the loop's tick (sample sequence number) the event refers to"},
    "ticks": {"type": "integer", "description": "end of a condition: how many ticks it lasted"},
    "count": {"type": "integer", "description": "gap: sequence numbers missing from seq on"},
    "channel": {"type": "string", "description": "gap: the channel that lost them"},
    "role": {"type": "string"},
    "generation": {"type": "integer"},
    "t_s": {"type": "number", "description": "supervisor: seconds since it started"},
    "detail": {}
  },
  "required": ["source", "kind"]
}"#;

type McapWriter<S> = mcap::Writer<NoSeek<BufWriter<S>>>;

/// Channel ids in the file.
#[derive(Debug, Clone, Copy)]
struct ChannelIds {
    measurement: u16,
    estimate: u16,
    command: u16,
    events: u16,
}

/// Why and where writing stopped.
#[derive(Debug, Clone)]
pub struct Failure {
    pub error: String,
    /// How the file was closed after it (or why it could not be).
    pub closed: Result<Closed, String>,
}

/// What the writer did, for the run summary.
#[derive(Debug, Clone, Default)]
pub struct WriteStats {
    /// Messages handed to the file.
    pub messages: u64,
    /// Of those, in chunks the storage accepted.
    pub stored_messages: u64,
    /// Messages that arrived after writing stopped.
    pub dropped_messages: u64,
    pub bytes: u64,
}

/// Writes the sample file; after the first write error it stops, closes
/// the file at its last complete chunk and only counts.
pub struct SampleWriter<S: Storage> {
    mcap: Option<McapWriter<S>>,
    ids: ChannelIds,
    /// Added to CLOCK_MONOTONIC stamps to get the file's log times.
    log_time_offset_ns: u64,
    event_seq: u32,
    stats: WriteStats,
    failure: Option<Failure>,
    failure_reported: bool,
    finished: bool,
}

impl SampleWriter<File> {
    /// Creates `path` (failing if it exists: a run never overwrites a log).
    pub fn create(path: &Path, log_time_offset_ns: u64) -> io::Result<Self> {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(path)?;
        SampleWriter::new(file, log_time_offset_ns)
    }
}

impl<S: Storage> SampleWriter<S> {
    /// Starts the file: header, schemas and channels (in the first chunk).
    pub fn new(storage: S, log_time_offset_ns: u64) -> io::Result<Self> {
        let options = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            // Chunks end at flush() only, so every write of a chunk to the
            // storage is a whole chunk with its index.
            .chunk_size(None)
            .disable_seeking(true)
            .library(format!("flexloop {}", env!("CARGO_PKG_VERSION")));
        let mut mcap = options
            .create(NoSeek::new(BufWriter::with_capacity(1 << 16, storage)))
            .map_err(to_io)?;
        let mut channel = |layout: &MessageLayout, topic: &str| -> io::Result<u16> {
            let schema = mcap
                .add_schema(
                    layout.type_name,
                    "ros1msg",
                    layout.ros1_definition().as_bytes(),
                )
                .map_err(to_io)?;
            mcap.add_channel(schema, topic, "ros1", &BTreeMap::new())
                .map_err(to_io)
        };
        let measurement = channel(&layout::MEASUREMENT, MEASUREMENT_TOPIC)?;
        let estimate = channel(&layout::ESTIMATE, ESTIMATE_TOPIC)?;
        let command = channel(&layout::COMMAND, COMMAND_TOPIC)?;
        let event_schema = mcap
            .add_schema(EVENT_SCHEMA_NAME, "jsonschema", EVENT_SCHEMA.as_bytes())
            .map_err(to_io)?;
        let events = mcap
            .add_channel(event_schema, EVENTS_TOPIC, "json", &BTreeMap::new())
            .map_err(to_io)?;
        Ok(Self {
            mcap: Some(mcap),
            ids: ChannelIds {
                measurement,
                estimate,
                command,
                events,
            },
            log_time_offset_ns,
            event_seq: 0,
            stats: WriteStats::default(),
            failure: None,
            failure_reported: false,
            finished: false,
        })
    }

    /// Writes the run's facts as the Metadata record `flexloop`.
    pub fn metadata(&mut self, entries: BTreeMap<String, String>) {
        let record = mcap::records::Metadata {
            name: METADATA_NAME.into(),
            metadata: entries,
        };
        if let Some(mcap) = &mut self.mcap
            && let Err(e) = mcap.write_metadata(&record)
        {
            self.fail(e);
        }
    }

    pub fn measurement(&mut self, m: &Measurement) {
        self.write(self.ids.measurement, m.seq, m.published_ns, m.wire_bytes());
    }

    pub fn estimate(&mut self, e: &Estimate) {
        self.write(self.ids.estimate, e.seq, e.published_ns, e.wire_bytes());
    }

    pub fn command(&mut self, c: &Command) {
        self.write(self.ids.command, c.seq, c.published_ns, c.wire_bytes());
    }

    /// One JSON event at `at_ns` (CLOCK_MONOTONIC).
    pub fn event(&mut self, at_ns: u64, message: &EventMessage) {
        self.event_seq = self.event_seq.wrapping_add(1);
        self.write(
            self.ids.events,
            u64::from(self.event_seq),
            at_ns,
            message.to_json().as_bytes(),
        );
    }

    fn write(&mut self, channel_id: u16, seq: u64, published_ns: u64, data: &[u8]) {
        let Some(mcap) = &mut self.mcap else {
            self.stats.dropped_messages += 1;
            return;
        };
        let time = published_ns.wrapping_add(self.log_time_offset_ns);
        let header = MessageHeader {
            channel_id,
            // The message's own sequence number (modulo 2^32: 5 days at 10 kHz).
            sequence: seq as u32,
            log_time: time,
            publish_time: time,
        };
        match mcap.write_to_known_channel(&header, data) {
            Ok(()) => self.stats.messages += 1,
            Err(e) => {
                self.stats.dropped_messages += 1;
                self.fail(e);
            }
        }
    }

    /// Ends the current chunk and hands it to the storage.
    pub fn flush(&mut self) {
        let Some(mcap) = &mut self.mcap else {
            return;
        };
        match mcap.flush() {
            Ok(()) => self.stats.stored_messages = self.stats.messages,
            Err(e) => self.fail(e),
        }
    }

    /// Writing stopped (the first time only; later calls return `None`).
    pub fn new_failure(&mut self) -> Option<&Failure> {
        if self.failure_reported {
            return None;
        }
        self.failure_reported = self.failure.is_some();
        self.failure.as_ref()
    }

    pub fn failure(&self) -> Option<&Failure> {
        self.failure.as_ref()
    }

    pub fn stats(&self) -> &WriteStats {
        &self.stats
    }

    /// Gives up the writer after `error`: keeps what the storage holds up to
    /// its last complete chunk and closes the file there.
    fn fail(&mut self, error: mcap::McapError) {
        let Some(mcap) = self.mcap.take() else {
            return;
        };
        let (mut storage, _unwritten) = mcap.into_inner().into_inner().into_parts();
        let closed = mcap_repair::close(&mut storage).map_err(|e| e.to_string());
        if let Ok(c) = &closed {
            self.stats.bytes = c.bytes;
            self.stats.stored_messages = c.messages;
        }
        self.failure = Some(Failure {
            error: to_io(error).to_string(),
            closed,
        });
    }

    /// Writes the summary and syncs; returns the storage (`None` after a
    /// failure, when the file was already closed).
    pub fn finish(&mut self) -> Option<S> {
        self.finished = true;
        let mut mcap = self.mcap.take()?;
        if let Err(e) = mcap.finish() {
            self.mcap = Some(mcap);
            self.fail(e);
            return None;
        }
        let (mut storage, unwritten) = mcap.into_inner().into_inner().into_parts();
        let synced = match unwritten {
            Ok(rest) if rest.is_empty() => storage.sync(),
            // finish() flushed the buffer; anything left means it failed.
            _ => Err(io::Error::other("the file's last bytes were not written")),
        };
        match synced.and_then(|()| storage.size()) {
            Ok(len) => {
                self.stats.bytes = len;
                self.stats.stored_messages = self.stats.messages;
                Some(storage)
            }
            Err(e) => {
                self.failure = Some(Failure {
                    error: e.to_string(),
                    closed: Err("the file may lack its end".into()),
                });
                None
            }
        }
    }
}

impl<S: Storage> SampleWriter<S> {
    /// The recording's outcome for the run summary.
    pub fn recording_json(&self) -> serde_json::Value {
        let stats = &self.stats;
        let mut out = serde_json::json!({
            "format": "mcap",
            "compression": "lz4",
            "state": match (&self.failure, self.finished) {
                (Some(_), _) => "stopped",
                (None, true) => "complete",
                (None, false) => "recording",
            },
            "messages": stats.messages,
            "stored_messages": stats.stored_messages,
            "dropped_messages": stats.dropped_messages,
            "bytes": stats.bytes,
        });
        if let Some(f) = &self.failure {
            out["error"] = f.error.clone().into();
            out["closed"] = match &f.closed {
                Ok(c) => serde_json::json!({
                    "bytes": c.bytes,
                    "cut_bytes": c.cut_bytes,
                    "chunks": c.chunks,
                    "messages": c.messages,
                    "indexed": c.indexed,
                }),
                Err(e) => serde_json::json!({ "error": e }),
            };
        }
        out
    }
}

fn to_io(e: mcap::McapError) -> io::Error {
    match e {
        mcap::McapError::Io(e) => e,
        other => io::Error::other(other),
    }
}

/// One recorded message of the loop.
#[derive(Debug, Clone)]
pub enum Record {
    Measurement(Measurement),
    Estimate(Box<Estimate>),
    Command(Command),
}

impl Record {
    /// The message's sequence number (its tick).
    pub fn seq(&self) -> u64 {
        match self {
            Record::Measurement(m) => m.seq,
            Record::Estimate(e) => e.seq,
            Record::Command(c) => c.seq,
        }
    }

    /// Its channel: 0 measurement, 1 estimate, 2 command.
    pub fn channel(&self) -> usize {
        match self {
            Record::Measurement(_) => 0,
            Record::Estimate(_) => 1,
            Record::Command(_) => 2,
        }
    }
}

/// One `/events` message.
#[derive(Debug, Clone)]
pub struct LogEvent {
    /// The file's log time (wall clock, ns).
    pub log_time_ns: u64,
    pub message: EventMessage,
}

/// Reads a sample file back, up to its last complete chunk when the writer
/// was killed.
#[derive(Debug)]
pub struct LogReader {
    /// The `flexloop` metadata as a JSON object (every value a string).
    pub metadata_json: String,
    pub metadata: BTreeMap<String, String>,
    pub records: Vec<Record>,
    pub events: Vec<LogEvent>,
    /// True if the file does not end as a finished MCAP file does (the
    /// writer was killed and nobody repaired it); `tail_error` says where
    /// reading stopped.
    pub torn_tail: bool,
    pub tail_error: Option<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Topic {
    Measurement,
    Estimate,
    Command,
    Events,
}

impl LogReader {
    pub fn open(path: &Path) -> io::Result<Self> {
        let mut records = Vec::new();
        let mut log = Self::scan(path, |r| records.push(r))?;
        log.records = records;
        Ok(log)
    }

    /// Reads the file at `path`, handing every message to `each` in file
    /// order instead of keeping it (a long run's messages take gigabytes);
    /// the result holds the metadata, the events and how the file ends, and
    /// no records.
    pub fn scan(path: &Path, each: impl FnMut(Record)) -> io::Result<Self> {
        let file = File::open(path)?;
        let len = file.metadata()?.len();
        Self::read(BufReader::with_capacity(1 << 20, file), len, each)
    }

    pub fn parse(bytes: &[u8]) -> io::Result<Self> {
        let mut records = Vec::new();
        let mut log = Self::read(bytes, bytes.len() as u64, |r| records.push(r))?;
        log.records = records;
        Ok(log)
    }

    fn read(mut source: impl Read, len: u64, mut each: impl FnMut(Record)) -> io::Result<Self> {
        let bad = |what: String| io::Error::new(io::ErrorKind::InvalidData, what);
        let mut reader = LinearReader::new_with_options(
            LinearReaderOptions::default()
                .with_skip_end_magic(true)
                // A torn chunk yields nothing, not a prefix of its messages.
                .with_prevalidate_chunk_crcs(true)
                // Guards against a garbage length; our chunks are a few MB.
                .with_record_length_limit(
                    usize::try_from(len.max(256 << 20)).unwrap_or(usize::MAX),
                ),
        );
        let mut schemas: BTreeMap<u16, (String, String, Vec<u8>)> = BTreeMap::new();
        let mut topics: BTreeMap<u16, Topic> = BTreeMap::new();
        let mut out = Self {
            metadata_json: "{}".into(),
            metadata: BTreeMap::new(),
            records: Vec::new(),
            events: Vec::new(),
            torn_tail: false,
            tail_error: None,
        };
        let mut saw_header = false;
        let mut saw_footer = false;
        while let Some(event) = reader.next_event() {
            let (opcode, data) = match event {
                Ok(LinearReadEvent::ReadRequest(need)) => {
                    let read = loop {
                        match source.read(reader.insert(need)) {
                            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                            other => break other?,
                        }
                    };
                    reader.notify_read(read);
                    continue;
                }
                Ok(LinearReadEvent::Record { opcode, data }) => (opcode, data),
                Err(e) if saw_header => {
                    out.tail_error = Some(e.to_string());
                    break;
                }
                Err(e) => return Err(bad(format!("not an MCAP sample file: {e}"))),
            };
            let record = match mcap::parse_record(opcode, data) {
                Ok(r) => r,
                Err(e) => {
                    out.tail_error = Some(e.to_string());
                    break;
                }
            };
            use mcap::records::Record as R;
            match record {
                R::Header(_) => saw_header = true,
                R::Footer(_) => saw_footer = true,
                R::Schema { header, data } => {
                    schemas.insert(header.id, (header.name, header.encoding, data.into_owned()));
                }
                R::Channel(c) => {
                    if let Some(topic) = channel_topic(&c, &schemas).map_err(bad)? {
                        topics.insert(c.id, topic);
                    }
                }
                R::Message { header, data } => match topics.get(&header.channel_id) {
                    Some(Topic::Measurement) => each(Record::Measurement(decode(&data)?)),
                    Some(Topic::Estimate) => {
                        each(Record::Estimate(Box::new(decode::<Estimate>(&data)?)));
                    }
                    Some(Topic::Command) => each(Record::Command(decode(&data)?)),
                    Some(Topic::Events) => out.events.push(LogEvent {
                        log_time_ns: header.log_time,
                        message: serde_json::from_slice(&data).map_err(|e| {
                            bad(format!(
                                "/events message {}: not an event ({e}): {}",
                                header.sequence,
                                String::from_utf8_lossy(&data)
                            ))
                        })?,
                    }),
                    None => {}
                },
                R::Metadata(m) if m.name == METADATA_NAME => out.metadata = m.metadata,
                _ => {}
            }
        }
        if !saw_header {
            return Err(bad("not an MCAP sample file: no header record".into()));
        }
        out.torn_tail = !saw_footer;
        if out.torn_tail && out.tail_error.is_none() {
            out.tail_error = Some("the file ends without its summary and footer".into());
        }
        out.metadata_json = serde_json::to_string(&out.metadata).unwrap_or_else(|_| "{}".into());
        Ok(out)
    }

    pub fn measurements(&self) -> impl Iterator<Item = &Measurement> {
        self.records.iter().filter_map(|r| match r {
            Record::Measurement(m) => Some(m),
            _ => None,
        })
    }

    pub fn commands(&self) -> impl Iterator<Item = &Command> {
        self.records.iter().filter_map(|r| match r {
            Record::Command(c) => Some(c),
            _ => None,
        })
    }

    pub fn estimates(&self) -> impl Iterator<Item = &Estimate> {
        self.records.iter().filter_map(|r| match r {
            Record::Estimate(e) => Some(e.as_ref()),
            _ => None,
        })
    }

    /// The `flexloop` metadata entry `key`.
    pub fn meta(&self, key: &str) -> Option<&str> {
        self.metadata.get(key).map(String::as_str)
    }
}

/// Which loop channel `c` is, checking that its schema is this version's;
/// `None` for a channel this version does not know.
fn channel_topic(
    c: &mcap::records::Channel,
    schemas: &BTreeMap<u16, (String, String, Vec<u8>)>,
) -> Result<Option<Topic>, String> {
    let (topic, layout) = match c.topic.as_str() {
        MEASUREMENT_TOPIC => (Topic::Measurement, Some(layout::MEASUREMENT)),
        ESTIMATE_TOPIC => (Topic::Estimate, Some(layout::ESTIMATE)),
        COMMAND_TOPIC => (Topic::Command, Some(layout::COMMAND)),
        EVENTS_TOPIC => (Topic::Events, None),
        _ => return Ok(None),
    };
    let Some((name, encoding, data)) = schemas.get(&c.schema_id) else {
        return Err(format!(
            "channel {}: schema {} missing",
            c.topic, c.schema_id
        ));
    };
    match layout {
        Some(layout)
            if name != layout.type_name
                || encoding != "ros1msg"
                || c.message_encoding != "ros1"
                || data.as_slice() != layout.ros1_definition().as_bytes() =>
        {
            return Err(format!(
                "channel {}: recorded as {name} ({encoding}) with another message layout than this flexloop's {}",
                c.topic, layout.type_name
            ));
        }
        Some(_) => {}
        None if c.message_encoding != "json" => {
            return Err(format!(
                "channel {}: message encoding {} (expected json)",
                c.topic, c.message_encoding
            ));
        }
        None => {}
    }
    Ok(Some(topic))
}

fn decode<T: Copy + Default>(payload: &[u8]) -> io::Result<T> {
    if payload.len() != size_of::<T>() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "a {} message of {} bytes (expected {})",
                std::any::type_name::<T>(),
                payload.len(),
                size_of::<T>()
            ),
        ));
    }
    let mut value = T::default();
    // SAFETY: T is a plain-data message for which every bit pattern is valid,
    // and the lengths match.
    unsafe {
        std::ptr::copy_nonoverlapping(
            payload.as_ptr(),
            (&mut value as *mut T).cast::<u8>(),
            payload.len(),
        );
    }
    Ok(value)
}
