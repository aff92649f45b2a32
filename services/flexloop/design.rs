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

use anyhow::{Context, bail};
use flexloop_analysis::loop_report::loop_report;
use flexloop_analysis::thesis_design::{ThesisDesignSpec, thesis_design_report};
use flexloop_design::acceptance::{self, Accepted};
use flexloop_scenario::Overrides;
use std::path::PathBuf;

/// `design [SCENARIO] [--continuous] [--json]`.
#[derive(Debug, clap::Args)]
pub struct DesignArgs {
    /// Scenario file, or its name under scenarios/ [default: scenarios/default.toml]
    scenario: Option<PathBuf>,
    /// The thesis chain's report in continuous time
    #[arg(long)]
    continuous: bool,
    /// Print JSON instead of text
    #[arg(long)]
    json: bool,
}

pub fn design(args: DesignArgs) -> anyhow::Result<i32> {
    let DesignArgs {
        scenario,
        continuous,
        json,
    } = args;
    let path = crate::launch::resolve_scenario(scenario)?;
    // The check `up` makes: a file design reports on is one up would run.
    let Accepted {
        scenario: s,
        design,
    } = acceptance::accept(
        &path,
        &Overrides::default(),
        flexloop_runtime::realtime::online_cpus(),
    )?;
    // The mass the thesis report is about, and whether the sensor sits on
    // it (a scanned sensor has no one mass: only its own loop is reported).
    let thesis_output =
        (s.plant.model == "thesis-chain" && s.plant.sensor_scan.is_none()).then(|| {
            let node = s.plant.sensor_node();
            let nearest = node.round().clamp(1.0, 7.0);
            (nearest as usize, nearest == node)
        });
    if continuous && thesis_output.is_none() {
        bail!(
            "{}: field plant.model: --continuous is the thesis chain's report, not `{}`'s",
            path.display(),
            s.plant.model
        );
    }
    let loop_part = match thesis_output {
        Some((_, true)) => None,
        _ => Some(
            loop_report(&s, &design)
                .map_err(anyhow::Error::msg)
                .with_context(|| path.display().to_string())?,
        ),
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
            Some(thesis_design_report(&spec).with_context(|| path.display().to_string())?)
        }
        None => None,
    };
    if json {
        let value = match (&loop_part, &thesis_part) {
            (None, Some(thesis)) => serde_json::to_value(thesis),
            (l, t) => Ok(serde_json::json!({ "loop": l, "thesis_at_nearest_mass": t })),
        }?;
        println!("{}", serde_json::to_string_pretty(&value)?);
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
