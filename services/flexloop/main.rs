//! flexloop: starts, drives and measures the loop's processes. This file
//! reads the command line and hands each command to its module; what the
//! commands ask of a loop (start it, supervise it, attach to it) is
//! flexloop-supervisor's.
//!
//! - [`loop_command`]: the flags shared by the commands that run or name a loop.
//! - [`running`]: `up`, and `down`, `status` and `swap` on a running loop.
//! - [`live_view`]: `up --live`, the loop served to Foxglove while it runs.
//! - [`tune`]: `get` and `set`, live tuning of a running loop.
//! - [`run`]: `run` and `fit-ff`; [`bench`], [`sweep`], [`logging_cost`],
//!   [`live_cost`], [`probes`]: `bench`; [`chaos`]: `chaos`; [`report`],
//!   [`design`], [`positions`], [`export`]; [`measure`]: `measure`.
//! - [`run_measurements`]: a run's measurements, for `measure` and `report`.

mod ab_table;
mod bench;
mod chaos;
mod deadline_sweep;
mod deployment;
mod design;
mod export;
mod live_cost;
mod live_view;
mod logging_cost;
mod loop_command;
mod measure;
mod positions;
mod probes;
mod report;
mod run;
mod run_measurements;
mod running;
mod sampling;
mod sweep;
mod tune;

use clap::{Parser, Subcommand};
use flexloop_runtime::shutdown;

/// Starts, drives and measures a real-time control loop of four processes
/// (plant, observer, controller, logger) over iceoryx2.
#[derive(Debug, Parser)]
#[command(name = "flexloop", version, arg_required_else_help = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Start the loop's processes until the scenario's duration ends, Ctrl-C or `flexloop down`.
    Up(running::UpArgs),
    /// Run the scenario's trajectory, then print its control metrics beside the timing summary; writes metrics.json.
    Run(run::RunFlags),
    /// A finished run as report.md (with SVG figures) and a self-contained report.html.
    Report(report::ReportArgs),
    /// Fit the four feedforward gains from a recorded run and write them into a scenario file.
    #[command(alias = "tune-ff")]
    FitFf(run::FitFfArgs),
    /// The frequency responses a run's [measure] excited, against the design; --fit: a plant file fitted to them.
    Measure(measure::MeasureArgs),
    /// Design report of the scenario's loop (and the thesis chain's) before anything runs.
    Design(design::DesignArgs),
    /// Table 4.1: rms e_true over the scan with the sensor along the chain.
    Positions(positions::PositionsArgs),
    /// A run's sample file as one CSV per channel.
    Export(export::ExportArgs),
    /// Stop a running loop (with several running: --prefix P, or --all).
    Down(running::DownArgs),
    /// Live counters and latency percentiles of a running loop (--scenario: its scenario as it stands).
    Status(running::StatusArgs),
    /// Replace a running loop's controller or observer by one designed from SCENARIO.
    Swap(running::SwapArgs),
    /// A running loop's tunables and their current values.
    Get(tune::GetArgs),
    /// Change tunables of a running loop: checked, then handed over bumplessly through the swap path.
    Set(tune::SetArgs),
    /// Run the loop, measure this machine's floors, print the latency table and a verdict
    /// (or, with --sweep, one run per point of a grid; with --logging-cost, with and without the logger).
    Bench(bench::BenchArgs),
    /// Kill the loop's processes at random moments and report what each kill cost (chaos.json).
    Chaos(chaos::ChaosArgs),
    /// The live server of `up --live` (started by the supervisor).
    #[command(hide = true)]
    LiveServer(live_view::LiveServerArgs),
}

impl Command {
    /// Whether SIGINT and SIGTERM end the command by their default action,
    /// at once, with no handler: `design` starts no process and writes no
    /// file, and a large model's design computes for long without a point
    /// that could look at the shutdown flag, so Ctrl-C must not wait for it
    /// (docs/own-plant.md). The shell sees the signal (exit status 130 or 143).
    fn ends_on_signal(&self) -> bool {
        matches!(self, Command::Design(_))
    }

    /// Whether the command supervises processes (it must outlive a closed stdout).
    fn supervises(&self) -> bool {
        matches!(
            self,
            Command::Up(_)
                | Command::Run(_)
                | Command::Bench(_)
                | Command::Positions(_)
                | Command::Chaos(_)
        )
    }
}

fn main() {
    let cli = Cli::parse();
    let code = match dispatch(cli.command) {
        Ok(code) => code,
        Err(e) => {
            // The whole chain of causes, outermost first.
            eprintln!("flexloop: {e:#}");
            2
        }
    };
    std::process::exit(code);
}

fn dispatch(command: Command) -> anyhow::Result<i32> {
    use anyhow::Context;
    if !command.ends_on_signal() {
        shutdown::install().context("cannot install signal handlers")?;
    }
    if !command.supervises() {
        // A command that only reads and prints ends quietly when its reader
        // does (`flexloop status | head`), as Unix tools do; one that
        // supervises processes must not die before it has stopped them.
        // SAFETY: restores the default action of a signal; no handler runs.
        unsafe { libc::signal(libc::SIGPIPE, libc::SIG_DFL) };
    }
    match command {
        Command::Up(args) => running::up(args),
        Command::Run(flags) => run::run(flags),
        Command::Report(args) => report::report(args),
        Command::FitFf(args) => run::fit_ff(args),
        Command::Design(args) => design::design(args),
        Command::Measure(args) => measure::measure(args),
        Command::Positions(args) => positions::positions(args),
        Command::Export(args) => export::export(args),
        Command::Down(args) => running::down(args),
        Command::Status(args) => running::status(args),
        Command::Swap(args) => running::swap(args),
        Command::Get(args) => tune::get(args),
        Command::Set(args) => tune::set_command(args),
        Command::Bench(args) => bench::dispatch(args),
        Command::Chaos(args) => chaos::chaos(args),
        Command::LiveServer(args) => live_view::serve(args),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_command_line_is_consistent() {
        use clap::CommandFactory;
        Cli::command().debug_assert();
    }
}
