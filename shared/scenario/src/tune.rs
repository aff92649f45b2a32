//! Live tuning: the fields of a running loop that `flexloop set` may
//! change, their current values, and a scenario's table with some of them
//! changed.
//!
//! A tunable is a field that a swap of the controller or the observer
//! carries bumplessly ([`crate::swap`], docs/architecture.md "What a swap
//! may change" and "Live tuning"), or one of the plant's safety settings
//! (`supervision.safe_action`, `supervision.command_watchdog_ticks`), which
//! the plant takes from the supervisor at its next tick (the plant is never
//! swapped). `safe_action = "standby"` is set at the start only: it also
//! decides whether a standby controller runs.
//!
//! A controller program of one's own (`controller.exec`) is tuned by its
//! own `controller.params.*` ([`program_param`]), which its law reads; the
//! built-in controller's fields do not act on it and are refused.
//!
//! The observer's fields (Q_ν, damping increase or target, band-pass Q)
//! are handed over by a swap of the observer alone: a new design on the
//! running observer's model continues its estimate in shadow
//! (`ObserverCore::load`), so at the boundary the command changes by what
//! the designs differ in. A change that gives the observer another model is
//! refused by the supervisor, which designs both (a set names the
//! controller's or the observer's fields, not both: each is one hand-over).

use crate::ProgramRole;
use crate::schema::{PidBandwidth, SafeAction, Scenario};
use std::fmt;

/// Which process runs a tunable, and so which one a change hands over.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TunedRole {
    Controller,
    Observer,
    Plant,
}

impl TunedRole {
    pub fn name(self) -> &'static str {
        match self {
            TunedRole::Controller => "controller",
            TunedRole::Plant => "plant",
            TunedRole::Observer => "observer",
        }
    }
}

/// One tunable field.
pub struct Tunable {
    /// Dotted, as the scenario file names it.
    pub field: &'static str,
    pub role: TunedRole,
    /// Its value in `s` (defaults written out); None: not set.
    pub value: fn(&Scenario) -> Option<toml::Value>,
}

fn float(v: f64) -> Option<toml::Value> {
    Some(toml::Value::Float(v))
}

fn feedforward_gain(
    s: &Scenario,
    gain: fn(&crate::schema::FeedforwardSection) -> f64,
) -> Option<toml::Value> {
    s.controller
        .feedforward
        .as_ref()
        .and_then(|f| float(gain(f)))
}

/// Every tunable, in the order `flexloop get` lists them.
pub const TUNABLES: &[Tunable] = &[
    Tunable {
        field: "controller.bandwidth_hz",
        role: TunedRole::Controller,
        value: |s| match s.controller.bandwidth_hz {
            PidBandwidth::Hz(hz) => float(hz),
            PidBandwidth::Auto => Some(toml::Value::String("auto".into())),
        },
    },
    Tunable {
        field: "controller.notches_hz",
        role: TunedRole::Controller,
        value: |s| {
            Some(toml::Value::Array(
                s.controller
                    .notches_hz
                    .iter()
                    .map(|hz| toml::Value::Float(*hz))
                    .collect(),
            ))
        },
    },
    Tunable {
        field: "controller.feedforward.snap",
        role: TunedRole::Controller,
        value: |s| feedforward_gain(s, |f| f.snap),
    },
    Tunable {
        field: "controller.feedforward.jerk",
        role: TunedRole::Controller,
        value: |s| feedforward_gain(s, |f| f.jerk),
    },
    Tunable {
        field: "controller.feedforward.acc",
        role: TunedRole::Controller,
        value: |s| feedforward_gain(s, |f| f.acc),
    },
    Tunable {
        field: "controller.feedforward.vel",
        role: TunedRole::Controller,
        value: |s| feedforward_gain(s, |f| f.vel),
    },
    Tunable {
        field: "controller.feedforward_form",
        role: TunedRole::Controller,
        value: |s| Some(toml::Value::String(s.controller.feedforward_form.clone())),
    },
    Tunable {
        field: "supervision.estimate_watchdog_ticks",
        role: TunedRole::Controller,
        value: |s| {
            Some(toml::Value::Integer(i64::from(
                s.supervision.estimate_watchdog_ticks,
            )))
        },
    },
    Tunable {
        field: "supervision.safe_action",
        role: TunedRole::Plant,
        value: |s| {
            Some(toml::Value::String(
                match s.supervision.safe_action {
                    SafeAction::Hold => "hold",
                    SafeAction::Zero => "zero",
                    SafeAction::Standby => "standby",
                }
                .into(),
            ))
        },
    },
    Tunable {
        field: "supervision.command_watchdog_ticks",
        role: TunedRole::Plant,
        value: |s| {
            Some(toml::Value::Integer(i64::from(
                s.supervision.command_watchdog_ticks,
            )))
        },
    },
    Tunable {
        field: "observer.damping_increase",
        role: TunedRole::Observer,
        value: |s| float(s.observer.damping_increase),
    },
    Tunable {
        field: "observer.damping_target",
        role: TunedRole::Observer,
        value: |s| s.observer.damping_target.and_then(float),
    },
    Tunable {
        field: "observer.bandpass_q",
        role: TunedRole::Observer,
        value: |s| float(s.observer.bandpass_q),
    },
    Tunable {
        field: "observer.q_nu",
        role: TunedRole::Observer,
        value: |s| s.observer.q_nu.and_then(float),
    },
];

