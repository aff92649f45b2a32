//! Whether a scenario is accepted: the one check every command makes of a
//! file before it uses it (`up`, `run`, `bench`, `positions`, `design`), so
//! that a file one command accepts, every other accepts too.

use crate::LoopDesign;
use flexloop_scenario::{Overrides, Scenario, ScenarioError};
use std::path::Path;

/// A scenario that passed every check, and its design.
#[derive(Debug, Clone)]
pub struct Accepted {
    pub scenario: Scenario,
    pub design: LoopDesign,
}

/// Reads `path` and checks it as [`accept_text`] does.
pub fn accept(
    path: &Path,
    overrides: &Overrides,
    online_cpus: usize,
) -> Result<Accepted, ScenarioError> {
    let text = flexloop_scenario::load::read_scenario_text(path)?;
    accept_text(path, &text, overrides, online_cpus)
}

/// `text` (read from `path`) parsed, overridden and validated, this
/// machine (`online_cpus`) fit for its real-time profile, and the loop
/// designed: ranges, fields that do not apply, costs and stability are all
/// refused here, before anything starts.
pub fn accept_text(
    path: &Path,
    text: &str,
    overrides: &Overrides,
    online_cpus: usize,
) -> Result<Accepted, ScenarioError> {
    let scenario = Scenario::from_text(path, text, overrides)?;
    scenario.check_machine(online_cpus)?;
    let design = LoopDesign::from_scenario(&scenario)?;
    Ok(Accepted { scenario, design })
}
