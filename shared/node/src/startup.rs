//! What a replacement's start-up costs: from `main` to following the running
//! loop, in wall time and in CPU time (spent beside the loop, on the other
//! CPU), written once to its stderr file for the run's record.

use crate::Role;
use flexloop_runtime::usage::process_cpu_ns;
use std::time::Instant;

pub struct StartupClock {
    since: Instant,
}

impl StartupClock {
    pub fn start() -> Self {
        Self {
            since: Instant::now(),
        }
    }

    /// Called once, when the process is about to follow the loop.
    pub fn report_joined(&self, role: Role) {
        eprintln!(
            "flexloop-{}: start-up {:.1} ms, {:.1} ms of CPU",
            role.name(),
            self.since.elapsed().as_secs_f64() * 1e3,
            process_cpu_ns() as f64 / 1e6
        );
    }
}
