//! The logger's sample file: every message as it was sent, and gap counting.
//!
//! Format (`.flxlog`): the line `FLXLOG1`, one line of JSON run metadata,
//! then records `[kind u8][0u8; 3][len u32 LE][payload]`, the payload being
//! the `#[repr(C)]` message bytes. Records are fixed per kind, so a reader
//! recognises a torn last record (after a crash) and stops before it.

use flexloop_protocol::{Command, Estimate, Measurement};
use flexloop_runtime::latency::LoopLatencies;
use std::fs::File;
use std::io::{self, BufWriter, Read, Write};
use std::path::Path;

const MAGIC: &[u8] = b"FLXLOG1\n";

/// Channels the recorder tracks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Kind {
    Measurement = 1,
    Estimate = 2,
    Command = 3,
}

/// One record read back from a file.
#[derive(Debug, Clone)]
pub enum Record {
    Measurement(Measurement),
    Estimate(Box<Estimate>),
    Command(Command),
}

/// Per-channel sequence bookkeeping, tolerant of reordering: during a swap
/// two instances publish on one channel and a reader may get sample k+1 from
/// the new one before sample k from the old one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelCount {
    pub samples: u64,
    /// Highest sequence number seen.
    pub last_seq: Option<u64>,
    /// Missing numbers that fell out of the reorder window.
    settled_gaps: u64,
    /// Bit i: `last_seq − i` was seen (numbers before the first count as seen).
    window: u64,
}

impl Default for ChannelCount {
    fn default() -> Self {
        Self {
            samples: 0,
            last_seq: None,
            settled_gaps: 0,
            window: u64::MAX,
        }
    }
}

/// How far back a late sample still fills its place.
const REORDER_WINDOW: u64 = 64;

impl ChannelCount {
    fn see(&mut self, seq: u64) {
        self.samples += 1;
        match self.last_seq {
            None => {
                self.last_seq = Some(seq);
            }
            Some(last) if seq > last => {
                let shift = seq - last;
                if shift >= REORDER_WINDOW {
                    // All of the window leaves, and so do the missing numbers
                    // too old for the new one; the newer missing ones stay
                    // in the new window as unseen.
                    self.settled_gaps +=
                        u64::from(self.window.count_zeros()) + shift - REORDER_WINDOW;
                    self.window = 0;
                } else {
                    let leaving = self.window >> (REORDER_WINDOW - shift);
                    self.settled_gaps += shift - u64::from(leaving.count_ones());
                    self.window <<= shift;
                }
                self.window |= 1;
                self.last_seq = Some(seq);
            }
            Some(last) => {
                let back = last - seq;
                if back < REORDER_WINDOW {
                    self.window |= 1 << back;
                }
            }
        }
    }

    /// Sequence numbers that never arrived (those still inside the reorder
    /// window count as missing too: a reader that asks now gets no more).
    pub fn gaps(&self) -> u64 {
        self.settled_gaps + u64::from(self.window.count_zeros())
    }
}

/// Writes samples as they come and keeps the loop's latency histograms.
pub struct Recorder<W: Write> {
    out: W,
    pub latencies: LoopLatencies,
    pub measurements: ChannelCount,
    pub estimates: ChannelCount,
    pub commands: ChannelCount,
    /// Commands computed with an estimate older than their tick (the observer
    /// was late and the controller went on without waiting).
    pub stale_estimates: u64,
    /// The newest measurement (its counters are the plant's totals).
    pub last_measurement: Option<Measurement>,
}

impl Recorder<BufWriter<File>> {
    /// Creates `path` (failing if it exists: a run never overwrites a log).
    pub fn create(path: &Path, metadata_json: &str) -> io::Result<Self> {
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)?;
        Recorder::new(BufWriter::with_capacity(1 << 20, file), metadata_json)
    }

    /// Flushes and syncs the file to disk.
    pub fn finish(mut self) -> io::Result<()> {
        self.out.flush()?;
        self.out.get_ref().sync_all()
    }
}

impl<W: Write> Recorder<W> {
    pub fn new(mut out: W, metadata_json: &str) -> io::Result<Self> {
        out.write_all(MAGIC)?;
        out.write_all(metadata_json.replace('\n', " ").as_bytes())?;
        out.write_all(b"\n")?;
        Ok(Self {
            out,
            latencies: LoopLatencies::new(),
            measurements: ChannelCount::default(),
            estimates: ChannelCount::default(),
            commands: ChannelCount::default(),
            stale_estimates: 0,
            last_measurement: None,
        })
    }

    fn write_record<T: Copy>(&mut self, kind: Kind, value: &T) -> io::Result<()> {
        let len = std::mem::size_of::<T>();
        // SAFETY: messages are #[repr(C)] plain data without padding (checked by
        // the protocol's size tests), so their bytes are initialised.
        let bytes = unsafe { std::slice::from_raw_parts((value as *const T).cast::<u8>(), len) };
        self.out.write_all(&[kind as u8, 0, 0, 0])?;
        self.out.write_all(&(len as u32).to_le_bytes())?;
        self.out.write_all(bytes)
    }

    pub fn measurement(&mut self, m: &Measurement) -> io::Result<()> {
        self.measurements.see(m.seq);
        self.latencies.observe_measurement(m);
        self.last_measurement = Some(*m);
        self.write_record(Kind::Measurement, m)
    }

