//! Live tuning from the command line: `flexloop get` shows a running loop's
//! tunables, `flexloop set` changes them through the swap path, and
//! `flexloop status --scenario` prints the scenario as it stands. [`set`]
//! and [`current`] are what a live server calls too: a set is the loop's
//! prefix and field/value pairs in, an outcome or a refusal with its reason
//! out (docs/architecture.md, "Live tuning").

use crate::registry;
use crate::registry::PrefixArg;
use anyhow::{Context, bail};
use flexloop_runfiles::json::read_json;
use flexloop_runfiles::supervision::Processes;
use flexloop_runfiles::supervision::{FieldValue, SetOutcome, SetRequest};
use flexloop_runfiles::{ProgramParams, RunDir};
use flexloop_scenario::tune::{self, Change, TUNABLES};
use flexloop_scenario::{ProgramRole, Scenario};
use std::fmt;
use std::path::PathBuf;

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

/// Why a set was not made; the loop runs on as it was.
#[derive(Debug, Clone, PartialEq)]
pub struct Refused {
    pub reason: String,
}

impl fmt::Display for Refused {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.reason)
    }
}

impl std::error::Error for Refused {}

fn refused(reason: impl fmt::Display) -> Refused {
    Refused {
        reason: format!("{reason:#}"),
    }
}

/// The one running loop `prefix` names, to change: the caller's own
/// (`registry::to_change`).
fn loop_to_change(prefix: Option<&str>) -> Result<registry::Entry, Refused> {
    registry::to_change(&registry::list(), prefix, registry::caller()).map_err(refused)
}

/// The one running loop `prefix` names (to read: anyone's).
fn running_loop(prefix: Option<&str>) -> Result<registry::Entry, Refused> {
    match registry::matching(prefix).as_slice() {
        [] => Err(refused("no loop running")),
        [one] => Ok(one.clone()),
        _ => Err(refused("several loops are running: name one with --prefix")),
    }
}

/// Changes `changes` (dotted field, value as TOML text) on the loop
/// `prefix` names, as `flexloop set` does: the supervisor checks the
/// changed scenario and hands the loop over to it, or refuses it.
pub fn set(prefix: Option<&str>, changes: &[(String, String)]) -> Result<SetOutcome, Refused> {
    // Syntax first, before the loop is asked anything.
    for (field, value) in changes {
        tune::parse_value(field, value).map_err(refused)?;
    }
    let entry = loop_to_change(prefix)?;
    let request = SetRequest {
        changes: changes
            .iter()
            .map(|(field, value)| FieldValue {
                field: field.clone(),
                value: value.clone(),
            })
            .collect(),
    };
    let answer = crate::conductor::request_set(&entry.run_dir, &request).map_err(refused)?;
    match (answer.outcome, answer.error) {
        (Some(outcome), _) => Ok(outcome),
        (None, error) => Err(refused(error.as_deref().unwrap_or("no reason given"))),
    }
}

/// The scenario of the loop `prefix` names as it stands (after swaps and
/// sets), as TOML text, and the file it was read from.
pub fn current(prefix: Option<&str>) -> Result<(PathBuf, String), Refused> {
    let entry = running_loop(prefix)?;
    let run_dir = RunDir::new(&entry.run_dir);
    // Before the first swap or set the loop runs the copy made at its start.
    let path = [run_dir.scenario_now(), run_dir.scenario_copy()]
        .into_iter()
        .find(|p| p.is_file())
        .ok_or_else(|| refused(format!("{}: no scenario file", entry.run_dir.display())))?;
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("{}", path.display()))
        .map_err(refused)?;
    Ok((path, text))
}

/// Every tunable of the loop `prefix` names and its value (`None`: unset):
/// for a role a program serves, the parameters its law runs with
/// ([`program_parameters`]) and not the built-in law's fields (they do not
/// act on it); for a built-in role, its fields.
pub fn values(prefix: Option<&str>) -> Result<Vec<(String, Option<toml::Value>)>, Refused> {
    Ok(described_values(prefix)?
        .into_iter()
        .map(|v| (v.field, v.value))
        .collect())
}

/// One tunable as `get` shows it.
pub struct TunableValue {
    pub field: String,
    pub value: Option<toml::Value>,
    /// The program's law uses its own default (the scenario gives none).
    pub defaulted: bool,
}

