//! Closes an MCAP sample file that its writer left unfinished (killed, or
//! stopped by a full disk), in place: keeps every complete chunk, cuts what
//! follows the last one, and writes the end a finished file has (data end,
//! a summary with schemas, channels, statistics, chunk and metadata indexes,
//! footer, magic), so that every MCAP reader, the indexed ones too, opens it
//! as if the writer had finished.
//!
//! It reads only record headers and message indexes, plus the chunks that
//! hold the channel definitions and the last chunk (whose index the writer
//! may not have written): the work is a few reads per chunk, not a copy of
//! the file, and it needs no free space beyond the summary.

use crate::storage::Storage;
use binrw::BinWrite;
use mcap::records::{self, op};
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::{BTreeMap, BTreeSet};
use std::io::{self, Cursor};
use std::path::Path;

const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";
/// Opcode and length in front of every record.
const RECORD_PREFIX: u64 = 9;
/// Footer record: prefix and its 20 bytes of body.
const FOOTER_RECORD: u64 = RECORD_PREFIX + 20;

/// What closing did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Closed {
    /// The file was finished already; nothing was changed.
    pub already_complete: bool,
    /// Length of the file now.
    pub bytes: u64,
    /// Bytes of torn data cut off the end.
    pub cut_bytes: u64,
    /// Chunks and messages the file holds (from the chunk indexes).
    pub chunks: u64,
    pub messages: u64,
    /// False when only a footer without summary fitted (readers then scan).
    pub indexed: bool,
}

/// Closes the file at `path` if it is unfinished.
pub fn repair_file(path: &Path) -> io::Result<Closed> {
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)?;
    close(&mut file)
}

struct ChunkInfo {
    start: u64,
    length: u64,
    header: records::ChunkHeader,
    index_offsets: BTreeMap<u16, u64>,
    index_length: u64,
    counts: BTreeMap<u16, u64>,
}

/// What a walk over the top-level records found.
#[derive(Default)]
struct Walk {
    chunks: Vec<ChunkInfo>,
    metadata: Vec<records::MetadataIndex>,
    schemas: BTreeMap<u16, (records::SchemaHeader, Vec<u8>)>,
    channels: BTreeMap<u16, records::Channel>,
    /// Start of every complete record, in order, and the end of the last one.
    boundaries: Vec<u64>,
    end: u64,
    /// The last records are the last chunk and (some of) its indexes only.
    last_chunk_open: bool,
}

