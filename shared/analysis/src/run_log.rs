//! A run's recording across logger generations. A restarted logger writes
//! its own `samples.g<N>.mcap` beside its predecessors', and a killed one
//! leaves no summary: this reads every sample file of a run directory in
//! generation order as one log ([`JoinedLog`]), finds the samples no logger
//! recorded between one generation and the next or after the last
//! ([`Outage`]), and rebuilds the run's summary from what the files hold
//! ([`joined_summary`]).

use crate::latency_log::LatencyLog;
use flexloop_recording::event_message::{EventMessage, Gap, GapCause, JoinEvent};
use flexloop_recording::{LogEvent, LogReader, Record};
use flexloop_runfiles::summary::{
    Counters, DroppedInLogger, GenerationAccount, Outage, PerChannel, Recording, SampleFileState,
};
use flexloop_runfiles::{Histogram, Percentiles, RunDir, RunSummary};
use flexloop_runtime::latency::QUANTILES;
use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

/// Why a run's recording could not be read; names the file or directory.
#[derive(Debug)]
pub struct RunLogError {
    pub path: PathBuf,
    pub reason: String,
}

impl std::fmt::Display for RunLogError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.reason)
    }
}

impl std::error::Error for RunLogError {}

fn error(path: &Path, reason: impl ToString) -> RunLogError {
    RunLogError {
        path: path.to_path_buf(),
        reason: reason.to_string(),
    }
}

/// A run of sequence numbers: the first and how many.
type Run = (u64, u64);

/// Sequence numbers above this are no tick (`NO_SEQ`, a damaged message).
const MAX_SEQ: u64 = 1 << 40;

/// Which sequence numbers of each channel the files hold, file by file.
#[derive(Default)]
struct Ledger {
    /// Per channel, bit `seq`: some file holds it.
    seen: [Vec<u64>; 3],
    /// Per file and channel: its lowest and highest number, and how many
    /// numbers no earlier file held.
    files: Vec<[FileRange; 3]>,
}

#[derive(Debug, Clone, Copy, Default)]
struct FileRange {
    /// The lowest and highest number no earlier file held.
    new_span: Option<(u64, u64)>,
    new: u64,
}

impl Ledger {
    fn begin_file(&mut self) {
        self.files.push(Default::default());
    }

    /// Notes `seq` of `channel` in the current file; false if a file
    /// (this one or an earlier one) held it already.
    fn see(&mut self, channel: usize, seq: u64) -> bool {
        if seq > MAX_SEQ {
            return false;
        }
        let bits = &mut self.seen[channel];
        let (word, bit) = ((seq / 64) as usize, seq % 64);
        if bits.len() <= word {
            bits.resize(word + 1, 0);
        }
        if bits[word] & (1 << bit) != 0 {
            return false;
        }
        bits[word] |= 1 << bit;
        let range = &mut self.files.last_mut().expect("a file begun")[channel];
        range.new_span = Some(match range.new_span {
            Some((lo, hi)) => (lo.min(seq), hi.max(seq)),
            None => (seq, seq),
        });
        range.new += 1;
        true
    }

    /// The lowest and highest number any file holds.
    fn span(&self, channel: usize) -> Option<(u64, u64)> {
        self.files
            .iter()
            .filter_map(|f| f[channel].new_span)
            .reduce(|(a, b), (c, d)| (a.min(c), b.max(d)))
    }

    fn distinct(&self, channel: usize) -> u64 {
        self.files.iter().map(|f| f[channel].new).sum()
    }

    /// The run's first recorded tick: the lowest number any channel holds
    /// (every channel has a sample for it; a channel whose first samples
    /// were lost misses them from there on).
    fn run_start(&self) -> Option<u64> {
        (0..3).filter_map(|c| self.span(c)).map(|(lo, _)| lo).min()
    }

    /// Numbers missing from the run's first tick to the channel's last held
    /// (or to `last_tick` when the run went on after its last logger).
    fn gaps(&self, channel: usize, last_tick: Option<u64>) -> u64 {
        let (Some(start), Some((_, hi))) = (self.run_start(), self.span(channel)) else {
            return 0;
        };
        let end = last_tick.map_or(hi, |t| t.max(hi));
        (end - start + 1) - self.distinct(channel)
    }

