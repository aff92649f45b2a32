//! The names of a run directory's files, in one place.

use crate::json::{FileError, read_json};
use crate::summary::{PlantLatency, RunSummary};
use std::path::{Path, PathBuf};

/// A run directory: where one run of the loop keeps everything it writes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunDir(PathBuf);

impl RunDir {
    /// The scenario as it ran, copied in before the processes start.
    pub const SCENARIO_COPY: &str = "scenario.toml";
    /// The logger's run summary ([`RunSummary`]).
    pub const SUMMARY: &str = "summary.json";
    /// The plant's own counters and latencies ([`PlantLatency`]).
    pub const PLANT_LATENCY: &str = "plant_latency.json";
    /// The sample file (MCAP) of the first logger.
    pub const SAMPLES: &str = "samples.mcap";
    /// The latency histogram log (HdrHistogram intervals) of the first logger.
    pub const HISTOGRAM_LOG: &str = "latency.hlog";
    /// The supervisor's events (swap, crash, restart, ...), one JSON object a
    /// line; the logger copies them into the sample file.
    pub const EVENTS: &str = "events.jsonl";
    /// The supervisor's list of live processes and their duties.
    pub const PROCESSES: &str = "processes.json";
    /// Where `flexloop swap` leaves requests and finds the answers.
    pub const REQUESTS: &str = "requests";
    /// `flexloop set`'s changed scenarios, one file per change (`tuned/001.toml`).
    pub const TUNED: &str = "tuned";
    /// The scenario as it stands after swaps and sets (absent until the
    /// first); `flexloop status --scenario` prints it.
    pub const SCENARIO_NOW: &str = "scenario-now.toml";
    /// Where the live server (`flexloop up --live`) listens, once it does.
    pub const LIVE: &str = "live.json";
    /// What the live server did, written when it stops.
    pub const LIVE_SUMMARY: &str = "live_summary.json";
    /// The parameters each program of one's own runs with
    /// ([`crate::ProgramParams`]), one file per instance.
    pub const PARAMS: &str = "params";
    /// `flexloop run`'s control metrics.
    pub const METRICS: &str = "metrics.json";
    /// `flexloop bench`'s results.
    pub const BENCH: &str = "bench.json";
    /// `flexloop chaos`: its results, and the loop it ran (a run directory of its own).
    pub const CHAOS: &str = "chaos.json";
    pub const CHAOS_LOOP: &str = "loop";
    /// `flexloop report`'s folder and its two documents.
    pub const REPORT: &str = "report";
    pub const REPORT_MARKDOWN: &str = "report.md";
    pub const REPORT_HTML: &str = "report.html";
    /// `flexloop export --csv`'s folder.
    pub const CSV: &str = "csv";

    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self(path.into())
    }

    pub fn path(&self) -> &Path {
        &self.0
    }

    /// A file of the run directory by name.
    pub fn join(&self, name: impl AsRef<Path>) -> PathBuf {
        self.0.join(name)
    }

    pub fn scenario_copy(&self) -> PathBuf {
        self.join(Self::SCENARIO_COPY)
    }

    /// The folder `flexloop measure` writes a measurement's files into.
    pub fn measurement(&self) -> PathBuf {
        self.join("measurement")
    }

    /// The folder of the measurement ordered to start at `start_seq`.
    pub fn ordered_measurement(&self, start_seq: u64) -> PathBuf {
        self.measurement().join(format!("at-{start_seq}"))
    }

    /// The scenario as it stood when the measurement ordered to start at
    /// `start_seq` was ordered: the loop it measures, whatever swaps and
    /// sets came after.
    pub fn measured_scenario(&self, start_seq: u64) -> PathBuf {
        self.ordered_measurement(start_seq).join("scenario.toml")
    }

    pub fn summary(&self) -> PathBuf {
        self.join(Self::SUMMARY)
    }

    pub fn plant_latency(&self) -> PathBuf {
        self.join(Self::PLANT_LATENCY)
    }

    /// The sample file of the logger of `generation`.
    pub fn samples(&self, generation: u32) -> PathBuf {
        self.join(generation_file(Self::SAMPLES, generation))
    }

    /// The histogram log of the logger of `generation`.
    pub fn histogram_log(&self, generation: u32) -> PathBuf {
        self.join(generation_file(Self::HISTOGRAM_LOG, generation))
    }

    pub fn events(&self) -> PathBuf {
        self.join(Self::EVENTS)
    }

    pub fn processes(&self) -> PathBuf {
        self.join(Self::PROCESSES)
    }

    pub fn tuned(&self) -> PathBuf {
        self.join(Self::TUNED)
    }

    pub fn live(&self) -> PathBuf {
        self.join(Self::LIVE)
    }

    pub fn live_summary(&self) -> PathBuf {
        self.join(Self::LIVE_SUMMARY)
    }

    pub fn scenario_now(&self) -> PathBuf {
        self.join(Self::SCENARIO_NOW)
    }

    pub fn requests(&self) -> PathBuf {
        self.join(Self::REQUESTS)
    }

    /// `params/<role>.json` for the first instance, `params/<role>.g<N>.json`
    /// for generation N (as the stderr files are named).
    pub fn program_params(&self, role: &str, generation: u32) -> PathBuf {
        self.join(Self::PARAMS)
            .join(generation_file(&format!("{role}.json"), generation))
    }

    pub fn metrics(&self) -> PathBuf {
        self.join(Self::METRICS)
    }

    pub fn bench(&self) -> PathBuf {
        self.join(Self::BENCH)
    }

    pub fn chaos(&self) -> PathBuf {
        self.join(Self::CHAOS)
    }

    pub fn chaos_loop(&self) -> RunDir {
        RunDir::new(self.join(Self::CHAOS_LOOP))
    }

    pub fn report(&self) -> PathBuf {
        self.join(Self::REPORT)
    }

    pub fn csv(&self) -> PathBuf {
        self.join(Self::CSV)
    }

    /// The stderr file of a process: `role.stderr` for the first instance,
    /// `role.gN.stderr` for the one of generation N.
    pub fn stderr(&self, role: &str, generation: u32) -> PathBuf {
        self.join(stderr_name(role, generation))
    }

    /// The summary a restarted logger of `generation` writes of its own
    /// share (`summary.g<N>.json`); the first logger's is `summary.json`.
    pub fn generation_summary(&self, generation: u32) -> PathBuf {
        self.join(generation_file(Self::SUMMARY, generation))
    }

    /// Every logger generation's sample file, in generation order.
    pub fn sample_files(&self) -> Vec<(u32, PathBuf)> {
        let mut found: Vec<(u32, PathBuf)> = std::fs::read_dir(&self.0)
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|e| {
                let name = e.file_name();
                let generation = sample_file_generation(name.to_str()?)?;
                Some((generation, e.path()))
            })
            .collect();
        found.sort();
        found
    }

    /// The files of an earlier run in this directory (sorted names): a new
    /// run there would mix them into its own (its report would read the old
    /// `samples.g2.mcap`, its events the old crashes).
    pub fn earlier_run_files(&self) -> Vec<String> {
        let Ok(entries) = std::fs::read_dir(&self.0) else {
            return Vec::new();
        };
        let mut found: Vec<String> = entries
            .flatten()
            .filter_map(|e| e.file_name().into_string().ok())
            .filter(|name| is_run_file(name))
            .collect();
        found.sort();
        found
    }

    /// The logger's summary, typed; the error names the file.
    pub fn read_summary(&self) -> Result<RunSummary, FileError> {
        read_json(&self.summary())
    }

    /// The plant's own figures, typed; the error names the file.
    pub fn read_plant_latency(&self) -> Result<PlantLatency, FileError> {
        read_json(&self.plant_latency())
    }
}

