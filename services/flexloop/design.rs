//! `flexloop design [SCENARIO] [--study [--continuous]] [--json]`: the
//! design report, before anything runs.
//!
//! Always, for every model: the scenario's own loop at its rate, loop
//! delay, observer and notches (flexloop-analysis' `loop_report`): modes,
//! observer poles, the damping achieved on every flexible mode and the
//! observer-error poles near it, |S| peaks per output, stability and its
//! margin, the 6 dB rule's verdict and the largest f_bw meeting it.
//!
//! `--study` adds the thesis' eight-case study (`thesis_design`) for the
//! thesis chain: every case at the scenario's rate and delay (or in
//! continuous time with `--continuous`), at the mass the sensor is on or
//! nearest to. A flag rather than a `study` subcommand: the study is a
//! second part of the same report on the same scenario, whose rate, delay
//! and sensor it takes, as `--continuous` already was.

use anyhow::{Context, bail};
use flexloop_analysis::loop_report::{
    LoopReport, LoopReportError, ProgramLoopReport, loop_report, program_loop_report,
};
use flexloop_analysis::thesis_design::{ThesisDesignSpec, thesis_design_report};
use flexloop_design::acceptance::{self, Accepted};
use flexloop_design::plants::thesis_chain::{chain_mass, chain_modal};
use flexloop_scenario::Overrides;
use std::path::PathBuf;

/// `design [SCENARIO] [--study [--continuous]] [--json]`.
#[derive(Debug, clap::Args)]
pub struct DesignArgs {
    /// Scenario file, or its name under scenarios/ [default: scenarios/default.toml]
    scenario: Option<PathBuf>,
    /// Add the thesis' eight-case study (thesis chain only): the largest f_bw of every case
    #[arg(long)]
    study: bool,
    /// The study in continuous time (the thesis' setting) instead of the scenario's rate and delay
    #[arg(long, requires = "study")]
    continuous: bool,
    /// Add the largest f_bw meeting the 6 dB rule against the command deadline tau_d
    /// (each command applied on arrival; docs/deadline.md)
    #[arg(long)]
    deadline_sweep: bool,
    /// With --deadline-sweep: a recorded run (e.g. `flexloop bench`'s) whose
    /// tick_to_command histogram gives each tau_d's share of late commands
    #[arg(long, value_name = "RUN_DIR", requires = "deadline_sweep")]
    latency: Option<PathBuf>,
    /// Print JSON ({"loop": ..., "study": ... or null, "deadline_sweep": ... or null}) instead of text
    #[arg(long)]
    json: bool,
}

/// The scenario's own loop: analysed, or served by programs whose laws
/// flexloop does not have.
#[derive(serde::Serialize)]
#[serde(untagged)]
enum OwnLoop {
    Analysed(Box<LoopReport>),
    Programs(Box<ProgramLoopReport>),
}

impl OwnLoop {
    fn render_text(&self) -> String {
        match self {
            OwnLoop::Analysed(r) => r.render_text(),
            OwnLoop::Programs(r) => r.render_text(),
        }
    }
}

/// The roles a program of one's own serves in `s`, with the program.
fn programs_of(s: &flexloop_scenario::Scenario) -> anyhow::Result<serde_json::Value> {
    let mut programs = serde_json::Map::new();
    for role in flexloop_scenario::ProgramRole::ALL {
        if let Some(p) = s.program(role)? {
            programs.insert(
                role.section().into(),
                serde_json::json!(p.program.display().to_string()),
            );
        }
    }
    Ok(serde_json::Value::Object(programs))
}

/// Which programs serve, when any does: their laws are theirs, so the
/// report below is of what was checked, not of the closed loop.
pub fn programs_notice(programs: &serde_json::Value) -> Option<String> {
    let programs = programs.as_object().filter(|p| !p.is_empty())?;
    let named: Vec<String> = programs
        .iter()
        .map(|(role, path)| format!("the {role} by {}", path.as_str().unwrap_or("?")))
        .collect();
    Some(format!(
        "Served by programs of one's own: {} (docs/components.md).",
        named.join(", ")
    ))
}

