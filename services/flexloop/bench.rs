//! `flexloop bench`: the loop's latency table, its verdict, and the
//! machine's own floors measured in the same run.

use crate::conductor::Switch;
use crate::{LoopArgs, prepare, probes, registry, run_registered_with};
use flexloop_components::LogReader;
use flexloop_node::Role;
use flexloop_protocol::channels::TELEMETRY;
use flexloop_protocol::{Telemetry, flags};
use flexloop_runtime::latency::{Metric, QUANTILE_LABELS};
use flexloop_transport::{Domain, Inlet};
use serde_json::{Value, json};
use std::time::{Duration, Instant};

pub fn bench(args: LoopArgs) -> Result<i32, String> {
    let prepared = prepare(&args)?;
    let scenario = prepared.scenario.clone();
    let run_dir = prepared.plan.run_dir.clone();
    let prefix = prepared.plan.prefix.clone();
    eprintln!(
        "flexloop bench: {} for {} s at {} Hz, run directory {}",
        scenario.name,
        scenario.timing.duration_s,
        scenario.timing.rate_hz,
        run_dir.display()
    );
    println!("{}", profile_line(&scenario));
    let started = Instant::now();
    let scenario_file = prepared.plan.scenario.clone();
    let mut next_swap = args
        .swap_every_s
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    let mut swap_roles = [Role::Controller, Role::Observer].into_iter().cycle();
    let mut swap_error: Option<String> = None;
    let (running, _, switches) = run_registered_with(prepared, |running, conductor| {
        let due = next_swap?;
        if Instant::now() < due {
            return None;
        }
        let role = swap_roles.next()?;
        if let Err(e) = conductor.swap(running, role, &scenario_file) {
            swap_error = Some(e);
            next_swap = None;
            return None;
        }
        next_swap = args
            .swap_every_s
            .map(|s| due.max(Instant::now()) + Duration::from_secs_f64(s));
        None
    })?;
    if let Some(e) = &swap_error {
        eprintln!("flexloop bench: swapping stopped: {e}");
    }
    // CPU shares are over the loop's run, not the probes after it.
    let wall_ns = started.elapsed().as_nanos().max(1) as f64;
    eprintln!("flexloop bench: loop ran {:.1} s", wall_ns / 1e9);
    let summary = flexloop_node::summary::read_summary(&run_dir)?;

    let samples = (scenario.timing.rate_hz * 2.0) as u64;
    let floors = if args.probes {
        Some(probes::Floors::measure(&scenario, &prefix, samples)?)
    } else {
        None
    };

    let ticks = summary["ticks"].as_u64().unwrap_or(0);
    let misses = summary["counters"]["misses"].as_u64().unwrap_or(0);
    let stalls = summary["counters"]["stalled_ticks"].as_u64().unwrap_or(0);
    let stall_misses = summary["counters"]["stall_misses"].as_u64().unwrap_or(0);
    let late = summary["counters"]["late_commands"].as_u64().unwrap_or(0);
    let stale = summary["counters"]["stale_estimates"].as_u64().unwrap_or(0);
    let over = summary["latency"]["tick_to_command"]["over_one_period"]
        .as_u64()
        .unwrap_or(0);
    let gaps: u64 = ["measurement", "estimate", "command"]
        .iter()
        .map(|k| summary["gaps"][k].as_u64().unwrap_or(0))
        .sum();

    println!();
    println!(
        "{:<24}{:>10}{:>10}{:>10}{:>10}{:>10}{:>10}{:>10}   (µs)",
        "histogram",
        "count",
        QUANTILE_LABELS[0],
        QUANTILE_LABELS[1],
        QUANTILE_LABELS[2],
        QUANTILE_LABELS[3],
        QUANTILE_LABELS[4],
        QUANTILE_LABELS[5]
    );
    let row = |name: &str, v: &Value| {
        let us = |k: &str| v[format!("{k}_ns")].as_u64().unwrap_or(0) as f64 / 1e3;
        println!(
            "{:<24}{:>10}{:>10.1}{:>10.1}{:>10.1}{:>10.1}{:>10.1}{:>10.1}",
            name,
            v["count"].as_u64().unwrap_or(0),
            us("p50"),
            us("p90"),
            us("p99"),
            us("p99.9"),
            us("p99.99"),
            us("max")
        );
    };
    for metric in Metric::ALL {
        row(metric.name(), &summary["latency"][metric.name()]);
    }
    let floors_json = floors.as_ref().map(probes::Floors::json);
    if let Some(f) = &floors_json {
        for (key, label) in probes::Floors::ROWS {
            row(label, &f[key]);
        }
    }
    let probe = |key: &str| floors_json.as_ref().map(|f| f[key].clone());
    let (timer_json, pp_json, sockets_json) = (
        probe("timer_wakeup"),
        probe("iceoryx2_event_ping_pong"),
        probe("unix_socket_ring"),
    );

    println!();
    println!(
        "ticks {ticks}, loop misses {misses}, late commands {late}, stalled ticks {stalls} (misses after stalls {stall_misses}), log gaps {gaps}"
    );
    println!(
        "stale estimates {stale} (observer later than half a period: the controller used the estimate of the tick before)"
    );
    if summary["recording"]["state"] == "stopped" {
        println!(
            "recording stopped: {} (the sample file keeps {} messages; the counts above cover the whole run)",
            summary["recording"]["error"].as_str().unwrap_or("?"),
            summary["recording"]["closed"]["messages"]
        );
    }
    let mut cpu = serde_json::Map::new();
    // Per role, over all its instances (swaps and restarts start more).
    let cpu_line: Vec<String> = Role::ALL
        .iter()
        .filter(|role| running.children.iter().any(|c| c.role == **role))
        .map(|role| {
            let ns: u64 = running
                .children
                .iter()
                .filter(|c| c.role == *role)
                .map(|c| c.exit.map_or(0, |e| e.cpu_ns))
                .sum();
            cpu.insert(role.name().into(), json!(ns));
            format!("{} {:.1} %", role.name(), 100.0 * ns as f64 / wall_ns)
        })
        .collect();
    println!(
        "CPU (share of one core over the run): {}",
        cpu_line.join(", ")
    );
    let p50 = |v: &Value| v["p50_ns"].as_u64().unwrap_or(0) as f64;
    let rt = &summary["latency"]["round_trip"];
    let hop = &summary["latency"]["plant_to_controller"];
    if let (Some(t), Some(p), Some(polling)) =
        (&timer_json, &pp_json, probe("iceoryx2_polling_ping_pong"))
    {
        println!(
            "ratios at p50: round trip / timer wake-up {:.2}, plant->controller hop / one-way ping-pong {:.2}, round trip / polling ping-pong {:.1}",
            p50(rt) / p50(t).max(1.0),
            p50(hop) / (p50(p) / 2.0).max(1.0),
            p50(rt) / p50(&polling).max(1.0)
        );
    }
    if let Some(s) = &sockets_json {
        let p9999 = |v: &Value| v["p99.99_ns"].as_u64().unwrap_or(0) as f64;
        println!(
            "round trip against the same chain over Unix sockets: p50 {:.2}x, p99.99 {:.2}x",
            p50(rt) / p50(s).max(1.0),
            p9999(rt) / p9999(s).max(1.0)
        );
    }
    let fits = misses == 0 && over == 0;
    let rate = if ticks > 0 {
        (misses as f64) / ticks as f64
    } else {
        0.0
    };
    println!(
        "verdict: {} — u(k) available before tick k+1 in {} of {} ticks; {} loop misses ({:.4} %), {} commands later than one period after their tick",
        if fits {
            "the round trip fits one sample period"
        } else if rate < 1e-4 {
            "fits one sample period except rare misses (< 1 in 10 000)"
        } else {
            "does NOT fit one sample period"
        },
        ticks.saturating_sub(misses + stall_misses),
        ticks,
        misses,
        100.0 * rate,
        over
    );
    let swaps = if switches.is_empty() {
        Value::Null
    } else {
        swap_report(&run_dir, &switches)?
    };
    let bench_json = json!({
        "swaps": swaps,
        "summary": summary,
        "probes": floors_json,
        "cpu_ns": Value::Object(cpu),
        "wall_ns": wall_ns,
    });
    let path = run_dir.join("bench.json");
    flexloop_node::summary::write_json_atomically(&path, &bench_json)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    println!(
        "histograms: {}, summary: {}",
        run_dir.join(flexloop_node::logger::HISTOGRAM_LOG).display(),
        path.display()
    );
    Ok(0)
}

