//! The scenario's supervision settings, and the restart back-off.

use super::silence::SilenceRule;
use flexloop_scenario::schema::{RestartPolicy, SafeAction};
use flexloop_scenario::{Mode, Scenario};
use std::time::Duration;

/// The scenario's supervision settings the decisions follow.
#[derive(Debug, Clone)]
pub struct Policy {
    pub restart: RestartPolicy,
    pub max_restarts: u32,
    pub restart_backoff_ms: u64,
    pub warm_spares: bool,
    /// `safe_action = "standby"`: keep a standby controller.
    pub keep_standby: bool,
    pub rate_hz: f64,
    pub n_inputs: usize,
    /// When a live controller or observer counts as hung.
    pub silence: SilenceRule,
}

impl Policy {
    pub fn of(scenario: &Scenario, n_inputs: usize) -> Self {
        let supervision = &scenario.supervision;
        Self {
            restart: supervision.restart,
            max_restarts: supervision.max_restarts,
            restart_backoff_ms: supervision.restart_backoff_ms,
            warm_spares: supervision.warm_spares,
            keep_standby: supervision.safe_action == SafeAction::Standby,
            rate_hz: scenario.timing.rate_hz,
            n_inputs,
            silence: SilenceRule {
                ticks: u64::from(supervision.silent_ticks),
                floor: if realtime_priority(scenario) {
                    SilenceRule::REALTIME_FLOOR
                } else {
                    SilenceRule::SHARED_MACHINE_FLOOR
                },
                lockstep: scenario.timing.mode == Mode::Lockstep,
            },
        }
    }
}

/// Whether the loop's controller and observer run at real-time priority:
/// the scenario asks for it (not dropped by `--no-realtime`) and the
/// supervisor may grant it (root: otherwise each process runs at normal
/// priority and says once what the kernel refused).
fn realtime_priority(scenario: &Scenario) -> bool {
    let rt = &scenario.realtime;
    // SAFETY: geteuid has no preconditions and cannot fail.
    let root = unsafe { libc::geteuid() } == 0;
    root && rt.controller.priority.is_some() && rt.observer.priority.is_some()
}

/// The wait before a component's restart, given how many restarts before it
/// in a row were a crash loop: none for a fault of its own, then the
/// configured back-off, doubled for each further one (at most 2¹⁰ times).
pub fn backoff(base_ms: u64, crash_loop: u32) -> Duration {
    match crash_loop {
        0 => Duration::ZERO,
        n => Duration::from_millis(base_ms << (n - 1).min(10)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_back_off_outside_a_crash_loop_then_doubling_up_to_ten_times() {
        assert_eq!(backoff(100, 0), Duration::ZERO);
        assert_eq!(backoff(100, 1), Duration::from_millis(100));
        assert_eq!(backoff(100, 2), Duration::from_millis(200));
        assert_eq!(backoff(100, 4), Duration::from_millis(800));
        assert_eq!(backoff(100, 11), Duration::from_millis(102_400));
        assert_eq!(backoff(100, 40), backoff(100, 11));
        assert_eq!(backoff(0, 5), Duration::ZERO);
    }
}