    /// The runs of numbers no file holds, from the run's first tick to
    /// `end`, that no range of `reported` covers: (first, count), as
    /// (unreported, not sent). An estimate or command is not sent when a
    /// logger recorded its tick's measurement (its producer was silent or
    /// dead); the rest is a killed logger's unwritten last.
    fn unreported(
        &self,
        channel: usize,
        reported: &[(u64, u64)],
        end: u64,
    ) -> (Vec<Run>, Vec<Run>) {
        let Some(lo) = self.run_start() else {
            return (Vec::new(), Vec::new());
        };
        let mut covered = vec![false; (end.saturating_sub(lo) + 1) as usize];
        for (first, count) in reported {
            for seq in (*first).max(lo)..(first + count).min(end + 1) {
                covered[(seq - lo) as usize] = true;
            }
        }
        let missing = |seq: u64| !covered[(seq - lo) as usize] && !self.held(channel, seq);
        let not_sent = |seq: u64| channel != 0 && self.held(0, seq);
        (
            self.runs(lo..end + 1, |seq| missing(seq) && !not_sent(seq)),
            self.runs(lo..end + 1, |seq| missing(seq) && not_sent(seq)),
        )
    }

    fn held(&self, channel: usize, seq: u64) -> bool {
        self.seen[channel]
            .get((seq / 64) as usize)
            .is_some_and(|w| w & (1 << (seq % 64)) != 0)
    }

    /// The first number above `seq` any file holds.
    fn first_held_after(&self, channel: usize, seq: u64) -> Option<u64> {
        let bits = &self.seen[channel];
        let mut at = seq + 1;
        while let Some(word) = bits.get((at / 64) as usize) {
            let rest = word >> (at % 64);
            if rest != 0 {
                return Some(at + u64::from(rest.trailing_zeros()));
            }
            at = (at / 64 + 1) * 64;
        }
        None
    }

    /// The runs no logger recorded: from the highest number of the
    /// generations so far to the next number a later one holds, and after
    /// the last one up to `last_tick`.
    fn outages(&self, generations: &[u32], last_tick: Option<u64>) -> Vec<Outage> {
        let mut out = Vec::new();
        for (channel, name) in PerChannel::NAMES.iter().enumerate() {
            // The highest number so far and the generation that held it.
            let mut reached: Option<(u64, u32)> = None;
            for (file, generation) in self.files.iter().zip(generations) {
                let Some((_, hi)) = file[channel].new_span else {
                    continue;
                };
                if let Some((top, after)) = reached
                    && hi > top
                {
                    // This file goes beyond the earlier ones: it holds the
                    // next number after their highest.
                    let next = self.first_held_after(channel, top).unwrap_or(top + 1);
                    if next > top + 1 {
                        out.push(Outage {
                            channel: name.to_string(),
                            seq: top + 1,
                            count: next - top - 1,
                            after_generation: after,
                            before_generation: Some(*generation),
                        });
                    }
                }
                if reached.is_none_or(|(top, _)| hi > top) {
                    reached = Some((hi, *generation));
                }
            }
            if let (Some((top, after)), Some(last)) = (reached, last_tick)
                && last > top
            {
                out.push(Outage {
                    channel: name.to_string(),
                    seq: top + 1,
                    count: last - top,
                    after_generation: after,
                    before_generation: None,
                });
            }
        }
        // An estimate or command missing at a tick whose measurement a
        // logger recorded was never sent (its producer silent or dead),
        // not lost for want of a logger: only the rest is an outage.
        out.into_iter()
            .flat_map(|o| {
                if o.channel == PerChannel::NAMES[0] {
                    return vec![o];
                }
                self.runs(o.seq..o.seq + o.count, |seq| !self.held(0, seq))
                    .into_iter()
                    .map(|(seq, count)| Outage {
                        seq,
                        count,
                        ..o.clone()
                    })
                    .collect()
            })
            .collect()
    }

    /// The runs of numbers in `range` for which `keep` holds: (first, count).
    fn runs(&self, range: std::ops::Range<u64>, keep: impl Fn(u64) -> bool) -> Vec<Run> {
        let mut runs: Vec<Run> = Vec::new();
        for seq in range.filter(|&s| keep(s)) {
            match runs.last_mut() {
                Some((first, count)) if *first + *count == seq => *count += 1,
                _ => runs.push((seq, 1)),
            }
        }
        runs
    }
}

