//! Attached to a running loop, as `flexloop get`, `set`, `status --scenario`
//! and the live view are: the scenario it runs now, its tunables and their
//! values, and a set ordered from its supervisor (docs/live.md).

use crate::registry;
use anyhow::Context;
use flexloop_runfiles::json::read_json;
use flexloop_runfiles::supervision::Processes;
use flexloop_runfiles::supervision::{
    FieldValue, MeasureOutcome, MeasureRequest, SetOutcome, SetRequest,
};
use flexloop_runfiles::{ProgramParams, RunDir};
use flexloop_scenario::tune::{self, TUNABLES};
use flexloop_scenario::{ProgramRole, Scenario};
use std::fmt;
use std::path::PathBuf;

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

/// Orders a measurement (`[measure]` fields, value as TOML text) on the
/// loop `prefix` names, as `flexloop measure --running` does: the
/// supervisor checks it against the loop's scenario and starts it a sample
/// ahead, or refuses it. Returns the loop's run directory and what it
/// ordered; the measurement runs on after this returns.
pub fn measure(
    prefix: Option<&str>,
    fields: &[(String, String)],
) -> Result<(PathBuf, MeasureOutcome), Refused> {
    let entry = loop_to_change(prefix)?;
    let request = MeasureRequest {
        fields: fields
            .iter()
            .map(|(field, value)| FieldValue {
                field: field.clone(),
                value: value.clone(),
            })
            .collect(),
    };
    let answer = crate::conductor::request_measure(&entry.run_dir, &request).map_err(refused)?;
    match (answer.outcome, answer.error) {
        (Some(outcome), _) => Ok((entry.run_dir, outcome)),
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

pub fn described_values(prefix: Option<&str>) -> Result<Vec<TunableValue>, Refused> {
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
