//! The facts of a run that its sample file carries: scenario (with the file
//! as it was), rates, version, host and the real-time settings in force.

use crate::args::{Role, ServiceArgs, realtime_settings};
use flexloop_runtime::realtime::RealtimeGuard;
use flexloop_scenario::Scenario;
use std::collections::BTreeMap;

/// The `flexloop` metadata of the sample file (MCAP metadata is text only).
pub fn run_metadata(
    args: &ServiceArgs,
    scenario: &Scenario,
    log_time_offset_ns: u64,
    logger_realtime: &[&RealtimeGuard],
) -> BTreeMap<String, String> {
    let mut m = BTreeMap::new();
    let mut put = |k: &str, v: String| {
        m.insert(k.to_string(), v);
    };
    put("scenario", scenario.name.clone());
    put("scenario_description", scenario.description.clone());
    put("scenario_file", scenario.source.display().to_string());
    put(
        "scenario_toml",
        std::fs::read_to_string(&scenario.source).unwrap_or_else(|e| format!("(unreadable: {e})")),
    );
    put("mode", scenario.timing.mode.as_str().into());
    put("rate_hz", scenario.timing.rate_hz.to_string());
    put("period_ns", scenario.period_ns().to_string());
    put("duration_s", scenario.timing.duration_s.to_string());
    put("prefix", args.prefix.clone());
    put("logger_generation", args.generation.to_string());
    put("flexloop_version", env!("CARGO_PKG_VERSION").into());
    put(
        "log_time",
        "published_ns (CLOCK_MONOTONIC) + log_time_offset_ns: wall clock".into(),
    );
    put("log_time_offset_ns", log_time_offset_ns.to_string());
    for role in Role::ALL {
        let rt = realtime_settings(scenario, role);
        put(
            &format!("realtime_{}", role.name()),
            format!(
                "{} cpu={} lock_memory={} timer_slack_ns={} cpu_dma_latency={}",
                rt.fifo_priority
                    .map_or("SCHED_OTHER".to_string(), |p| format!("SCHED_FIFO {p}")),
                rt.cpu.map_or("any".to_string(), |c| c.to_string()),
                rt.lock_memory,
                rt.timer_slack_ns
                    .map_or("default".to_string(), |s| s.to_string()),
                rt.hold_cpu_dma_latency,
            ),
        );
    }
    if scenario.plant_sleeps_for_ticks() {
        // As the scenario resolves on this machine; the plant's own record
        // (plant_latency.json) also knows whether its priority was granted.
        put(
            "realtime_tick",
            scenario
                .tick_decision(flexloop_runtime::realtime::online_cpus())
                .describe(),
        );
    }
    let applied: Vec<String> = logger_realtime.iter().map(|g| g.summary()).collect();
    put("realtime_logger_applied", applied.join(" "));
    for (key, path) in [
        ("host_name", "/proc/sys/kernel/hostname"),
        ("kernel_release", "/proc/sys/kernel/osrelease"),
        ("kernel_version", "/proc/sys/kernel/version"),
        ("cpus_isolated", "/sys/devices/system/cpu/isolated"),
        ("cpus_online", "/sys/devices/system/cpu/online"),
        ("kernel_realtime", "/sys/kernel/realtime"),
    ] {
        if let Ok(text) = std::fs::read_to_string(path) {
            put(key, text.trim().to_string());
        }
    }
    // SAFETY: sysconf has no preconditions.
    let cpus = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) };
    put("cpu_count", cpus.to_string());
    if let Some(model) = std::fs::read_to_string("/proc/cpuinfo").ok().and_then(|t| {
        t.lines()
            .find(|l| l.starts_with("model name"))
            .and_then(|l| l.split_once(':'))
            .map(|(_, v)| v.trim().to_string())
    }) {
        put("cpu_model", model);
    }
    m
}
