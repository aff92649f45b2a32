//! Live tuning on the supervisor's side: the scenario as it stands (after
//! swaps and sets), and a `flexloop set` turned into a checked scenario
//! file and the roles to hand over to it (docs/architecture.md, "Live
//! tuning"). The hand-over itself is the swap's (`shell.rs`).

use anyhow::{Context, Result, bail};
use flexloop_components::{ControllerCore, ObserverCore};
use flexloop_design::LoopDesign;
use flexloop_design::acceptance::{Accepted, accept_text};
use flexloop_node::Role;
use flexloop_protocol::PlantSettings;
use flexloop_protocol::plant_settings::{SAFE_HOLD, SAFE_STANDBY, SAFE_ZERO};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::supervision::{FieldChange, SetRequest};
use flexloop_scenario::schema::SafeAction;
use flexloop_scenario::tune::{self, Change, TunedRole};
use flexloop_scenario::{Overrides, ProgramRole, Scenario};
use std::path::{Path, PathBuf};

const NOT_VALID: &str = "the changed scenario is not valid (nothing written, the loop untouched)";

/// What a set will do once checked: the roles to hand over, in order, or
/// the plant's settings to publish; the file and the fields it changes.
#[derive(Debug)]
pub struct SetPlan {
    pub roles: Vec<Role>,
    pub plant: Option<PlantSettings>,
    pub file: PathBuf,
    pub fields: Vec<FieldChange>,
}

/// The scenario as it stands, as a TOML table (loaded from the run's copy
/// when first needed) and the number of changed files written so far.
#[derive(Debug, Default)]
pub struct Tuning {
    now: Option<toml::Table>,
    written: u32,
}

