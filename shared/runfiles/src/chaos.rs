//! `chaos.json`: the faults `flexloop chaos` injected into a running loop
//! and what each cost it.

use serde::{Deserialize, Serialize};

/// `chaos.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChaosFile {
    /// The scenario file the loop ran (with `max_restarts` raised for the kills).
    pub scenario: String,
    pub seed: u64,
    pub rate_hz: f64,
    /// The loop's run directory.
    pub run_dir: String,
    /// Every kill, in order.
    pub kills: Vec<Kill>,
    /// Per role killed.
    pub roles: Vec<RoleFaults>,
    /// Ticks the plant ran, and its loop misses and stalled ticks over the run.
    pub ticks: u64,
    pub misses: u64,
    pub stalled_ticks: u64,
    /// Samples between the first and last recorded that no file holds.
    pub missing_samples: u64,
    /// Files of the loop's prefix left in shared memory after it ended.
    pub files_left: u64,
    /// `flexloop up`'s exit status.
    pub exit_code: i32,
    /// Why the kills stopped short of the number asked for (the loop
    /// ended, or had nothing of a role to kill for 10 s: it did not recover).
    pub aborted: Option<String>,
}

/// One fault: a kill -9, or a hang (SIGSTOP: alive, silent).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Kill {
    pub role: String,
    pub pid: i32,
    /// `kill` (SIGKILL) or `hang` (SIGSTOP).
    #[serde(default = "kill")]
    pub fault: String,
    /// When it was sent (CLOCK_MONOTONIC ns, the loop's clock).
    pub at_ns: u64,
    /// The loop's newest recorded tick before it.
    pub seq: Option<u64>,
    /// Ticks on the plant's safe action until the loop recovered; `None`
    /// if the recording shows no recovery.
    pub held_ticks: Option<u64>,
    /// Of those, the ticks the plant marked stalled (the machine's part).
    #[serde(default)]
    pub held_stalled_ticks: Option<u64>,
    /// Samples the recording lacks in the second after it.
    pub missing_samples: u64,
    /// A replacement was seen serving before the next kill.
    pub replaced: bool,
}

/// What the kills of one role cost.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RoleFaults {
    pub role: String,
    pub kills: u32,
    pub held_p50: u64,
    pub held_p99: u64,
    pub held_max: u64,
    /// The held ticks less those the plant marked stalled: what the
    /// hand-over itself cost.
    #[serde(default)]
    pub unstalled_p50: u64,
    #[serde(default)]
    pub unstalled_p99: u64,
    /// Kills after which the recording shows no recovery.
    pub unrecovered: u32,
    /// Kills after which no replacement was seen serving.
    pub not_replaced: u32,
    pub missing_samples: u64,
}

fn kill() -> String {
    "kill".into()
}
