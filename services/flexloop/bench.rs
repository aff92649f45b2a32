//! `flexloop bench`: the loop's latency table, its verdict, and the
//! machine's own floors measured in the same run; `--sweep` and
//! `--logging-cost` and `--live-cost` hand over to [`crate::sweep`],
//! [`crate::logging_cost`] and [`crate::live_cost`].

use crate::{ab_table, live_cost, logging_cost, probes, sweep};
use anyhow::Context;
use flexloop_analysis::verdict::GridCounts;
use flexloop_node::Role;
use flexloop_node::overrides::OverrideFlags;
use flexloop_protocol::flags;
use flexloop_recording::LogReader;
use flexloop_runfiles::bench::{BenchFile, SwapReport};
use flexloop_runfiles::json::write_json_atomically;
use flexloop_runfiles::{Histogram, RunDir};
use flexloop_runtime::latency::{Metric, QUANTILE_LABELS};
use flexloop_scenario::{Mode, Overrides};
use flexloop_supervisor::conductor::Switch;
use flexloop_supervisor::launch::{LoopArgs, prepare, resolve_scenario, supervise};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// `bench [SCENARIO] [--duration S] [--rate HZ] [--no-probes] [--swap-every S]`,
/// `bench --sweep [...]`, `bench --logging-cost [...]`.
#[derive(Debug, Clone, clap::Args)]
pub struct BenchArgs {
    /// Scenario file, or its name under scenarios/ [default: scenarios/default.toml]
    #[arg(conflicts_with = "sweep")]
    pub scenario: Option<PathBuf>,
    /// One run per point: rates, observer sizes and axes (see --series)
    #[arg(long, conflicts_with_all = ["logging_cost", "live_cost", "rate_hz", "mode", "swap_every"])]
    pub sweep: bool,
    /// The loop twice, with the logger and without: what recording costs
    #[arg(long, conflicts_with_all = ["mode", "no_probes", "swap_every"])]
    pub logging_cost: bool,
    /// The loop twice, served live with a client subscribed to everything and
    /// without a live server: what the live view costs
    #[arg(long, conflicts_with_all = ["logging_cost", "mode", "no_probes", "swap_every"])]
    pub live_cost: bool,
    /// --duration [default: 10 s; 4 s per point with --sweep], --rate [default: 10000 Hz;
    /// the scenario's with --logging-cost], --mode [default: realtime], --no-realtime
    #[command(flatten)]
    pub overrides: OverrideFlags,
    /// Skip measuring the machine's floors after the run
    #[arg(long)]
    pub no_probes: bool,
    /// Swap controller and observer in turn every S seconds
    #[arg(long, value_name = "S", value_parser = positive_seconds)]
    pub swap_every: Option<f64>,
    /// Where the results go [default: runs/<stamp>-<kind>-<pid>]
    #[arg(long, value_name = "DIR")]
    pub run_dir: Option<PathBuf>,
    #[command(flatten)]
    pub grid: sweep::GridArgs,
}

fn positive_seconds(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(s) if s.is_finite() && s > 0.0 => Ok(s),
        _ => Err(format!("needs a positive number of seconds, got {text}")),
    }
}

/// `bench`, `bench --sweep` or `bench --logging-cost`.
pub fn dispatch(args: BenchArgs) -> anyhow::Result<i32> {
    if args.sweep {
        sweep::sweep(sweep::Options::from_args(
            &args.grid,
            &args.overrides,
            args.no_probes,
            args.run_dir.clone(),
        )?)
    } else if args.logging_cost {
        logging_cost::logging_cost(ab_table::Options::from_args(
            args.scenario.clone(),
            &args.overrides,
            args.run_dir.clone(),
        )?)
    } else if args.live_cost {
        live_cost::live_cost(ab_table::Options::from_args(
            args.scenario.clone(),
            &args.overrides,
            args.run_dir.clone(),
        )?)
    } else {
        bench(args)
    }
}

