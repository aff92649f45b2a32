//! What the commands that run a loop share on their command line (`up`,
//! `run`: [`LoopFlags`]; those that name a running loop: [`PrefixArg`]),
//! their exit status for a failed verdict, and the words they print about
//! the loop's design before it starts.

use flexloop_node::overrides::OverrideFlags;
use flexloop_supervisor::launch::{LoopArgs, Prepared, resolve_scenario};
use std::path::PathBuf;

/// Exit status of a command whose loop ran to its end but whose verdict
/// failed: stalls dominated (`up`, `status`), or `run`'s control figures
/// are not the design's (`flexloop_analysis::verdict`). 2 is an error.
pub const VERDICT_FAILED: i32 = 3;

/// `[SCENARIO] [--rate HZ] [--duration S] [--mode M] [--no-realtime] [--run-dir DIR]`:
/// the command line of `up` and `run`.
#[derive(Debug, Clone, clap::Args)]
pub struct LoopFlags {
    /// Scenario file, or its name under scenarios/ [default: scenarios/default.toml]
    pub scenario: Option<PathBuf>,
    #[command(flatten)]
    pub overrides: OverrideFlags,
    /// Where the run's files go [default: runs/<stamp>-<scenario>-<pid>]
    #[arg(long, value_name = "DIR")]
    pub run_dir: Option<PathBuf>,
}

impl LoopFlags {
    pub fn into_loop_args(self) -> anyhow::Result<LoopArgs> {
        Ok(LoopArgs {
            scenario: resolve_scenario(self.scenario)?,
            overrides: self.overrides.into(),
            run_dir: self.run_dir,
        })
    }
}

/// The PID's f_bw in words ("PID f_bw 43.5 Hz (auto)"), None without one.
pub fn pid_words(design: &flexloop_design::LoopDesign) -> Option<String> {
    design.pid_bandwidth.map(|p| {
        format!(
            "PID f_bw {:.1} Hz{}",
            p.hz,
            if p.auto { " (auto)" } else { "" }
        )
    })
}

/// `up` and `run`: one line on stderr when the loop breaks the 6 dB rule or
/// is close to unstable (flexloop-analysis' `LoopReport::warning`, which
/// defines both). The loop still starts: the scenario is valid, its design
/// only questionable.
pub fn warn_about_design(prepared: &Prepared) {
    // A program's law is its own: the built-in design's rule does not judge it.
    let scenario = &prepared.scenario;
    if scenario.controller.exec.is_some() || scenario.observer.exec.is_some() {
        return;
    }
    match flexloop_analysis::loop_report::loop_check(&prepared.scenario, &prepared.design) {
        Ok(report) => {
            if let Some(line) = report.warning() {
                eprintln!("flexloop: warning: {line}");
            }
        }
        Err(e) => eprintln!("flexloop: warning: the loop's design could not be checked: {e}"),
    }
}

/// `[--prefix P]`: which running loop (default: every one, or the only one).
#[derive(Debug, Clone, clap::Args)]
pub struct PrefixArg {
    /// The loop's iceoryx2 prefix, as `flexloop status` shows it
    #[arg(long, value_name = "P")]
    pub prefix: Option<String>,
}
