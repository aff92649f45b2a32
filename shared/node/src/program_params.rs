//! A program of one's own reports the parameters its law runs with
//! (`params/<role>.json` in the run directory, flexloop-runfiles'
//! `ProgramParams`), defaults included, so that `flexloop get` lists what
//! the running law reads rather than only what its scenario wrote.

use crate::NodeError;
use crate::args::ServiceArgs;
use flexloop_components::LawSetup;
use flexloop_runfiles::json::write_json_atomically;
use flexloop_runfiles::{ProgramParams, RunDir};

/// Writes what the law made from `setup` read, when a program serves the
/// role (the built-in laws' tuning is the scenario's own fields).
pub fn record(setup: &LawSetup<'_>, args: &ServiceArgs) -> Result<(), NodeError> {
    if setup.scenario.program(setup.role)?.is_none() {
        return Ok(());
    }
    let read = setup.params_read();
    let record = ProgramParams {
        role: setup.role.section().to_string(),
        generation: setup.generation,
        params: read.as_ref().map(|r| r.values.clone()).unwrap_or_default(),
        defaulted: read.map(|r| r.defaulted).unwrap_or_default(),
    };
    let path = RunDir::new(&args.run_dir).program_params(&record.role, record.generation);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|error| NodeError::Io {
            path: dir.display().to_string(),
            error,
        })?;
    }
    write_json_atomically(&path, &record).map_err(NodeError::RunFile)
}
