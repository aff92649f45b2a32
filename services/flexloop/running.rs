//! The commands on a running loop: `up` starts a loop and supervises it in
//! the foreground; `down`, `status` and `swap` find a running one through
//! the registry and stop, show or change it.

use crate::loop_command::PrefixArg;
use crate::loop_command::VERDICT_FAILED;
use anyhow::bail;
use flexloop_analysis::verdict::GridCounts;
use flexloop_protocol::Telemetry;
use flexloop_protocol::channels::TELEMETRY;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::{EventKind, parse_events};
use flexloop_runfiles::json::read_json;
use flexloop_runfiles::supervision::Processes;
use flexloop_runtime::latency::QUANTILE_LABELS;
use flexloop_scenario::ProgramRole;
use flexloop_supervisor::launch::{prepare, resolve_scenario, supervise};
use flexloop_supervisor::registry;
use flexloop_transport::{Domain, Inlet};
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// `status [--prefix P] [--scenario]`.
#[derive(Debug, clap::Args)]
pub struct StatusArgs {
    #[command(flatten)]
    pub which: PrefixArg,
    /// Print the loop's scenario as it stands (after swaps and sets) as TOML
    /// instead (`flexloop status --scenario > tuned.toml` saves a tuned loop)
    #[arg(long)]
    pub scenario: bool,
}

/// `down [--prefix P | --all]`.
#[derive(Debug, clap::Args)]
pub struct DownArgs {
    /// The loop's iceoryx2 prefix, as `flexloop status` shows it
    #[arg(long, value_name = "P")]
    pub prefix: Option<String>,
    /// Stop every running loop (needed when more than one runs and no --prefix names one)
    #[arg(long, conflicts_with = "prefix")]
    pub all: bool,
}

/// `swap controller|observer SCENARIO [--prefix P]`, or
/// `swap controller|observer [--prefix P] --exec PROGRAM [ARGS]...`.
#[derive(Debug, clap::Args)]
pub struct SwapArgs {
    /// The component to replace
    #[arg(value_enum)]
    pub role: SwapRole,
    /// The scenario to design the new one from (same rate, [plant], [reference] and loop delay)
    #[arg(required_unless_present = "exec", conflicts_with = "exec")]
    pub scenario: Option<PathBuf>,
    #[command(flatten)]
    pub which: PrefixArg,
    /// The loop as it stands, with the component served by this program
    /// (built on flexloop-sdk or the Python package; docs/components.md);
    /// the rest of the line is its arguments
    #[arg(long, num_args = 1.., allow_hyphen_values = true, value_name = "PROGRAM [ARGS]")]
    pub exec: Option<Vec<String>>,
    /// With --exec (and before it): one of the program's parameters, its
    /// value in TOML (`kp=9000.0`, `mode="fast"`); given any, they are its
    /// whole `[controller.params]` (or `[observer.params]`), else the loop's
    /// own table stays
    #[arg(long = "param", value_name = "KEY=VALUE", requires = "exec")]
    pub params: Vec<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SwapRole {
    Controller,
    Observer,
}

impl SwapRole {
    fn name(self) -> &'static str {
        match self {
            SwapRole::Controller => "controller",
            SwapRole::Observer => "observer",
        }
    }
}

/// `up [SCENARIO] [loop flags] [--live [ADDR:PORT] ...]`.
#[derive(Debug, clap::Args)]
pub struct UpArgs {
    #[command(flatten)]
    pub flags: crate::loop_command::LoopFlags,
    #[command(flatten)]
    pub live: crate::live_view::LiveFlags,
}

