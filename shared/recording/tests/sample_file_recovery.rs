//! The sample file when its writer does not finish: a file cut anywhere
//! reads back up to its last complete chunk and closes into a finished,
//! indexed MCAP file holding the same messages; a full disk stops the
//! writing, leaves a finished file and the counting goes on.

use flexloop_protocol::{Command, Estimate, Measurement};
use flexloop_recording::mcap_repair;
use flexloop_recording::storage::Storage;
use flexloop_recording::{LogReader, Recorder, SampleWriter};
use std::cell::RefCell;
use std::collections::BTreeMap;
use std::io::{self, Cursor, Write};
use std::rc::Rc;

const TICKS_PER_CHUNK: u64 = 100;

/// Values that do not compress away (xorshift), so that the file grows
/// about as a real run's does.
fn noise(k: u64, i: u64) -> f64 {
    let mut x = (k << 8 | i) ^ 0x9e37_79b9_7f4a_7c15;
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    (x >> 11) as f64 / (1u64 << 53) as f64
}

fn tick(k: u64) -> (Measurement, Estimate, Command) {
    let t = 1_000_000 + k * 100_000;
    let m = Measurement {
        seq: k,
        tick_ns: t,
        published_ns: t + 5_000 + k % 7,
        n_outputs: 1,
        n_inputs: 1,
        y: std::array::from_fn(|i| noise(k, i as u64)),
        ..Default::default()
    };
    let e = Estimate {
        seq: k + 1,
        published_ns: t + 30_000,
        source_published_ns: t + 5_000,
        n_states: 4,
        x_hat: std::array::from_fn(|i| noise(k, 100 + i as u64)),
        ..Default::default()
    };
    let c = Command {
        seq: k,
        estimate_seq: k,
        published_ns: t + 20_000,
        u: std::array::from_fn(|i| noise(k, 200 + i as u64)),
        ..Default::default()
    };
    (m, e, c)
}

/// Records `ticks` ticks into `storage`, a chunk every 100 ticks.
fn record<S: Storage>(storage: S, ticks: u64) -> Recorder<SampleWriter<S>> {
    record_chunks(storage, ticks, TICKS_PER_CHUNK)
}

/// Records `ticks` ticks into `storage`, a chunk every `per_chunk` ticks.
fn record_chunks<S: Storage>(storage: S, ticks: u64, per_chunk: u64) -> Recorder<SampleWriter<S>> {
    let mut r = Recorder::new(SampleWriter::new(storage, 7).unwrap());
    r.sink()
        .metadata(BTreeMap::from([("scenario".into(), "recovery".into())]));
    r.sink().flush();
    for k in 0..ticks {
        let (m, e, c) = tick(k);
        r.measurement(&m);
        r.estimate(&e);
        r.command(&c);
        if (k + 1).is_multiple_of(per_chunk) {
            r.sink().flush();
        }
    }
    r
}

/// Ends the recording and returns the file's bytes.
fn finished(mut r: Recorder<SampleWriter<Cursor<Vec<u8>>>>) -> Vec<u8> {
    r.finish(0);
    r.sink().finish().expect("a finished file").into_inner()
}

fn seqs(log: &LogReader) -> Vec<u64> {
    log.measurements().map(|m| m.seq).collect()
}

/// A finished file as the strict readers of the mcap crate see it: the
/// summary's message count, and the messages read through the footer.
fn strict_count(bytes: &[u8]) -> (u64, usize) {
    let summary = mcap::Summary::read(bytes)
        .expect("a readable summary")
        .expect("a summary");
    let messages = mcap::MessageStream::new(bytes)
        .expect("start and end magic")
        .collect::<Result<Vec<_>, _>>()
        .expect("every message");
    (summary.stats.unwrap().message_count, messages.len())
}