fn described_values(prefix: Option<&str>) -> Result<Vec<TunableValue>, Refused> {
    let entry = running_loop(prefix)?;
    let (path, text) = current(prefix)?;
    let scenario = Scenario::parse(&path, &text).map_err(refused)?;
    let table: toml::Table = toml::from_str(&text).map_err(refused)?;
    let run_dir = RunDir::new(&entry.run_dir);
    let mut out = Vec::new();
    let mut programs = Vec::new();
    for role in ProgramRole::ALL {
        if scenario.program(role).ok().flatten().is_none() {
            continue;
        }
        programs.push(role);
        out.extend(program_parameters(&run_dir, &table, role));
    }
    out.extend(
        TUNABLES
            .iter()
            .filter(|t| !programs.iter().any(|r| t.field.starts_with(r.section())))
            .filter(|t| {
                // The estimate watchdog is the built-in controller's law's.
                !(programs.contains(&ProgramRole::Controller)
                    && ProgramRole::Controller.built_in_only().contains(&t.field))
            })
            .map(|t| TunableValue {
                field: t.field.to_string(),
                value: (t.value)(&scenario),
                defaulted: false,
            }),
    );
    Ok(out)
}

/// The parameters the program serving `role` runs with: what its active
/// instance's law read, defaults included (`params/<role>.gN.json`, written
/// by the program: flexloop-runfiles' `ProgramParams`), else, before it
/// wrote it, the scenario's `[<role>.params]` as written.
fn program_parameters(
    run_dir: &RunDir,
    table: &toml::Table,
    role: ProgramRole,
) -> Vec<TunableValue> {
    let section = role.section();
    let prefix = format!("{section}.params");
    let active = read_json::<Processes>(&run_dir.processes())
        .ok()
        .and_then(|p| {
            p.processes
                .into_iter()
                .find(|e| e.role == section && e.duty == "active")
        })
        .map(|e| e.generation.unwrap_or(0));
    let record = active.and_then(|generation| {
        read_json::<ProgramParams>(&run_dir.program_params(section, generation)).ok()
    });
    let mut out = Vec::new();
    match record {
        Some(record) => {
            for (key, value) in &record.params {
                let mut leaves = Vec::new();
                match json_to_toml(value) {
                    Some(toml::Value::Table(inner)) => {
                        flatten(&format!("{prefix}.{key}"), &inner, &mut leaves)
                    }
                    Some(v) => leaves.push((format!("{prefix}.{key}"), v)),
                    None => continue,
                }
                let defaulted = record.defaulted.contains(key);
                out.extend(leaves.into_iter().map(|(field, v)| TunableValue {
                    field,
                    value: Some(v),
                    defaulted,
                }));
            }
        }
        None => {
            if let Some(toml::Value::Table(params)) = tune::value_at(table, &prefix) {
                let mut leaves = Vec::new();
                flatten(&prefix, &params, &mut leaves);
                out.extend(leaves.into_iter().map(|(field, v)| TunableValue {
                    field,
                    value: Some(v),
                    defaulted: false,
                }));
            }
        }
    }
    out
}

/// A JSON value as TOML (None for a null, which TOML has not).
fn json_to_toml(value: &serde_json::Value) -> Option<toml::Value> {
    Some(match value {
        serde_json::Value::Null => return None,
        serde_json::Value::Bool(b) => toml::Value::Boolean(*b),
        serde_json::Value::Number(n) => match n.as_i64() {
            Some(i) => toml::Value::Integer(i),
            None => toml::Value::Float(n.as_f64()?),
        },
        serde_json::Value::String(s) => toml::Value::String(s.clone()),
        serde_json::Value::Array(items) => {
            toml::Value::Array(items.iter().filter_map(json_to_toml).collect())
        }
        serde_json::Value::Object(map) => toml::Value::Table(
            map.iter()
                .filter_map(|(k, v)| Some((k.clone(), json_to_toml(v)?)))
                .collect(),
        ),
    })
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

/// Every leaf of `table` under the dotted `prefix`, in order.
fn flatten(prefix: &str, table: &toml::Table, out: &mut Vec<(String, toml::Value)>) {
    for (key, value) in table {
        let field = format!("{prefix}.{key}");
        match value {
            toml::Value::Table(inner) => flatten(&field, inner, out),
            _ => out.push((field, value.clone())),
        }
    }
}