/// The tunable named `field`, if it is one.
pub fn tunable(field: &str) -> Option<&'static Tunable> {
    TUNABLES.iter().find(|t| t.field == field)
}

/// One `FIELD=VALUE` of `flexloop set`, the value parsed as TOML.
#[derive(Debug, Clone, PartialEq)]
pub struct Change {
    pub field: String,
    pub value: toml::Value,
}

impl Change {
    /// Parses `FIELD=VALUE` (`controller.notches_hz=[900.0]`).
    pub fn parse(text: &str) -> Result<Self, TuneError> {
        let Some((field, value)) = text.split_once('=') else {
            return Err(TuneError::Syntax(text.to_string()));
        };
        let field = field.trim();
        if field.is_empty() {
            return Err(TuneError::Syntax(text.to_string()));
        }
        let value = parse_value(field, value.trim())?;
        Ok(Self {
            field: field.to_string(),
            value,
        })
    }
}

/// `text` as one TOML value (`60`, `"auto"`, `[900.0]`).
pub fn parse_value(field: &str, text: &str) -> Result<toml::Value, TuneError> {
    let bad = |reason: String| TuneError::BadValue {
        field: field.to_string(),
        value: text.to_string(),
        reason,
    };
    let table: toml::Table =
        toml::from_str(&format!("v = {text}")).map_err(|e| bad(e.message().trim().to_string()))?;
    match table.into_iter().next() {
        Some((key, value)) if key == "v" => Ok(value),
        _ => Err(bad("not one TOML value".into())),
    }
}

/// Why a change is refused before any design is made.
#[derive(Debug, Clone, PartialEq)]
pub enum TuneError {
    /// Not `FIELD=VALUE`.
    Syntax(String),
    /// The value is not one TOML value.
    BadValue {
        field: String,
        value: String,
        reason: String,
    },
    /// The scenario format has no such field.
    UnknownField(String),
    /// A field a swap may not change (the plant, rate, set-point, delay).
    NotSwappable(String),
    /// Another field a swap may differ in but that is no tunable.
    NotTunable(String),
    /// Fields of two roles (controller, observer, plant) in one set.
    TwoRoles { first: String, second: String },
    /// The same field twice in one change.
    Repeated(String),
    /// A built-in law's field while a program of one's own serves its
    /// role (`section`).
    BuiltInOnProgram {
        field: String,
        section: &'static str,
    },
}

impl fmt::Display for TuneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let tunables = || {
            TUNABLES
                .iter()
                .map(|t| t.field)
                .collect::<Vec<_>>()
                .join(", ")
        };
        match self {
            TuneError::Syntax(text) => {
                write!(
                    f,
                    "`{text}`: expected FIELD=VALUE (controller.bandwidth_hz=60)"
                )
            }
            TuneError::BadValue {
                field,
                value,
                reason,
            } => write!(f, "{field}: `{value}` is not a TOML value: {reason}"),
            TuneError::UnknownField(field) => {
                write!(f, "{field}: no such field (tunables: {})", tunables())
            }
            TuneError::NotSwappable(field) => write!(
                f,
                "{field}: a swap may not change it: the loop's rate, mode, plant, set-point and \
                 loop delay stay as they run (docs/architecture.md#what-a-swap-may-change)"
            ),
            TuneError::NotTunable(field) => {
                write!(f, "{field}: not a tunable (tunables: {})", tunables())
            }
            TuneError::TwoRoles { first, second } => write!(
                f,
                "{first} and {second}: the controller's, the observer's and the plant's fields \
                 are handed over apart; set them in two sets"
            ),
            TuneError::Repeated(field) => write!(f, "{field}: given twice"),
            TuneError::BuiltInOnProgram { field, section } => write!(
                f,
                "{field}: the {section} is a program of one's own ({section}.exec), which the \
                 built-in {section}'s fields do not tune; its tunables are {section}.params.* \
                 (docs/components.md)"
            ),
        }
    }
}