/// The run's last tick as its plant counted it (`plant_latency.json`), if
/// the plant wrote it: ticks after the last logger's last sample are lost
/// too.
fn last_tick(run_dir: &RunDir) -> Option<u64> {
    run_dir
        .read_plant_latency()
        .ok()
        .and_then(|p| p.ticks.checked_sub(1))
}

/// Every sample file of a run read as one log, in generation order.
#[derive(Debug)]
pub struct JoinedLog {
    /// The messages of every file (a number a predecessor holds is kept
    /// once), every event (the supervisor's, which each logger copies, once)
    /// with a `gap` event (cause `logger-outage`) per outage, and the first
    /// file's metadata. `torn_tail`: some file ends torn.
    pub log: LogReader,
    pub files: Vec<PathBuf>,
    pub outages: Vec<Outage>,
    /// Per channel: numbers no file holds, from the first held to the last
    /// (or to the run's last tick); outages included. Messages + gaps =
    /// the run's ticks (measurements).
    pub gaps: PerChannel,
    /// Missing samples no logger wrote a gap event for (a killed logger's
    /// last ones), now in `gap` events of cause `unreported`: per channel.
    pub unreported: PerChannel,
    /// Estimates and commands missing at ticks a logger recorded, that no
    /// logger wrote a gap event for: never sent (their producer silent or
    /// dead), now in `gap` events of cause `not-sent`.
    pub not_sent: PerChannel,
    /// Files that end without their footer, and where reading stopped.
    pub torn: Vec<(PathBuf, String)>,
}

impl JoinedLog {
    /// Every `samples*.mcap` of the run directory `dir`.
    pub fn open(dir: &Path) -> Result<Self, RunLogError> {
        let run_dir = RunDir::new(dir);
        let files = run_dir.sample_files();
        if files.is_empty() {
            return Err(error(
                dir,
                format!("no {} in it (not a run directory?)", RunDir::SAMPLES),
            ));
        }
        let (generations, paths): (Vec<u32>, Vec<PathBuf>) = files.into_iter().unzip();
        Self::join(&paths, &generations, last_tick(&run_dir))
    }

    /// One sample file on its own.
    pub fn open_file(path: &Path) -> Result<Self, RunLogError> {
        Self::join(&[path.to_path_buf()], &[0], None)
    }

