//! flexloop-recording: the run's record of every sample, apart from the
//! per-sample cores that make them (docs/recording.md).
//!
//! - [`recorder`]: the logger's bookkeeping: gaps, latencies, events, and
//!   every message into the sample file.
//! - [`sample_file`]: the run's MCAP sample file, written and read back.
//! - [`mcap_repair`]: closes a sample file its writer left unfinished.
//! - [`storage`]: where a sample file lives (a file, or memory), as the
//!   writer and the repair both use it.
//! - [`event_message`]: one `/events` message, typed: the logger's, flexloop's
//!   and the supervisor's events.
//! - [`loop_events`]: conditions of the loop (misses, stalls, fallbacks, ...)
//!   read off the samples.

pub mod event_message;
pub mod loop_events;
pub mod mcap_repair;
pub mod recorder;
pub mod sample_file;
pub mod storage;

pub use event_message::EventMessage;
pub use recorder::{RecordSink, Recorder};
pub use sample_file::{LogEvent, LogReader, Record, SampleWriter};