#[test]
fn a_file_cut_anywhere_keeps_its_complete_chunks_and_closes_with_all_of_them() {
    let full = finished(record(Cursor::new(Vec::new()), 1_000));
    let whole = LogReader::parse(&full).unwrap();
    assert!(!whole.torn_tail);
    assert_eq!(seqs(&whole), (0..1_000).collect::<Vec<_>>());
    let (count, read) = strict_count(&full);
    assert_eq!(count as usize, read);

    let mut cuts: Vec<usize> = (1..400).map(|i| i * full.len() / 400).collect();
    cuts.extend([8, 9, 20, full.len() - 1]);
    let mut seen_sizes = std::collections::BTreeSet::new();
    for cut in cuts {
        let torn = LogReader::parse(&full[..cut]);
        let Ok(torn) = torn else {
            // Only a cut inside the header leaves nothing to read; closing
            // makes it an empty file.
            assert!(cut < 64, "cut at {cut}: {torn:?}");
            let mut storage = Cursor::new(full[..cut].to_vec());
            mcap_repair::close(&mut storage).unwrap();
            let empty = LogReader::parse(&storage.into_inner()).unwrap();
            assert!(!empty.torn_tail && empty.records.is_empty());
            continue;
        };
        // (A cut in the end magic leaves the footer: that reads as finished.)
        assert!(torn.torn_tail || cut >= full.len() - 8, "cut at {cut}");
        let kept = seqs(&torn);
        // Whole chunks only: a multiple of the chunk's ticks, from 0 on.
        assert_eq!(
            kept,
            (0..kept.len() as u64).collect::<Vec<_>>(),
            "cut at {cut}"
        );
        assert_eq!(kept.len() as u64 % TICKS_PER_CHUNK, 0, "cut at {cut}");
        assert_eq!(torn.commands().count(), kept.len());
        seen_sizes.insert(kept.len());

        let mut storage = Cursor::new(full[..cut].to_vec());
        let closed = mcap_repair::close(&mut storage).unwrap();
        assert!(!closed.already_complete && closed.indexed, "cut at {cut}");
        let repaired = storage.into_inner();
        let log = LogReader::parse(&repaired).unwrap();
        assert!(!log.torn_tail, "cut at {cut}: {:?}", log.tail_error);
        assert_eq!(
            seqs(&log),
            kept,
            "cut at {cut}: the repair keeps what was readable"
        );
        assert_eq!(log.meta("scenario"), torn.meta("scenario"));
        let (count, read) = strict_count(&repaired);
        assert_eq!(count, closed.messages, "cut at {cut}");
        assert_eq!(read as u64, closed.messages, "cut at {cut}");
        assert_eq!(
            closed.messages as usize,
            log.records.len() + log.events.len(),
            "cut at {cut}"
        );
        // Closing a closed file changes nothing.
        let mut again = Cursor::new(repaired.clone());
        assert!(mcap_repair::close(&mut again).unwrap().already_complete);
        assert_eq!(again.into_inner(), repaired);
    }
    assert!(
        seen_sizes.len() >= 10,
        "cuts across the file: {seen_sizes:?}"
    );
}

#[test]
fn the_index_of_the_last_chunk_is_written_anew_when_it_was_cut() {
    let full = finished(record(Cursor::new(Vec::new()), 300));
    // Cut right after the last data chunk record, before its message
    // indexes: find it from the summary's chunk indexes.
    let summary = mcap::Summary::read(&full).unwrap().unwrap();
    let last = summary.chunk_indexes.last().unwrap();
    let end = (last.chunk_start_offset + last.chunk_length) as usize;
    for cut in [end, end + 5, end + 40] {
        let mut storage = Cursor::new(full[..cut].to_vec());
        mcap_repair::close(&mut storage).unwrap();
        let repaired = storage.into_inner();
        let summary = mcap::Summary::read(&repaired).unwrap().unwrap();
        // Every channel of every chunk is indexed: reading by index finds all.
        let mut indexed = 0;
        for chunk in &summary.chunk_indexes {
            // The first chunk holds the channel definitions only.
            if chunk.message_index_offsets.is_empty() {
                continue;
            }
            let indexes = summary.read_message_indexes(&repaired, chunk).unwrap();
            for entries in indexes.values() {
                indexed += entries.len();
                for entry in entries {
                    summary.seek_message(&repaired, chunk, entry).unwrap();
                }
            }
        }
        assert_eq!(
            indexed as u64,
            summary.stats.as_ref().unwrap().message_count
        );
        assert_eq!(seqs(&LogReader::parse(&repaired).unwrap()).len(), 300);
    }
}

