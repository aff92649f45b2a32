//! The plant's choice of tick wait (`realtime.tick`), once its real-time
//! settings are in force, and its account for `plant_latency.json`.

use flexloop_runfiles::{SpinReport, TickWaitReport};
use flexloop_runtime::realtime::RealtimeGuard;
use flexloop_runtime::tick_wait::{TickWait as Wait, TickWaiter};
use flexloop_scenario::tick::FALLBACK_PRIORITY_REFUSED;
use flexloop_scenario::{Scenario, TickDecision, TickWait};

/// What the plant does about `realtime.tick` on `online_cpus` CPUs, with
/// `scheduling` the outcome of its priority and CPU set-up: a refused
/// SCHED_FIFO priority cannot spin either. A fallback is said once on
/// stderr.
pub fn decide(scenario: &Scenario, online_cpus: usize, scheduling: &RealtimeGuard) -> TickDecision {
    let mut decision = scenario.tick_decision(online_cpus);
    let priority_refused = scheduling
        .applied
        .iter()
        .any(|a| a.setting == "priority" && a.outcome.is_err());
    if decision == TickDecision::As(TickWait::SleepThenSpin) && priority_refused {
        decision = TickDecision::Fallback {
            reason: FALLBACK_PRIORITY_REFUSED,
        };
    }
    if let TickDecision::Fallback { reason } = &decision {
        eprintln!(
            "flexloop-plant: realtime.tick = \"sleep-then-spin\" cannot work here ({reason}); \
             sleeping until each tick instead"
        );
    }
    decision
}

/// The runtime's wait for a decision.
pub fn waiter(decision: &TickDecision, period_ns: u64) -> TickWaiter {
    let wait = match decision.wait() {
        TickWait::Sleep => Wait::Sleep,
        TickWait::SleepThenSpin => Wait::SleepThenSpin,
    };
    TickWaiter::new(wait, period_ns)
}

/// The account of `plant_latency.json`.
pub fn report(decision: &TickDecision, waiter: &TickWaiter) -> TickWaitReport {
    let spin = (waiter.setting() == Wait::SleepThenSpin).then(|| {
        let m = waiter.margin();
        let (lowest, highest) = m.range_ns();
        let (lower, upper) = m.bounds_ns();
        let c = waiter.counts();
        SpinReport {
            margin_ns: m.current_ns(),
            margin_lowest_ns: lowest,
            margin_highest_ns: highest,
            margin_lower_bound_ns: lower,
            margin_upper_bound_ns: upper,
            spun_ticks: c.spun_ticks,
            late_wakeups: c.late_wakeups,
            capped_spins: c.capped_spins,
            spin_ns: c.spin_ns,
        }
    });
    TickWaitReport {
        setting: decision.describe(),
        spin,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_runtime::realtime::{Applied, RealtimeError};
    use flexloop_scenario::Overrides;
    use std::path::Path;

    fn spin_scenario() -> Scenario {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/default.toml");
        let text = std::fs::read_to_string(path)
            .unwrap()
            .replace("[realtime]", "[realtime]\ntick = \"sleep-then-spin\"");
        let mut s = Scenario::parse(Path::new("t.toml"), &text).unwrap();
        s.apply(&Overrides::default());
        s.validate().unwrap();
        s
    }

    #[test]
    fn a_refused_priority_falls_back_to_sleep() {
        let s = spin_scenario();
        let granted = RealtimeGuard::default();
        assert_eq!(
            decide(&s, 2, &granted),
            TickDecision::As(TickWait::SleepThenSpin)
        );
        let mut refused = RealtimeGuard::default();
        refused.applied.push(Applied {
            setting: "priority",
            outcome: Err(RealtimeError::Os(libc::EPERM)),
        });
        let d = decide(&s, 2, &refused);
        assert_eq!(
            d,
            TickDecision::Fallback {
                reason: FALLBACK_PRIORITY_REFUSED
            }
        );
        let r = report(&d, &waiter(&d, s.period_ns()));
        assert!(r.setting.starts_with("sleep (fallback: "), "{}", r.setting);
        assert_eq!(r.spin, None);
    }

    #[test]
    fn a_spinning_plant_reports_its_margin() {
        let s = spin_scenario();
        let d = decide(&s, 2, &RealtimeGuard::default());
        let w = waiter(&d, s.period_ns());
        let r = report(&d, &w);
        assert_eq!(r.setting, "sleep-then-spin");
        let spin = r.spin.unwrap();
        // Before any tick: the upper bound, half of the 100 µs period.
        assert_eq!(spin.margin_ns, 50_000);
        assert_eq!(spin.margin_upper_bound_ns, 50_000);
        assert_eq!(spin.spun_ticks, 0);
    }
}
