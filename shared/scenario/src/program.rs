//! `controller.exec` and `observer.exec`: the program that serves a role in
//! place of the built-in `flexloop-controller` or `flexloop-observer`
//! (docs/components.md).
//!
//! The supervisor starts it exactly as it starts the built-in process (the
//! same flags after the scenario's own arguments), so a program written on
//! flexloop-sdk, or on the Python package, joins, shadows and hands over
//! like the built-in one. Everything about the program is checked here,
//! before any process starts: a program that is missing or not executable
//! is a scenario error naming the field, not a failed start in the middle
//! of a run.

use crate::ScenarioError;
use crate::schema::Scenario;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

/// A user's program for a role, resolved.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ComponentProgram {
    /// The executable, absolute (or as PATH found it).
    pub program: PathBuf,
    /// Its own arguments, before the ones flexloop adds.
    pub args: Vec<String>,
    /// Where it runs.
    pub workdir: PathBuf,
}

/// A role a program of one's own may serve, and its section's fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgramRole {
    Controller,
    Observer,
}

impl ProgramRole {
    pub const ALL: [ProgramRole; 2] = [ProgramRole::Controller, ProgramRole::Observer];

    pub fn section(self) -> &'static str {
        match self {
            ProgramRole::Controller => "controller",
            ProgramRole::Observer => "observer",
        }
    }

    /// The built-in law's tuning: fields a program does not read.
    pub fn built_in_only(self) -> &'static [&'static str] {
        match self {
            ProgramRole::Controller => &CONTROLLER_BUILT_IN_ONLY,
            ProgramRole::Observer => &OBSERVER_BUILT_IN_ONLY,
        }
    }
}

impl Scenario {
    /// The controller's program, if the scenario names one
    /// (`controller.exec`), resolved and checked.
    pub fn controller_program(&self) -> Result<Option<ComponentProgram>, ScenarioError> {
        self.program(ProgramRole::Controller)
    }

    /// The program serving `role`, if the scenario names one (`exec` in
    /// its section), resolved and checked.
    pub fn program(&self, role: ProgramRole) -> Result<Option<ComponentProgram>, ScenarioError> {
        let (exec, workdir) = match role {
            ProgramRole::Controller => (&self.controller.exec, &self.controller.workdir),
            ProgramRole::Observer => (&self.observer.exec, &self.observer.workdir),
        };
        let section = role.section();
        let exec_field = format!("{section}.exec");
        let Some(exec) = exec else {
            return Ok(None);
        };
        let Some((program, args)) = exec.split_first() else {
            return Err(self.err(
                &exec_field,
                "is empty: give the program, then its arguments (`exec = [\"./my-law\"]`)",
            ));
        };
        let dir = self.directory();
        let program = if program.contains('/') {
            let path = Path::new(program);
            let path = if path.is_relative() {
                dir.join(path)
            } else {
                path.to_path_buf()
            };
            check_executable(&path).map_err(|why| {
                self.err(&exec_field, format!("program {}: {why}", path.display()))
            })?;
            path
        } else {
            find_on_path(program).ok_or_else(|| {
                self.err(
                    &exec_field,
                    format!(
                        "no executable `{program}` on PATH (a program in the scenario's \
                         directory is written `./{program}`)"
                    ),
                )
            })?
        };
        let workdir = match workdir {
            Some(w) if w.is_relative() => dir.join(w),
            Some(w) => w.clone(),
            None => dir,
        };
        if !workdir.is_dir() {
            return Err(self.err(
                &format!("{section}.workdir"),
                format!("{} is not a directory", workdir.display()),
            ));
        }
        Ok(Some(ComponentProgram {
            program,
            args: args.to_vec(),
            workdir,
        }))
    }

    /// The directory the scenario's relative paths start from.
    fn directory(&self) -> PathBuf {
        let dir = self
            .source
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .map_or_else(|| PathBuf::from("."), Path::to_path_buf);
        std::fs::canonicalize(&dir).unwrap_or(dir)
    }

    fn gives(&self, field: &str) -> bool {
        self.given
            .iter()
            .any(|g| g == field || g.starts_with(&format!("{field}.")))
    }