/// Storage on a disk with `capacity` bytes: a write past it stores what
/// fits, then fails as a full disk does. The bytes stay with the test.
#[derive(Clone)]
struct SmallDisk {
    file: Rc<RefCell<Cursor<Vec<u8>>>>,
    capacity: usize,
}

impl SmallDisk {
    fn new(bytes: Vec<u8>, capacity: usize) -> Self {
        let len = bytes.len() as u64;
        let mut file = Cursor::new(bytes);
        file.set_position(len);
        Self {
            file: Rc::new(RefCell::new(file)),
            capacity,
        }
    }

    fn bytes(&self) -> Vec<u8> {
        self.file.borrow().get_ref().clone()
    }
}

/// ENOSPC on Linux.
const NO_SPACE: i32 = 28;

impl Write for SmallDisk {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let mut file = self.file.borrow_mut();
        let room = self.capacity.saturating_sub(file.get_ref().len());
        if room == 0 {
            return Err(io::Error::from_raw_os_error(NO_SPACE));
        }
        file.write(&buf[..buf.len().min(room)])
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl Storage for SmallDisk {
    fn size(&mut self) -> io::Result<u64> {
        self.file.borrow_mut().size()
    }

    fn read_exact_at(&mut self, offset: u64, buf: &mut [u8]) -> io::Result<()> {
        self.file.borrow_mut().read_exact_at(offset, buf)
    }

    fn truncate(&mut self, len: u64) -> io::Result<()> {
        self.file.borrow_mut().truncate(len)
    }

    fn sync(&mut self) -> io::Result<()> {
        Ok(())
    }
}

#[test]
fn a_full_disk_stops_the_writing_and_leaves_a_finished_file() {
    // 60 kB: not even the first data chunk (about 70 kB) fits.
    for capacity in [60_000, 200_000, 1_000_000] {
        let disk = SmallDisk::new(Vec::new(), capacity);
        let mut r = record(disk.clone(), 2_000);
        let failure = r.sink().new_failure().expect("the disk filled").clone();
        assert!(failure.error.contains("No space left"), "{}", failure.error);
        assert!(r.sink().new_failure().is_none(), "reported once");
        // The counting went on past the failure.
        assert_eq!(r.measurements.samples, 2_000);
        assert_eq!(r.total_gaps(), 0);
        r.finish(0);
        assert!(r.sink().finish().is_none(), "nothing more to finish");
        let recording = r.sink().recording_json();
        assert_eq!(recording["state"], "stopped");
        assert!(recording["dropped_messages"].as_u64().unwrap() > 0);
        let closed = failure.closed.expect("closed");
        assert!(closed.indexed);
        let bytes = disk.bytes();
        assert_eq!(bytes.len() as u64, closed.bytes);
        assert!(bytes.len() <= capacity);
        let log = LogReader::parse(&bytes).unwrap();
        assert!(!log.torn_tail, "{:?}", log.tail_error);
        let kept = seqs(&log);
        assert!(kept.len() < 2_000, "{capacity}: {}", kept.len());
        assert_eq!(
            kept.is_empty(),
            capacity < 100_000,
            "{capacity}: {}",
            kept.len()
        );
        assert_eq!(kept, (0..kept.len() as u64).collect::<Vec<_>>());
        assert_eq!(recording["stored_messages"], closed.messages);
        let (count, read) = strict_count(&bytes);
        assert_eq!((count, read as u64), (closed.messages, closed.messages));
    }
}

/// The end of the last complete chunk's index and the start of the chunk
/// before it, in a finished file of more than two chunks.
fn last_chunks(full: &[u8]) -> (usize, usize, usize) {
    let summary = mcap::Summary::read(full).unwrap().unwrap();
    let n = summary.chunk_indexes.len();
    let last = &summary.chunk_indexes[n - 1];
    let previous = &summary.chunk_indexes[n - 2];
    let previous_end = (previous.chunk_start_offset
        + previous.chunk_length
        + previous.message_index_length) as usize;
    let last_end = (last.chunk_start_offset + last.chunk_length) as usize;
    (previous.chunk_start_offset as usize, previous_end, last_end)
}

#[test]
fn a_disk_too_full_for_the_summary_gives_up_the_last_chunk_for_it() {
    // Torn inside the last chunk, and the disk full just past the chunk
    // before: no room for the summary, until that chunk makes room.
    let full = finished(record(Cursor::new(Vec::new()), 500));
    let (_, previous_end, last_end) = last_chunks(&full);
    let mut disk = SmallDisk::new(full[..last_end - 10].to_vec(), previous_end + 60);
    let closed = mcap_repair::close(&mut disk).unwrap();
    assert!(closed.indexed);
    let bytes = disk.bytes();
    let log = LogReader::parse(&bytes).unwrap();
    assert!(!log.torn_tail, "{:?}", log.tail_error);
    assert_eq!(seqs(&log), (0..300).collect::<Vec<_>>());
    let (count, read) = strict_count(&bytes);
    assert_eq!((count, read as u64), (closed.messages, closed.messages));
}

#[test]
fn a_disk_too_full_even_for_that_still_gets_a_footer() {
    // Chunks of one tick are smaller than the summary: giving up one does
    // not make room for it, and only a footer fits.
    let full = finished(record_chunks(Cursor::new(Vec::new()), 50, 1));
    let (previous_start, previous_end, last_end) = last_chunks(&full);
    let mut disk = SmallDisk::new(full[..last_end - 10].to_vec(), previous_end + 60);
    let closed = mcap_repair::close(&mut disk).unwrap();
    assert!(!closed.indexed);
    let bytes = disk.bytes();
    assert_eq!(
        bytes.len(),
        previous_start + 50,
        "data end, footer and magic"
    );
    let log = LogReader::parse(&bytes).unwrap();
    assert!(!log.torn_tail, "{:?}", log.tail_error);
    assert_eq!(seqs(&log), (0..48).collect::<Vec<_>>());
    assert!(mcap::Summary::read(&bytes).unwrap().is_none());
    let all = mcap::MessageStream::new(&bytes).unwrap().count();
    assert_eq!(all, log.records.len() + log.events.len());
}

#[test]
fn topic_counts_read_the_indexes_of_a_file_being_written() {
    let full = finished(record(Cursor::new(Vec::new()), 300));
    let path = std::env::temp_dir().join(format!("flexloop-counts-{}.mcap", std::process::id()));
    std::fs::write(&path, &full).unwrap();
    let counts = mcap_repair::topic_counts(&path).unwrap();
    assert_eq!(counts.get("/measurement"), Some(&300));
    assert_eq!(counts.get("/command"), Some(&300));
    // Cut inside the last chunk: the complete chunks count.
    let summary = mcap::Summary::read(&full).unwrap().unwrap();
    let last = summary.chunk_indexes.last().unwrap();
    std::fs::write(&path, &full[..last.chunk_start_offset as usize + 100]).unwrap();
    let counts = mcap_repair::topic_counts(&path).unwrap();
    assert_eq!(counts.get("/measurement"), Some(&200));
    let _ = std::fs::remove_file(&path);
}
