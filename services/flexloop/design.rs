//! `flexloop design [SCENARIO] [--continuous] [--json]`: the design report,
//! before anything runs.
//!
//! - The thesis chain with its sensor on a mass y1..y7: the thesis report
//!   (modal table, observer poles, damping AD achieves, and the largest PID
//!   bandwidth meeting the 6 dB rule for every case) at the scenario's rate
//!   and loop delay, for that output.
//! - The thesis chain with its sensor elsewhere (between masses, on ma):
//!   the scenario's own loop at its sensor, then the thesis report at the
//!   mass nearest the sensor, named as such.
//! - A scanned sensor, and every other model: the scenario's own loop
//!   (modes, observer poles, per-output sensitivity peaks).

use flexloop_analysis::loop_report::loop_report;
use flexloop_control::report::{ThesisDesignSpec, thesis_design_report};
use flexloop_scenario::{LoopDesign, Overrides, Scenario};
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
    // The mass the thesis report is about, and whether the sensor sits on
    // it (a scanned sensor has no one mass: only its own loop is reported).
    let thesis_output =
        (s.plant.model == "thesis-chain" && s.plant.sensor_scan.is_none()).then(|| {
            let node = s.plant.sensor_node();
            let nearest = node.round().clamp(1.0, 7.0);
            (nearest as usize, nearest == node)
        });
    if continuous && thesis_output.is_none() {
        return Err(format!(
            "{}: field plant.model: --continuous is the thesis chain's report, not `{}`'s",
            path.display(),
            s.plant.model
        ));
    }
    let loop_part = match thesis_output {
        Some((_, true)) => None,
        _ => {
            let d = LoopDesign::from_scenario(&s).map_err(|e| e.to_string())?;
            Some(loop_report(&s, &d).map_err(|e| format!("{}: {e}", path.display()))?)
        }
    };
    let thesis_part = match thesis_output {
        Some((output, _)) => {
            let mut spec = if continuous {
                ThesisDesignSpec::continuous()
            } else {
                ThesisDesignSpec::discrete(
                    1.0 / s.timing.rate_hz,
                    1 + s.controller.extra_delay_samples as usize,
                )
            };
            spec.output = output;
            Some(thesis_design_report(&spec).map_err(|e| format!("{}: {e}", path.display()))?)
        }
        None => None,
    };
    if json {
        let value = match (&loop_part, &thesis_part) {
            (None, Some(thesis)) => serde_json::to_value(thesis),
            (l, t) => Ok(serde_json::json!({ "loop": l, "thesis_at_nearest_mass": t })),
        }
        .map_err(|e| e.to_string())?;
        println!(
            "{}",
            serde_json::to_string_pretty(&value).map_err(|e| e.to_string())?
        );
        return Ok(0);
    }
    if let Some(l) = &loop_part {
        print!("{}", l.render_text());
    }
    if let Some([from, to]) = s.plant.sensor_scan {
        println!(
            "\nThe sensor is scanned from {from} to {to}: the figures above are the loop \
             frozen where the scan starts; the design was checked stable frozen at every \
             point of the observer's position grid and halfway between."
        );
    }
    if let (Some(t), Some((output, on_mass))) = (&thesis_part, thesis_output) {
        if !on_mass {
            println!(
                "\nThe thesis cases at y{output}, the mass nearest the sensor at {}:\n",
                s.plant.sensor_node()
            );
        }
        print!("{}", t.render_text());
    }
    Ok(0)
}