impl std::error::Error for TuneError {}

/// Why `field` (not a tunable) may not be set: a known field of the format
/// is refused for what it is; anything else is unknown. `known` says
/// whether the format has the field.
pub fn refusal(field: &str, known: bool) -> TuneError {
    if !known {
        return TuneError::UnknownField(field.to_string());
    }
    let section = field.split('.').next().unwrap_or_default();
    match field {
        "loop.duration_s" => TuneError::NotTunable(field.to_string()),
        "controller.extra_delay_samples" | "controller.feedback" => {
            TuneError::NotSwappable(field.to_string())
        }
        _ if matches!(section, "loop" | "plant" | "reference") => {
            TuneError::NotSwappable(field.to_string())
        }
        _ => TuneError::NotTunable(field.to_string()),
    }
}

/// `table` (a scenario's) with `changes` written in: each dotted field set,
/// the tables on its way made if absent. Checks nothing but the syntax of
/// the path; [`check_changes`] says whether they may be made.
pub fn with_changes(table: &toml::Table, changes: &[Change]) -> Result<toml::Table, TuneError> {
    let mut out = table.clone();
    for change in changes {
        let mut keys: Vec<&str> = change.field.split('.').collect();
        let Some(last) = keys.pop() else {
            return Err(TuneError::Syntax(change.field.clone()));
        };
        let mut at = &mut out;
        for key in keys {
            let entry = at
                .entry(key.to_string())
                .or_insert_with(|| toml::Value::Table(toml::Table::new()));
            at = match entry {
                toml::Value::Table(inner) => inner,
                _ => return Err(TuneError::UnknownField(change.field.clone())),
            };
        }
        at.insert(last.to_string(), change.value.clone());
    }
    Ok(out)
}

/// The value at the dotted `field` of `table` (a scenario's), if set.
pub fn value_at(table: &toml::Table, field: &str) -> Option<toml::Value> {
    let mut keys = field.split('.');
    let mut value = table.get(keys.next()?)?;
    for key in keys {
        value = value.as_table()?.get(key)?;
    }
    Some(value.clone())
}

/// Whether the scenario format has `field`: `table` (a scenario's) with it
/// written in parses, or fails for its value's sake rather than as an
/// unknown field.
pub fn known_field(table: &toml::Table, field: &str) -> bool {
    // Any value: only an unknown field's error says "unknown field".
    let change = Change {
        field: field.into(),
        value: toml::Value::Boolean(false),
    };
    let Ok(with) = with_changes(table, &[change]) else {
        return false;
    };
    let Ok(text) = toml::to_string(&with) else {
        return false;
    };
    match Scenario::parse(std::path::Path::new("-"), &text) {
        Ok(_) => true,
        Err(e) => !e.reason.contains("unknown field"),
    }
}

/// The program role whose own tunable `field` is (`controller.params.KEY`
/// or `observer.params.KEY`, docs/components.md): its law reads them, and a
/// swap to the changed file hands the loop over to a new process of it.
pub fn program_param(field: &str) -> Option<ProgramRole> {
    ProgramRole::ALL.into_iter().find(|role| {
        field
            .strip_prefix(role.section())
            .and_then(|rest| rest.strip_prefix(".params."))
            .is_some_and(|key| !key.is_empty() && key.split('.').all(|k| !k.is_empty()))
    })
}