impl AsRef<Path> for RunDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

/// `samples.mcap` for the first logger, `samples.g2.mcap` for generation 2.
pub fn generation_file(name: &str, generation: u32) -> String {
    match (generation, name.rsplit_once('.')) {
        (0, _) | (_, None) => name.to_string(),
        (g, Some((stem, ext))) => format!("{stem}.g{g}.{ext}"),
    }
}

/// The sample file and the histogram log of the logger of `generation`.
pub fn logger_files(generation: u32) -> [String; 2] {
    [
        generation_file(RunDir::SAMPLES, generation),
        generation_file(RunDir::HISTOGRAM_LOG, generation),
    ]
}

/// The logger generation whose sample file is named `name`: 0 for
/// `samples.mcap`, N for `samples.gN.mcap`; none for any other name.
pub fn sample_file_generation(name: &str) -> Option<u32> {
    if name == RunDir::SAMPLES {
        return Some(0);
    }
    let n: u32 = name
        .strip_prefix("samples.g")?
        .strip_suffix(".mcap")?
        .parse()
        .ok()?;
    (n > 0).then_some(n)
}

/// Whether `name` is a sample file of any logger generation.
pub fn is_sample_file(name: &str) -> bool {
    name.starts_with("samples") && name.ends_with(".mcap")
}