impl Tuning {
    /// The table of the loop as it runs now: the run's copy of its scenario
    /// with the rate and mode it was started with written in (they shape
    /// every block), and `plant.file` made absolute (a changed file lives
    /// in `tuned/`, where a relative path would find nothing).
    fn now(&mut self, run_dir: &RunDir, running: &Scenario) -> Result<&toml::Table> {
        if self.now.is_none() {
            let path = run_dir.scenario_copy();
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("cannot read {}", path.display()))?;
            let mut table: toml::Table =
                toml::from_str(&text).with_context(|| format!("{}", path.display()))?;
            let timing = [
                Change {
                    field: "loop.rate_hz".into(),
                    value: toml::Value::Float(running.timing.rate_hz),
                },
                Change {
                    field: "loop.mode".into(),
                    value: toml::Value::String(running.timing.mode.as_str().into()),
                },
            ];
            table = tune::with_changes(&table, &timing)?;
            // The tuned files live under the run directory: their model and
            // correction files are the running scenario's.
            flexloop_scenario::plant_description::anchor_files(&mut table, &running.source);
            self.now = Some(table);
        }
        Ok(self.now.as_ref().expect("loaded above"))
    }

    /// Checks `request` against the loop as it stands: only tunables, each
    /// field of the format and its value valid, the changed scenario
    /// accepted as every command accepts a file, and its loop meeting the
    /// 6 dB rule and stable at the loop's real delay (flexloop-analysis'
    /// `loop_check`). Writes the changed file (`tuned/NNN.toml`); None
    /// when no value changes.
    pub fn plan(
        &mut self,
        run_dir: &RunDir,
        running: &Scenario,
        overrides: &Overrides,
        request: &SetRequest,
    ) -> Result<Option<SetPlan>> {
        let changes = request
            .changes
            .iter()
            .map(|c| {
                tune::parse_value(&c.field, &c.value).map(|value| Change {
                    field: c.field.clone(),
                    value,
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        if changes.is_empty() {
            bail!("nothing to set");
        }
        let now = self.now(run_dir, running)?.clone();
        let now_path = run_dir.scenario_now();
        let programs: Vec<ProgramRole> = ProgramRole::ALL
            .into_iter()
            .filter(|r| now.get(r.section()).and_then(|c| c.get("exec")).is_some())
            .collect();
        let program = !programs.is_empty();
        let role =
            match tune::check_changes(&changes, |field| tune::known_field(&now, field), &programs)?
            {
                TunedRole::Controller => Role::Controller,
                TunedRole::Observer => Role::Observer,
                TunedRole::Plant => Role::Plant,
            };
        let table = tune::with_changes(&now, &changes)?;
        let old = Scenario::from_text(&now_path, &toml::to_string(&now)?, overrides)
            .context("the running loop's scenario")?;
        let index = self.written + 1;
        let file = run_dir.tuned().join(format!("{index:03}.toml"));
        let text = toml::to_string(&table)?;
        // The values as the scenario reads them (`60` is 60.0), before
        // anything is designed: a set of the running values changes nothing.
        let read = Scenario::parse(&file, &text).context(NOT_VALID)?;
        let fields: Vec<FieldChange> = changes
            .iter()
            .filter_map(|change| {
                let (before, after) = if tune::program_param(&change.field).is_some() {
                    (
                        tune::value_at(&now, &change.field),
                        tune::value_at(&table, &change.field),
                    )
                } else {
                    let t = tune::tunable(&change.field)?;
                    ((t.value)(&old), (t.value)(&read))
                };
                (before != after).then(|| FieldChange {
                    field: change.field.clone(),
                    old: tune::shown(before.as_ref()),
                    new: tune::shown(after.as_ref()),
                })
            })
            .collect();
        if fields.is_empty() {
            return Ok(None);
        }
        let Accepted {
            scenario: new,
            design,
        } = accept_text(
            &file,
            &text,
            overrides,
            flexloop_runtime::realtime::online_cpus(),
        )
        .context(NOT_VALID)?;
        let (roles, plant) = match role {
            // A program's new process continues its predecessor as its law
            // decides (`load`); the built-in controller's design does not
            // follow a program's parameters.
            Role::Observer if programs.contains(&ProgramRole::Observer) => {
                (vec![Role::Observer], None)
            }
            Role::Observer => (observer_roles(&old, &design)?, None),
            Role::Plant => (Vec::new(), Some(plant_settings(&old, &new)?)),
            _ => (vec![role], None),
        };
        // A program's law is its own: it checks its parameters when it
        // starts (a law that refuses them fails the swap, the loop
        // untouched), and the built-in design's rule does not judge it
        // (nor a loop whose observer is a program: the design has no
        // closed loop then).
        let report = match flexloop_analysis::loop_report::loop_check(&new, &design) {
            Ok(report) => Some(report),
            Err(flexloop_analysis::loop_report::LoopReportError::NotAnalysed(_)) => None,
            Err(e) => bail!("the changed loop could not be checked: {e}"),
        };
        if let Some(report) = report.filter(|r| !program && !r.meets_6db_rule) {
            bail!(
                "the changed loop at {} Hz with {} sample(s) of loop delay: {}",
                new.timing.rate_hz,
                design.loop_delay_samples,
                report.rule_verdict()
            );
        }
        std::fs::create_dir_all(run_dir.tuned())
            .with_context(|| format!("{}", run_dir.tuned().display()))?;
        std::fs::write(&file, text).with_context(|| format!("{}", file.display()))?;
        self.written = index;
        Ok(Some(SetPlan {
            roles,
            plant,
            file,
            fields,
        }))
    }

    /// Writes the scenario as it stands to `to` (its files anchored, so it
    /// reads from anywhere): what a measurement ordered now measures.
    pub fn snapshot(&mut self, run_dir: &RunDir, running: &Scenario, to: &Path) -> Result<()> {
        let text = toml::to_string(self.now(run_dir, running)?)?;
        if let Some(dir) = to.parent() {
            std::fs::create_dir_all(dir).with_context(|| format!("{}", dir.display()))?;
        }
        let tmp = to.with_extension("toml.tmp");
        std::fs::write(&tmp, text).with_context(|| format!("{}", tmp.display()))?;
        std::fs::rename(&tmp, to).with_context(|| format!("{}", to.display()))?;
        Ok(())
    }

    /// `role` now runs `file` (a swap or a set's hand-over): its part of
    /// the scenario as it stands is now that file's, rewritten in
    /// `scenario-now.toml`. The controller's part is `[controller]` and
    /// `supervision.estimate_watchdog_ticks`; the observer's `[observer]`;
    /// the plant's (a set of its settings) `supervision.safe_action` and
    /// `command_watchdog_ticks`.
    pub fn swapped(
        &mut self,
        run_dir: &RunDir,
        running: &Scenario,
        role: Role,
        file: &Path,
    ) -> Result<()> {
        let text = std::fs::read_to_string(file).with_context(|| format!("{}", file.display()))?;
        let mut from: toml::Table =
            toml::from_str(&text).with_context(|| format!("{}", file.display()))?;
        // Its relative files and program as named from its own directory.
        flexloop_scenario::plant_description::anchor_files(&mut from, file);
        self.now(run_dir, running)?;
        let now = self.now.as_mut().expect("loaded above");
        // The observer's and the controller's design model goes with either
        // (a swap of both, as `flexloop measure --swap` makes, leaves them
        // on one).
        if matches!(role, Role::Observer | Role::Controller) {
            take_plant_design_file(now, &from);
        }
        match role {
            Role::Observer => take(now, &from, "observer"),
            Role::Plant => {
                take_supervision(now, &from, "safe_action");
                take_supervision(now, &from, "command_watchdog_ticks");
            }
            _ => {
                take(now, &from, "controller");
                take_supervision(now, &from, "estimate_watchdog_ticks");
            }
        }
        let text = toml::to_string(now)?;
        let path = run_dir.scenario_now();
        let tmp = path.with_extension("toml.tmp");
        std::fs::write(&tmp, text).with_context(|| format!("{}", tmp.display()))?;
        std::fs::rename(&tmp, &path).with_context(|| format!("{}", path.display()))?;
        Ok(())
    }
}

/// `plant.design_file` as `from` has it (absent: none).
fn take_plant_design_file(table: &mut toml::Table, from: &toml::Table) {
    let value = from
        .get("plant")
        .and_then(|p| p.get("design_file"))
        .cloned();
    if let Some(toml::Value::Table(plant)) = table.get_mut("plant") {
        match value {
            Some(v) => plant.insert("design_file".into(), v),
            None => plant.remove("design_file"),
        };
    }
}

/// `table`'s section `name` replaced by `from`'s (removed if it has none).
/// `supervision.<name>` as `from` has it (absent: the default).
fn take_supervision(table: &mut toml::Table, from: &toml::Table, name: &str) {
    let value = from.get("supervision").and_then(|s| s.get(name)).cloned();
    let supervision = table
        .entry("supervision")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if let toml::Value::Table(supervision) = supervision {
        match value {
            Some(v) => supervision.insert(name.into(), v),
            None => supervision.remove(name),
        };
    }
}

fn take(table: &mut toml::Table, from: &toml::Table, name: &str) {
    match from.get(name) {
        Some(section) => table.insert(name.into(), section.clone()),
        None => table.remove(name),
    };
}

/// The plant's settings a set changes. `safe_action = "standby"` is set at
/// the start only: it decides whether the supervisor keeps a standby
/// controller, which a set neither starts nor stops.
fn plant_settings(running: &Scenario, new: &Scenario) -> Result<PlantSettings> {
    let (was, asked) = (running.supervision.safe_action, new.supervision.safe_action);
    if was != asked && (was == SafeAction::Standby || asked == SafeAction::Standby) {
        bail!(
            "supervision.safe_action: \"standby\" is set at the start only (it decides whether a \
             standby controller runs); change it in the scenario and start the loop again"
        );
    }
    Ok(PlantSettings {
        published_ns: 0,
        command_watchdog_ticks: new.supervision.command_watchdog_ticks,
        safe_action: match asked {
            SafeAction::Hold => SAFE_HOLD,
            SafeAction::Zero => SAFE_ZERO,
            SafeAction::Standby => SAFE_STANDBY,
        },
    })
}

/// The roles an observer set hands over: the observer, on the running
/// observer's model (so that it continues its estimate:
/// `ObserverCore::load`); then the controller, when the changed scenario
/// designs it otherwise (the modified feedforward of thesis App. A holds
/// the actively damped loop, so it follows the damping), but never its
/// feedback: the loop between the two hand-overs would be one the 6 dB
/// check did not judge (`bandwidth_hz = "auto"` designs the PID from the
/// observer).
fn observer_roles(running: &Scenario, new: &LoopDesign) -> Result<Vec<Role>> {
    let old = LoopDesign::from_scenario(running)
        .map_err(|e| anyhow::anyhow!("the running loop's design: {e}"))?;
    let (old_observer, new_observer) = (
        ObserverCore::for_design(&old).map_err(|e| anyhow::anyhow!("{e}"))?,
        ObserverCore::for_design(new).map_err(|e| anyhow::anyhow!("{e}"))?,
    );
    if new_observer.model_hash() == 0 || new_observer.model_hash() != old_observer.model_hash() {
        bail!(
            "the changed observer has another model than the running one (its modes, MC or \
             noise model, or a scheduled gain): its estimate could not continue the running \
             observer's, and the command would step at the switch; change it in the scenario \
             and start the loop again"
        );
    }
    if new.feedback != old.feedback {
        bail!(
            "the changed observer changes the controller's feedback too (controller.bandwidth_hz \
             = \"auto\" follows the observer): set controller.bandwidth_hz to a number first"
        );
    }
    if ControllerCore::new(new, 0).design_hash() == ControllerCore::new(&old, 0).design_hash() {
        Ok(vec![Role::Observer])
    } else {
        Ok(vec![Role::Observer, Role::Controller])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_runfiles::supervision::FieldValue;

    fn default_scenario() -> PathBuf {
        shipped("default")
    }

    fn shipped(name: &str) -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../scenarios/{name}.toml"))
    }

    /// A run directory holding the default scenario's copy, and the
    /// scenario as the supervisor runs it.
    fn run_dir(test: &str) -> (RunDir, Scenario) {
        let overrides = Overrides {
            rate_hz: Some(5_000.0),
            ..Overrides::default()
        };
        run_dir_of(test, &default_scenario(), &overrides)
    }

    fn run_dir_of(test: &str, scenario: &Path, overrides: &Overrides) -> (RunDir, Scenario) {
        let dir =
            std::env::temp_dir().join(format!("flexloop-tuning-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let run_dir = RunDir::new(&dir);
        std::fs::copy(scenario, run_dir.scenario_copy()).unwrap();
        (run_dir, Scenario::load(scenario, overrides).unwrap())
    }

    fn now(run_dir: &RunDir) -> toml::Table {
        toml::from_str(&std::fs::read_to_string(run_dir.scenario_now()).unwrap()).unwrap()
    }

    #[test]
    fn a_swap_moves_its_role_s_part_of_the_scenario_as_it_stands_and_no_other() {
        let (run_dir, running) = run_dir("swapped");
        let file = run_dir.path().join("other.toml");
        let text = std::fs::read_to_string(default_scenario())
            .unwrap()
            .replace("bandwidth_hz = 43.5", "bandwidth_hz = 40.0")
            .replace("q_nu = 1000.0", "q_nu = 500.0");
        std::fs::write(
            &file,
            format!("{text}\n[supervision]\nestimate_watchdog_ticks = 3\n"),
        )
        .unwrap();
        let mut tuning = Tuning::default();
        tuning
            .swapped(&run_dir, &running, Role::Controller, &file)
            .unwrap();
        let table = now(&run_dir);
        let _ = std::fs::remove_dir_all(run_dir.path());
        assert_eq!(table["controller"]["bandwidth_hz"].as_float(), Some(40.0));
        assert_eq!(
            table["supervision"]["estimate_watchdog_ticks"].as_integer(),
            Some(3)
        );
        // The observer is not the controller's: it stays the running one's.
        assert_eq!(table["observer"]["q_nu"].as_float(), Some(1000.0));
        // The rate the loop was started with is the scenario's now.
        assert_eq!(table["loop"]["rate_hz"].as_float(), Some(5_000.0));
    }

    #[test]
    fn a_set_of_a_field_that_is_not_the_controller_s_writes_nothing() {
        let (run_dir, running) = run_dir("refused");
        let request = |field: &str, value: &str| SetRequest {
            changes: vec![FieldValue {
                field: field.into(),
                value: value.into(),
            }],
        };
        let mut tuning = Tuning::default();
        for (field, value, says) in [
            ("plant.output", "3", "a swap may not change it"),
            ("loop.duration_s", "5.0", "not a tunable"),
            ("controller.bandwith_hz", "40", "no such field"),
        ] {
            let e = tuning
                .plan(
                    &run_dir,
                    &running,
                    &Overrides::default(),
                    &request(field, value),
                )
                .unwrap_err();
            let message = format!("{e:#}");
            assert!(
                message.contains(field) && message.contains(says),
                "{message}"
            );
        }
        let written = run_dir.tuned().exists() || run_dir.scenario_now().exists();
        let _ = std::fs::remove_dir_all(run_dir.path());
        assert!(!written);
    }

    #[test]
    fn a_plant_set_publishes_its_settings_and_standby_stays_as_started() {
        let request = |value: &str| SetRequest {
            changes: vec![FieldValue {
                field: "supervision.safe_action".into(),
                value: value.into(),
            }],
        };
        let plain = Overrides::default();
        let (run_dir, running) = run_dir_of("plant", &default_scenario(), &plain);
        let plan = Tuning::default()
            .plan(&run_dir, &running, &plain, &request("\"zero\""))
            .unwrap()
            .unwrap();
        let standby = Tuning::default()
            .plan(&run_dir, &running, &plain, &request("\"standby\""))
            .unwrap_err();
        let _ = std::fs::remove_dir_all(run_dir.path());
        assert!(plan.roles.is_empty());
        let settings = plan.plant.unwrap();
        assert_eq!(settings.safe_action, SAFE_ZERO);
        assert_eq!(
            settings.command_watchdog_ticks,
            running.supervision.command_watchdog_ticks
        );
        assert!(
            format!("{standby:#}").contains("at the start only"),
            "{standby:#}"
        );
    }

    #[test]
    fn an_observer_set_hands_over_the_observer_on_the_same_model_only() {
        let request = |field: &str, value: &str| SetRequest {
            changes: vec![FieldValue {
                field: field.into(),
                value: value.into(),
            }],
        };
        let plain = Overrides::default();
        let (run_dir, running) = run_dir_of("observer", &default_scenario(), &plain);
        let plan = Tuning::default()
            .plan(
                &run_dir,
                &running,
                &plain,
                &request("observer.damping_increase", "0.05"),
            )
            .unwrap()
            .unwrap();
        let _ = std::fs::remove_dir_all(run_dir.path());
        // Its modified feedforward follows the damping: the controller too.
        assert_eq!(plan.roles, [Role::Observer, Role::Controller]);

        for (scenario, field, value, says) in [
            // A scheduled gain follows the sensor: no estimate to continue.
            (
                "thesis-sensor-scan-ad",
                "observer.bandpass_q",
                "3.0",
                "another model",
            ),
            // "auto" designs the PID from the observer.
            (
                "drive-train",
                "observer.damping_increase",
                "0.15",
                "the controller's feedback",
            ),
        ] {
            let (run_dir, running) = run_dir_of(scenario, &shipped(scenario), &plain);
            let e = Tuning::default()
                .plan(&run_dir, &running, &plain, &request(field, value))
                .unwrap_err();
            let written = run_dir.scenario_now().exists();
            let _ = std::fs::remove_dir_all(run_dir.path());
            let message = format!("{e:#}");
            assert!(message.contains(says), "{scenario}: {message}");
            assert!(!written, "{scenario}");
        }
    }
}
