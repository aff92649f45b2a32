//! flexloop-runfiles: what a run directory holds, named once and typed once.
//!
//! The logger (in `flexloop-node`) and the `flexloop` binary both write and
//! read these files; a low crate of plain data serves both without a circle.
//!
//! - [`RunDir`]: the path of every file of a run directory.
//! - [`json`]: reading and atomically writing one JSON file, errors naming it.
//! - [`latency`]: a histogram's count and percentiles, as every file keeps them.
//! - [`summary`]: `summary.json` (the logger) and `plant_latency.json` (the plant).
//! - [`events`]: `events.jsonl`, what the supervisor did and saw, one typed event a line.
//! - [`supervision`]: `processes.json`, swap and set requests and their answers.
//! - [`metrics`]: `metrics.json` (`flexloop run`).
//! - [`bench`]: `bench.json`, `logging_cost.json` and `sweep.json`.
//! - [`chaos`]: `chaos.json`, what `flexloop chaos` did and what it cost.
//! - [`program`]: `params/<role>.g<N>.json`, the parameters a program of
//!   one's own runs with.
//! - [`live`]: `live.json` and `live_summary.json`, where a loop's live server
//!   listens and what it did.

pub mod bench;
pub mod chaos;
pub mod events;
pub mod json;
pub mod latency;
pub mod live;
pub mod metrics;
pub mod program;
pub mod run_dir;
pub mod summary;
pub mod supervision;

pub use json::FileError;
pub use latency::{Histogram, Percentiles};
pub use program::ProgramParams;
pub use run_dir::RunDir;
pub use summary::{PlantLatency, RunSummary, SpinReport, TickWaitReport};
