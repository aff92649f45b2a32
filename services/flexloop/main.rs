//! flexloop: starts, drives and measures the loop's processes.
//!
//! `flexloop up [SCENARIO]`, `flexloop run SCENARIO`, `flexloop down`,
//! `flexloop status`, `flexloop bench [--duration S] [--rate HZ]`,
//! `flexloop tune-ff RUN`, `flexloop report RUN`. See README.md.

mod bench;
mod conductor;
mod design;
mod export;
mod logging_cost;
mod positions;
mod probes;
mod progress;
mod registry;
mod report;
mod run;
mod supervisor;
mod sweep;

use flexloop_runtime::shutdown;
use flexloop_scenario::{Mode, Overrides, Scenario};
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::Duration;

const USAGE: &str = "usage:
  flexloop up [SCENARIO] [--duration S] [--rate HZ] [--mode realtime|lockstep] [--run-dir DIR] [--no-realtime]
      start the loop's processes (default scenario: scenarios/default.toml) until the
      scenario's duration ends, Ctrl-C or `flexloop down`
  flexloop run [SCENARIO] [--mode realtime|lockstep] [--rate HZ] [--duration S] [--run-dir DIR] [--no-realtime]
      run the scenario's trajectory, then print its control metrics (tracking, effort,
      innovation, modal damping) beside the timing summary; writes metrics.json
  flexloop report RUN [--out DIR]
      a finished run as report.md (with SVG figures) and a self-contained report.html in
      RUN/report/ (or DIR): latency percentile plots, tick timing, tracking error, command
      parts, estimated against true flexible output, timing and control tables, events;
      RUN is a run directory or its name under runs/
  flexloop tune-ff RUN_DIR [--into SCENARIO]
      fit the four feedforward gains from a recorded run by least squares and write
      them into the scenario file (default: the one the run used)
  flexloop design [SCENARIO] [--continuous] [--json]
      design report of the thesis chain at the scenario's rate and loop delay: modes,
      observer poles, AD damping, largest f_bw meeting the 6 dB rule per case
  flexloop positions [SCENARIO...] [--json] [--each] [--per-span N (4) | --at P,P...]
                   [--feedforward compliance-shifted|as-tuned|mass-only] [--processes [--run-dir DIR] [--keep-logs]]
      Table 4.1: each scenario (default: the seven thesis cases) with the sensor at
      7·N+1 positions along the chain (0 = ma … 7 = m7); min / mean / max rms e_true over
      the scan beside the thesis; in-process lockstep, or --processes through the processes
      in lockstep (one run directory per position; sample logs removed unless --keep-logs)
  flexloop export RUN --csv [--out DIR]
      the run's sample file (RUN: a run directory or a samples*.mcap file) as one CSV per
      channel (measurement, estimate, command, events; header row with units) in RUN/csv
  flexloop down [--prefix P]          stop running loops
  flexloop status [--prefix P]        live counters and latency percentiles of a running loop
  flexloop swap controller|observer SCENARIO [--prefix P]
      replace a running loop's controller or observer by one designed from SCENARIO
      (same [loop] and [plant]): it starts in shadow, takes over the state and
      becomes active at a sample boundary; prints the command's step there
  flexloop bench [SCENARIO] [--duration S (10)] [--rate HZ (10000)] [--no-realtime] [--no-probes] [--run-dir DIR]
               [--swap-every S]
      run the loop, measure this machine's floors, print the latency table and a verdict;
      with --swap-every, replace the controller and the observer in turn every S seconds
      and count the misses inside the swap windows apart from the rest
  flexloop bench --sweep [--series rate,states,axes] [--rates HZ,...] [--states N,...] [--duration S (4)]
               [--no-probes] [--no-realtime] [--keep-logs] [--run-dir DIR]
      one run per point: the default scenario at 1, 2, 5, 10, 20, 40 kHz, uniform chains with
      16, 32, 64, 128 observer states and the 2×2 and 3-DOF models at 10 kHz; latency, misses,
      compute and CPU per sample per process, the highest rate under 1 miss in 10 000, the
      cost's growth exponent, the floors; sweep.md, sweep.json and SVG plots in the run directory
  flexloop bench --logging-cost [SCENARIO] [--duration S (10)] [--rate HZ] [--no-realtime] [--run-dir DIR]
      run the loop twice, with the logger and without one, and compare the plant's own
      round-trip histograms: what recording costs at p50 and p99.99";