pub fn design(args: DesignArgs) -> anyhow::Result<i32> {
    let DesignArgs {
        scenario,
        study,
        continuous,
        deadline_sweep,
        latency,
        json,
    } = args;
    let path = flexloop_supervisor::launch::resolve_scenario(scenario)?;
    // The check `up` makes: a file design reports on is one up would run.
    let Accepted {
        scenario: s,
        design,
    } = acceptance::accept(
        &path,
        &Overrides::default(),
        flexloop_runtime::realtime::online_cpus(),
    )?;
    // A program's law is its own: its loop is not analysed, and the
    // report says what was checked instead.
    let own = match loop_report(&s, &design) {
        Ok(report) => OwnLoop::Analysed(Box::new(report)),
        Err(LoopReportError::NotAnalysed(_)) => {
            OwnLoop::Programs(Box::new(program_loop_report(&s, &design)))
        }
        Err(e) => return Err(anyhow::Error::msg(e).context(path.display().to_string())),
    };
    // The study and the sweep redesign the scenario's own plant model: they
    // would not be the design the file's laws are made on.
    if s.plant.design_file.is_some() && (study || deadline_sweep) {
        bail!(
            "{}: field plant.design_file: --study and --deadline-sweep redesign the plant \
             `{}` itself, not the design file's model; leave them out, or the design file",
            path.display(),
            s.plant.model
        );
    }
    // The study's mass: the sensor's, or the nearest (a scanned sensor
    // starts at its scan's first point).
    let study_output = if study {
        if s.plant.model != "thesis-chain" {
            bail!(
                "{}: field plant.model: --study is the thesis chain's eight-case study, not \
                 `{}`'s",
                path.display(),
                s.plant.model
            );
        }
        let node = s
            .plant
            .sensor_scan
            .map_or_else(|| s.plant.sensor_node(), |[from, _]| from);
        let nearest = node.round().clamp(1.0, 7.0);
        Some((nearest as usize, nearest == node, node))
    } else {
        None
    };
    let study_part = match study_output {
        Some((output, _, _)) => {
            let ts = 1.0 / s.timing.rate_hz;
            let mut spec = match (continuous, s.command_deadline_s()) {
                (true, _) => ThesisDesignSpec::continuous(),
                (false, Some(tau)) => ThesisDesignSpec::on_arrival(ts, tau),
                (false, None) => {
                    ThesisDesignSpec::discrete(ts, 1 + s.controller.extra_delay_samples as usize)
                }
            };
            spec.output = output;
            // The scenario's chain (its masses, springs, ζ, actuator), not Table 3.2's.
            let chain = chain_modal(&s).with_context(|| path.display().to_string())?;
            spec = spec.with_chain(chain, chain_mass(&s));
            Some(thesis_design_report(&spec).with_context(|| path.display().to_string())?)
        }
        None => None,
    };
    let sweep_part = if deadline_sweep {
        Some(
            crate::deadline_sweep::sweep(&s, latency.as_deref())
                .with_context(|| path.display().to_string())?,
        )
    } else {
        None
    };
    let programs = programs_of(&s)?;
    let design_file = s.design_file_path().map(|p| p.display().to_string());
    if json {
        let value = serde_json::json!({
            "loop": own,
            "study": study_part,
            "deadline_sweep": sweep_part,
            "programs": programs,
            "design_file": design_file,
        });
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(0);
    }
    if let Some(notice) = programs_notice(&programs) {
        println!("{notice}\n");
    }
    if let Some(file) = &design_file {
        println!(
            "The observer and the controller are designed on {file} (plant.design_file); the \
             loop below is that design around the plant `{}`, the one that runs.\n",
            s.plant.model
        );
    }
    print!("{}", own.render_text());
    if let (Some([from, to]), OwnLoop::Analysed(_)) = (s.plant.sensor_scan, &own) {
        println!(
            "\nThe sensor is scanned from {from} to {to}: the figures above are the loop \
             frozen where the scan starts; the design was checked stable frozen at every \
             point of the observer's position grid and halfway between."
        );
    }
    if let (Some(t), Some((output, on_mass, node))) = (&study_part, study_output) {
        if on_mass {
            println!(
                "\nThe thesis' study at y{output} (every case re-tuned; not this scenario's loop):\n"
            );
        } else {
            println!(
                "\nThe thesis' study at y{output}, the mass nearest the sensor at {node} \
                 (every case re-tuned; not this scenario's loop):\n"
            );
        }
        print!("{}", t.render_text());
    }
    if let Some(sweep) = &sweep_part {
        println!();
        print!("{}", sweep.render_text());
    }
    Ok(0)
}
