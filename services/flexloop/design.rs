//! `flexloop design [SCENARIO] [--continuous] [--json]`: the design report of
//! the thesis chain (modal table, observer poles, damping AD achieves, and
//! the largest PID bandwidth meeting the 6 dB rule for every case), at the
//! scenario's rate and loop delay, before anything runs.

use flexloop_control::report::{ThesisDesignSpec, thesis_design_report};
use flexloop_scenario::{Overrides, Scenario};
use std::ffi::OsString;
use std::path::PathBuf;

pub fn design(args: Vec<OsString>) -> Result<i32, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let mut scenario = None;
    let (mut json, mut continuous) = (false, false);
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Value(v) if scenario.is_none() => scenario = Some(PathBuf::from(v)),
            Long("json") => json = true,
            Long("continuous") => continuous = true,
            other => return Err(other.unexpected().to_string()),
        }
    }
    let path = crate::resolve_scenario(scenario)?;
    let s = Scenario::load(&path, &Overrides::default()).map_err(|e| e.to_string())?;
    if s.plant.model != "thesis-chain" {
        return Err(format!(
            "{}: field plant.model: the design report covers the thesis chain, not `{}`",
            path.display(),
            s.plant.model
        ));
    }
    let mut spec = if continuous {
        ThesisDesignSpec::continuous()
    } else {
        ThesisDesignSpec::discrete(
            1.0 / s.timing.rate_hz,
            1 + s.controller.extra_delay_samples as usize,
        )
    };
    spec.output = s.plant.output;
    let report = thesis_design_report(&spec).map_err(|e| format!("{}: {e}", path.display()))?;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?
        );
    } else {
        print!("{}", report.render_text());
    }
    Ok(0)
}
