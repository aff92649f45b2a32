//! flexloop-node: each loop process's life around its per-sample component:
//! arguments, ports, real-time set-up, the loop itself, and a clean exit.
//!
//! The service binaries under `services/` are thin mains over [`run`].

pub mod args;
pub mod controller;
pub mod duty;
pub mod handover;
pub mod instance;
pub mod logger;
pub mod observer;
pub mod overrides;
pub mod plant;
pub mod prepared;
pub mod recording;
pub mod replay;
pub mod run_metadata;
pub mod spare;
pub mod startup;
pub mod summary;
pub mod tick;

use std::fmt;
use std::time::{Duration, Instant};

pub use args::{Role, ServiceArgs};

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
}

impl fmt::Display for NodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NodeError::Usage(m) => write!(f, "usage: {m}"),
            NodeError::Scenario(e) => e.fmt(f),
            NodeError::Transport(e) => e.fmt(f),
            NodeError::Io { path, error } => write!(f, "{path}: {error}"),
            NodeError::Peer(m) | NodeError::Order(m) => f.write_str(m),
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

/// Runs the process for `role` with the command line `args` (without argv[0]);
/// returns the exit code. Used by every service main.
pub fn main_for(role: Role) -> i32 {
    let args = match ServiceArgs::parse(role, std::env::args_os().skip(1)) {
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
    let result = match role {
        Role::Plant => plant::run(&args),
        Role::Observer => instance::run::<observer::Observer>(&args),
        Role::Controller => instance::run::<controller::Controller>(&args),
        Role::Logger => logger::run(&args),
    };
    match result {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("flexloop-{}: {e}", role.name());
            1
        }
    }
}