    pub fn estimate(&mut self, e: &Estimate) -> io::Result<()> {
        self.estimates.see(e.seq);
        // The initial estimate answers no measurement.
        if e.source_published_ns != 0 {
            self.latencies.observe_estimate(e);
        }
        self.write_record(Kind::Estimate, e)
    }

    pub fn command(&mut self, c: &Command) -> io::Result<()> {
        self.commands.see(c.seq);
        if c.estimate_seq != c.seq {
            self.stale_estimates += 1;
        }
        self.latencies.observe_command(c);
        self.write_record(Kind::Command, c)
    }

    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }

    pub fn total_gaps(&self) -> u64 {
        self.measurements.gaps() + self.estimates.gaps() + self.commands.gaps()
    }
}

/// Reads a `.flxlog` file back.
pub struct LogReader {
    pub metadata_json: String,
    pub records: Vec<Record>,
    /// True if the file ended inside a record (the writer was killed).
    pub torn_tail: bool,
}

impl LogReader {
    pub fn open(path: &Path) -> io::Result<Self> {
        let mut bytes = Vec::new();
        File::open(path)?.read_to_end(&mut bytes)?;
        Self::parse(&bytes)
    }

    pub fn parse(bytes: &[u8]) -> io::Result<Self> {
        let bad = |what: &str| io::Error::new(io::ErrorKind::InvalidData, what.to_string());
        if !bytes.starts_with(MAGIC) {
            return Err(bad("not a flexloop sample log (bad magic)"));
        }
        let rest = &bytes[MAGIC.len()..];
        let eol = rest
            .iter()
            .position(|b| *b == b'\n')
            .ok_or_else(|| bad("metadata line not terminated"))?;
        let metadata_json = String::from_utf8_lossy(&rest[..eol]).into_owned();
        let mut body = &rest[eol + 1..];
        let mut records = Vec::new();
        let mut torn_tail = false;
        while !body.is_empty() {
            if body.len() < 8 {
                torn_tail = true;
                break;
            }
            let kind = body[0];
            let len = u32::from_le_bytes([body[4], body[5], body[6], body[7]]) as usize;
            if body.len() < 8 + len {
                torn_tail = true;
                break;
            }
            let payload = &body[8..8 + len];
            let record = match kind {
                1 => Record::Measurement(decode(payload).ok_or_else(|| bad("measurement size"))?),
                2 => Record::Estimate(Box::new(
                    decode(payload).ok_or_else(|| bad("estimate size"))?,
                )),
                3 => Record::Command(decode(payload).ok_or_else(|| bad("command size"))?),
                _ => return Err(bad("unknown record kind")),
            };
            records.push(record);
            body = &body[8 + len..];
        }
        Ok(Self {
            metadata_json,
            records,
            torn_tail,
        })
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
}

fn decode<T: Copy + Default>(payload: &[u8]) -> Option<T> {
    if payload.len() != std::mem::size_of::<T>() {
        return None;
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
    Some(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_records_and_counts_gaps() {
        let mut buf = Vec::new();
        {
            let mut r = Recorder::new(&mut buf, "{\"scenario\":\"t\"}").unwrap();
            for seq in [0u64, 1, 2, 5] {
                r.measurement(&Measurement {
                    seq,
                    y: [seq as f64; 8],
                    ..Default::default()
                })
                .unwrap();
            }
            r.command(&Command {
                seq: 0,
                ..Default::default()
            })
            .unwrap();
            assert_eq!(r.measurements.gaps(), 2);
            assert_eq!(r.measurements.samples, 4);
            assert_eq!(r.total_gaps(), 2);
        }
        let log = LogReader::parse(&buf).unwrap();
        assert_eq!(log.metadata_json, "{\"scenario\":\"t\"}");
        let seqs: Vec<u64> = log.measurements().map(|m| m.seq).collect();
        assert_eq!(seqs, vec![0, 1, 2, 5]);
        assert_eq!(log.measurements().last().unwrap().y[3], 5.0);
        assert_eq!(log.commands().count(), 1);
        assert!(!log.torn_tail);

        // A file cut inside its last record keeps everything before it.
        let cut = LogReader::parse(&buf[..buf.len() - 3]).unwrap();
        assert!(cut.torn_tail);
        assert_eq!(cut.measurements().count(), 4);
        assert_eq!(cut.commands().count(), 0);
    }

    #[test]
    fn rejects_foreign_files() {
        assert!(LogReader::parse(b"hello").is_err());
    }
}

#[cfg(test)]
mod channel_count_tests {
    use super::ChannelCount;

    fn count(seqs: &[u64]) -> ChannelCount {
        let mut c = ChannelCount::default();
        for s in seqs {
            c.see(*s);
        }
        c
    }

    #[test]
    fn reordering_within_the_window_is_not_a_gap() {
        assert_eq!(count(&[0, 1, 3, 2, 4]).gaps(), 0);
        assert_eq!(count(&[5, 6, 8, 9]).gaps(), 1);
        assert_eq!(count(&[0, 1, 200, 2]).gaps(), 198);
        // A sample that comes back after the window was already counted missing.
        let mut late = count(&(0..100).filter(|s| *s != 10).collect::<Vec<_>>());
        late.see(10);
        assert_eq!(late.gaps(), 1);
    }
}
