//! The command line every loop process shares.

use crate::NodeError;
use crate::overrides::OverrideFlags;
use flexloop_design::LoopDesign;
use flexloop_protocol::Joining;
use flexloop_runtime::realtime::RealtimeSettings;
use flexloop_scenario::{Overrides, Scenario};
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
    /// How it enters the loop (`--join`, `--restart`, `--standby`,
    /// `--spare`; none: at start-up). A spare's `--scenario` gives only the
    /// run's real-time set-up until the supervisor's order names one.
    pub joining: Joining,
}

/// The command line as clap reads it; [`ServiceArgs::parse`] checks the
/// flags only some roles take. The join flags are one way of joining each
/// (a group of which at most one is given).
#[derive(Debug, clap::Parser)]
#[command(no_binary_name = true, disable_help_flag = true)]
#[command(group(clap::ArgGroup::new("joining").multiple(false)))]
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
    #[arg(long, group = "joining")]
    join: bool,
    #[arg(long, group = "joining")]
    standby: bool,
    #[arg(long, group = "joining")]
    restart: bool,
    #[arg(long, group = "joining")]
    spare: bool,
}

impl Flags {
    fn joining(&self) -> Joining {
        if self.join {
            Joining::Replacement
        } else if self.standby {
            Joining::Standby
        } else if self.restart {
            Joining::Restart
        } else if self.spare {
            Joining::Spare
        } else {
            Joining::AtStart
        }
    }
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
        let joining = flags.joining();
        Ok(Self {
            role,
            scenario: flags.scenario,
            prefix: flags.prefix,
            run_dir: flags.run_dir,
            overrides: flags.overrides.into(),
            generation: flags.generation,
            joining,
        })
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

    /// The required arguments and `flags`, parsed for `role`.
    fn with_flags(role: Role, flags: &[&str]) -> Result<ServiceArgs, NodeError> {
        let mut v = os(&["--scenario", "s", "--prefix", "p", "--run-dir", "r"]);
        v.extend(os(flags));
        ServiceArgs::parse(role, v)
    }

    #[test]
    fn each_flag_names_one_way_of_joining() {
        let joining = |role, flags: &[&str]| with_flags(role, flags).unwrap().joining;
        assert_eq!(joining(Role::Observer, &[]), Joining::AtStart);
        assert_eq!(joining(Role::Observer, &["--join"]), Joining::Replacement);
        assert_eq!(joining(Role::Observer, &["--restart"]), Joining::Restart);
        assert_eq!(joining(Role::Controller, &["--standby"]), Joining::Standby);
        assert_eq!(joining(Role::Observer, &["--spare"]), Joining::Spare);
        // Only a controller stands by; the plant and the logger are no spares.
        assert!(with_flags(Role::Observer, &["--standby"]).is_err());
        assert!(with_flags(Role::Plant, &["--spare"]).is_err());
    }

    #[test]
    fn two_ways_of_joining_are_a_usage_error() {
        let e = with_flags(Role::Controller, &["--restart", "--standby"]).unwrap_err();
        assert!(e.to_string().contains("cannot be used with"), "{e}");
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