/// Closes `storage` if it holds an unfinished MCAP file.
pub fn close<S: Storage>(storage: &mut S) -> io::Result<Closed> {
    let len = storage.size()?;
    let bad = |what: &str| io::Error::new(io::ErrorKind::InvalidData, what.to_string());
    let mut start = [0u8; 8];
    let head = len.min(8) as usize;
    storage.read_exact_at(0, &mut start[..head])?;
    if start[..head] != MAGIC[..head] {
        return Err(bad("not an MCAP file (bad magic)"));
    }
    if is_complete(storage, len)? {
        return Ok(Closed {
            already_complete: true,
            bytes: len,
            cut_bytes: 0,
            chunks: 0,
            messages: 0,
            indexed: true,
        });
    }
    let mut walk = walk(storage, len)?;
    if walk.boundaries.is_empty() {
        // Not even the header is complete: start the file anew, empty.
        storage.truncate(0)?;
        let mut start = MAGIC.to_vec();
        let header = records::Header {
            profile: String::new(),
            library: format!("flexloop {}", env!("CARGO_PKG_VERSION")),
        };
        record(&mut start, op::HEADER, &body(&header)?);
        storage.write_all(&start)?;
        walk.end = start.len() as u64;
    }
    let mut cut = walk.end;
    let mut regenerated = Vec::new();
    if walk.last_chunk_open
        && let Some(last) = walk.chunks.last_mut()
    {
        // Its index records may be partial: cut them and write them anew.
        cut = last.start + last.length;
        last.index_offsets.clear();
        last.index_length = 0;
        last.counts.clear();
        match chunk_contents(storage, last, &mut walk.schemas, &mut walk.channels) {
            Ok(indexes) => regenerated = indexes,
            Err(_) => {
                // A chunk that does not decode is dropped whole.
                cut = last.start;
                walk.chunks.pop();
            }
        }
        walk.boundaries.retain(|b| *b < cut);
    }
    find_channels(storage, &mut walk)?;
    storage.truncate(cut)?;
    let tail = full_tail(&mut walk, cut, &regenerated)?;
    let mut indexed = storage.write_all(&tail).is_ok();
    if !indexed && let Some(last) = walk.chunks.last().map(|c| c.start) {
        // Short of room (a full disk): the last chunk gives up its room to
        // the summary, so that every reader (the indexed ones of Foxglove
        // and PlotJuggler too) opens the file.
        walk.chunks.pop();
        walk.metadata.retain(|m| m.offset < last);
        walk.boundaries.retain(|b| *b < last);
        cut = last;
        storage.truncate(cut)?;
        indexed = storage.write_all(&full_tail(&mut walk, cut, &[])?).is_ok();
    }
    if !indexed {
        // Not even that fits: a footer alone still makes a valid file
        // (readers scan it); cut records off the end until it fits.
        cut = write_bare_tail(storage, cut, &mut walk)?;
    }
    storage.sync()?;
    let bytes = storage.size()?;
    let chunks = walk.chunks.len() as u64;
    let messages = walk.chunks.iter().flat_map(|c| c.counts.values()).sum();
    Ok(Closed {
        already_complete: false,
        bytes,
        cut_bytes: len.saturating_sub(cut),
        chunks,
        messages,
        indexed,
    })
}

/// Messages per topic in the chunks of the MCAP file at `path`, from its
/// message indexes alone (only the chunk with the channel definitions is
/// decompressed): cheap enough to poll a file while it is being written.
pub fn topic_counts(path: &Path) -> io::Result<BTreeMap<String, u64>> {
    let mut file = std::fs::File::open(path)?;
    let len = file.size()?;
    let mut walk = walk(&mut file, len)?;
    find_channels(&mut file, &mut walk)?;
    let mut counts = BTreeMap::new();
    for chunk in &walk.chunks {
        for (id, n) in &chunk.counts {
            if let Some(channel) = walk.channels.get(id) {
                *counts.entry(channel.topic.clone()).or_default() += n;
            }
        }
    }
    Ok(counts)
}

/// The file ends in footer and magic.
fn is_complete<S: Storage>(storage: &mut S, len: u64) -> io::Result<bool> {
    if len < 8 + FOOTER_RECORD + 8 {
        return Ok(false);
    }
    let mut end = [0u8; (FOOTER_RECORD + 8) as usize];
    storage.read_exact_at(len - end.len() as u64, &mut end)?;
    Ok(end[0] == op::FOOTER
        && u64::from_le_bytes(end[1..9].try_into().expect("8 bytes")) == 20
        && &end[end.len() - 8..] == MAGIC)
}

fn read_at<S: Storage>(storage: &mut S, offset: u64, n: u64) -> io::Result<Vec<u8>> {
    let mut buf = vec![0u8; usize::try_from(n).map_err(io::Error::other)?];
    storage.read_exact_at(offset, &mut buf)?;
    Ok(buf)
}