fn main() {
    let args: Vec<OsString> = std::env::args_os().skip(1).collect();
    let code = match run(args) {
        Ok(code) => code,
        Err(message) => {
            eprintln!("flexloop: {message}");
            2
        }
    };
    std::process::exit(code);
}

fn run(args: Vec<OsString>) -> Result<i32, String> {
    let Some((command, rest)) = args.split_first() else {
        println!("{USAGE}");
        return Ok(2);
    };
    shutdown::install().map_err(|e| format!("cannot install signal handlers: {e}"))?;
    let rest = rest.to_vec();
    if rest.iter().any(|a| a == "--help" || a == "-h") {
        println!("{USAGE}");
        return Ok(0);
    }
    let supervises = matches!(command.to_str(), Some("up" | "bench" | "run" | "positions"));
    if !supervises {
        // A command that only reads and prints ends quietly when its reader
        // does (`flexloop status | head`), as Unix tools do; one that
        // supervises processes must not die before it has stopped them.
        // SAFETY: restores the default action of a signal; no handler runs.
        unsafe { libc::signal(libc::SIGPIPE, libc::SIG_DFL) };
    }
    match command.to_str() {
        Some("up") => up(LoopArgs::parse(rest, false)?),
        Some("bench") if rest.iter().any(|a| a == "--sweep") => sweep::sweep(rest),
        Some("bench") if rest.iter().any(|a| a == "--logging-cost") => {
            logging_cost::logging_cost(rest)
        }
        Some("bench") => bench::bench(LoopArgs::parse(rest, true)?),
        Some("run") => run::run(LoopArgs::parse(rest, false)?),
        Some("tune-ff") => run::tune_ff(rest),
        Some("report") => report::report(rest),
        Some("design") => design::design(rest),
        Some("positions") => positions::positions(rest),
        Some("export") => export::export(rest),
        Some("down") => down(prefix_arg(rest)?),
        Some("status") => status(prefix_arg(rest)?),
        Some("swap") => swap(rest),
        Some("help") | Some("--help") | Some("-h") => {
            println!("{USAGE}");
            Ok(0)
        }
        _ => Err(format!("unknown command {command:?}\n{USAGE}")),
    }
}

/// Arguments shared by `up` and `bench`.
#[derive(Debug, Clone)]
pub struct LoopArgs {
    pub scenario: PathBuf,
    pub overrides: Overrides,
    pub run_dir: Option<PathBuf>,
    pub probes: bool,
    /// `bench --swap-every S`: swap controller and observer in turn.
    pub swap_every_s: Option<f64>,
}

impl LoopArgs {
    fn parse(args: Vec<OsString>, bench: bool) -> Result<Self, String> {
        use lexopt::prelude::*;
        let mut parser = lexopt::Parser::from_args(args);
        let mut scenario = None;
        let mut overrides = Overrides::default();
        let mut run_dir = None;
        let mut probes = true;
        let mut swap_every_s = None;
        if bench {
            overrides.duration_s = Some(10.0);
            overrides.rate_hz = Some(10_000.0);
            overrides.mode = Some(Mode::Realtime);
        }
        let number = |p: &mut lexopt::Parser, flag: &str| -> Result<f64, String> {
            let v = p.value().map_err(|e| e.to_string())?;
            v.to_str()
                .and_then(|s| s.parse::<f64>().ok())
                .ok_or_else(|| format!("{flag} needs a number, got {v:?}"))
        };
        while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
            match arg {
                Value(v) if scenario.is_none() => scenario = Some(PathBuf::from(v)),
                Long("duration") => overrides.duration_s = Some(number(&mut parser, "--duration")?),
                Long("rate") => overrides.rate_hz = Some(number(&mut parser, "--rate")?),
                Long("mode") => {
                    let v = parser.value().map_err(|e| e.to_string())?;
                    let text = v.to_string_lossy();
                    overrides.mode =
                        Some(Mode::parse(&text).ok_or_else(|| format!("unknown mode `{text}`"))?);
                }
                Long("run-dir") => {
                    run_dir = Some(PathBuf::from(parser.value().map_err(|e| e.to_string())?))
                }
                Long("no-realtime") => overrides.no_realtime = true,
                Long("no-probes") if bench => probes = false,
                Long("swap-every") if bench => {
                    let s = number(&mut parser, "--swap-every")?;
                    if !(s.is_finite() && s > 0.0) {
                        return Err(format!(
                            "--swap-every needs a positive number of seconds, got {s}"
                        ));
                    }
                    swap_every_s = Some(s);
                }
                other => return Err(format!("{}\n{USAGE}", other.unexpected())),
            }
        }
        Ok(Self {
            scenario: resolve_scenario(scenario)?,
            overrides,
            run_dir,
            probes,
            swap_every_s,
        })
    }

    /// Everything `flexloop-*` processes get besides scenario, prefix and run dir.
    pub fn process_overrides(&self) -> Vec<String> {
        let mut out = Vec::new();
        if let Some(r) = self.overrides.rate_hz {
            out.extend(["--rate".into(), r.to_string()]);
        }
        if let Some(d) = self.overrides.duration_s {
            out.extend(["--duration".into(), d.to_string()]);
        }
        if let Some(m) = self.overrides.mode {
            out.extend(["--mode".into(), m.as_str().to_string()]);
        }
        if self.overrides.no_realtime {
            out.push("--no-realtime".into());
        }
        out
    }
}