    fn join(
        paths: &[PathBuf],
        generations: &[u32],
        last_tick: Option<u64>,
    ) -> Result<Self, RunLogError> {
        let mut ledger = Ledger::default();
        let mut records = Vec::new();
        let mut events: Vec<LogEvent> = Vec::new();
        let mut supervisor_events = HashSet::new();
        let mut metadata = None;
        let mut torn = Vec::new();
        for path in paths {
            ledger.begin_file();
            let log = LogReader::scan(path, |r| {
                if ledger.see(r.channel(), r.seq()) {
                    records.push(r);
                }
            })
            .map_err(|e| error(path, e))?;
            if log.torn_tail {
                torn.push((path.clone(), log.tail_error.clone().unwrap_or_default()));
            }
            // Each logger copies the supervisor's events file from its start.
            events.extend(log.events.into_iter().filter(|e| match &e.message {
                EventMessage::Supervisor(event) => {
                    supervisor_events.insert(serde_json::to_string(event).unwrap_or_default())
                }
                _ => true,
            }));
            if metadata.is_none() {
                metadata = Some((log.metadata, log.metadata_json));
            }
        }
        let outages = ledger.outages(generations, last_tick);
        let gaps = PerChannel::from_array([0, 1, 2].map(|c| ledger.gaps(c, last_tick)));
        let (metadata, metadata_json) = metadata.unwrap_or_default();
        let offset_ns: u64 = metadata
            .get("log_time_offset_ns")
            .and_then(|v| v.parse().ok())
            .unwrap_or(0);
        // Placed at the last measurement before it.
        let published: BTreeMap<u64, u64> = records
            .iter()
            .filter_map(|r| match r {
                Record::Measurement(m) => Some((m.seq, m.published_ns)),
                _ => None,
            })
            .collect();
        let at = |seq: u64| published.range(..seq).next_back().map_or(0, |(_, ns)| *ns) + offset_ns;
        // A killed logger never wrote the gaps still open in its reorder
        // window, nor those in its torn last chunk: the join does, so that
        // every missing sample is in a gap event.
        let mut unreported = Vec::new();
        let mut not_sent = Vec::new();
        for (channel, name) in PerChannel::NAMES.iter().enumerate() {
            let mut reported: Vec<(u64, u64)> = events
                .iter()
                .filter_map(|e| e.message.gap())
                .filter(|g| g.channel == *name)
                .filter_map(|g| {
                    let count = match g.last_seq {
                        Some(last) => last.checked_sub(g.seq)? + 1,
                        None => g.count,
                    };
                    Some((g.seq, count))
                })
                .collect();
            reported.extend(
                outages
                    .iter()
                    .filter(|o| o.channel == *name)
                    .map(|o| (o.seq, o.count)),
            );
            let Some((_, hi)) = ledger.span(channel) else {
                continue;
            };
            let end = last_tick.map_or(hi, |t| t.max(hi));
            let (lost, never_sent) = ledger.unreported(channel, &reported, end);
            for (first, count) in lost {
                unreported.push((*name, first, count));
            }
            for (first, count) in never_sent {
                not_sent.push((*name, first, count));
            }
        }
        for o in &outages {
            events.push(LogEvent {
                log_time_ns: at(o.seq),
                message: EventMessage::Flexloop(JoinEvent::Gap(Gap {
                    channel: o.channel.clone(),
                    seq: o.seq,
                    count: o.count,
                    cause: Some(GapCause::LoggerOutage),
                    last_seq: None,
                    after_generation: Some(o.after_generation),
                })),
            });
        }
        for (cause, runs) in [
            (GapCause::Unreported, &unreported),
            (GapCause::NotSent, &not_sent),
        ] {
            for (channel, first, count) in runs {
                events.push(LogEvent {
                    log_time_ns: at(*first),
                    message: EventMessage::Flexloop(JoinEvent::Gap(Gap {
                        channel: channel.to_string(),
                        seq: *first,
                        count: *count,
                        cause: Some(cause),
                        last_seq: None,
                        after_generation: None,
                    })),
                });
            }
        }
        events.sort_by_key(|e| e.log_time_ns);
        let log = LogReader {
            metadata_json,
            metadata,
            records,
            events,
            torn_tail: !torn.is_empty(),
            tail_error: torn.first().map(|(p, e)| format!("{}: {e}", p.display())),
        };
        let count_of = |runs: &[(&str, u64, u64)], name: &str| -> u64 {
            runs.iter()
                .filter(|(c, _, _)| *c == name)
                .map(|(_, _, n)| n)
                .sum()
        };
        Ok(Self {
            log,
            files: paths.to_vec(),
            outages,
            gaps,
            unreported: PerChannel::from_array(PerChannel::NAMES.map(|n| count_of(&unreported, n))),
            not_sent: PerChannel::from_array(PerChannel::NAMES.map(|n| count_of(&not_sent, n))),
            torn,
        })
    }

    /// What joining did, for the user: the files and the samples no logger
    /// recorded; none for one file and nothing lost between loggers.
    pub fn describe(&self) -> Option<String> {
        if self.files.len() < 2
            && self.outages.is_empty()
            && self.unreported.total() == 0
            && self.not_sent.total() == 0
        {
            return None;
        }
        let names = file_names(&self.files);
        let unreported = if self.unreported.total() == 0 {
            String::new()
        } else {
            format!(
                "; {} samples missing without a gap event (a killed logger's last) added as gap events of cause unreported",
                self.unreported.total()
            )
        };
        let not_sent = if self.not_sent.total() == 0 {
            String::new()
        } else {
            format!(
                "; {} estimates and {} commands never sent at ticks the logger recorded (their producer silent or dead), added as gap events of cause not-sent",
                self.not_sent.estimate, self.not_sent.command
            )
        };
        Some(format!(
            "joined {} sample files ({}); {}{unreported}{not_sent}",
            names.len(),
            names.join(", "),
            describe_outages(&self.outages)
        ))
    }
}

/// "no sample lost between loggers", or the outages and what they cost.
pub fn describe_outages(outages: &[Outage]) -> String {
    if outages.is_empty() {
        return "no sample lost between loggers".into();
    }
    let lost = |channel: &str| -> u64 {
        outages
            .iter()
            .filter(|o| o.channel == channel)
            .map(|o| o.count)
            .sum()
    };
    let runs = outages
        .iter()
        .filter(|o| o.channel == PerChannel::NAMES[0])
        .count();
    format!(
        "{runs} outages without a logger: {} measurements, {} estimates and {} commands not recorded (gap events, cause logger-outage)",
        lost("measurement"),
        lost("estimate"),
        lost("command")
    )
}

