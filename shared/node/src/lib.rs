//! flexloop-node: each loop process's life around its per-sample component:
//! arguments, ports, real-time set-up, the loop itself, and a clean exit.
//!
//! The service binaries under `services/` are thin mains over [`run`].

pub mod args;
pub mod controller;
pub mod duty;
pub mod handover;
pub mod in_order;
pub mod instance;
pub mod logger;
pub mod measure_orders;
pub mod observer;
pub mod overrides;
pub mod plant;
pub mod prepared;
pub mod program_params;
pub mod recording;
pub mod replay;
pub mod run_metadata;
pub mod spare;
pub mod startup;
pub mod summary;
pub mod tick;

use std::ffi::OsString;
use std::fmt;
use std::time::{Duration, Instant};

pub use args::{Role, ServiceArgs};
use flexloop_components::{ControlLaw, ControllerCore, EstimationLaw, ObserverCore};

/// Why a loop process stopped with an error.
#[derive(Debug)]
pub enum NodeError {
    Usage(String),
    Scenario(flexloop_scenario::ScenarioError),
    Transport(flexloop_transport::TransportError),
    Io {
        path: String,
        error: std::io::Error,
    },
    /// Another process did not show up or went silent.
    Peer(String),
    /// A run file (the summary) could not be written.
    RunFile(flexloop_runfiles::FileError),
    /// A supervisor's order this process cannot serve.
    Order(String),
    /// The controller's law could not be built for this loop.
    Law(String),
}

impl fmt::Display for NodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NodeError::Usage(m) => write!(f, "usage: {m}"),
            NodeError::Scenario(e) => e.fmt(f),
            NodeError::Transport(e) => e.fmt(f),
            NodeError::Io { path, error } => write!(f, "{path}: {error}"),
            NodeError::Peer(m) | NodeError::Order(m) | NodeError::Law(m) => f.write_str(m),
            NodeError::RunFile(e) => e.fmt(f),
        }
    }
}

impl std::error::Error for NodeError {}

impl From<flexloop_scenario::ScenarioError> for NodeError {
    fn from(e: flexloop_scenario::ScenarioError) -> Self {
        NodeError::Scenario(e)
    }
}

impl From<flexloop_runfiles::FileError> for NodeError {
    fn from(e: flexloop_runfiles::FileError) -> Self {
        NodeError::RunFile(e)
    }
}

impl From<flexloop_transport::TransportError> for NodeError {
    fn from(e: flexloop_transport::TransportError) -> Self {
        NodeError::Transport(e)
    }
}

/// How long a process waits at start-up for the peers it needs.
pub(crate) const PEER_TIMEOUT: Duration = Duration::from_secs(20);

/// Start-up wait: polls `ready` every 2 ms until it holds (`Ok(true)`) or a
/// shutdown is requested (`Ok(false)`); after [`PEER_TIMEOUT`] an error says
/// what was still `missing`.
pub(crate) fn await_peers(
    mut ready: impl FnMut() -> Result<bool, NodeError>,
    missing: impl Fn() -> String,
) -> Result<bool, NodeError> {
    let since = Instant::now();
    loop {
        if ready()? {
            return Ok(true);
        }
        if flexloop_runtime::shutdown::requested() {
            return Ok(false);
        }
        if since.elapsed() > PEER_TIMEOUT {
            return Err(NodeError::Peer(format!(
                "peers did not connect within {PEER_TIMEOUT:?}: {}",
                missing()
            )));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Runs the process for `role` with this process's command line; returns
/// the exit code. Used by every service main.
pub fn main_for(role: Role) -> i32 {
    serve_role(role, |args| match role {
        Role::Plant => plant::run(args),
        Role::Observer => {
            instance::run::<observer::Observer<ObserverCore>>(args, instance::Spares::Serves)
        }
        Role::Controller => {
            instance::run::<controller::Controller<ControllerCore>>(args, instance::Spares::Serves)
        }
        Role::Logger => logger::run(args),
    })
}

/// Runs a controller process around the law `L` (a user's program, built on
/// flexloop-sdk): the life the built-in controller has, but never as a warm
/// spare. Returns the exit code.
pub fn run_controller<L: ControlLaw>() -> i32 {
    serve_role(Role::Controller, |args| {
        instance::run::<controller::Controller<L>>(args, instance::Spares::Never)
    })
}

/// Runs an observer process around the law `L` (a user's program, built
/// on flexloop-sdk), as [`run_controller`] does a controller's.
pub fn run_observer<L: EstimationLaw>() -> i32 {
    serve_role(Role::Observer, |args| {
        instance::run::<observer::Observer<L>>(args, instance::Spares::Never)
    })
}

/// The command line, the signal handlers, `serve`, and the stderr line and
/// exit code of its result.
fn serve_role(role: Role, serve: impl FnOnce(&ServiceArgs) -> Result<(), NodeError>) -> i32 {
    let args = match ServiceArgs::parse(role, flexloop_args(std::env::args_os().skip(1))) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("flexloop-{}: {e}", role.name());
            return 2;
        }
    };
    if let Err(e) = flexloop_runtime::shutdown::install() {
        eprintln!(
            "flexloop-{}: cannot install signal handlers: {e}",
            role.name()
        );
        return 1;
    }
    match serve(&args) {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("flexloop-{}: {e}", role.name());
            1
        }
    }
}

/// The arguments flexloop gives a process: all of them for a built-in one;
/// for a user's program, those after the last `--`, since its own come
/// first (`exec = ["python3", "law.py", "--gain", "2"]` runs
/// `python3 law.py --gain 2 -- --scenario …`).
pub fn flexloop_args(args: impl IntoIterator<Item = OsString>) -> Vec<OsString> {
    let args: Vec<OsString> = args.into_iter().collect();
    match args.iter().rposition(|a| a == "--") {
        Some(at) => args[at + 1..].to_vec(),
        None => args,
    }
}

/// A user's program's own arguments: those before the `--` that starts
/// flexloop's (see [`flexloop_args`]); all of them if there is none.
pub fn own_args() -> Vec<String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.iter().rposition(|a| a == "--") {
        Some(at) => args[..at].to_vec(),
        None => args,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_programs_own_arguments_come_before_flexloops() {
        let line = ["--gain", "2", "--", "--scenario", "s.toml"].map(OsString::from);
        assert_eq!(flexloop_args(line.clone()), ["--scenario", "s.toml"]);
        let built_in = ["--scenario", "s.toml"].map(OsString::from);
        assert_eq!(flexloop_args(built_in.clone()), built_in);
    }
}