/// A scenario given by path, or by name from the scenarios directory.
pub fn resolve_scenario(given: Option<PathBuf>) -> Result<PathBuf, String> {
    let dirs = scenario_dirs();
    let Some(given) = given else {
        return dirs
            .iter()
            .map(|d| d.join("default.toml"))
            .find(|p| p.is_file())
            .ok_or_else(|| "no scenario given and no scenarios/default.toml found".to_string());
    };
    if given.is_file() || given.components().count() > 1 {
        return Ok(given);
    }
    let named = given.with_extension("toml");
    Ok(dirs
        .iter()
        .map(|d| d.join(&named))
        .find(|p| p.is_file())
        .unwrap_or(given))
}

fn scenario_dirs() -> Vec<PathBuf> {
    let mut dirs = vec![PathBuf::from("scenarios")];
    if let Ok(exe) = std::env::current_exe()
        && let Some(repo) = exe.parent().and_then(Path::parent).and_then(Path::parent)
    {
        dirs.push(repo.join("scenarios"));
    }
    dirs
}

/// The value of the option just parsed, as text.
fn string_value(parser: &mut lexopt::Parser) -> Result<String, String> {
    Ok(parser
        .value()
        .map_err(|e| e.to_string())?
        .to_string_lossy()
        .into_owned())
}

fn prefix_arg(args: Vec<OsString>) -> Result<Option<String>, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let mut prefix = None;
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("prefix") => prefix = Some(string_value(&mut parser)?),
            other => return Err(other.unexpected().to_string()),
        }
    }
    Ok(prefix)
}

/// A started loop: its prefix, run directory and the validated scenario.
pub struct Prepared {
    pub scenario: Scenario,
    pub overrides: Overrides,
    pub plan: supervisor::LaunchPlan,
}

/// Validates the scenario and designs it before anything starts, then makes
/// the run directory.
pub fn prepare(args: &LoopArgs) -> Result<Prepared, String> {
    let scenario = Scenario::load(&args.scenario, &args.overrides).map_err(|e| e.to_string())?;
    scenario
        .check_machine(flexloop_runtime::realtime::online_cpus())
        .map_err(|e| e.to_string())?;
    flexloop_scenario::LoopDesign::from_scenario(&scenario).map_err(|e| e.to_string())?;
    let run_dir = match &args.run_dir {
        Some(d) => d.clone(),
        None => {
            let stamp = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_secs())
                .unwrap_or(0);
            PathBuf::from("runs").join(format!("{stamp}-{}-{}", scenario.name, std::process::id()))
        }
    };
    std::fs::create_dir_all(&run_dir)
        .map_err(|e| format!("run directory {}: {e}", run_dir.display()))?;
    let probe = run_dir.join(".writable");
    std::fs::write(&probe, b"")
        .map_err(|e| format!("run directory {}: not writable: {e}", run_dir.display()))?;
    let _ = std::fs::remove_file(probe);
    // The scenario as it ran, so that the run can be analysed and refitted later.
    std::fs::copy(&args.scenario, run_dir.join(run::SCENARIO_COPY)).map_err(|e| {
        format!(
            "run directory {}: cannot copy the scenario: {e}",
            run_dir.display()
        )
    })?;
    let prefix = format!("flx{}_", std::process::id());
    Ok(Prepared {
        plan: supervisor::LaunchPlan {
            scenario: args.scenario.clone(),
            prefix,
            run_dir,
            overrides: args.process_overrides(),
            with_logger: scenario.logger.enabled,
            warm_spares: scenario.supervision.warm_spares,
        },
        scenario,
        overrides: args.overrides.clone(),
    })
}