/// Which deployment profile runs and why, for the head of the bench table.
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

/// Misses inside the swap windows (from the replacement's start to 100
/// samples after its boundary) apart from the rest, and the command's step at
/// each switch.
fn swap_report(run_dir: &std::path::Path, switches: &[Switch]) -> Result<Value, String> {
    let path = run_dir.join(flexloop_node::logger::SAMPLES_FILE);
    let log = LogReader::open(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let in_window = |seq: u64| {
        switches
            .iter()
            .any(|s| seq >= s.start_seq && seq <= s.from_seq + 100)
    };
    let (inside, outside) = tally_misses(
        log.measurements()
            .map(|m| (m.seq, m.misses, m.flags & flags::STALLED_TICK != 0)),
        in_window,
    );
    let warm = switches.iter().filter(|s| s.warm).count();
    let mut steps: Vec<f64> = switches
        .iter()
        .map(|s| s.du_switch)
        .filter(|d| d.is_finite())
        .collect();
    steps.sort_by(f64::total_cmp);
    let median = steps.get(steps.len() / 2).copied().unwrap_or(f64::NAN);
    let largest = steps.last().copied().unwrap_or(f64::NAN);
    let ordinary = switches
        .iter()
        .map(|s| s.du_before.max(s.du_after))
        .fold(0.0, f64::max);
    println!(
        "swaps {} ({warm} by a warm spare): misses inside swap windows {} (of {} ticks; {} not in a machine stall's wake), outside {} (of {} ticks; {} not in a stall's wake)",
        switches.len(),
        inside.misses,
        inside.ticks,
        inside.misses - inside.after_stalls,
        outside.misses,
        outside.ticks,
        outside.misses - outside.after_stalls,
    );
    println!(
        "machine stalls (runs of ticks the plant woke half a period late for): {} inside the windows, {} outside",
        inside.stalls, outside.stalls
    );
    println!(
        "|Δu| at the switches: median {median:.3e}, largest {largest:.3e}; largest ordinary |Δu| around them {ordinary:.3e}"
    );
    if switches.len() > 10 {
        println!("  (the first 10; all in bench.json)");
    }
    for s in switches.iter().take(10) {
        println!(
            "  {} generation {} from sample {}: |Δu| {:.3e} (ordinary before {:.3e}, after {:.3e})",
            s.role.name(),
            s.generation,
            s.from_seq,
            s.du_switch,
            s.du_before,
            s.du_after
        );
    }
    Ok(json!({
        "count": switches.len(),
        "warm": warm,
        "misses_inside": inside.misses,
        "misses_inside_after_stalls": inside.after_stalls,
        "stalls_inside": inside.stalls,
        "ticks_inside": inside.ticks,
        "misses_outside": outside.misses,
        "misses_outside_after_stalls": outside.after_stalls,
        "stalls_outside": outside.stalls,
        "ticks_outside": outside.ticks,
        "switches": switches.iter().map(Switch::json).collect::<Vec<_>>(),
    }))
}

/// A miss this many ticks after a stalled tick is the stall's: the plant
/// catches up on the ticks it slept through in a burst, and the controller,
/// which acts on the newest sample only, answers the last of them.
const STALL_WAKE: u64 = 3;

/// Misses and stalls over a set of ticks (inside or outside swap windows).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
struct MissTally {
    ticks: u64,
    misses: u64,
    /// Misses within [`STALL_WAKE`] ticks after a stalled tick.
    after_stalls: u64,
    /// Runs of stalled ticks that began here.
    stalls: u64,
}

/// Tallies (seq, cumulative misses, stalled) samples in order, inside and
/// outside the ticks `in_window` names.
fn tally_misses(
    samples: impl Iterator<Item = (u64, u64, bool)>,
    in_window: impl Fn(u64) -> bool,
) -> (MissTally, MissTally) {
    let (mut inside, mut outside) = (MissTally::default(), MissTally::default());
    let mut previous_misses = 0;
    let mut last_stall: Option<u64> = None;
    for (seq, misses, stalled) in samples {
        let tally = if in_window(seq) {
            &mut inside
        } else {
            &mut outside
        };
        let missed = misses.saturating_sub(previous_misses);
        previous_misses = misses;
        tally.ticks += 1;
        tally.misses += missed;
        if stalled {
            tally.stalls += u64::from(last_stall.is_none_or(|s| s + 1 != seq));
            last_stall = Some(seq);
        }
        if last_stall.is_some_and(|s| seq - s <= STALL_WAKE) {
            tally.after_stalls += missed;
        }
    }
    (inside, outside)
}

/// Swaps, crashes and restarts so far, from the supervisor's events file.
fn print_events(run_dir: &std::path::Path) {
    let text =
        std::fs::read_to_string(run_dir.join(crate::conductor::EVENTS_FILE)).unwrap_or_default();
    let events: Vec<Value> = text
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect();
    let count = |kind: &str| events.iter().filter(|e| e["kind"] == kind).count();
    println!(
        "  events: {} swaps, {} crashes, {} restarts",
        count("swap"),
        count("crash"),
        count("restart")
    );
    if let Some(last) = events.last() {
        println!(
            "  last: {} of {} (generation {}) at {:.1} s",
            last["kind"].as_str().unwrap_or("?"),
            last["role"].as_str().unwrap_or("?"),
            last["generation"],
            last["t_s"].as_f64().unwrap_or(0.0)
        );
    }
}

/// Prints the newest telemetry of a running loop (waits up to 3 s for it).
/// The loop's processes and their duties, from the supervisor's list.
fn print_processes(run_dir: &std::path::Path) {
    let path = run_dir.join(crate::conductor::PROCESSES_FILE);
    let Some(list) = std::fs::read_to_string(&path)
        .ok()
        .and_then(|text| serde_json::from_str::<Value>(&text).ok())
    else {
        return;
    };
    let shown: Vec<String> = list["processes"]
        .as_array()
        .map(Vec::as_slice)
        .unwrap_or_default()
        .iter()
        .map(|p| {
            let generation = p["generation"]
                .as_u64()
                .map(|g| format!(" g{g}"))
                .unwrap_or_default();
            format!(
                "{} {}{} (pid {})",
                p["role"].as_str().unwrap_or("?"),
                p["duty"].as_str().unwrap_or("?"),
                generation,
                p["pid"]
            )
        })
        .collect();
    println!("  processes: {}", shown.join(", "));
}

pub fn print_status(entry: &registry::Entry) -> Result<(), String> {
    let domain = Domain::new(&entry.prefix).map_err(|e| e.to_string())?;
    let node = domain.node("status").map_err(|e| e.to_string())?;
    let inlet = Inlet::<Telemetry>::open_polling(&node, &TELEMETRY, TELEMETRY.qos.loop_buffer_size)
        .map_err(|e| e.to_string())?;
    let since = Instant::now();
    let mut first: Option<Telemetry> = None;
    let mut last: Option<Telemetry> = None;
    while since.elapsed() < Duration::from_secs(3) {
        while let Some(t) = inlet.receive().map_err(|e| e.to_string())? {
            if first.is_none() {
                first = Some(*t);
            }
            last = Some(*t);
        }
        if let (Some(a), Some(b)) = (first, last)
            && b.published_ns > a.published_ns
        {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    println!(
        "loop {} ({}), run directory {}",
        entry.scenario,
        entry.prefix,
        entry.run_dir.display()
    );
    print_processes(&entry.run_dir);
    let Some(t) = last else {
        println!("  no telemetry yet (the logger publishes once a second)");
        return Ok(());
    };
    if let Some(a) = first.filter(|a| t.published_ns > a.published_ns) {
        let rate =
            (t.samples - a.samples) as f64 / ((t.published_ns - a.published_ns) as f64 / 1e9);
        println!("  rate {rate:.0} samples/s");
    }
    println!(
        "  tick {}, samples {}, misses {}, late commands {}, stalled ticks {}, stale estimates {}, log gaps {}",
        t.seq, t.samples, t.misses, t.late_commands, t.stalled_ticks, t.stale_estimates, t.gaps
    );
    let fmt = |v: [u64; 6]| {
        QUANTILE_LABELS
            .iter()
            .zip(v)
            .map(|(l, ns)| format!("{l} {:.1}", ns as f64 / 1e3))
            .collect::<Vec<_>>()
            .join("  ")
    };
    println!("  round trip µs:    {}", fmt(t.round_trip));
    println!("  tick lateness µs: {}", fmt(t.tick_lateness));
    print_events(&entry.run_dir);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn misses_in_a_stalls_wake_are_told_apart() {
        // Ticks 0..40; a window over 10..20; a stall run 12..14 with misses
        // at 13 (in it), 17 (3 after its end) and 18 (4 after: the loop's);
        // one miss outside at 30 with no stall near.
        let stalled = |seq: u64| (12..=14).contains(&seq);
        let miss_at = [13u64, 17, 18, 30];
        let samples = (0..40u64).map(|seq| {
            let cumulative = miss_at.iter().filter(|&&m| m <= seq).count() as u64;
            (seq, cumulative, stalled(seq))
        });
        let (inside, outside) = tally_misses(samples, |seq| (10..20).contains(&seq));
        assert_eq!(
            inside,
            MissTally {
                ticks: 10,
                misses: 3,
                after_stalls: 2,
                stalls: 1
            }
        );
        assert_eq!(
            outside,
            MissTally {
                ticks: 30,
                misses: 1,
                after_stalls: 0,
                stalls: 0
            }
        );
    }
}