/// Refuses a change of anything but tunables, a field given twice and
/// the two roles' fields together; the role the change hands over.
/// `known(field)` says whether the scenario format has the field. For a
/// role a program serves (`programs`), its `<role>.params.*` are its
/// tunables and the built-in law's fields are refused.
pub fn check_changes(
    changes: &[Change],
    known: impl Fn(&str) -> bool,
    programs: &[ProgramRole],
) -> Result<TunedRole, TuneError> {
    // The first field of each role the change names.
    let mut roles: Vec<(TunedRole, &str)> = Vec::new();
    for (i, change) in changes.iter().enumerate() {
        if changes[..i].iter().any(|c| c.field == change.field) {
            return Err(TuneError::Repeated(change.field.clone()));
        }
        let role = if let Some(role) = program_param(&change.field) {
            if !programs.contains(&role) {
                return Err(TuneError::NotTunable(change.field.clone()));
            }
            tuned_role(role)
        } else {
            if let Some(role) = programs
                .iter()
                .find(|r| r.built_in_only().iter().any(|f| is_under(&change.field, f)))
            {
                return Err(TuneError::BuiltInOnProgram {
                    field: change.field.clone(),
                    section: role.section(),
                });
            }
            match tunable(&change.field) {
                None => return Err(refusal(&change.field, known(&change.field))),
                Some(t) => t.role,
            }
        };
        if !roles.iter().any(|(r, _)| *r == role) {
            roles.push((role, &change.field));
        }
    }
    match roles.as_slice() {
        [] | [(TunedRole::Controller, _)] => Ok(TunedRole::Controller),
        [(role, _)] => Ok(*role),
        [(_, first), (_, second), ..] => Err(TuneError::TwoRoles {
            first: first.to_string(),
            second: second.to_string(),
        }),
    }
}

/// `field` is `parent` or one of its sub-fields.
fn is_under(field: &str, parent: &str) -> bool {
    field
        .strip_prefix(parent)
        .is_some_and(|rest| rest.is_empty() || rest.starts_with('.'))
}

fn tuned_role(role: ProgramRole) -> TunedRole {
    match role {
        ProgramRole::Controller => TunedRole::Controller,
        ProgramRole::Observer => TunedRole::Observer,
    }
}