/// Whether `name` is a file a run writes into its directory (any logger
/// generation, any role's stderr).
pub fn is_run_file(name: &str) -> bool {
    let generational = |file: &str| {
        let (stem, ext) = file.rsplit_once('.').unwrap_or((file, ""));
        name == file
            || name
                .strip_prefix(&format!("{stem}.g"))
                .and_then(|rest| rest.strip_suffix(&format!(".{ext}")))
                .is_some_and(|g| !g.is_empty() && g.bytes().all(|b| b.is_ascii_digit()))
    };
    [
        RunDir::SCENARIO_COPY,
        RunDir::SUMMARY,
        RunDir::PLANT_LATENCY,
        RunDir::EVENTS,
        RunDir::PROCESSES,
        RunDir::REQUESTS,
        RunDir::TUNED,
        RunDir::SCENARIO_NOW,
        RunDir::METRICS,
        RunDir::BENCH,
        RunDir::LIVE,
        RunDir::LIVE_SUMMARY,
    ]
    .contains(&name)
        || is_sample_file(name)
        || generational(RunDir::HISTOGRAM_LOG)
        || name.ends_with(".stderr")
}

/// The stderr file name of a role's instance of `generation`.
pub fn stderr_name(role: &str, generation: u32) -> String {
    if generation == 0 {
        format!("{role}.stderr")
    } else {
        format!("{role}.g{generation}.stderr")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generations_after_the_first_get_their_own_files() {
        let dir = RunDir::new("r");
        assert_eq!(dir.samples(0), Path::new("r/samples.mcap"));
        assert_eq!(dir.samples(2), Path::new("r/samples.g2.mcap"));
        assert_eq!(logger_files(3), ["samples.g3.mcap", "latency.g3.hlog"]);
        assert!(is_sample_file("samples.g3.mcap") && !is_sample_file("latency.hlog"));
        assert_eq!(sample_file_generation("samples.mcap"), Some(0));
        assert_eq!(sample_file_generation("samples.g12.mcap"), Some(12));
        assert_eq!(sample_file_generation("samples.g0.mcap"), None);
        assert_eq!(sample_file_generation("samples.gx.mcap"), None);
        assert_eq!(sample_file_generation("samples-old.mcap"), None);
        assert_eq!(dir.generation_summary(2), Path::new("r/summary.g2.json"));
        assert_eq!(dir.stderr("observer", 0), Path::new("r/observer.stderr"));
        assert_eq!(dir.stderr("observer", 4), Path::new("r/observer.g4.stderr"));
    }

    #[test]
    fn a_run_file_is_told_from_a_users_file() {
        for name in [
            "samples.g2.mcap",
            "latency.g3.hlog",
            "latency.hlog",
            "events.jsonl",
            "scenario.toml",
            "plant.stderr",
        ] {
            assert!(is_run_file(name), "{name}");
        }
        for name in ["notes.txt", "latency.gx.hlog", "my.toml", "report.md"] {
            assert!(!is_run_file(name), "{name}");
        }
    }
}
