//! Why the live server stopped or could not start: one error type for the
//! server and what feeds it.

use flexloop_node::NodeError;
use std::fmt;

/// Why the server stopped or could not start.
#[derive(Debug)]
pub enum LiveError {
    /// The WebSocket server could not start (the address is taken, ...).
    Start { address: String, reason: String },
    /// A channel of the Foxglove context could not be made.
    Channel { topic: &'static str, reason: String },
    /// Reading the loop's channels failed.
    Loop(NodeError),
    /// `live.json` could not be written.
    RunFile(flexloop_runfiles::FileError),
}

impl fmt::Display for LiveError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LiveError::Start { address, reason } => {
                write!(f, "the live server cannot listen on {address}: {reason}")
            }
            LiveError::Channel { topic, reason } => write!(f, "live channel {topic}: {reason}"),
            LiveError::Loop(e) => write!(f, "reading the loop: {e}"),
            LiveError::RunFile(e) => e.fmt(f),
        }
    }
}

impl std::error::Error for LiveError {}

impl From<NodeError> for LiveError {
    fn from(e: NodeError) -> Self {
        LiveError::Loop(e)
    }
}

impl From<flexloop_transport::TransportError> for LiveError {
    fn from(e: flexloop_transport::TransportError) -> Self {
        LiveError::Loop(NodeError::Transport(e))
    }
}