/// A logger generation's own summary, if it wrote one (a joined summary
/// in `summary.json` is not the first logger's).
fn own_summary(run_dir: &RunDir, generation: u32) -> Option<RunSummary> {
    let path = run_dir.generation_summary(generation);
    flexloop_runfiles::json::read_json::<RunSummary>(&path)
        .ok()
        .filter(|s| s.generations.is_empty())
}

/// The run's summary rebuilt from its sample files and latency logs, for a
/// run that several loggers recorded or whose logger was killed before it
/// wrote one: every tick is recorded or counted in `gaps` (outages
/// included), the counters are the plant's as its last recorded
/// measurement carries them, the latencies those of every generation's
/// latency log.
pub fn joined_summary(dir: &Path) -> Result<RunSummary, RunLogError> {
    let run_dir = RunDir::new(dir);
    let files = run_dir.sample_files();
    if files.is_empty() {
        return Err(error(dir, "no sample file in it"));
    }
    let last_tick = last_tick(&run_dir);
    let mut ledger = Ledger::default();
    let mut last_measurement: Option<flexloop_protocol::Measurement> = None;
    let mut stale_estimates = 0u64;
    let mut metadata = BTreeMap::new();
    let mut generations = Vec::new();
    let mut own = Vec::new();
    let mut queue_drops = Vec::new();
    for (generation, path) in &files {
        ledger.begin_file();
        let mut first = None;
        let mut last = None;
        let log = LogReader::scan(path, |r| {
            let new = ledger.see(r.channel(), r.seq());
            match &r {
                Record::Measurement(m) => {
                    first = Some(first.map_or(m.seq, |f: u64| f.min(m.seq)));
                    last = Some(last.map_or(m.seq, |l: u64| l.max(m.seq)));
                    if last_measurement.is_none_or(|l| m.seq > l.seq) {
                        last_measurement = Some(*m);
                    }
                }
                Record::Command(c) if new && c.estimate_seq != c.seq => stale_estimates += 1,
                _ => {}
            }
        })
        .map_err(|e| error(path, e))?;
        let summary = own_summary(&run_dir, *generation);
        if summary.is_none() {
            // A killed logger's drops: only its file's gap events tell them.
            queue_drops.push(logger_queue_drops(&log.events));
        }
        if metadata.is_empty() {
            metadata = log.metadata;
        }
        let range = ledger.files.last().expect("a file begun");
        generations.push(GenerationAccount {
            generation: *generation,
            file: path
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned(),
            state: summary.as_ref().map_or("killed".to_string(), |s| {
                s.recording.sample_file.state.clone()
            }),
            samples: PerChannel::from_array([range[0].new, range[1].new, range[2].new]),
            first_seq: first,
            last_seq: last,
        });
        own.push(summary);
    }
    let generation_numbers: Vec<u32> = files.iter().map(|(g, _)| *g).collect();
    let outages = ledger.outages(&generation_numbers, last_tick);
    let samples = PerChannel::from_array([0, 1, 2].map(|c| ledger.distinct(c)));
    let gaps = PerChannel::from_array([0, 1, 2].map(|c| ledger.gaps(c, last_tick)));
    let meta = |key: &str| metadata.get(key).cloned().unwrap_or_default();
    let period_ns: u64 = meta("period_ns").parse().unwrap_or(0);
    let latest = own.iter().rev().flatten().next();
    let m = last_measurement.unwrap_or_default();
    let mut dropped = DroppedInLogger::default();
    for d in own
        .iter()
        .flatten()
        .map(|s| s.recording.dropped_in_logger)
        .chain(queue_drops)
    {
        dropped.measurement += d.measurement;
        dropped.estimate += d.estimate;
        dropped.command += d.command;
        dropped.events += d.events;
    }
    let last_file = generations
        .last()
        .map(|g| g.file.clone())
        .unwrap_or_default();
    let recording = match own.last().and_then(Option::as_ref) {
        Some(s) => Recording {
            dropped_in_logger: dropped,
            ..s.recording.clone()
        },
        None => Recording {
            sample_file: SampleFileState {
                format: "mcap".into(),
                state: "killed".into(),
                ..Default::default()
            },
            file: last_file,
            latency_log_complete: false,
            dropped_in_logger: dropped,
        },
    };
    Ok(RunSummary {
        scenario: latest.map_or_else(|| meta("scenario"), |s| s.scenario.clone()),
        scenario_file: latest.map_or_else(|| meta("scenario_file"), |s| s.scenario_file.clone()),
        mode: latest.map_or_else(|| meta("mode"), |s| s.mode.clone()),
        rate_hz: latest.map_or_else(|| meta("rate_hz").parse().unwrap_or(0.0), |s| s.rate_hz),
        duration_s: latest.map_or_else(
            || meta("duration_s").parse().unwrap_or(0.0),
            |s| s.duration_s,
        ),
        period_ns,
        ticks: samples.measurement + gaps.measurement,
        last_seq: last_tick.unwrap_or(0).max(m.seq),
        counters: Counters {
            misses: m.misses,
            late_commands: m.late_commands,
            stalled_ticks: m.stalled_ticks,
            stall_misses: m.stall_misses,
            stale_estimates,
            fallback_ticks: m.fallback_ticks,
            rejected_commands: m.rejected_commands,
            foreign_commands: own
                .iter()
                .flatten()
                .map(|s| s.counters.foreign_commands)
                .sum(),
        },
        samples,
        gaps,
        logger_cpu_ns: own.iter().flatten().map(|s| s.logger_cpu_ns).sum(),
        latency: joined_latencies(&run_dir, &generation_numbers, period_ns, latest),
        recording,
        generations,
        outages,
    })
}