fn le_u64(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

fn le_u32(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// Walks the data section's records up to the first incomplete one (or the
/// start of a torn summary).
fn walk<S: Storage>(storage: &mut S, len: u64) -> io::Result<Walk> {
    let mut w = Walk {
        end: MAGIC.len() as u64,
        ..Walk::default()
    };
    let mut pos = MAGIC.len() as u64;
    while pos + RECORD_PREFIX <= len {
        let prefix = read_at(storage, pos, RECORD_PREFIX)?;
        let opcode = prefix[0];
        let body_len = le_u64(&prefix, 1).expect("9 bytes");
        let Some(end) = (pos + RECORD_PREFIX)
            .checked_add(body_len)
            .filter(|e| *e <= len)
        else {
            break;
        };
        let body_at = pos + RECORD_PREFIX;
        match opcode {
            op::CHUNK => {
                let Some(header) = chunk_header(&read_at(storage, body_at, body_len.min(512))?)
                else {
                    break;
                };
                w.chunks.push(ChunkInfo {
                    start: pos,
                    length: end - pos,
                    header,
                    index_offsets: BTreeMap::new(),
                    index_length: 0,
                    counts: BTreeMap::new(),
                });
            }
            op::MESSAGE_INDEX => {
                let head = read_at(storage, body_at, body_len.min(6))?;
                let (Some(channel), Some(bytes), Some(chunk)) = (
                    head.get(..2).map(|b| u16::from_le_bytes([b[0], b[1]])),
                    le_u32(&head, 2),
                    w.chunks.last_mut(),
                ) else {
                    break;
                };
                chunk.index_offsets.insert(channel, pos);
                chunk.index_length += end - pos;
                *chunk.counts.entry(channel).or_default() += u64::from(bytes) / 16;
            }
            op::METADATA => {
                let body = read_at(storage, body_at, body_len)?;
                if let Ok(records::Record::Metadata(m)) = mcap::parse_record(opcode, &body) {
                    w.metadata.push(records::MetadataIndex {
                        offset: pos,
                        length: end - pos,
                        name: m.name,
                    });
                }
            }
            op::SCHEMA | op::CHANNEL => {
                let body = read_at(storage, body_at, body_len)?;
                collect_definition(opcode, &body, &mut w.schemas, &mut w.channels);
            }
            // The data section ended: what follows is a torn summary.
            op::DATA_END | op::FOOTER => break,
            _ => {}
        }
        w.last_chunk_open = match opcode {
            op::CHUNK => true,
            op::MESSAGE_INDEX => w.last_chunk_open,
            _ => false,
        };
        w.boundaries.push(pos);
        pos = end;
        w.end = end;
    }
    Ok(w)
}

/// The chunk header at the start of a chunk record's body.
fn chunk_header(b: &[u8]) -> Option<records::ChunkHeader> {
    let name_len = le_u32(b, 28)? as usize;
    let compression = std::str::from_utf8(b.get(32..32 + name_len)?).ok()?;
    Some(records::ChunkHeader {
        message_start_time: le_u64(b, 0)?,
        message_end_time: le_u64(b, 8)?,
        uncompressed_size: le_u64(b, 16)?,
        uncompressed_crc: le_u32(b, 24)?,
        compression: compression.to_string(),
        compressed_size: le_u64(b, 32 + name_len)?,
    })
}

fn collect_definition(
    opcode: u8,
    body: &[u8],
    schemas: &mut BTreeMap<u16, (records::SchemaHeader, Vec<u8>)>,
    channels: &mut BTreeMap<u16, records::Channel>,
) {
    match mcap::parse_record(opcode, body) {
        Ok(records::Record::Schema { header, data }) => {
            schemas.insert(header.id, (header, data.into_owned()));
        }
        Ok(records::Record::Channel(c)) => {
            channels.insert(c.id, c);
        }
        _ => {}
    }
}

/// Decompresses `chunk`, collecting its definitions; returns its message
/// index records (fills its counts), or an error if it does not decode.
fn chunk_contents<S: Storage>(
    storage: &mut S,
    chunk: &mut ChunkInfo,
    schemas: &mut BTreeMap<u16, (records::SchemaHeader, Vec<u8>)>,
    channels: &mut BTreeMap<u16, records::Channel>,
) -> io::Result<Vec<records::MessageIndex>> {
    let bytes = read_at(storage, chunk.start, chunk.length)?;
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_validate_chunk_crcs(true),
    );
    let mut fed = 0;
    let mut offset = 0u64;
    let mut entries: BTreeMap<u16, Vec<records::MessageIndexEntry>> = BTreeMap::new();
    while let Some(event) = reader.next_event() {
        match event.map_err(io::Error::other)? {
            LinearReadEvent::ReadRequest(need) => {
                let n = need.min(bytes.len() - fed);
                reader.insert(n).copy_from_slice(&bytes[fed..fed + n]);
                reader.notify_read(n);
                fed += n;
            }
            LinearReadEvent::Record { opcode, data } => {
                if opcode == op::MESSAGE
                    && let (Some(channel), Some(log_time)) = (
                        data.get(..2).map(|b| u16::from_le_bytes([b[0], b[1]])),
                        le_u64(data, 6),
                    )
                {
                    entries
                        .entry(channel)
                        .or_default()
                        .push(records::MessageIndexEntry { log_time, offset });
                } else {
                    collect_definition(opcode, data, schemas, channels);
                }
                offset += RECORD_PREFIX + data.len() as u64;
            }
        }
    }
    chunk.counts = entries
        .iter()
        .map(|(ch, e)| (*ch, e.len() as u64))
        .collect();
    Ok(entries
        .into_iter()
        .map(|(channel_id, mut records)| {
            // Indexes are sorted by log time (stable: file order for ties).
            records.sort_by_key(|e| e.log_time);
            records::MessageIndex {
                channel_id,
                records,
            }
        })
        .collect())
}

/// Decompresses chunks from the first on until every channel the indexes
/// name, and its schema, is known.
fn find_channels<S: Storage>(storage: &mut S, walk: &mut Walk) -> io::Result<()> {
    let wanted: BTreeSet<u16> = walk
        .chunks
        .iter()
        .flat_map(|c| c.counts.keys().copied())
        .collect();
    let known = |w: &Walk| {
        wanted.iter().all(|id| {
            w.channels
                .get(id)
                .is_some_and(|c| c.schema_id == 0 || w.schemas.contains_key(&c.schema_id))
        })
    };
    for i in 0..walk.chunks.len() {
        if known(walk) {
            break;
        }
        let mut chunk = ChunkInfo {
            start: walk.chunks[i].start,
            length: walk.chunks[i].length,
            header: walk.chunks[i].header.clone(),
            index_offsets: BTreeMap::new(),
            index_length: 0,
            counts: BTreeMap::new(),
        };
        // A chunk that does not decode adds no definitions; its messages
        // stay for readers that can use them.
        let _ = chunk_contents(storage, &mut chunk, &mut walk.schemas, &mut walk.channels);
    }
    Ok(())
}

fn record(out: &mut Vec<u8>, opcode: u8, body: &[u8]) {
    out.push(opcode);
    out.extend_from_slice(&(body.len() as u64).to_le_bytes());
    out.extend_from_slice(body);
}

fn body<T>(value: &T) -> io::Result<Vec<u8>>
where
    for<'a> T: BinWrite<Args<'a> = ()>,
{
    let mut out = Vec::new();
    value
        .write_le(&mut Cursor::new(&mut out))
        .map_err(io::Error::other)?;
    Ok(out)
}

/// The regenerated indexes of the last chunk, data end, summary, footer and
/// magic, to be written at `cut`.
fn full_tail(
    walk: &mut Walk,
    cut: u64,
    regenerated: &[records::MessageIndex],
) -> io::Result<Vec<u8>> {
    let mut out = Vec::new();
    if let Some(last) = walk.chunks.last_mut().filter(|_| !regenerated.is_empty()) {
        for index in regenerated {
            let at = cut + out.len() as u64;
            last.index_offsets.insert(index.channel_id, at);
            record(&mut out, op::MESSAGE_INDEX, &body(index)?);
        }
        last.index_length = out.len() as u64;
    }
    record(&mut out, op::DATA_END, &body(&records::DataEnd::default())?);
    let summary_start = cut + out.len() as u64;
    let mut groups = Vec::new();
    let mut group = |out: &mut Vec<u8>, opcode: u8, bodies: Vec<Vec<u8>>| {
        if bodies.is_empty() {
            return;
        }
        let start = cut + out.len() as u64;
        for b in &bodies {
            record(out, opcode, b);
        }
        groups.push(records::SummaryOffset {
            group_opcode: opcode,
            group_start: start,
            group_length: cut + out.len() as u64 - start,
        });
    };
    let mut schema_bodies = Vec::new();
    for (header, data) in walk.schemas.values() {
        let mut b = body(header)?;
        b.extend_from_slice(&(data.len() as u32).to_le_bytes());
        b.extend_from_slice(data);
        schema_bodies.push(b);
    }
    group(&mut out, op::SCHEMA, schema_bodies);
    let channel_bodies = walk
        .channels
        .values()
        .map(body)
        .collect::<io::Result<_>>()?;
    group(&mut out, op::CHANNEL, channel_bodies);
    let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
    for c in &walk.chunks {
        for (ch, n) in &c.counts {
            *counts.entry(*ch).or_default() += n;
        }
    }
    let with_messages = || walk.chunks.iter().filter(|c| !c.counts.is_empty());
    let statistics = records::Statistics {
        message_count: counts.values().sum(),
        schema_count: walk.schemas.len() as u16,
        channel_count: walk.channels.len() as u32,
        attachment_count: 0,
        metadata_count: walk.metadata.len() as u32,
        chunk_count: walk.chunks.len() as u32,
        message_start_time: with_messages()
            .map(|c| c.header.message_start_time)
            .min()
            .unwrap_or(0),
        message_end_time: with_messages()
            .map(|c| c.header.message_end_time)
            .max()
            .unwrap_or(0),
        channel_message_counts: counts,
    };
    group(&mut out, op::STATISTICS, vec![body(&statistics)?]);
    let chunk_bodies = walk
        .chunks
        .iter()
        .map(|c| {
            body(&records::ChunkIndex {
                message_start_time: c.header.message_start_time,
                message_end_time: c.header.message_end_time,
                chunk_start_offset: c.start,
                chunk_length: c.length,
                message_index_offsets: c.index_offsets.clone(),
                message_index_length: c.index_length,
                compression: c.header.compression.clone(),
                compressed_size: c.header.compressed_size,
                uncompressed_size: c.header.uncompressed_size,
            })
        })
        .collect::<io::Result<_>>()?;
    group(&mut out, op::CHUNK_INDEX, chunk_bodies);
    let metadata_bodies = walk.metadata.iter().map(body).collect::<io::Result<_>>()?;
    group(&mut out, op::METADATA_INDEX, metadata_bodies);
    let summary_offset_start = cut + out.len() as u64;
    for g in &groups {
        record(&mut out, op::SUMMARY_OFFSET, &body(g)?);
    }
    out.push(op::FOOTER);
    out.extend_from_slice(&20u64.to_le_bytes());
    out.extend_from_slice(&summary_start.to_le_bytes());
    out.extend_from_slice(&summary_offset_start.to_le_bytes());
    // The CRC covers the summary and the footer up to this field.
    let crc = crc32fast::hash(&out[(summary_start - cut) as usize..]);
    out.extend_from_slice(&crc.to_le_bytes());
    out.extend_from_slice(MAGIC);
    Ok(out)
}

/// Data end, a footer without summary and magic at `cut`, or as far before
/// it as it takes to fit; returns where the data now ends.
fn write_bare_tail<S: Storage>(storage: &mut S, mut cut: u64, walk: &mut Walk) -> io::Result<u64> {
    let mut tail = Vec::new();
    record(&mut tail, op::DATA_END, &[0u8; 4]);
    record(&mut tail, op::FOOTER, &[0u8; 20]);
    tail.extend_from_slice(MAGIC);
    loop {
        storage.truncate(cut)?;
        match storage.write_all(&tail) {
            Ok(()) => return Ok(cut),
            Err(e) => {
                // Never past the header: the file would not be MCAP.
                let Some(previous) = walk.boundaries.pop().filter(|b| *b < cut && *b > 8) else {
                    return Err(e);
                };
                cut = previous;
                walk.chunks.retain(|c| c.start < cut);
            }
        }
    }
}
