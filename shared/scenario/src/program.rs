//! `controller.exec`: the program that serves the controller role in place
//! of the built-in `flexloop-controller` (docs/components.md).
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

impl Scenario {
    /// The controller's program, if the scenario names one
    /// (`controller.exec`), resolved and checked.
    pub fn controller_program(&self) -> Result<Option<ComponentProgram>, ScenarioError> {
        let Some(exec) = &self.controller.exec else {
            return Ok(None);
        };
        let Some((program, args)) = exec.split_first() else {
            return Err(self.err(
                "controller.exec",
                "is empty: give the program, then its arguments (`exec = [\"./my-controller\"]`)",
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
                self.err(
                    "controller.exec",
                    format!("program {}: {why}", path.display()),
                )
            })?;
            path
        } else {
            find_on_path(program).ok_or_else(|| {
                self.err(
                    "controller.exec",
                    format!(
                        "no executable `{program}` on PATH (a program in the scenario's \
                         directory is written `./{program}`)"
                    ),
                )
            })?
        };
        let workdir = match &self.controller.workdir {
            Some(w) if w.is_relative() => dir.join(w),
            Some(w) => w.clone(),
            None => dir,
        };
        if !workdir.is_dir() {
            return Err(self.err(
                "controller.workdir",
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

    /// `controller.workdir` and `controller.params` act only on a program,
    /// the built-in controller's tuning only on the built-in controller.
    pub(crate) fn validate_program(&self) -> Result<(), ScenarioError> {
        if self.controller.exec.is_some() {
            // The built-in law's watchdog: a program sees each estimate's
            // sequence number and decides itself what a stale one means.
            if self.given.contains("supervision.estimate_watchdog_ticks") {
                return Err(self.err(
                    "supervision.estimate_watchdog_ticks",
                    "acts on the built-in controller's law, not on a program of one's own \
                     (`controller.exec`), which sees each estimate's `seq` and decides itself",
                ));
            }
            for field in BUILT_IN_ONLY {
                if self
                    .given
                    .iter()
                    .any(|g| g == field || g.starts_with(&format!("{field}.")))
                {
                    return Err(self.err(
                        field,
                        "tunes the built-in controller, not a program of one's own \
                         (`controller.exec`); its tunables are `[controller.params]`",
                    ));
                }
            }
        } else {
            for field in ["controller.workdir", "controller.params"] {
                if self
                    .given
                    .iter()
                    .any(|g| g == field || g.starts_with(&format!("{field}.")))
                {
                    return Err(self.err(
                        field,
                        "applies only to a controller program (`controller.exec`); the \
                         built-in controller is tuned by the other controller fields",
                    ));
                }
            }
        }
        self.controller_program().map(|_| ())
    }
}

/// The built-in controller's own tuning: fields a program does not read.
pub const BUILT_IN_ONLY: [&str; 5] = [
    "controller.feedback",
    "controller.bandwidth_hz",
    "controller.notches_hz",
    "controller.feedforward",
    "controller.feedforward_form",
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
