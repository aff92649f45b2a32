//! The scenario's supervision settings, and the restart back-off.

use flexloop_scenario::Scenario;
use flexloop_scenario::schema::{RestartPolicy, SafeAction};
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
        }
    }
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