fn up(args: LoopArgs) -> Result<i32, String> {
    let prepared = prepare(&args)?;
    eprintln!(
        "flexloop: {} at {} Hz ({}), run directory {}; Ctrl-C or `flexloop down` stops it",
        prepared.scenario.name,
        prepared.scenario.timing.rate_hz,
        prepared.scenario.timing.mode.as_str(),
        prepared.plan.run_dir.display()
    );
    run_registered_with(prepared, |_, _| None).map(|_| 0)
}

/// The sample and histogram logs of the logger of `generation`.
pub fn logger_files(generation: u32) -> [String; 2] {
    use flexloop_node::logger::{HISTOGRAM_LOG, SAMPLES_FILE, generation_file};
    [
        generation_file(SAMPLES_FILE, generation),
        generation_file(HISTOGRAM_LOG, generation),
    ]
}

/// Starts and supervises until the end, with `hook` called every 20 ms
/// beside the conductor (bench swaps); returns the switches made.
pub fn run_supervised_with(
    prepared: Prepared,
    mut hook: impl FnMut(
        &mut supervisor::RunningLoop,
        &mut conductor::Conductor,
    ) -> Option<supervisor::Outcome>,
) -> Result<
    (
        supervisor::RunningLoop,
        supervisor::Outcome,
        Vec<conductor::Switch>,
    ),
    String,
> {
    let limit = prepared
        .scenario
        .ticks()
        .map(|_| Duration::from_secs_f64(prepared.scenario.timing.duration_s * 3.0 + 30.0));
    let rate_hz = prepared.scenario.timing.rate_hz;
    let prefix = prepared.plan.prefix.clone();
    let run_dir = prepared.plan.run_dir.clone();
    let mut conductor = conductor::Conductor::open(
        &prefix,
        &prepared.plan.run_dir,
        &prepared.scenario,
        &prepared.overrides,
    )?;
    // The supervisor and every process it starts (they inherit it) work off
    // the loop's CPU: on a kernel without preemption their system calls
    // (fork, exec, mapping memory) would delay the loop there by up to a
    // millisecond each (seen in a scheduler trace of a swap).
    if let Some(cpu) = prepared.scenario.realtime.plant.cpu
        && prepared.scenario.timing.mode == Mode::Realtime
    {
        let _ = flexloop_runtime::realtime::avoid_cpu(cpu);
    }
    let mut running = supervisor::start(prepared.plan)?;
    let mut progress = progress::Progress::open(&prefix);
    let outcome = running.watch(limit, |running| {
        progress.show(rate_hz);
        conductor
            .tick(running)
            .or_else(|| hook(running, &mut conductor))
    });
    let switches = std::mem::take(&mut conductor.switches);
    // Our own nodes go first: cleanup removes every file of the prefix.
    drop(progress);
    drop(conductor);
    running.stop();
    running.cleanup();
    // It lists live processes: there are none now.
    let _ = std::fs::remove_file(run_dir.join(conductor::PROCESSES_FILE));
    close_sample_files(&run_dir);
    match outcome {
        supervisor::Outcome::ChildFailed(role, code) => Err(format!(
            "flexloop-{} failed (exit {code}); all processes stopped\n{}",
            role.name(),
            running.failure_report()
        )),
        supervisor::Outcome::TimedOut => Err(format!(
            "the run did not end in time; all processes stopped\n{}",
            running.failure_report()
        )),
        _ => Ok((running, outcome, switches)),
    }
}