fn bench(args: BenchArgs) -> anyhow::Result<i32> {
    let loop_args = LoopArgs {
        scenario: resolve_scenario(args.scenario.clone())?,
        overrides: Overrides {
            duration_s: Some(args.overrides.duration_s.unwrap_or(10.0)),
            rate_hz: Some(args.overrides.rate_hz.unwrap_or(10_000.0)),
            mode: Some(args.overrides.mode.unwrap_or(Mode::Realtime)),
            no_realtime: args.overrides.no_realtime,
            tick: args.overrides.tick,
        },
        run_dir: args.run_dir.clone(),
    };
    let prepared = prepare(&loop_args)?;
    let scenario = prepared.scenario.clone();
    let run_dir = prepared.run_dir();
    let prefix = prepared.plan.prefix.clone();
    eprintln!(
        "flexloop bench: {} for {} s at {} Hz, run directory {}",
        scenario.name,
        scenario.timing.duration_s,
        scenario.timing.rate_hz,
        run_dir.path().display()
    );
    println!("{}", crate::deployment::profile_line(&scenario));
    // The plant's CPU (what a spinning tick wait costs there), CPU 0 if unpinned.
    let plant_cpu = scenario.realtime.plant.cpu.unwrap_or(0);
    let cpu_before = crate::sampling::CpuTimes::read(plant_cpu);
    let started = Instant::now();
    let scenario_file = prepared.plan.scenario.clone();
    let mut next_swap = args
        .swap_every
        .map(|s| Instant::now() + Duration::from_secs_f64(s));
    let mut swap_roles = [Role::Controller, Role::Observer].into_iter().cycle();
    let mut swap_error: Option<String> = None;
    let finished = supervise(prepared, |running, conductor| {
        let due = next_swap?;
        if Instant::now() < due {
            return None;
        }
        let role = swap_roles.next()?;
        if let Err(e) = conductor.swap(running, role, &scenario_file) {
            swap_error = Some(format!("{e:#}"));
            next_swap = None;
            return None;
        }
        next_swap = args
            .swap_every
            .map(|s| due.max(Instant::now()) + Duration::from_secs_f64(s));
        None
    })?;
    if let Some(e) = &swap_error {
        eprintln!("flexloop bench: swapping stopped: {e}");
    }
    // CPU shares are over the loop's run, not the probes after it.
    let wall_ns = started.elapsed().as_nanos().max(1) as f64;
    let plant_cpu_busy = cpu_before
        .zip(crate::sampling::CpuTimes::read(plant_cpu))
        .map(|(a, b)| a.busy_until(&b));
    eprintln!("flexloop bench: loop ran {:.1} s", wall_ns / 1e9);
    let summary = run_dir.read_summary()?;

    let samples = (scenario.timing.rate_hz * 2.0) as u64;
    let floors = if args.no_probes {
        None
    } else {
        Some(probes::Floors::measure(&scenario, &prefix, samples)?.file())
    };

    let ticks = summary.ticks;
    let c = summary.counters;
    let over = summary
        .latency(Metric::TickToCommand.name())
        .over_one_period
        .unwrap_or(0);
    let gaps = summary.gaps.total();

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
    let row = |name: &str, h: &Histogram| {
        let [p50, p90, p99, p999, p9999, max] = h.percentiles.values().map(|ns| ns as f64 / 1e3);
        println!(
            "{:<24}{:>10}{:>10.1}{:>10.1}{:>10.1}{:>10.1}{:>10.1}{:>10.1}",
            name, h.count, p50, p90, p99, p999, p9999, max
        );
    };
    for metric in Metric::ALL {
        row(metric.name(), &summary.latency(metric.name()));
    }
    let sampling = crate::sampling::jitter(&run_dir.samples(0), scenario.period_ns());
    if let Some(j) = &sampling {
        row("published - tick", &j.published_after_tick);
        row("|interval - period|", &j.interval_error);
    }
    if let Some(f) = &floors {
        for (label, h) in f.rows() {
            row(label, h);
        }
    }

    println!();
    println!(
        "ticks {ticks}, loop misses {}, late commands {}, stalled ticks {} (misses after stalls {}), log gaps {gaps}",
        c.misses, c.late_commands, c.stalled_ticks, c.stall_misses
    );
    println!(
        "stale estimates {} (observer later than half a period: the controller used the estimate of the tick before)",
        c.stale_estimates
    );
    let recording = &summary.recording.sample_file;
    if recording.stopped() {
        let kept = match &recording.closed {
            Some(flexloop_runfiles::summary::ClosedFile::Closed { messages, .. }) => {
                messages.to_string()
            }
            _ => "null".to_string(),
        };
        println!(
            "recording stopped: {} (the sample file keeps {kept} messages; the counts above cover the whole run)",
            recording.error.as_deref().unwrap_or("?"),
        );
    }
    let mut cpu_ns = BTreeMap::new();
    // Per role, over all its instances (swaps and restarts start more).
    let cpu_line: Vec<String> = Role::ALL
        .iter()
        .filter(|role| finished.running.children.iter().any(|c| c.role == **role))
        .map(|role| {
            let ns: u64 = finished
                .running
                .children
                .iter()
                .filter(|c| c.role == *role)
                .map(|c| c.exit.map_or(0, |e| e.cpu_ns))
                .sum();
            cpu_ns.insert(role.name().to_string(), ns);
            format!("{} {:.1} %", role.name(), 100.0 * ns as f64 / wall_ns)
        })
        .collect();
    println!(
        "CPU (share of one core over the run): {}",
        cpu_line.join(", ")
    );
    let plant_cpu_per_tick_ns = cpu_ns
        .get(Role::Plant.name())
        .filter(|_| ticks > 0)
        .map(|ns| *ns as f64 / ticks as f64);
    let tick_wait = run_dir.read_plant_latency().ok().and_then(|p| p.tick_wait);
    println!(
        "{}",
        tick_line(
            tick_wait.as_ref(),
            plant_cpu_per_tick_ns,
            plant_cpu_busy.as_ref(),
            sampling.as_ref()
        )
    );
    let p50 = |h: &Histogram| h.percentiles.p50 as f64;
    let rt = summary.latency(Metric::RoundTrip.name());
    let hop = summary.latency(Metric::PlantToController.name());
    if let Some(f) = &floors {
        println!(
            "ratios at p50: round trip / timer wake-up {:.2}, plant->controller hop / one-way ping-pong {:.2}, round trip / polling ping-pong {:.1}",
            p50(&rt) / p50(&f.timer_wakeup).max(1.0),
            p50(&hop) / (p50(&f.iceoryx2_event_ping_pong) / 2.0).max(1.0),
            p50(&rt) / p50(&f.iceoryx2_polling_ping_pong).max(1.0)
        );
        let p9999 = |h: &Histogram| h.percentiles.p99_99 as f64;
        println!(
            "round trip against the same chain over Unix sockets: p50 {:.2}x, p99.99 {:.2}x",
            p50(&rt) / p50(&f.unix_socket_ring).max(1.0),
            p9999(&rt) / p9999(&f.unix_socket_ring).max(1.0)
        );
    }
    let misses = c.misses;
    // Misses after stalls are not counted as the loop's: with most ticks
    // stalled that would call a loop that never ran at its rate a fit.
    let grid = GridCounts {
        ticks,
        stalled_ticks: c.stalled_ticks,
        late_commands: c.late_commands,
        misses,
        stall_misses: c.stall_misses,
    };
    let fits = misses == 0 && over == 0;
    let rate = if ticks > 0 {
        (misses as f64) / ticks as f64
    } else {
        0.0
    };
    // With a command deadline the plant's misses are against t_k + τ_d
    // (docs/deadline.md); the one-sample count stays beside them.
    let (due, budget, miss_kind) = match scenario.timing.command_deadline_us {
        Some(us) => (
            format!("t_k + {us} µs (its deadline)"),
            format!("its command deadline of {us} µs"),
            "deadline misses",
        ),
        None => (
            "tick k+1".to_string(),
            "one sample period".to_string(),
            "loop misses",
        ),
    };
    println!(
        "verdict: {} — u(k) available before {due} in {} of {} ticks; {} {miss_kind} ({:.4} %), {} commands later than one period after their tick",
        if grid.stalls_dominate() {
            "FAILED: the plant did not keep its grid (stalls dominate: see below)".to_string()
        } else if fits {
            format!("the round trip fits {budget}")
        } else if rate < 1e-4 {
            format!("fits {budget} except rare misses (< 1 in 10 000)")
        } else {
            format!("does NOT fit {budget}")
        },
        ticks.saturating_sub(misses + c.stall_misses),
        ticks,
        misses,
        100.0 * rate,
        over
    );
    println!("grid: {}", grid.verdict());
    println!("{}", grid.late_components(c.stale_estimates));
    let swaps = if finished.switches.is_empty() {
        None
    } else {
        Some(swap_report(&run_dir, &finished.switches)?)
    };
    let bench_file = BenchFile {
        swaps,
        summary,
        probes: floors,
        cpu_ns,
        wall_ns,
        sampling,
        tick_wait,
        plant_cpu_per_tick_ns,
        plant_cpu_busy,
    };
    write_json_atomically(&run_dir.bench(), &bench_file)?;
    println!(
        "histograms: {}, summary: {}",
        run_dir.histogram_log(0).display(),
        run_dir.bench().display()
    );
    // A verdict that fails is the command's failure: a script running the
    // benchmark must not read a FAILED or a does-NOT-fit as a pass.
    let verdict_failed = grid.stalls_dominate() || (!fits && rate >= 1e-4);
    Ok(if verdict_failed {
        crate::loop_command::VERDICT_FAILED
    } else {
        0
    })
}