    /// `workdir` and `params` act only on a program, the built-in law's
    /// tuning only on the built-in law.
    pub(crate) fn validate_program(&self) -> Result<(), ScenarioError> {
        for role in ProgramRole::ALL {
            let section = role.section();
            if self.program(role)?.is_some() {
                if let Some(field) = role.built_in_only().iter().find(|f| self.gives(f)) {
                    return Err(self.err(
                        field,
                        format!(
                            "tunes the built-in {section}, not a program of one's own \
                             (`{section}.exec`): its tunables are `[{section}.params]`"
                        ),
                    ));
                }
                continue;
            }
            for field in [format!("{section}.workdir"), format!("{section}.params")] {
                if self.gives(&field) {
                    return Err(self.err(
                        &field,
                        format!(
                            "applies only to a {section} program (`{section}.exec`); the \
                             built-in {section} is tuned by the other {section} fields"
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// `table` (a scenario as TOML) with `role` served by the program `exec`
/// (its program, then its own arguments) run in `workdir`, its own
/// parameters `params` (None: the table's own `[<role>.params]`, if any):
/// the built-in law's fields, which do not apply to a program and are
/// refused with it, are taken out. What `flexloop swap --exec` writes, and
/// the one way every test makes a program's scenario from a built-in one.
pub fn served_by_program(
    table: &mut toml::Table,
    role: ProgramRole,
    exec: &[String],
    workdir: Option<&Path>,
    params: Option<toml::Table>,
) {
    for field in role.built_in_only() {
        let (section, key) = field.split_once('.').expect("a dotted field");
        if let Some(toml::Value::Table(section)) = table.get_mut(section) {
            section.remove(key);
            if section.is_empty() && section_is_optional(field) {
                table.remove(field.split_once('.').expect("dotted").0);
            }
        }
    }
    let section = table
        .entry(role.section())
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    if !section.is_table() {
        *section = toml::Value::Table(toml::Table::new());
    }
    let toml::Value::Table(section) = section else {
        unreachable!("made a table above")
    };
    section.insert(
        "exec".into(),
        toml::Value::Array(exec.iter().cloned().map(toml::Value::String).collect()),
    );
    if let Some(dir) = workdir {
        section.insert(
            "workdir".into(),
            toml::Value::String(dir.display().to_string()),
        );
    }
    if let Some(params) = params {
        section.insert("params".into(), toml::Value::Table(params));
    }
}

/// A section a program's scenario may drop once the built-in fields are
/// out of it (`[supervision]` holds only defaults then).
fn section_is_optional(field: &str) -> bool {
    field.starts_with("supervision.")
}

/// The built-in controller's own tuning (and its law's watchdog: a program
/// sees each estimate's sequence number and decides itself what a stale
/// one means).
const CONTROLLER_BUILT_IN_ONLY: [&str; 6] = [
    "controller.feedback",
    "controller.bandwidth_hz",
    "controller.notches_hz",
    "controller.feedforward",
    "controller.feedforward_form",
    "supervision.estimate_watchdog_ticks",
];

/// The built-in observer's tuning; `observer.design` stays, since it gives
/// the estimate's layout the built-in controller reads.
const OBSERVER_BUILT_IN_ONLY: [&str; 21] = [
    "observer.observer_bandwidth_hz",
    "observer.observer_damping",
    "observer.feedback_bandwidth_hz",
    "observer.feedback_damping",
    "observer.mc",
    "observer.ad",
    "observer.q_nu",
    "observer.damping_increase",
    "observer.damping_target",
    "observer.process_noise",
    "observer.measurement_noise",
    "observer.kalman_q",
    "observer.kalman_r",
    "observer.max_mode_hz",
    "observer.flexible_modes",
    "observer.bandpass_q",
    "observer.scheduling",
    "observer.scheduling_step",
    "observer.correction",
    "observer.correction_file",
    "observer.correction_arrays",
];

fn check_executable(path: &Path) -> Result<(), String> {
    let meta = std::fs::metadata(path).map_err(|e| e.to_string())?;
    if !meta.is_file() {
        return Err("not a file".into());
    }
    if meta.permissions().mode() & 0o111 == 0 {
        return Err("not executable (chmod +x)".into());
    }
    Ok(())
}

fn find_on_path(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|dir| dir.join(name))
        .find(|candidate| check_executable(candidate).is_ok())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Overrides;

    fn scenario_in(dir: &Path, controller: &str) -> Result<Scenario, ScenarioError> {
        let path = dir.join("s.toml");
        let text = format!(
            "{}\n[controller]\n{controller}\n",
            include_str!("../../../scenarios/lecture-double-integrator.toml")
        );
        Scenario::from_text(&path, &text, &Overrides::default())
    }

    fn temp_dir(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("flexloop-program-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn a_relative_program_is_found_beside_the_scenario() {
        let dir = temp_dir("relative");
        let program = dir.join("law");
        std::fs::write(&program, "#!/bin/sh\n").unwrap();
        std::fs::set_permissions(&program, std::fs::Permissions::from_mode(0o755)).unwrap();
        let s = scenario_in(&dir, "exec = [\"./law\", \"--gain\", \"2\"]").unwrap();
        let p = s.controller_program().unwrap().unwrap();
        assert_eq!(
            p.program,
            std::fs::canonicalize(&dir).unwrap().join("./law")
        );
        assert_eq!(p.args, ["--gain", "2"]);
        assert_eq!(p.workdir, std::fs::canonicalize(&dir).unwrap());
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_missing_or_plain_file_is_refused_by_field() {
        let dir = temp_dir("missing");
        let e = scenario_in(&dir, "exec = [\"./absent\"]").unwrap_err();
        assert_eq!(e.field.as_deref(), Some("controller.exec"));
        assert!(e.reason.contains("absent"), "{e}");
        std::fs::write(dir.join("plain"), "x").unwrap();
        let e = scenario_in(&dir, "exec = [\"./plain\"]").unwrap_err();
        assert!(e.reason.contains("not executable"), "{e}");
        let e = scenario_in(&dir, "exec = []").unwrap_err();
        assert!(e.reason.contains("empty"), "{e}");
        let e = scenario_in(&dir, "exec = [\"no-such-program-flexloop\"]").unwrap_err();
        assert!(e.reason.contains("PATH"), "{e}");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn an_observer_program_takes_its_own_params_not_the_built_in_tuning() {
        let dir = temp_dir("observer");
        let lecture = include_str!("../../../scenarios/lecture-double-integrator.toml");
        let with_observer = |observer: &str| {
            let text = lecture.replace(
                "[observer]\ndesign = \"state-feedback\"\nobserver_bandwidth_hz = 200.0\nobserver_damping = 0.7\nfeedback_bandwidth_hz = 20.0\nfeedback_damping = 0.7\n",
                &format!("[observer]\ndesign = \"state-feedback\"\n{observer}\n"),
            );
            assert_ne!(text, lecture, "the lecture scenario's [observer] changed");
            Scenario::from_text(&dir.join("s.toml"), &text, &Overrides::default())
        };
        let s = with_observer("exec = [\"sh\"]\n[observer.params]\nbandwidth_hz = 200.0").unwrap();
        assert!(s.program(ProgramRole::Observer).unwrap().is_some());
        let e = with_observer("exec = [\"sh\"]\nq_nu = 3.0").unwrap_err();
        assert_eq!(e.field.as_deref(), Some("observer.q_nu"));
        let e = with_observer("[observer.params]\nbandwidth_hz = 200.0").unwrap_err();
        assert_eq!(e.field.as_deref(), Some("observer.params"));
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn params_and_workdir_need_a_program() {
        let dir = temp_dir("params");
        let e = scenario_in(&dir, "[controller.params]\nkp = 1.0").unwrap_err();
        assert_eq!(e.field.as_deref(), Some("controller.params"));
        let e = scenario_in(&dir, "workdir = \".\"").unwrap_err();
        assert_eq!(e.field.as_deref(), Some("controller.workdir"));
        let e = scenario_in(&dir, "exec = [\"sh\"]\nbandwidth_hz = 40.0").unwrap_err();
        assert_eq!(e.field.as_deref(), Some("controller.bandwidth_hz"));
        let e = scenario_in(
            &dir,
            "exec = [\"sh\"]\n[supervision]\nestimate_watchdog_ticks = 3",
        )
        .unwrap_err();
        assert_eq!(
            e.field.as_deref(),
            Some("supervision.estimate_watchdog_ticks")
        );
        let s = scenario_in(&dir, "exec = [\"sh\"]\n[controller.params]\nkp = 1.0").unwrap();
        assert_eq!(s.controller.params.unwrap()["kp"].as_float(), Some(1.0));
        std::fs::remove_dir_all(dir).unwrap();
    }
}