pub fn up(args: UpArgs) -> anyhow::Result<i32> {
    let live = args.live.options()?;
    let mut prepared = prepare(&args.flags.into_loop_args()?)?;
    prepared.live = live;
    crate::loop_command::warn_about_design(&prepared);
    eprintln!(
        "flexloop: {} at {} Hz ({}{}), run directory {}; Ctrl-C or `flexloop down` stops it",
        prepared.scenario.name,
        prepared.scenario.timing.rate_hz,
        prepared.scenario.timing.mode.as_str(),
        crate::loop_command::pid_words(&prepared.design)
            .map_or(String::new(), |w| format!(", {w}")),
        prepared.plan.run_dir.display()
    );
    let run_dir = prepared.run_dir();
    supervise(prepared, |_, _| None)?;
    Ok(grid_verdict(&run_dir))
}

/// The run's verdict from the plant's counts, printed last; a run whose
/// ticks mostly stalled fails (`flexloop_analysis::verdict`).
fn grid_verdict(run_dir: &RunDir) -> i32 {
    let summary = run_dir.read_summary().unwrap_or_default();
    let grid = crate::run::grid_counts(run_dir, &summary);
    eprintln!("flexloop: verdict: {}", grid.verdict());
    if grid.stalls_dominate() {
        VERDICT_FAILED
    } else {
        0
    }
}

pub fn down(args: DownArgs) -> anyhow::Result<i32> {
    say_finished_dead_loops("down");
    let loops = registry::matching(args.prefix.as_deref());
    if loops.is_empty() {
        println!("flexloop: no loop running");
        return Ok(0);
    }
    let loops = loops_to_stop(loops, &args)?;
    for entry in &loops {
        flexloop_supervisor::conductor::note_stop_request(&entry.run_dir);
    }
    let mut code = 0;
    for entry in loops {
        if registry::stop(&entry, Duration::from_secs(15)) {
            println!(
                "flexloop: stopped {} ({})",
                entry.scenario,
                entry.run_dir.display()
            );
        } else {
            eprintln!("flexloop: supervisor {} did not stop", entry.supervisor_pid);
            code = 1;
        }
    }
    Ok(code)
}

/// The running `loops` (those `--prefix` matched) that `down` stops: the
/// caller's own only (another user's loop is theirs to stop); with several
/// of the caller's and neither `--prefix` nor `--all`, none but an error that
/// names them (stopping a loop by accident costs a run).
fn loops_to_stop(
    loops: Vec<registry::Entry>,
    args: &DownArgs,
) -> anyhow::Result<Vec<registry::Entry>> {
    let caller = registry::caller();
    if args.all {
        // Every loop of the caller's; another user's are theirs to stop.
        let (mine, theirs): (Vec<_>, Vec<_>) = loops
            .into_iter()
            .partition(|e| e.owner.is_none_or(|o| o == caller));
        for e in &theirs {
            eprintln!(
                "flexloop: left {} running: started by another user (uid {})",
                e.prefix,
                e.owner.unwrap_or(u32::MAX)
            );
        }
        return Ok(mine);
    }
    // The loops `--prefix` chose, if all are the caller's.
    if args.prefix.is_some() {
        for e in &loops {
            registry::to_change(std::slice::from_ref(e), Some(&e.prefix), caller)?;
        }
        return Ok(loops);
    }
    // One loop: the caller's only one.
    match registry::to_change(&loops, None, caller) {
        Ok(one) => return Ok(vec![one]),
        Err(registry::NotYours::Several(_)) => {}
        Err(e) => bail!(e),
    }
    let loops: Vec<registry::Entry> = loops
        .into_iter()
        .filter(|e| e.owner.is_none_or(|o| o == caller))
        .collect();
    let running: Vec<String> = loops
        .iter()
        .map(|e| {
            format!(
                "  --prefix {}  {} ({})",
                e.prefix,
                e.scenario,
                e.run_dir.display()
            )
        })
        .collect();
    bail!(
        "{} loops are running; name one with --prefix or stop them all with --all:\n{}",
        loops.len(),
        running.join("\n")
    )
}

