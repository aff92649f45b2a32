//! Live tuning from the command line: `flexloop get` shows a running loop's
//! tunables, `flexloop set` changes them through the swap path, and
//! `flexloop status --scenario` prints the scenario as it stands; what they
//! ask of the loop is flexloop_supervisor::attach's, which the live view
//! calls too (docs/architecture.md, "Live tuning").

use crate::loop_command::PrefixArg;
use anyhow::bail;
use flexloop_runfiles::supervision::SetOutcome;
use flexloop_scenario::tune::{self, Change};
use flexloop_scenario::{ProgramRole, Scenario};
use flexloop_supervisor::attach::{current, described_values, set};

/// `get [FIELD] [--prefix P]`.
#[derive(Debug, clap::Args)]
pub struct GetArgs {
    /// One tunable (`controller.bandwidth_hz`); absent: every one
    pub field: Option<String>,
    #[command(flatten)]
    pub which: PrefixArg,
}

/// `set FIELD=VALUE... [--prefix P]`.
#[derive(Debug, clap::Args)]
pub struct SetArgs {
    /// Tunables and their new values as TOML (`controller.bandwidth_hz=60`,
    /// `controller.notches_hz=[900.0]`), all handed over together
    #[arg(required = true, value_name = "FIELD=VALUE")]
    pub changes: Vec<String>,
    #[command(flatten)]
    pub which: PrefixArg,
}

pub fn get(args: GetArgs) -> anyhow::Result<i32> {
    let prefix = args.which.prefix.as_deref();
    let values = described_values(prefix)?;
    let Some(field) = args.field else {
        for v in values {
            match (v.value, v.defaulted) {
                (Some(value), false) => println!("{} = {value}", v.field),
                (Some(value), true) => println!("{} = {value}  # the law's default", v.field),
                (None, _) => println!("# {} unset", v.field),
            }
        }
        return Ok(0);
    };
    if let Some(v) = values.iter().find(|v| v.field == field) {
        println!("{}", tune::shown(v.value.as_ref()));
        return Ok(0);
    }
    let (_, text) = current(prefix)?;
    let table: toml::Table = toml::from_str(&text)?;
    if tune::program_param(&field).is_some() {
        // Not read by the running law (nor written in its scenario).
        println!("{}", tune::shown(tune::value_at(&table, &field).as_ref()));
        return Ok(0);
    }
    // A built-in law's field of a role a program serves, or no tunable.
    let (path, _) = current(prefix)?;
    let scenario = Scenario::parse(&path, &text)?;
    let programs: Vec<ProgramRole> = ProgramRole::ALL
        .into_iter()
        .filter(|r| scenario.program(*r).ok().flatten().is_some())
        .collect();
    let probe = Change {
        field: field.clone(),
        value: toml::Value::Boolean(false),
    };
    match tune::check_changes(&[probe], |f| tune::known_field(&table, f), &programs) {
        Err(e) => bail!(e),
        Ok(_) => bail!(tune::refusal(&field, tune::known_field(&table, &field))),
    }
}

/// What a set did, a line each: the fields' old and new values, each
/// hand-over's switch, the file the loop runs now.
pub fn outcome_lines(outcome: &SetOutcome) -> Vec<String> {
    if outcome.fields.is_empty() {
        return vec!["nothing changed: every value is the running one".into()];
    }
    let mut lines: Vec<String> = outcome
        .fields
        .iter()
        .map(|f| format!("{} {} -> {}", f.field, f.old, f.new))
        .collect();
    for s in &outcome.switches {
        lines.push(format!(
            "{} generation {} active from sample {}; |Δu| at the switch {:.3e}, largest ordinary |Δu| over 100 samples before {:.3e} and after {:.3e}",
            s.role, s.generation, s.from_seq, s.du_switch, s.du_before, s.du_after
        ));
    }
    if outcome.switches.is_empty() {
        // A set of the plant's settings: published, nothing handed over.
        lines.push("the plant takes them at its next tick".into());
    }
    if let Some(file) = &outcome.file {
        lines.push(format!(
            "the loop runs {file} (checked in {:.2} s, handed over in {:.2} s)",
            outcome.check_s, outcome.handover_s
        ));
    }
    lines
}

pub fn set_command(args: SetArgs) -> anyhow::Result<i32> {
    let mut changes = Vec::new();
    for text in &args.changes {
        let change = Change::parse(text)?;
        let value = text
            .split_once('=')
            .map(|(_, v)| v.trim().to_string())
            .unwrap_or_default();
        changes.push((change.field, value));
    }
    let outcome = set(args.which.prefix.as_deref(), &changes)
        .map_err(|e| anyhow::anyhow!("set refused: {e}"))?;
    for line in outcome_lines(&outcome) {
        println!("flexloop: {line}");
    }
    Ok(0)
}