/// A tunable's value as the events and `flexloop get` show it ("unset"
/// for an optional field not given).
pub fn shown(value: Option<&toml::Value>) -> String {
    value.map_or_else(|| "unset".to_string(), ToString::to_string)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_assignment_is_a_field_and_one_toml_value() {
        let c = Change::parse("controller.bandwidth_hz=60").unwrap();
        assert_eq!(c.field, "controller.bandwidth_hz");
        assert_eq!(c.value, toml::Value::Integer(60));
        let c = Change::parse("controller.notches_hz=[900.0, 1200]").unwrap();
        assert_eq!(c.value.as_array().map(Vec::len), Some(2));
        let e = Change::parse("controller.bandwidth_hz=sixty").unwrap_err();
        assert!(
            e.to_string()
                .starts_with("controller.bandwidth_hz: `sixty`"),
            "{e}"
        );
        assert!(matches!(
            Change::parse("bandwidth"),
            Err(TuneError::Syntax(_))
        ));
        assert!(matches!(Change::parse("=3"), Err(TuneError::Syntax(_))));
    }

    #[test]
    fn a_programs_params_are_its_tunables_and_the_built_in_fields_are_not() {
        let change = |field: &str| Change {
            field: field.into(),
            value: toml::Value::Float(1.0),
        };
        let known = |_: &str| true;
        let controller = &[ProgramRole::Controller][..];
        let observer = &[ProgramRole::Observer][..];
        assert!(check_changes(&[change("controller.params.kp")], known, controller).is_ok());
        assert!(check_changes(&[change("controller.params.gains.kd")], known, controller).is_ok());
        assert!(matches!(
            check_changes(&[change("controller.bandwidth_hz")], known, controller),
            Err(TuneError::BuiltInOnProgram {
                section: "controller",
                ..
            })
        ));
        assert!(matches!(
            check_changes(&[change("controller.feedforward.acc")], known, controller),
            Err(TuneError::BuiltInOnProgram { .. })
        ));
        assert!(matches!(
            check_changes(&[change("controller.params.kp")], known, &[]),
            Err(TuneError::NotTunable(_))
        ));
        // An observer program: its params hand over the observer, the
        // built-in observer's fields are refused, the controller's tune on.
        assert_eq!(
            check_changes(&[change("observer.params.bandwidth_hz")], known, observer).unwrap(),
            TunedRole::Observer
        );
        assert!(matches!(
            check_changes(&[change("observer.q_nu")], known, observer),
            Err(TuneError::BuiltInOnProgram {
                section: "observer",
                ..
            })
        ));
        assert!(check_changes(&[change("controller.bandwidth_hz")], known, observer).is_ok());
        assert!(matches!(
            check_changes(&[change("observer.params.bandwidth_hz")], known, controller),
            Err(TuneError::NotTunable(_))
        ));
        assert_eq!(
            program_param("observer.params.l1"),
            Some(ProgramRole::Observer)
        );
        assert_eq!(program_param("controller.params."), None);
        assert_eq!(program_param("controller.params..kp"), None);
        assert_eq!(program_param("controller.bandwidth_hz"), None);
    }

    #[test]
    fn only_tunables_may_change_and_each_refusal_says_why() {
        let known = |f: &str| !f.contains("bogus");
        let change_of = |field: &str| Change {
            field: field.into(),
            value: toml::Value::Integer(1),
        };
        let one = |field: &str| {
            check_changes(
                &[Change {
                    field: field.into(),
                    value: toml::Value::Integer(1),
                }],
                known,
                &[],
            )
        };
        assert!(one("controller.bandwidth_hz").is_ok());
        assert_eq!(one("observer.q_nu"), Ok(TunedRole::Observer));
        assert_eq!(one("controller.notches_hz"), Ok(TunedRole::Controller));
        let both = check_changes(
            &[
                change_of("controller.bandwidth_hz"),
                change_of("observer.bandpass_q"),
            ],
            known,
            &[],
        );
        assert!(matches!(both, Err(TuneError::TwoRoles { .. })), "{both:?}");
        assert_eq!(one("supervision.safe_action"), Ok(TunedRole::Plant));
        assert_eq!(
            one("supervision.command_watchdog_ticks"),
            Ok(TunedRole::Plant)
        );
        assert!(matches!(
            one("plant.output"),
            Err(TuneError::NotSwappable(_))
        ));
        assert!(matches!(
            one("loop.rate_hz"),
            Err(TuneError::NotSwappable(_))
        ));
        assert!(matches!(
            one("controller.extra_delay_samples"),
            Err(TuneError::NotSwappable(_))
        ));
        assert!(matches!(
            one("realtime.profile"),
            Err(TuneError::NotTunable(_))
        ));
        let e = one("controller.bogus").unwrap_err();
        assert!(matches!(e, TuneError::UnknownField(_)));
        assert!(e.to_string().contains("controller.bogus"), "{e}");
        let twice = Change::parse("controller.notches_hz=[]").unwrap();
        assert!(matches!(
            check_changes(&[twice.clone(), twice], known, &[]),
            Err(TuneError::Repeated(_))
        ));
    }

    #[test]
    fn a_field_is_known_by_the_format_whatever_its_value() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenarios/default.toml");
        let table: toml::Table = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        assert!(known_field(&table, "plant.output"));
        assert!(known_field(&table, "loop.rate_hz"));
        assert!(known_field(&table, "controller.bandwidth_hz"));
        assert!(known_field(&table, "supervision.safe_action"));
        assert!(!known_field(&table, "controller.bandwith_hz"));
        assert!(!known_field(&table, "plant.output.x"));
        assert!(!known_field(&table, "nonsense.field"));
    }

    #[test]
    fn changes_are_written_into_the_table_and_nothing_else_moves() {
        let table: toml::Table =
            toml::from_str("name = \"x\"\n[controller]\nbandwidth_hz = 40.0\n").unwrap();
        let changes = [
            Change::parse("controller.bandwidth_hz=60").unwrap(),
            Change::parse("controller.feedforward.acc=2.5").unwrap(),
        ];
        let out = with_changes(&table, &changes).unwrap();
        assert_eq!(out["name"], table["name"]);
        assert_eq!(out["controller"]["bandwidth_hz"], toml::Value::Integer(60));
        assert_eq!(
            out["controller"]["feedforward"]["acc"],
            toml::Value::Float(2.5)
        );
        // A value where a table is needed is no field of the format.
        let e = with_changes(&table, &[Change::parse("name.x=1").unwrap()]).unwrap_err();
        assert!(matches!(e, TuneError::UnknownField(_)));
    }
}
