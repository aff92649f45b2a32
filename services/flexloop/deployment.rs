//! Which deployment profile a loop runs under and why
//! (docs/architecture.md, "Scheduling and deployment profiles"), as the
//! bench table and the sweep print it at their head.

/// Which deployment profile runs and why, for the head of a bench table.
pub fn profile_line(scenario: &flexloop_scenario::Scenario) -> String {
    use flexloop_scenario::{DEDICATED_CORES_MIN_CPUS, Profile};
    let cpus = flexloop_runtime::realtime::online_cpus();
    let rt = &scenario.realtime;
    let cpu = |p: &flexloop_scenario::schema::ProcessRealtime| {
        p.cpu.map_or("any".to_string(), |c| c.to_string())
    };
    let placement = format!(
        "plant CPU {}, observer {}, controller {}, logger {}",
        cpu(&rt.plant),
        cpu(&rt.observer),
        cpu(&rt.controller),
        cpu(&rt.logger)
    );
    match rt.profile {
        Profile::SharedCores => format!(
            "profile shared-cores: event wake-ups, {placement}; {}",
            if cpus < DEDICATED_CORES_MIN_CPUS {
                format!(
                    "this machine has {cpus} CPUs, a spinning dedicated-cores profile needs {DEDICATED_CORES_MIN_CPUS}"
                )
            } else {
                format!(
                    "this machine has {cpus} CPUs: realtime.profile = \"dedicated-cores\" would spin each loop process on its own"
                )
            }
        ),
        Profile::DedicatedCores => format!(
            "profile dedicated-cores: plant, observer and controller spin on their own CPUs ({placement}; {cpus} CPUs)"
        ),
    }
}
