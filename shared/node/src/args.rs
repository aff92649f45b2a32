//! The command line every loop process shares.

use crate::NodeError;
use flexloop_runtime::realtime::RealtimeSettings;
use flexloop_scenario::{LoopDesign, Mode, Overrides, Scenario};
use std::ffi::OsString;
use std::path::PathBuf;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    Plant,
    Observer,
    Controller,
    Logger,
}

impl Role {
    pub const ALL: [Role; 4] = [Role::Plant, Role::Observer, Role::Controller, Role::Logger];

    pub fn name(self) -> &'static str {
        match self {
            Role::Plant => "plant",
            Role::Observer => "observer",
            Role::Controller => "controller",
            Role::Logger => "logger",
        }
    }
}

/// `flexloop-<role> --scenario FILE --prefix P --run-dir DIR [overrides]`.
#[derive(Debug, Clone)]
pub struct ServiceArgs {
    pub role: Role,
    pub scenario: PathBuf,
    pub prefix: String,
    pub run_dir: PathBuf,
    pub overrides: Overrides,
    /// Generation of this instance (the plant accepts commands of this one).
    pub generation: u32,
    /// Join a running loop as a replacement (swap or restart): no start-up
    /// handshake, shadow until the activation hands it its samples.
    pub join: bool,
    /// A controller that follows the active one in shadow and publishes its
    /// commands for the plant's safe action (scenario `safe_action = "standby"`).
    pub standby: bool,
    /// Replaces an instance that crashed (implies `join`): its last state
    /// comes from the supervisor, which replays the measurements since to
    /// an observer.
    pub restart: bool,
    /// Start as a warm spare: open every port, then wait for the
    /// supervisor's order (`--scenario` gives only the run's real-time
    /// set-up until then).
    pub spare: bool,
}

pub const USAGE: &str = "--scenario FILE --prefix PREFIX --run-dir DIR [--rate HZ] [--duration S] [--mode realtime|lockstep] [--no-realtime] [--generation N] [--join] [--standby] [--restart] [--spare]";

impl ServiceArgs {
    pub fn parse(role: Role, args: impl IntoIterator<Item = OsString>) -> Result<Self, NodeError> {
        use lexopt::prelude::*;
        let usage =
            |m: String| NodeError::Usage(format!("{m}\n  flexloop-{} {USAGE}", role.name()));
        let mut parser =
            lexopt::Parser::from_iter(std::iter::once(OsString::from("x")).chain(args));
        let (mut scenario, mut prefix, mut run_dir) = (None, None, None);
        let mut overrides = Overrides::default();
        let mut generation = 0;
        let mut join = false;
        let mut standby = false;
        let mut restart = false;
        let mut spare = false;
        while let Some(arg) = parser.next().map_err(|e| usage(e.to_string()))? {
            let value = |p: &mut lexopt::Parser| -> Result<String, NodeError> {
                p.value()
                    .map_err(|e| usage(e.to_string()))?
                    .into_string()
                    .map_err(|_| usage("argument is not UTF-8".into()))
            };
            match arg {
                Long("scenario") => scenario = Some(PathBuf::from(value(&mut parser)?)),
                Long("prefix") => prefix = Some(value(&mut parser)?),
                Long("run-dir") => run_dir = Some(PathBuf::from(value(&mut parser)?)),
                Long("rate") => {
                    overrides.rate_hz = Some(
                        value(&mut parser)?
                            .parse()
                            .map_err(|_| usage("--rate needs a number".into()))?,
                    )
                }
                Long("duration") => {
                    overrides.duration_s = Some(
                        value(&mut parser)?
                            .parse()
                            .map_err(|_| usage("--duration needs a number".into()))?,
                    )
                }
                Long("mode") => {
                    let v = value(&mut parser)?;
                    overrides.mode =
                        Some(Mode::parse(&v).ok_or_else(|| usage(format!("unknown mode `{v}`")))?)
                }
                Long("no-realtime") => overrides.no_realtime = true,
                Long("join") => join = true,
                Long("standby") if role == Role::Controller => standby = true,
                Long("restart") => restart = true,
                Long("spare") if matches!(role, Role::Controller | Role::Observer) => spare = true,
                Long("generation") => {
                    generation = value(&mut parser)?
                        .parse()
                        .map_err(|_| usage("--generation needs a number".into()))?
                }
                other => {
                    return Err(usage(format!(
                        "unexpected argument {:?}",
                        other.unexpected()
                    )));
                }
            }
        }
        Ok(Self {
            role,
            scenario: scenario.ok_or_else(|| usage("--scenario is required".into()))?,
            prefix: prefix.ok_or_else(|| usage("--prefix is required".into()))?,
            run_dir: run_dir.ok_or_else(|| usage("--run-dir is required".into()))?,
            overrides,
            generation,
            join: join || standby || restart || spare,
            standby,
            restart,
            spare,
        })
    }