/// The messages a logger had no room for in its writer queue, from its
/// file's `gap` events of cause `logger-queue`.
fn logger_queue_drops(events: &[LogEvent]) -> DroppedInLogger {
    let mut d = DroppedInLogger::default();
    for e in events {
        let Some(gap) = e.message.gap() else {
            continue;
        };
        if gap.cause != Some(GapCause::LoggerQueue) {
            continue;
        }
        match gap.channel.as_str() {
            "measurement" => d.measurement += gap.count,
            "estimate" => d.estimate += gap.count,
            "command" => d.command += gap.count,
            _ => {}
        }
    }
    d
}

/// Every generation's latency log merged per metric; metrics a logger's
/// own summary names but no log holds count 0.
fn joined_latencies(
    run_dir: &RunDir,
    generations: &[u32],
    period_ns: u64,
    latest: Option<&RunSummary>,
) -> BTreeMap<String, Histogram> {
    let mut joined = LatencyLog::default();
    for g in generations {
        if let Ok(log) = LatencyLog::read(&run_dir.histogram_log(*g)) {
            joined.merge(log);
        }
    }
    let mut out: BTreeMap<String, Histogram> = latest
        .map(|s| {
            s.latency
                .keys()
                .map(|k| (k.clone(), Histogram::default()))
                .collect()
        })
        .unwrap_or_default();
    for (tag, h) in &joined.histograms {
        let mut values = [0u64; 6];
        if !h.is_empty() {
            for (slot, q) in values.iter_mut().zip(QUANTILES) {
                *slot = h.value_at_quantile(q);
            }
            values[5] = h.max();
        }
        let within = h.count_between(0, period_ns);
        out.insert(
            tag.clone(),
            Histogram {
                count: h.len(),
                percentiles: Percentiles::from_values(values),
                over_one_period: Some(h.len().saturating_sub(within)),
            },
        );
    }
    out
}