/// As [`run_supervised_with`], registered while it runs (so that `flexloop
/// down` and `status` find it).
pub fn run_registered_with(
    prepared: Prepared,
    hook: impl FnMut(
        &mut supervisor::RunningLoop,
        &mut conductor::Conductor,
    ) -> Option<supervisor::Outcome>,
) -> Result<
    (
        supervisor::RunningLoop,
        supervisor::Outcome,
        Vec<conductor::Switch>,
    ),
    String,
> {
    let entry = registry::Entry {
        prefix: prepared.plan.prefix.clone(),
        supervisor_pid: std::process::id() as i32,
        run_dir: prepared.plan.run_dir.clone(),
        scenario: prepared.scenario.name.clone(),
    };
    registry::register(&entry).map_err(|e| format!("cannot register the loop: {e}"))?;
    let result = run_supervised_with(prepared, hook);
    registry::unregister(&entry.prefix);
    result
}

/// `runs/<stamp>-<kind>-<pid>`, for a command's results.
pub fn stamped_run_dir(kind: &str) -> PathBuf {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    PathBuf::from("runs").join(format!("{stamp}-{kind}-{}", std::process::id()))
}

/// Closes the sample files of a run whose logger was killed before it
/// finished them (a restarted logger writes its own), so that every MCAP
/// reader opens them; finished files are left as they are.
fn close_sample_files(run_dir: &Path) {
    let Ok(entries) = std::fs::read_dir(run_dir) else {
        return;
    };
    for path in entries.flatten().map(|e| e.path()) {
        let is_samples = path
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with("samples") && n.ends_with(".mcap"));
        if !is_samples {
            continue;
        }
        match flexloop_components::mcap_repair::repair_file(&path) {
            Ok(c) if c.already_complete => {}
            Ok(c) => eprintln!(
                "flexloop: {}: the logger did not finish it; closed after its last complete chunk ({} messages in {} chunks kept, {} bytes of torn data cut)",
                path.display(),
                c.messages,
                c.chunks,
                c.cut_bytes
            ),
            Err(e) => eprintln!("flexloop: {}: cannot close it: {e}", path.display()),
        }
    }
}

fn swap(args: Vec<OsString>) -> Result<i32, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let (mut role, mut scenario, mut prefix) = (None, None, None);
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("prefix") => prefix = Some(string_value(&mut parser)?),
            Value(v) if role.is_none() => role = Some(v.to_string_lossy().into_owned()),
            Value(v) if scenario.is_none() => scenario = Some(PathBuf::from(v)),
            other => return Err(other.unexpected().to_string()),
        }
    }
    let role = role.ok_or("swap needs a role: controller or observer")?;
    if role != "controller" && role != "observer" {
        return Err(format!("cannot swap `{role}`: only controller or observer"));
    }
    let scenario = resolve_scenario(Some(scenario.ok_or("swap needs a scenario file")?))?;
    let loops = registry::matching(prefix.as_deref());
    let entry = match loops.as_slice() {
        [] => return Err("no loop running".into()),
        [one] => one.clone(),
        _ => return Err("several loops are running: name one with --prefix".into()),
    };
    let answer = conductor::request_swap(&entry.run_dir, &role, &scenario)?;
    if answer["ok"].as_bool() != Some(true) {
        return Err(format!(
            "swap refused: {}",
            answer["error"].as_str().unwrap_or("no reason given")
        ));
    }
    let s = &answer["switch"];
    println!(
        "flexloop: {role} generation {} active from sample {}; |Δu| at the switch {:.3e}, largest ordinary |Δu| over 100 samples before {:.3e} and after {:.3e}",
        s["generation"],
        s["from_seq"],
        s["du_switch"].as_f64().unwrap_or(f64::NAN),
        s["du_before"].as_f64().unwrap_or(f64::NAN),
        s["du_after"].as_f64().unwrap_or(f64::NAN)
    );
    Ok(0)
}

fn down(prefix: Option<String>) -> Result<i32, String> {
    let loops = registry::matching(prefix.as_deref());
    if loops.is_empty() {
        println!("flexloop: no loop running");
        return Ok(0);
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

fn status(prefix: Option<String>) -> Result<i32, String> {
    let loops = registry::matching(prefix.as_deref());
    if loops.is_empty() {
        println!("flexloop: no loop running");
        return Ok(1);
    }
    for entry in loops {
        bench::print_status(&entry)?;
    }
    Ok(0)
}