    /// What a process needs before its ports exist: the scenario (for its
    /// real-time set-up) and, unless it is a spare, which designs only once
    /// it is ordered to serve, the design.
    pub fn load_at_start(&self) -> Result<(Scenario, Option<LoopDesign>), NodeError> {
        if self.spare {
            Ok((Scenario::load(&self.scenario, &self.overrides)?, None))
        } else {
            let (scenario, design) = self.load()?;
            Ok((scenario, Some(design)))
        }
    }

    /// Loads and designs the scenario (the same in every process).
    pub fn load(&self) -> Result<(Scenario, LoopDesign), NodeError> {
        let scenario = Scenario::load(&self.scenario, &self.overrides)?;
        let design = LoopDesign::from_scenario(&scenario)?;
        Ok((scenario, design))
    }
}

/// The scenario's real-time settings for `role`.
/// How the loop's processes wait, from the scenario's `realtime.profile`.
pub fn wait_mode(scenario: &Scenario) -> flexloop_runtime::wait::WaitMode {
    match scenario.realtime.profile {
        flexloop_scenario::Profile::SharedCores => flexloop_runtime::wait::WaitMode::Events,
        flexloop_scenario::Profile::DedicatedCores => flexloop_runtime::wait::WaitMode::Spin,
    }
}

pub fn realtime_settings(scenario: &Scenario, role: Role) -> RealtimeSettings {
    let rt = &scenario.realtime;
    let process = match role {
        Role::Plant => &rt.plant,
        Role::Observer => &rt.observer,
        Role::Controller => &rt.controller,
        Role::Logger => &rt.logger,
    };
    let is_loop = role != Role::Logger;
    // Lockstep runs the chain flat out: under SCHED_FIFO it would starve
    // everything else on its CPU (kernel threads, a replacement instance).
    let lockstep = scenario.timing.mode == flexloop_scenario::Mode::Lockstep;
    RealtimeSettings {
        fifo_priority: process.priority.filter(|_| !lockstep),
        cpu: process.cpu,
        lock_memory: rt.lock_memory && is_loop,
        timer_slack_ns: Some(rt.timer_slack_ns),
        hold_cpu_dma_latency: rt.hold_cpu_dma_latency && role == Role::Plant,
        prefault_private: false,
        // Start-up work stays off the CPU of the plant's clock (the loop's).
        avoid_cpu: rt.plant.cpu,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn os(v: &[&str]) -> Vec<OsString> {
        v.iter().map(OsString::from).collect()
    }

    #[test]
    fn parses_all_flags() {
        let a = ServiceArgs::parse(
            Role::Plant,
            os(&[
                "--scenario",
                "s.toml",
                "--prefix",
                "p_",
                "--run-dir",
                "r",
                "--rate",
                "2000",
                "--mode",
                "lockstep",
                "--no-realtime",
            ]),
        )
        .unwrap();
        assert_eq!(a.prefix, "p_");
        assert_eq!(a.overrides.rate_hz, Some(2000.0));
        assert_eq!(a.overrides.mode, Some(Mode::Lockstep));
        assert!(a.overrides.no_realtime);
    }

    #[test]
    fn a_restart_joins_the_running_loop() {
        let a = ServiceArgs::parse(
            Role::Observer,
            os(&[
                "--scenario",
                "s",
                "--prefix",
                "p",
                "--run-dir",
                "r",
                "--restart",
            ]),
        )
        .unwrap();
        assert!(a.restart && a.join && !a.standby);
    }

    #[test]
    fn missing_and_bad_flags_are_usage_errors() {
        let e = ServiceArgs::parse(Role::Plant, os(&["--prefix", "p"])).unwrap_err();
        assert!(e.to_string().contains("--scenario is required"));
        let e = ServiceArgs::parse(Role::Plant, os(&["--scenario", "s", "--mode", "fast"]))
            .unwrap_err();
        assert!(e.to_string().contains("unknown mode"));
    }
}