/// The files' names without their directory, for the user.
pub fn file_names(files: &[PathBuf]) -> Vec<String> {
    files
        .iter()
        .map(|p| {
            p.file_name()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ledger(files: &[&[u64]]) -> Ledger {
        let mut l = Ledger::default();
        for f in files {
            l.begin_file();
            for s in *f {
                for c in 0..3 {
                    l.see(c, *s);
                }
            }
        }
        l
    }

    #[test]
    fn the_samples_between_two_loggers_are_one_outage() {
        // Generation 0 recorded 0..=9, generation 1 from 15 (and 9 again).
        let l = ledger(&[&(0..10).collect::<Vec<_>>(), &[9, 15, 16, 17]]);
        let outages = l.outages(&[0, 1], None);
        assert_eq!(outages.len(), 3, "{outages:?}");
        assert_eq!(
            outages[0],
            Outage {
                channel: "measurement".into(),
                seq: 10,
                count: 5,
                after_generation: 0,
                before_generation: Some(1),
            }
        );
        assert_eq!(l.distinct(0), 13);
        assert_eq!(l.gaps(0, None), 5);
        // Every tick recorded or in a gap.
        assert_eq!(l.distinct(0) + l.gaps(0, None), 18);
    }

    #[test]
    fn ticks_after_the_last_logger_are_an_outage_and_gaps_inside_a_file_are_not() {
        let l = ledger(&[&[0, 1, 2, 4, 5]]);
        let outages = l.outages(&[0], Some(9));
        assert_eq!(outages.len(), 3);
        assert_eq!((outages[0].seq, outages[0].count), (6, 4));
        assert_eq!(outages[0].before_generation, None);
        // 3 inside the file (a gap its logger wrote), 6..=9 after it.
        assert_eq!(l.gaps(0, Some(9)), 5);
        assert_eq!(l.distinct(0) + l.gaps(0, Some(9)), 10);
        assert!(l.outages(&[0], Some(5)).is_empty());
    }

    #[test]
    fn a_later_logger_that_fills_an_earlier_hole_still_shows_the_outage() {
        // Generation 1 holds 3 (generation 0 lost it) and starts again at 8.
        let l = ledger(&[&[0, 1, 2, 4, 5], &[3, 8, 9]]);
        let outages = l.outages(&[0, 1], None);
        assert_eq!((outages[0].seq, outages[0].count), (6, 2), "{outages:?}");
        assert_eq!(l.gaps(0, None), 2);
    }

    #[test]
    fn a_channel_whose_first_samples_were_lost_misses_them_from_the_runs_start() {
        let mut l = Ledger::default();
        l.begin_file();
        for s in 0..10 {
            l.see(0, s);
        }
        for s in 4..10 {
            l.see(2, s);
        }
        assert_eq!(l.gaps(2, None), 4);
        // Their ticks' measurements are recorded: never sent.
        assert_eq!(l.unreported(2, &[], 9), (vec![], vec![(0, 4)]));
    }

    /// The controller stopped at command 499 and the loop ran on to tick
    /// 999 with its logger recording: 500 commands never sent, none lost
    /// for want of a logger (it was "1 outage without a logger").
    #[test]
    fn commands_missing_while_the_logger_recorded_their_ticks_were_never_sent() {
        let mut l = Ledger::default();
        l.begin_file();
        for s in 0..1000 {
            l.see(0, s);
            l.see(1, s + 1);
        }
        for s in 0..500 {
            l.see(2, s);
        }
        assert!(l.outages(&[0], Some(999)).is_empty());
        assert_eq!(l.gaps(2, Some(999)), 500);
        assert_eq!(l.unreported(2, &[], 999), (vec![], vec![(500, 500)]));
        // Ticks after the logger's last measurement are an outage on every
        // channel alike.
        let outages = l.outages(&[0], Some(1099));
        let commands: Vec<_> = outages.iter().filter(|o| o.channel == "command").collect();
        assert_eq!(commands.len(), 1, "{outages:?}");
        assert_eq!((commands[0].seq, commands[0].count), (1000, 100));
    }

    #[test]
    fn missing_numbers_no_event_reports_are_found() {
        let l = ledger(&[&[0, 1, 3, 4, 8, 9], &[12]]);
        // 2 was reported by its logger, 10..=11 is the outage.
        let (runs, never_sent) = l.unreported(0, &[(2, 1), (10, 2)], 14);
        assert_eq!(runs, vec![(5, 3), (13, 2)]);
        assert!(never_sent.is_empty(), "a measurement is always sent");
        assert_eq!(
            l.unreported(0, &[(2, 1), (5, 3), (10, 2)], 12),
            (vec![], vec![])
        );
    }

    #[test]
    fn a_later_logger_that_starts_behind_its_predecessor_loses_nothing() {
        let l = ledger(&[&[0, 1, 2, 3], &[2, 3, 4, 5]]);
        assert!(l.outages(&[0, 1], None).is_empty());
        assert_eq!(l.distinct(0), 6);
        assert_eq!(l.files[1][0].new, 2);
    }
}
