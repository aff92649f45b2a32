//! `params/<role>.g<N>.json`: the parameters a program of one's own runs
//! with, as its law read them (defaults included), written by the program
//! (flexloop-sdk in Rust, the `flexloop` package in Python) once its law is
//! made, so that `flexloop get` lists what the running law really uses
//! rather than only what the scenario wrote (docs/components.md).

use serde::{Deserialize, Serialize};

/// What one program instance runs with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProgramParams {
    /// `controller` or `observer`.
    pub role: String,
    pub generation: u32,
    /// Every parameter the law reads, by name, with the value it uses: the
    /// scenario's `[<role>.params]` entry, or the law's default where the
    /// scenario gives none.
    pub params: serde_json::Map<String, serde_json::Value>,
    /// The names among `params` that the scenario did not give (the law's
    /// defaults).
    pub defaulted: Vec<String>,
}