pub fn status(args: StatusArgs) -> anyhow::Result<i32> {
    let prefix = args.which.prefix;
    if args.scenario {
        let (_, text) = flexloop_supervisor::attach::current(prefix.as_deref())?;
        print!("{text}");
        return Ok(0);
    }
    say_finished_dead_loops("status");
    let loops = registry::matching(prefix.as_deref());
    if loops.is_empty() {
        println!("flexloop: no loop running");
        return Ok(1);
    }
    let mut code = 0;
    for entry in loops {
        if print_status(&entry)? {
            code = VERDICT_FAILED;
        }
    }
    Ok(code)
}

/// Finishes the loops whose supervisor died, saying what it did.
fn say_finished_dead_loops(command: &str) {
    for line in flexloop_supervisor::dead_loops::finish_dead_loops(command) {
        println!("flexloop: {line}");
    }
}

pub fn swap(args: SwapArgs) -> anyhow::Result<i32> {
    let role = args.role.name();
    let entry = registry::to_change(
        &registry::list(),
        args.which.prefix.as_deref(),
        registry::caller(),
    )?;
    let scenario = match (args.scenario, args.exec) {
        (_, Some(exec)) => {
            let program_role = match args.role {
                SwapRole::Controller => ProgramRole::Controller,
                SwapRole::Observer => ProgramRole::Observer,
            };
            let params = program_params(&args.params)?;
            // The loop chosen above (the caller's), named: others may run.
            with_program(
                Some(&entry.prefix),
                &entry.run_dir,
                program_role,
                &exec,
                params,
            )?
        }
        (scenario, None) => resolve_scenario(scenario)?,
    };
    let answer = flexloop_supervisor::conductor::request_swap(&entry.run_dir, role, &scenario)?;
    let switch = match (answer.ok, answer.switch) {
        (true, Some(switch)) => switch,
        _ => bail!(
            "swap refused: {}",
            answer.error.as_deref().unwrap_or("no reason given")
        ),
    };
    println!(
        "flexloop: {role} generation {} active from sample {}; |Δu| at the switch {:.3e}, largest ordinary |Δu| over 100 samples before {:.3e} and after {:.3e}",
        switch.generation, switch.from_seq, switch.du_switch, switch.du_before, switch.du_after
    );
    Ok(0)
}

/// `--param KEY=VALUE`s as a params table (None when none is given).
fn program_params(given: &[String]) -> anyhow::Result<Option<toml::Table>> {
    if given.is_empty() {
        return Ok(None);
    }
    let mut table = toml::Table::new();
    for text in given {
        let Some((key, value)) = text.split_once('=') else {
            bail!("--param {text}: expected KEY=VALUE (kp=9000.0)");
        };
        let key = key.trim();
        if key.is_empty() || key.contains('.') {
            bail!("--param {text}: the key must be one plain name");
        }
        let value = flexloop_scenario::tune::parse_value(key, value.trim())
            .map_err(|e| anyhow::anyhow!("--param {text}: {e}"))?;
        if table.insert(key.to_string(), value).is_some() {
            bail!("--param {key} is given twice");
        }
    }
    Ok(Some(table))
}

/// The loop's scenario as it stands, with `role` served by the program
/// `exec` (a path with a `/` is relative to the working directory, which
/// the program runs in), written beside the run's other scenarios.
fn with_program(
    prefix: Option<&str>,
    run_dir: &std::path::Path,
    role: ProgramRole,
    exec: &[String],
    params: Option<toml::Table>,
) -> anyhow::Result<PathBuf> {
    let (path, text) = flexloop_supervisor::attach::current(prefix)?;
    let mut table: toml::Table = toml::from_str(&text)?;
    flexloop_scenario::plant_description::anchor_files(&mut table, &path);
    let here = std::env::current_dir()?;
    let mut exec = exec.to_vec();
    if exec[0].contains('/') {
        exec[0] = std::path::absolute(&exec[0])?.display().to_string();
    }
    flexloop_scenario::program::served_by_program(&mut table, role, &exec, Some(&here), params);
    let dir = RunDir::new(run_dir).tuned();
    std::fs::create_dir_all(&dir)?;
    let file = (1..)
        .map(|i| dir.join(format!("exec-{i:03}.toml")))
        .find(|f| !f.exists())
        .expect("an unused name");
    std::fs::write(&file, toml::to_string(&table)?)?;
    Ok(file)
}

