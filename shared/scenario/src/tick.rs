//! `realtime.tick`: whether it applies to a scenario, whether its priorities
//! let a spinning plant be preempted by the chain, and what the plant does on
//! a machine where spinning cannot work (docs/architecture.md, "Waiting for
//! the tick").

use crate::ScenarioError;
use crate::schema::{Mode, Profile, Scenario, TickWait};

/// What the plant does about `realtime.tick` on this machine.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TickDecision {
    /// The setting as the scenario asks (or as it defaults).
    As(TickWait),
    /// `sleep-then-spin` was asked but cannot work here: the plant sleeps.
    Fallback { reason: &'static str },
}

impl TickDecision {
    /// The wait the plant uses.
    pub fn wait(&self) -> TickWait {
        match self {
            TickDecision::As(w) => *w,
            TickDecision::Fallback { .. } => TickWait::Sleep,
        }
    }

    /// For run records: `sleep`, `sleep-then-spin` or `sleep (fallback: …)`.
    pub fn describe(&self) -> String {
        match self {
            TickDecision::As(w) => w.as_str().to_string(),
            TickDecision::Fallback { reason } => format!("sleep (fallback: {reason})"),
        }
    }
}

/// Fallback reasons (one stderr line each, and the run's records).
pub const FALLBACK_ONE_CPU: &str = "sleep-then-spin needs a second online CPU; this machine has \
     one, which a spinning plant would hold from everything else";
pub const FALLBACK_NO_PRIORITY: &str = "sleep-then-spin needs the plant under SCHED_FIFO below \
     the observer and controller (--no-realtime or realtime.plant.priority absent), so that \
     they preempt its spin";
pub const FALLBACK_PRIORITY_REFUSED: &str = "sleep-then-spin needs the plant under SCHED_FIFO, \
     and the system refused its priority";

impl Scenario {
    /// Whether the plant waits on its clock at all: realtime mode under the
    /// shared-cores profile (lockstep ticks when the command arrives;
    /// dedicated-cores spins the whole period).
    pub fn plant_sleeps_for_ticks(&self) -> bool {
        self.timing.mode == Mode::Realtime && self.realtime.profile == Profile::SharedCores
    }

    /// `realtime.tick` given where it does not act, and a spinning plant the
    /// observer or the controller could not preempt, are refused.
    pub(crate) fn validate_tick(&self) -> Result<(), ScenarioError> {
        let rt = &self.realtime;
        if self.given.contains("realtime.tick") {
            if self.timing.mode == Mode::Lockstep {
                return Err(self.err(
                    "realtime.tick",
                    "does not apply: in lockstep the plant does not wait on its clock (each \
                     tick starts when the command arrives)",
                ));
            }
            if rt.profile == Profile::DedicatedCores {
                return Err(self.err(
                    "realtime.tick",
                    "does not apply: under dedicated-cores the plant spins on its clock the \
                     whole period",
                ));
            }
        }
        if rt.tick != TickWait::SleepThenSpin || !self.plant_sleeps_for_ticks() {
            return Ok(());
        }
        // Without a plant priority the plant falls back to sleeping (see
        // `tick_decision`); with one, the chain must run above it, or the
        // spin holds them off the CPU they share with it.
        let Some(plant) = rt.plant.priority else {
            return Ok(());
        };
        for (role, p) in [("observer", &rt.observer), ("controller", &rt.controller)] {
            match p.priority {
                Some(q) if q > plant => {}
                Some(q) => {
                    return Err(self.err(
                        "realtime.plant.priority",
                        format!(
                            "realtime.tick = \"sleep-then-spin\" spins the plant at SCHED_FIFO \
                             {plant}, and the {role} runs at {q}: it must run above the plant \
                             to preempt the spin (the shipped scenarios: plant 79, observer 80, \
                             controller 81)"
                        ),
                    ));
                }
                None => {
                    return Err(self.err(
                        "realtime.plant.priority",
                        format!(
                            "realtime.tick = \"sleep-then-spin\" spins the plant at SCHED_FIFO \
                             {plant}, and realtime.{role}.priority is absent (SCHED_OTHER, \
                             which the spin would hold off): give the {role} a priority above \
                             the plant's"
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// What the plant does about `realtime.tick` on a machine with
    /// `online_cpus` CPUs (the scenario validated).
    pub fn tick_decision(&self, online_cpus: usize) -> TickDecision {
        let asked = self.realtime.tick;
        if asked != TickWait::SleepThenSpin || !self.plant_sleeps_for_ticks() {
            return TickDecision::As(asked);
        }
        if online_cpus < 2 {
            return TickDecision::Fallback {
                reason: FALLBACK_ONE_CPU,
            };
        }
        if self.realtime.plant.priority.is_none() {
            return TickDecision::Fallback {
                reason: FALLBACK_NO_PRIORITY,
            };
        }
        TickDecision::As(asked)
    }
}
