//! The CPU time of each loop process over a sweep point's run, past its
//! start-up, from the scheduler's own account.

use flexloop_node::Role;
use flexloop_protocol::Telemetry;
use flexloop_protocol::channels::TELEMETRY;
use flexloop_runfiles::bench::PerRole;
use flexloop_runtime::monotonic_ns;
use flexloop_supervisor::children::RunningLoop;
use flexloop_transport::{Domain, Inlet};
use iceoryx2::prelude::{Node, ipc};

/// CPU time of each loop process from the first moment the logger has
/// seen the warm-up's samples (start-up, such as designing the observer of a
/// large model, takes seconds and stays out) to the last moment every loop
/// process still ran; per sample at the scenario's rate.
pub struct CpuWindow {
    prefix: String,
    warm_up_samples: u64,
    rate_hz: f64,
    // Field order: the inlet must drop before its node.
    inlet: Option<Inlet<Telemetry>>,
    node: Option<Node<ipc::Service>>,
    first: Option<CpuSnapshot>,
    last: Option<CpuSnapshot>,
}

#[derive(Debug, Clone)]
struct CpuSnapshot {
    at_ns: u64,
    /// (role, pid, ns on a CPU) of every running loop process.
    cpu: Vec<(Role, i32, u64)>,
}

impl CpuWindow {
    pub fn new(prefix: &str, warm_up_samples: u64, rate_hz: f64) -> Self {
        Self {
            prefix: prefix.to_string(),
            warm_up_samples,
            rate_hz,
            inlet: None,
            node: None,
            first: None,
            last: None,
        }
    }

    pub fn observe(&mut self, running: &RunningLoop) {
        if self.first.is_none() && !self.warmed_up() {
            return;
        }
        let snapshot = CpuSnapshot {
            at_ns: monotonic_ns(),
            cpu: running
                .children
                .iter()
                .filter(|c| c.exit.is_none())
                .filter_map(|c| Some((c.role, c.pid, on_cpu_ns(c.pid)?)))
                .collect(),
        };
        match &self.first {
            None => self.first = Some(snapshot),
            // Only while every process of the window's start still runs:
            // at the end the plant exits first.
            Some(first) if first.cpu.len() == snapshot.cpu.len() => self.last = Some(snapshot),
            Some(_) => {}
        }
    }

    /// Whether the logger's telemetry has counted the warm-up's samples.
    fn warmed_up(&mut self) -> bool {
        if self.inlet.is_none() {
            // The logger creates the channel; until then try again next time.
            if self.node.is_none() {
                self.node = Domain::new(&self.prefix)
                    .and_then(|d| d.node("sweep-cpu"))
                    .ok();
            }
            self.inlet = self.node.as_ref().and_then(|n| {
                Inlet::<Telemetry>::open_polling(n, &TELEMETRY, TELEMETRY.qos.loop_buffer_size).ok()
            });
        }
        let Some(inlet) = &self.inlet else {
            return false;
        };
        let mut warm = false;
        while let Ok(Some(t)) = inlet.receive() {
            warm |= t.samples >= self.warm_up_samples;
        }
        warm
    }

    /// Per role: CPU ns per sample and share of one core (NaN: no window).
    pub fn result(&self) -> (PerRole, PerRole) {
        let (mut per_sample, mut share) = ([f64::NAN; 4], [f64::NAN; 4]);
        let (Some(a), Some(b)) = (&self.first, &self.last) else {
            return (per_role(per_sample), per_role(share));
        };
        let wall = b.at_ns.saturating_sub(a.at_ns).max(1) as f64;
        let samples = (wall / 1e9 * self.rate_hz).max(1.0);
        for (i, role) in Role::ALL.iter().enumerate() {
            let used: u64 = b
                .cpu
                .iter()
                .filter(|(r, _, _)| r == role)
                .filter_map(|(_, pid, end)| {
                    let (_, _, start) = a.cpu.iter().find(|(_, p, _)| p == pid)?;
                    Some(end.saturating_sub(*start))
                })
                .sum();
            per_sample[i] = used as f64 / samples;
            share[i] = used as f64 / wall;
        }
        (per_role(per_sample), per_role(share))
    }
}

/// Values in [`Role::ALL`] order, by role.
fn per_role([plant, observer, controller, logger]: [f64; 4]) -> PerRole {
    PerRole {
        plant,
        observer,
        controller,
        logger,
    }
}

/// Nanoseconds the process's threads have run on a CPU (the scheduler's own
/// account, `/proc/PID/task/*/schedstat`; getrusage only covers the dead).
fn on_cpu_ns(pid: i32) -> Option<u64> {
    let tasks = std::fs::read_dir(format!("/proc/{pid}/task")).ok()?;
    let mut total = 0u64;
    for task in tasks.flatten() {
        let text = std::fs::read_to_string(task.path().join("schedstat")).unwrap_or_default();
        total += text
            .split_whitespace()
            .next()
            .and_then(|v| v.parse::<u64>().ok())
            .unwrap_or(0);
    }
    Some(total)
}