/// The loop's design as it stands after swaps and sets (its scenario
/// now, designed again: what `"auto"` chose included), or, when that
/// cannot be read, what was chosen at start.
fn design_now(entry: &registry::Entry) -> Vec<String> {
    let at_start = || -> Vec<String> {
        entry
            .design
            .iter()
            .flat_map(|d| d.lines())
            .map(String::from)
            .collect()
    };
    // Unchanged since the start (no swap or set wrote the scenario as it
    // stands): the words the start wrote.
    if !RunDir::new(&entry.run_dir).scenario_now().is_file() {
        return at_start();
    }
    let now = flexloop_supervisor::attach::current(Some(&entry.prefix))
        .ok()
        .and_then(|(path, text)| flexloop_analysis::loop_report::design_words(&path, &text).ok());
    match now {
        Some(parts) => parts
            .into_iter()
            .map(|(part, words)| format!("{part}: {words}"))
            .collect(),
        None => at_start(),
    }
}

/// Prints the newest telemetry of a running loop (waits up to 3 s for it),
/// its processes and its events so far. Returns whether stalls dominate.
fn print_status(entry: &registry::Entry) -> anyhow::Result<bool> {
    let domain = Domain::new(&entry.prefix)?;
    let node = domain.node("status")?;
    let inlet =
        Inlet::<Telemetry>::open_polling(&node, &TELEMETRY, TELEMETRY.qos.loop_buffer_size)?;
    let since = Instant::now();
    let mut first: Option<Telemetry> = None;
    let mut last: Option<Telemetry> = None;
    while since.elapsed() < Duration::from_secs(3) {
        while let Some(t) = inlet.receive()? {
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
    let run_dir = RunDir::new(&entry.run_dir);
    println!(
        "loop {} ({}), run directory {}",
        entry.scenario,
        entry.prefix,
        entry.run_dir.display()
    );
    for line in design_now(entry) {
        println!("  {line}");
    }
    print_processes(&run_dir);
    if let Ok(live) = flexloop_live::endpoint(&entry.run_dir) {
        println!(
            "  live view: ws://{}{}{}",
            live.address,
            if live.read_only { ", read-only" } else { "" },
            if live.token_required {
                ", changes need live.token"
            } else {
                ""
            }
        );
    }
    let Some(t) = last else {
        println!("  no telemetry yet (the logger publishes once a second)");
        return Ok(false);
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
    if let Some(us) = command_deadline_us(&run_dir) {
        println!(
            "  command deadline tau_d {us} us: its misses are commands sent after t_k + tau_d \
             (the plant held its input for that sample); docs/deadline.md"
        );
    }
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
    print_events(&run_dir);
    let grid = GridCounts {
        ticks: t.seq + 1,
        stalled_ticks: t.stalled_ticks,
        late_commands: t.late_commands,
        misses: t.misses,
        stall_misses: t.stall_misses,
    };
    println!("  {}", grid.late_components(t.stale_estimates));
    println!("  verdict: {}", grid.verdict());
    Ok(grid.stalls_dominate())
}

/// `loop.command_deadline_us` of the run's scenario, if it sets one (a
/// deadline cannot change while the loop runs: a swap refuses it).
fn command_deadline_us(run_dir: &RunDir) -> Option<f64> {
    let text = std::fs::read_to_string(run_dir.scenario_copy()).ok()?;
    let table: toml::Table = toml::from_str(&text).ok()?;
    let value = table.get("loop")?.get("command_deadline_us")?;
    value
        .as_float()
        .or_else(|| value.as_integer().map(|us| us as f64))
}

/// The loop's processes and their duties, from the supervisor's list.
fn print_processes(run_dir: &RunDir) {
    let Ok(list) = read_json::<Processes>(&run_dir.processes()) else {
        return;
    };
    let shown: Vec<String> = list
        .processes
        .iter()
        .map(|p| {
            let generation = p.generation.map(|g| format!(" g{g}")).unwrap_or_default();
            let program = program_name(&p.role, &p.duty, &p.scenario)
                .map(|name| format!(", program {name}"))
                .unwrap_or_default();
            format!(
                "{} {}{} (pid {}{program})",
                p.role, p.duty, generation, p.pid
            )
        })
        .collect();
    println!("  processes: {}", shown.join(", "));
}

/// The program of one's own a process of `role` on `duty` runs, by its
/// file name, if its scenario names one (a spare is always built-in).
fn program_name(role: &str, duty: &str, scenario: &str) -> Option<String> {
    let role = flexloop_node::Role::ALL
        .into_iter()
        .find(|r| r.name() == role)?;
    if duty == "spare" {
        return None;
    }
    let program =
        flexloop_supervisor::children::own_program(role, std::path::Path::new(scenario)).ok()??;
    let name = program.program.file_name()?.to_string_lossy().into_owned();
    Some(match program.args.first() {
        // An interpreter: the script names it better.
        Some(script) if !script.starts_with('-') => format!("{name} {script}"),
        _ => name,
    })
}

/// Swaps, crashes and restarts so far, from the supervisor's events file.
fn print_events(run_dir: &RunDir) {
    let text = std::fs::read_to_string(run_dir.events()).unwrap_or_default();
    let events = match parse_events(&text) {
        Ok(events) => events,
        Err(e) => {
            println!("  events: {}: {e}", run_dir.events().display());
            return;
        }
    };
    let count = |which: fn(&EventKind) -> bool| events.iter().filter(|e| which(&e.kind)).count();
    println!(
        "  events: {} swaps, {} crashes, {} restarts",
        count(|k| matches!(k, EventKind::Swap(_))),
        count(|k| matches!(k, EventKind::Crash(_))),
        count(|k| matches!(k, EventKind::Restart(_)))
    );
    if let Some(last) = events.last() {
        println!(
            "  last: {} of {} (generation {}) at {:.1} s",
            last.kind.name(),
            last.role,
            last.generation
                .map_or("null".to_string(), |g| g.to_string()),
            last.t_s
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(prefix: &str) -> registry::Entry {
        registry::Entry {
            prefix: prefix.into(),
            supervisor_pid: 1,
            run_dir: format!("runs/{prefix}").into(),
            scenario: "default".into(),
            cpus: Vec::new(),
            design: None,
            owner: None,
        }
    }

    fn args(prefix: Option<&str>, all: bool) -> DownArgs {
        DownArgs {
            prefix: prefix.map(String::from),
            all,
        }
    }

    #[test]
    fn a_bare_down_stops_one_loop_but_not_several() {
        let one = loops_to_stop(vec![entry("flx1_")], &args(None, false)).unwrap();
        assert_eq!(one.len(), 1);
        let several = || vec![entry("flx1_"), entry("flx2_")];
        let e = loops_to_stop(several(), &args(None, false)).unwrap_err();
        let message = e.to_string();
        assert!(
            message.contains("2 loops are running")
                && message.contains("--prefix flx1_")
                && message.contains("--prefix flx2_")
                && message.contains("--all"),
            "{message}"
        );
        assert_eq!(
            loops_to_stop(several(), &args(None, true)).unwrap().len(),
            2
        );
        // --prefix chose these (registry::matching): all of them go.
        assert_eq!(
            loops_to_stop(several(), &args(Some("flx"), false))
                .unwrap()
                .len(),
            2
        );
    }
}
