//! flexloop-live: the live view of a running loop (`flexloop up --live`).
//!
//! A Foxglove WebSocket server (the official `foxglove` crate) that reads
//! the loop's channels as one more polling subscriber and serves them with
//! the sample file's schemas, so a layout made on a recording works live:
//! `/measurement`, `/estimate`, `/command` (ros1msg), `/events`, a
//! once-a-second `/latency`, `/scenario`, and `/measurement/response`, a
//! measurement's frequency responses while it runs. The loop's tunables are its
//! parameters; setting one goes through the same check and hand-over as
//! `flexloop set` (docs/live.md).
//!
//! - [`options`]: what is exposed and to whom (loopback, token, read-only).
//! - [`gate`]: the public address: the connection cap, the size of what a
//!   client may send, and the mark of a connection that came through it.
//! - [`token`]: the token compared in constant time, wrong ones throttled.
//! - [`clients`]: each client's rate, subscriptions and token.
//! - [`parameters`]: tunables as Foxglove parameters and back.
//! - [`tuning`]: what the server asks of the loop ([`Tuner`]).
//! - [`server`]: the server, its parameters and the loop that feeds it.
//! - `reader`: the loop's samples as the server reads them.
//! - `feeds`: what the JSON channels carry (latency, events, scenario).
//! - `measured`, `estimate`: `/measurement/response`, the periods of a
//!   measurement collected from the samples read, and its responses
//!   computed on worker threads.

pub mod clients;
mod counts;
mod error;
mod estimate;
mod feeds;
pub mod gate;
mod measured;
pub mod options;
pub mod parameters;
mod reader;
pub mod server;
pub mod token;
pub mod tuning;

pub use error::LiveError;
pub use options::{
    DEFAULT_ADDRESS, HOW_TO_GIVE_A_TOKEN, LiveOptions, MIN_TOKEN_CHARS, OptionsError, TOKEN_ENV,
};
pub use server::{LoopSide, endpoint, serve};
pub use tuning::{SetOutcome, Tuner};