/// How the plant waited for its ticks and what it cost: the setting (or its
/// fallback), the spin margin, the plant's CPU per tick and its CPU's busy
/// share, the publication intervals.
fn tick_line(
    tick_wait: Option<&flexloop_runfiles::TickWaitReport>,
    plant_cpu_per_tick_ns: Option<f64>,
    busy: Option<&flexloop_runfiles::bench::CpuBusy>,
    sampling: Option<&flexloop_runfiles::bench::SamplingJitter>,
) -> String {
    let us = |ns: u64| ns as f64 / 1e3;
    let mut parts = vec![format!(
        "tick wait {}",
        tick_wait.map_or("(not recorded)", |t| t.setting.as_str())
    )];
    if let Some(s) = tick_wait.and_then(|t| t.spin.as_ref()) {
        parts.push(format!(
            "margin {:.1} µs at the end, {:.1}..{:.1} µs over the run (bounds {:.0}..{:.0}), {} ticks spun, {} woke after the tick, {} spins capped, {:.1} µs spun per spinning tick",
            us(s.margin_ns),
            us(s.margin_lowest_ns),
            us(s.margin_highest_ns),
            us(s.margin_lower_bound_ns),
            us(s.margin_upper_bound_ns),
            s.spun_ticks,
            s.late_wakeups,
            s.capped_spins,
            s.spin_ns as f64 / 1e3 / s.spun_ticks.max(1) as f64
        ));
    }
    if let Some(ns) = plant_cpu_per_tick_ns {
        parts.push(format!("plant CPU {:.1} µs per tick", ns / 1e3));
    }
    if let Some(b) = busy {
        parts.push(format!("CPU {} busy {:.1} %", b.cpu, 100.0 * b.share));
    }
    if let Some(j) = sampling {
        parts.push(format!(
            "publication interval {:.1}..{:.1} µs",
            us(j.interval_min_ns),
            us(j.interval_max_ns)
        ));
    }
    parts.join("; ")
}

/// Misses inside the swap windows (from the replacement's start to 100
/// samples after its boundary) apart from the rest, and the command's step at
/// each switch.
fn swap_report(run_dir: &RunDir, switches: &[Switch]) -> anyhow::Result<SwapReport> {
    let path = run_dir.samples(0);
    let log = LogReader::open(&path).with_context(|| path.display().to_string())?;
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
    Ok(SwapReport {
        count: switches.len(),
        warm,
        misses_inside: inside.misses,
        misses_inside_after_stalls: inside.after_stalls,
        stalls_inside: inside.stalls,
        ticks_inside: inside.ticks,
        misses_outside: outside.misses,
        misses_outside_after_stalls: outside.after_stalls,
        stalls_outside: outside.stalls,
        ticks_outside: outside.ticks,
        switches: switches.iter().map(Switch::record).collect(),
    })
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
