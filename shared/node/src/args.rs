//! The command line every loop process shares.

use crate::NodeError;
use crate::overrides::OverrideFlags;
use flexloop_runtime::realtime::RealtimeSettings;
use flexloop_scenario::{LoopDesign, Overrides, Scenario};
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

/// The command line as clap reads it; [`ServiceArgs::parse`] checks the
/// flags only some roles take.
#[derive(Debug, clap::Parser)]
#[command(no_binary_name = true, disable_help_flag = true)]
struct Flags {
    #[arg(long, value_name = "FILE")]
    scenario: PathBuf,
    #[arg(long, value_name = "PREFIX")]
    prefix: String,
    #[arg(long, value_name = "DIR")]
    run_dir: PathBuf,
    #[command(flatten)]
    overrides: OverrideFlags,
    #[arg(long, value_name = "N", default_value_t = 0)]
    generation: u32,
    #[arg(long)]
    join: bool,
    #[arg(long)]
    standby: bool,
    #[arg(long)]
    restart: bool,
    #[arg(long)]
    spare: bool,
}

impl ServiceArgs {
    pub fn parse(role: Role, args: impl IntoIterator<Item = OsString>) -> Result<Self, NodeError> {
        use clap::Parser;
        let flags = Flags::try_parse_from(args).map_err(|e| NodeError::Usage(e.to_string()))?;
        let only = |taken: bool, flag: &str, roles: &str| {
            if taken {
                Err(NodeError::Usage(format!(
                    "{flag}: only the {roles} takes it, not the {}",
                    role.name()
                )))
            } else {
                Ok(())
            }
        };
        only(
            flags.standby && role != Role::Controller,
            "--standby",
            "controller",
        )?;
        only(
            flags.spare && !matches!(role, Role::Controller | Role::Observer),
            "--spare",
            "controller or observer",
        )?;
        Ok(Self {
            role,
            scenario: flags.scenario,
            prefix: flags.prefix,
            run_dir: flags.run_dir,
            overrides: flags.overrides.into(),
            generation: flags.generation,
            join: flags.join || flags.standby || flags.restart || flags.spare,
            standby: flags.standby,
            restart: flags.restart,
            spare: flags.spare,
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
    use flexloop_scenario::Mode;

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
    fn only_a_controller_stands_by() {
        let e = ServiceArgs::parse(
            Role::Observer,
            os(&[
                "--scenario",
                "s",
                "--prefix",
                "p",
                "--run-dir",
                "r",
                "--standby",
            ]),
        )
        .unwrap_err();
        assert!(e.to_string().contains("--standby"), "{e}");
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
        assert!(e.to_string().contains("--scenario"), "{e}");
        let e = ServiceArgs::parse(Role::Plant, os(&["--scenario", "s", "--mode", "fast"]))
            .unwrap_err();
        assert!(e.to_string().contains("unknown mode"));
    }
}
