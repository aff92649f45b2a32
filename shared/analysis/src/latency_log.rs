//! The logger's latency log read back: an HdrHistogram interval log (one
//! interval per second, one tag per histogram) merged into one histogram per
//! tag over the whole run, and the percentile distribution of each as
//! HdrHistogram's plots draw it.

use base64::Engine;
use hdrhistogram::Histogram;
use hdrhistogram::serialization::Deserializer;
use hdrhistogram::serialization::interval_log::{IntervalLogIterator, LogEntry, LogIteratorError};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A latency log, merged per tag.
#[derive(Debug, Clone, Default)]
pub struct LatencyLog {
    /// Tag -> every interval of it added together.
    pub histograms: BTreeMap<String, Histogram<u64>>,
    /// Intervals read (all tags).
    pub intervals: usize,
    /// The file ended inside a line (its writer was killed); the intervals
    /// before it are all there.
    pub torn_tail: bool,
}

/// Why a latency log could not be read; names the file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LatencyLogError {
    pub path: PathBuf,
    pub reason: String,
}

impl std::fmt::Display for LatencyLogError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.reason)
    }
}

impl std::error::Error for LatencyLogError {}

impl LatencyLog {
    /// Every logger generation's log of the run directory `dir`
    /// (`latency.hlog`, `latency.g<N>.hlog`, ...) merged per tag. A log
    /// that cannot be read is named in the error unless another generation's
    /// could (a logger killed in its first second wrote no interval).
    pub fn read_run(dir: &Path) -> Result<Self, LatencyLogError> {
        let run_dir = flexloop_runfiles::RunDir::new(dir);
        let mut generations: Vec<u32> = run_dir.sample_files().iter().map(|(g, _)| *g).collect();
        if generations.is_empty() {
            generations.push(0);
        }
        let mut joined: Option<Self> = None;
        let mut first_error = None;
        for g in generations {
            match Self::read(&run_dir.histogram_log(g)) {
                Ok(log) => joined.get_or_insert_with(Self::default).merge(log),
                Err(e) => {
                    first_error.get_or_insert(e);
                }
            }
        }
        match (joined, first_error) {
            (Some(log), _) => Ok(log),
            (None, Some(e)) => Err(e),
            (None, None) => Ok(Self::default()),
        }
    }

    /// Adds another log's histograms (another logger generation's) to these.
    pub fn merge(&mut self, other: Self) {
        for (tag, h) in other.histograms {
            match self.histograms.get_mut(&tag) {
                Some(mine) => {
                    // Same bounds (the same logger wrote both): adding cannot fail.
                    let _ = mine.add(&h);
                }
                None => {
                    self.histograms.insert(tag, h);
                }
            }
        }
        self.intervals += other.intervals;
        self.torn_tail |= other.torn_tail;
    }

    pub fn read(path: &Path) -> Result<Self, LatencyLogError> {
        let error = |reason: String| LatencyLogError {
            path: path.to_path_buf(),
            reason,
        };
        let bytes = std::fs::read(path).map_err(|e| error(e.to_string()))?;
        Self::parse(&bytes).map_err(error)
    }

    /// Parses the text of an interval log; untagged intervals go under "".
    pub fn parse(bytes: &[u8]) -> Result<Self, String> {
        let mut histograms: BTreeMap<String, Histogram<u64>> = BTreeMap::new();
        let mut intervals = 0;
        let mut torn_tail = false;
        let mut deserializer = Deserializer::new();
        for entry in IntervalLogIterator::new(bytes) {
            let entry = match entry {
                Ok(entry) => entry,
                Err(LogIteratorError::ParseError { offset }) => {
                    if !bytes[offset..].contains(&b'\n') {
                        torn_tail = true;
                        break;
                    }
                    return Err(format!(
                        "not an HdrHistogram interval log line at byte {offset}"
                    ));
                }
            };
            let LogEntry::Interval(interval) = entry else {
                continue;
            };
            intervals += 1;
            let tag = interval.tag().map_or("", |t| t.as_str()).to_string();
            let at = interval.start_timestamp().as_secs_f64();
            let encoded = base64::engine::general_purpose::STANDARD
                .decode(interval.encoded_histogram())
                .map_err(|e| format!("interval {tag} at {at:.3} s: bad base64: {e}"))?;
            let histogram: Histogram<u64> = deserializer
                .deserialize(&mut encoded.as_slice())
                .map_err(|e| format!("interval {tag} at {at:.3} s: bad histogram: {e:?}"))?;
            histograms
                .entry(tag.clone())
                .or_insert_with(|| Histogram::new_from(&histogram))
                .add(&histogram)
                .map_err(|e| format!("interval {tag} at {at:.3} s: cannot be added: {e:?}"))?;
        }
        if intervals == 0 {
            return Err("no intervals (is this an HdrHistogram interval log?)".into());
        }
        Ok(Self {
            histograms,
            intervals,
            torn_tail,
        })
    }
}

/// (quantile, value) pairs evenly spaced on the log-percentile axis,
/// `per_decade` of them per added nine, from 0 % to the last sample's
/// quantile 1 − 1/count, where the maximum sits.
pub fn percentile_distribution(h: &Histogram<u64>, per_decade: u32) -> Vec<(f64, u64)> {
    let count = h.len();
    if count == 0 {
        return Vec::new();
    }
    let last = 1.0 - 1.0 / count as f64;
    let mut out = Vec::new();
    for i in 0.. {
        let q = 1.0 - 10f64.powf(-(i as f64) / per_decade.max(1) as f64);
        // Within rounding of the last sample's quantile: the maximum goes there.
        if q >= last - 1e-12 {
            break;
        }
        out.push((q, h.value_at_quantile(q)));
    }
    out.push((last.max(0.0), h.max()));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use hdrhistogram::serialization::V2DeflateSerializer;
    use hdrhistogram::serialization::interval_log::{IntervalLogWriterBuilder, Tag};
    use std::time::{Duration, SystemTime};

    fn histogram(values: impl Iterator<Item = u64>) -> Histogram<u64> {
        let mut h = Histogram::new_with_bounds(1, 10_000_000_000, 3).unwrap();
        for v in values {
            h.record(v).unwrap();
        }
        h
    }

    fn log() -> Vec<u8> {
        let mut out = Vec::new();
        let mut serializer = V2DeflateSerializer::new();
        let mut writer = IntervalLogWriterBuilder::new()
            .add_comment("test")
            .with_base_time(SystemTime::now())
            .begin_log_with(&mut out, &mut serializer)
            .unwrap();
        let second = Duration::from_secs(1);
        let a1 = histogram(1_000..2_000);
        let a2 = histogram(2_000..3_000);
        let b = histogram([5_000u64; 10].into_iter());
        writer
            .write_histogram(&a1, Duration::ZERO, second, Tag::new("round_trip"))
            .unwrap();
        writer
            .write_histogram(&b, Duration::ZERO, second, Tag::new("tick_lateness"))
            .unwrap();
        writer
            .write_histogram(&a2, second, second, Tag::new("round_trip"))
            .unwrap();
        drop(writer);
        out
    }

    #[test]
    fn intervals_merge_per_tag() {
        let log = LatencyLog::parse(&log()).unwrap();
        assert_eq!(log.intervals, 3);
        let rt = &log.histograms["round_trip"];
        assert_eq!(rt.len(), 2_000);
        // 1000..3000 ns: the median near 2000 (3 significant digits).
        assert!((rt.value_at_quantile(0.5) as i64 - 2_000).abs() <= 2);
        assert_eq!(log.histograms["tick_lateness"].len(), 10);
    }

    #[test]
    fn distribution_is_monotone_and_ends_at_the_max() {
        let h = histogram(1..=100_000);
        let d = percentile_distribution(&h, 5);
        assert!(d.windows(2).all(|w| w[0].0 < w[1].0 && w[0].1 <= w[1].1));
        assert_eq!(d[0].0, 0.0);
        let (q, v) = *d.last().unwrap();
        assert!((q - (1.0 - 1e-5)).abs() < 1e-12);
        assert_eq!(v, h.max());
        // Five points per nine over five nines, plus the maximum.
        assert_eq!(d.len(), 26);
    }

    #[test]
    fn garbage_is_refused_with_a_reason() {
        let e = LatencyLog::parse(b"#comment\nthis is not a log\n").unwrap_err();
        assert!(e.contains("byte"), "{e}");
        let mut torn = log();
        torn.extend_from_slice(b"Tag=round_trip,2.000,1.0");
        let read = LatencyLog::parse(&torn).unwrap();
        assert!(read.torn_tail);
        assert_eq!(read.histograms["round_trip"].len(), 2_000);
        let e = LatencyLog::parse(b"#only comments\n").unwrap_err();
        assert!(e.contains("no intervals"), "{e}");
        let path = Path::new("/nonexistent/latency.hlog");
        let e = LatencyLog::read(path).unwrap_err();
        assert!(
            e.to_string().starts_with("/nonexistent/latency.hlog: "),
            "{e}"
        );
    }
}
