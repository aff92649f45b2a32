//! `flexloop chaos`: fault injection as a user runs it before trusting a
//! deployment. It starts a loop (`flexloop up`), kills its processes with
//! SIGKILL at random moments (or, `--fault hang`, stops them with SIGSTOP:
//! alive and silent, which the supervisor must find by itself), stops it,
//! and reads from the recording what each fault cost: ticks on the plant's
//! safe action until the loop recovered, samples the recording lacks,
//! whether a replacement came, and the files left in shared memory.

use anyhow::{Context, Result, anyhow, bail};
use flexloop_analysis::fault_recovery::{self, Tick};
use flexloop_protocol::flags;
use flexloop_recording::sample_file::LogReader;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::chaos::{ChaosFile, Kill, RoleFaults};
use flexloop_runfiles::json::{read_json, write_json_atomically};
use flexloop_runfiles::supervision::Processes;
use flexloop_runtime::{monotonic_ns, shutdown};
use flexloop_scenario::{Overrides, Scenario};
use flexloop_supervisor::launch::{resolve_scenario, stamped_run_dir};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The time between two kills is drawn uniformly from this range: long
/// enough for the replacement of the last one to settle (a kill during a
/// restart is a different fault), short enough for 100 kills in a minute.
const KILL_INTERVAL_MS: std::ops::Range<u64> = 300..700;
/// How long a kill's replacement may take to be seen serving.
const REPLACEMENT_WAIT: Duration = Duration::from_secs(10);
/// How long the loop may take to start serving, and to stop.
const START_WAIT: Duration = Duration::from_secs(60);
const STOP_WAIT: Duration = Duration::from_secs(60);
/// Samples after a kill in which the recording's holes are counted against
/// it (a restarted logger should be back well within this).
const MISSING_WINDOW_S: f64 = 1.0;

/// `flexloop chaos [SCENARIO] [--kills N] [--seed S] [--roles ...]`.
#[derive(Debug, clap::Args)]
pub struct ChaosArgs {
    /// Scenario file, or its name under scenarios/ [default: scenarios/default.toml]
    pub scenario: Option<PathBuf>,
    /// How many processes to kill
    #[arg(long, default_value_t = 20)]
    pub kills: u32,
    /// Seed of the kill schedule (which role, and when)
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// The roles to kill, each kill picking one at random
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "controller,observer"
    )]
    pub roles: Vec<Target>,
    /// The fault: `kill` (SIGKILL) or `hang` (SIGSTOP: the process stays
    /// alive and silent, and the supervisor must find it)
    #[arg(long, value_enum, default_value = "kill")]
    pub fault: Fault,
    /// Loop rate [default: the scenario's]
    #[arg(long = "rate", value_name = "HZ")]
    pub rate_hz: Option<f64>,
    /// Without real-time priorities (a shared machine)
    #[arg(long)]
    pub no_realtime: bool,
    /// Where chaos.json and the loop's run directory (loop/) go [default: runs/<stamp>-chaos-<pid>]
    #[arg(long, value_name = "DIR")]
    pub run_dir: Option<PathBuf>,
}

/// What is done to the process aimed at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Fault {
    /// SIGKILL: it dies, and the supervisor hears of its exit.
    Kill,
    /// SIGSTOP: it stays alive and sends nothing (a deadlock, an endless
    /// loop); the supervisor must judge it silent (docs/architecture.md).
    Hang,
}

impl Fault {
    fn name(self) -> &'static str {
        match self {
            Fault::Kill => "kill",
            Fault::Hang => "hang",
        }
    }

    fn signal(self) -> i32 {
        match self {
            Fault::Kill => libc::SIGKILL,
            Fault::Hang => libc::SIGSTOP,
        }
    }
}

/// What a kill aims at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Target {
    /// The active controller.
    Controller,
    /// The active observer.
    Observer,
    /// The logger.
    Logger,
    /// An idle warm spare (controller's or observer's).
    Spare,
}

impl Target {
    fn name(self) -> &'static str {
        match self {
            Target::Controller => "controller",
            Target::Observer => "observer",
            Target::Logger => "logger",
            Target::Spare => "spare",
        }
    }

    /// Whether `entry` of the supervisor's process list is one this aims at.
    fn aims_at(self, role: &str, duty: &str) -> bool {
        match self {
            Target::Spare => duty == "spare",
            _ => role == self.name() && duty == "active",
        }
    }
}

pub fn chaos(args: ChaosArgs) -> Result<i32> {
    if args.kills == 0 {
        bail!("--kills: at least one kill");
    }
    if args.roles.is_empty() {
        bail!("--roles: at least one role");
    }
    let scenario_path = resolve_scenario(args.scenario.clone())?;
    let overrides = Overrides {
        rate_hz: args.rate_hz,
        no_realtime: args.no_realtime,
        ..Overrides::default()
    };
    let scenario = Scenario::load(&scenario_path, &overrides)?;
    if args.roles.contains(&Target::Spare) && !scenario.supervision.warm_spares {
        bail!(
            "--roles spare: {} has no warm spares (supervision.warm_spares = false)",
            scenario_path.display()
        );
    }
    let dir = RunDir::new(
        args.run_dir
            .clone()
            .unwrap_or_else(|| stamped_run_dir("chaos")),
    );
    std::fs::create_dir_all(dir.path())
        .with_context(|| format!("run directory {}", dir.path().display()))?;
    let variant = dir.join("chaos-scenario.toml");
    write_variant(&scenario_path, &variant, args.kills)?;

    let loop_dir = dir.chaos_loop();
    let mut up = UpProcess::start(&variant, &loop_dir, &args, &dir)?;
    eprintln!(
        "flexloop chaos: {} kills of {} in {} at {} Hz; loop run directory {}",
        args.kills,
        args.roles
            .iter()
            .map(|r| r.name())
            .collect::<Vec<_>>()
            .join(","),
        scenario_path.display(),
        scenario.timing.rate_hz,
        loop_dir.path().display()
    );
    let injected =
        wait_until_serving(&loop_dir, &mut up).map(|()| inject(&args, &loop_dir, &mut up));
    let exit_code = up.stop();
    let Injected { kills, aborted } = injected?;
    let files_left = flexloop_transport::leftover_files_for_prefix(&up.prefix).len() as u64;
    let recorded = recorded_ticks(&loop_dir)?;
    let file = summarise(
        &args,
        &variant,
        scenario.timing.rate_hz,
        &loop_dir,
        Injected { kills, aborted },
        &recorded,
        files_left,
        exit_code,
    );
    write_json_atomically(&dir.chaos(), &file)?;
    print_table(&file);
    println!("written: {}", dir.chaos().display());
    // `up`'s failed grid verdict (stalls dominated) is the machine's; what
    // chaos judges is how the loop survived the kills.
    let up_failed = file.exit_code != 0 && file.exit_code != crate::loop_command::VERDICT_FAILED;
    let failed = up_failed
        || file.aborted.is_some()
        || file.files_left > 0
        || file
            .roles
            .iter()
            .any(|r| r.unrecovered + r.not_replaced > 0);
    Ok(if failed { 1 } else { 0 })
}

/// The scenario with a restart budget for every kill (a user's own budget
/// would end the run before the last kill: that is not what is measured).
fn write_variant(scenario: &Path, variant: &Path, kills: u32) -> Result<()> {
    let text = std::fs::read_to_string(scenario)
        .with_context(|| format!("cannot read {}", scenario.display()))?;
    let mut table: toml::Table =
        toml::from_str(&text).with_context(|| format!("{}", scenario.display()))?;
    flexloop_scenario::plant_description::anchor_files(&mut table, scenario);
    let supervision = table
        .entry("supervision")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()))
        .as_table_mut()
        .ok_or_else(|| anyhow!("{}: [supervision] is not a table", scenario.display()))?;
    supervision.insert(
        "max_restarts".into(),
        toml::Value::Integer(i64::from(kills) + 10),
    );
    let text = toml::to_string(&table)?;
    std::fs::write(variant, text).with_context(|| format!("cannot write {}", variant.display()))
}

/// `flexloop up` on the variant, stopped (SIGTERM, then SIGKILL) if chaos
/// ends early.
struct UpProcess {
    child: Option<Child>,
    prefix: String,
}

impl UpProcess {
    fn start(variant: &Path, loop_dir: &RunDir, args: &ChaosArgs, dir: &RunDir) -> Result<Self> {
        let exe = std::env::current_exe().context("cannot find the flexloop binary")?;
        let log = |name: &str| -> Result<Stdio> {
            let path = dir.join(name);
            Ok(std::fs::File::create(&path)
                .with_context(|| format!("cannot create {}", path.display()))?
                .into())
        };
        let mut command = Command::new(exe);
        command
            .arg("up")
            .arg(variant)
            .args(["--duration", "0", "--run-dir"])
            .arg(loop_dir.path())
            .stdout(log("up.stdout")?)
            .stderr(log("up.stderr")?);
        if let Some(rate) = args.rate_hz {
            command.args(["--rate", &rate.to_string()]);
        }
        if args.no_realtime {
            command.arg("--no-realtime");
        }
        let child = command.spawn().context("cannot start flexloop up")?;
        let prefix = format!("flx{}_", child.id());
        Ok(Self {
            child: Some(child),
            prefix,
        })
    }

    /// The loop's exit status if it has ended.
    fn ended(&mut self) -> Option<i32> {
        let child = self.child.as_mut()?;
        child
            .try_wait()
            .ok()
            .flatten()
            .map(|s| s.code().unwrap_or(-1))
    }

    /// Asks the loop to stop as Ctrl-C would and waits (bounded) for it.
    fn stop(&mut self) -> i32 {
        let Some(mut child) = self.child.take() else {
            return -1;
        };
        // SAFETY: the pid of the child this process started and has not reaped.
        unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
        let since = Instant::now();
        loop {
            if let Ok(Some(status)) = child.try_wait() {
                return status.code().unwrap_or(-1);
            }
            if since.elapsed() > STOP_WAIT {
                let _ = child.kill();
                let _ = child.wait();
                return -1;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for UpProcess {
    fn drop(&mut self) {
        if self.child.is_some() {
            self.stop();
        }
    }
}

fn processes(loop_dir: &RunDir) -> Vec<(String, i32, String)> {
    read_json::<Processes>(&loop_dir.processes())
        .map(|list| {
            list.processes
                .into_iter()
                .map(|p| (p.role, p.pid, p.duty))
                .collect()
        })
        .unwrap_or_default()
}

fn pids_of(loop_dir: &RunDir, target: Target) -> Vec<i32> {
    processes(loop_dir)
        .into_iter()
        .filter(|(role, _, duty)| target.aims_at(role, duty))
        .map(|(_, pid, _)| pid)
        .collect()
}

/// Waits until the loop ticks (its first samples recorded) with an active
/// controller and observer.
fn wait_until_serving(loop_dir: &RunDir, up: &mut UpProcess) -> Result<()> {
    let since = Instant::now();
    loop {
        if let Some(code) = up.ended() {
            bail!(
                "flexloop up ended (exit {code}) before the loop served; see {}",
                loop_dir
                    .path()
                    .parent()
                    .unwrap_or(Path::new("."))
                    .join("up.stderr")
                    .display()
            );
        }
        // Listed, and the loop ticks: a process stopped before the loop's
        // first sample is a start-up that fails, not a fault of a running
        // loop (the plant waits for its peers, then ends the run).
        let serving = [Target::Controller, Target::Observer]
            .iter()
            .all(|&t| !pids_of(loop_dir, t).is_empty())
            && flexloop_recording::mcap_repair::topic_counts(&loop_dir.samples(0))
                .is_ok_and(|c| c.get("/measurement").copied().unwrap_or(0) > 0);
        if serving {
            return Ok(());
        }
        if since.elapsed() > START_WAIT || shutdown::requested() {
            bail!("the loop did not start serving within {START_WAIT:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The kills made, and why they stopped short of the number asked for.
struct Injected {
    kills: Vec<Kill>,
    aborted: Option<String>,
}

/// The kills, one after another; the loop no longer recovering (or ending)
/// stops them, and what was done is still reported.
fn inject(args: &ChaosArgs, loop_dir: &RunDir, up: &mut UpProcess) -> Injected {
    // Let the loop settle (spares started, standby following) first.
    std::thread::sleep(Duration::from_secs(1));
    let mut rng = oorandom::Rand64::new(u128::from(args.seed));
    let mut kills = Vec::with_capacity(args.kills as usize);
    for i in 0..args.kills {
        let pause = KILL_INTERVAL_MS.start
            + rng.rand_range(0..KILL_INTERVAL_MS.end - KILL_INTERVAL_MS.start);
        std::thread::sleep(Duration::from_millis(pause));
        let stop = |aborted: String, kills: Vec<Kill>| Injected {
            kills,
            aborted: Some(aborted),
        };
        if shutdown::requested() {
            return stop(format!("interrupted after {i} kills"), kills);
        }
        if let Some(code) = up.ended() {
            return stop(
                format!("the loop ended (exit {code}) after {i} kills"),
                kills,
            );
        }
        let target = args.roles[rng.rand_range(0..args.roles.len() as u64) as usize];
        let Some(pid) = await_target(loop_dir, target) else {
            let why = format!(
                "kill {}: no {} to kill within {REPLACEMENT_WAIT:?}",
                i + 1,
                target.name()
            );
            return stop(why, kills);
        };
        let at_ns = monotonic_ns();
        // SAFETY: a pid from this loop's process list, a child of the
        // `flexloop up` this command started.
        unsafe { libc::kill(pid, args.fault.signal()) };
        let replaced = await_replacement(loop_dir, target, pid);
        eprintln!(
            "{} {:>3}/{}: {} pid {pid}{}",
            args.fault.name(),
            i + 1,
            args.kills,
            target.name(),
            if replaced {
                ""
            } else {
                ", no replacement seen"
            }
        );
        kills.push(Kill {
            role: target.name().into(),
            pid,
            fault: args.fault.name().into(),
            at_ns,
            seq: None,
            held_ticks: None,
            held_stalled_ticks: None,
            missing_samples: 0,
            replaced,
        });
    }
    // The last replacement recovers and its samples reach the recording.
    std::thread::sleep(Duration::from_secs(2));
    Injected {
        kills,
        aborted: None,
    }
}

/// A process `target` aims at, waiting (bounded) for one to be listed.
fn await_target(loop_dir: &RunDir, target: Target) -> Option<i32> {
    let since = Instant::now();
    while since.elapsed() < REPLACEMENT_WAIT {
        if let Some(&pid) = pids_of(loop_dir, target).first() {
            return Some(pid);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    None
}

/// Whether another process takes the killed one's place in time.
fn await_replacement(loop_dir: &RunDir, target: Target, killed: i32) -> bool {
    let since = Instant::now();
    while since.elapsed() < REPLACEMENT_WAIT {
        if pids_of(loop_dir, target).iter().any(|&pid| pid != killed) {
            return true;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    false
}

/// What the run's sample files hold (all logger generations).
struct Recorded {
    /// Every tick, in sequence order.
    ticks: Vec<Tick>,
    /// The plant's cumulative loop misses and stalled ticks at its newest sample.
    misses: u64,
    stalled_ticks: u64,
}

fn recorded_ticks(loop_dir: &RunDir) -> Result<Recorded> {
    let files = loop_dir.sample_files();
    let mut ticks = Vec::new();
    let (mut newest, mut misses, mut stalled_ticks) = (None, 0, 0);
    for (_, path) in files {
        let log =
            LogReader::open(&path).with_context(|| format!("cannot read {}", path.display()))?;
        for m in log.measurements() {
            if newest.is_none_or(|s| m.seq > s) {
                (newest, misses, stalled_ticks) = (Some(m.seq), m.misses, m.stalled_ticks);
            }
        }
        // The controller's own safe action: a command computed without a
        // fresh estimate (the observer is dead or late).
        let without_estimate: std::collections::HashSet<u64> = log
            .commands()
            .filter(|c| c.flags & flags::STANDBY == 0 && c.flags & flags::OBSERVER_FALLBACK != 0)
            .map(|c| c.seq + 1)
            .collect();
        ticks.extend(log.measurements().map(|m| Tick {
            seq: m.seq,
            tick_ns: m.tick_ns,
            // A standby's command applied as the safe action is control
            // going on, not a held input.
            safe_action: (m.flags & flags::FALLBACK != 0 && m.flags & flags::STANDBY == 0)
                || without_estimate.contains(&m.seq),
            stalled: m.flags & flags::STALLED_TICK != 0,
        }));
    }
    ticks.sort_by_key(|t| t.seq);
    ticks.dedup_by_key(|t| t.seq);
    Ok(Recorded {
        ticks,
        misses,
        stalled_ticks,
    })
}

#[allow(clippy::too_many_arguments)]
fn summarise(
    args: &ChaosArgs,
    variant: &Path,
    rate_hz: f64,
    loop_dir: &RunDir,
    injected: Injected,
    recorded: &Recorded,
    files_left: u64,
    exit_code: i32,
) -> ChaosFile {
    let Injected { mut kills, aborted } = injected;
    let ticks = &recorded.ticks;
    let window = (rate_hz * MISSING_WINDOW_S) as u64;
    for kill in &mut kills {
        let before = ticks.partition_point(|t| t.tick_ns < kill.at_ns);
        kill.seq = before.checked_sub(1).map(|i| ticks[i].seq);
        kill.held_ticks = fault_recovery::held_ticks(ticks, kill.at_ns);
        kill.held_stalled_ticks = fault_recovery::held_stalled_ticks(ticks, kill.at_ns);
        kill.missing_samples = fault_recovery::missing_after(ticks, kill.at_ns, window);
    }
    let mut roles = Vec::new();
    for target in &args.roles {
        let of_role: Vec<&Kill> = kills.iter().filter(|k| k.role == target.name()).collect();
        if of_role.is_empty() || roles.iter().any(|r: &RoleFaults| r.role == target.name()) {
            continue;
        }
        let held: Vec<u64> = of_role.iter().filter_map(|k| k.held_ticks).collect();
        let unstalled: Vec<u64> = of_role
            .iter()
            .filter_map(|k| Some(k.held_ticks? - k.held_stalled_ticks?))
            .collect();
        roles.push(RoleFaults {
            role: target.name().into(),
            kills: of_role.len() as u32,
            held_p50: fault_recovery::percentile(&held, 50.0),
            held_p99: fault_recovery::percentile(&held, 99.0),
            held_max: held.iter().copied().max().unwrap_or(0),
            unstalled_p50: fault_recovery::percentile(&unstalled, 50.0),
            unstalled_p99: fault_recovery::percentile(&unstalled, 99.0),
            unrecovered: of_role.iter().filter(|k| k.held_ticks.is_none()).count() as u32,
            not_replaced: of_role.iter().filter(|k| !k.replaced).count() as u32,
            missing_samples: of_role.iter().map(|k| k.missing_samples).sum(),
        });
    }
    let last = ticks.last();
    ChaosFile {
        scenario: variant.display().to_string(),
        seed: args.seed,
        rate_hz,
        run_dir: loop_dir.path().display().to_string(),
        kills,
        roles,
        ticks: last.map_or(0, |t| t.seq + 1),
        misses: recorded.misses,
        stalled_ticks: recorded.stalled_ticks,
        missing_samples: fault_recovery::missing_ticks(ticks),
        files_left,
        exit_code,
        aborted,
    }
}

fn print_table(file: &ChaosFile) {
    if let Some(why) = &file.aborted {
        println!("stopped after {} kills: {why}", file.kills.len());
    }
    println!(
        "{:<11} {:>5}  {:>13} {:>13} {:>13}  {:>15}  {:>11}  {:>12}  {:>8}",
        "role",
        "kills",
        "held p50",
        "held p99",
        "held max",
        "unstalled p50/99",
        "unrecovered",
        "not replaced",
        "missing"
    );
    for r in &file.roles {
        println!(
            "{:<11} {:>5}  {:>7} ticks {:>7} ticks {:>7} ticks  {:>15}  {:>11}  {:>12}  {:>8}",
            r.role,
            r.kills,
            r.held_p50,
            r.held_p99,
            r.held_max,
            format!("{} / {}", r.unstalled_p50, r.unstalled_p99),
            r.unrecovered,
            r.not_replaced,
            r.missing_samples
        );
    }
    println!(
        "ticks {}, misses {}, stalled ticks {} (the machine's), samples missing from the recording {}, \
         files left in shared memory {}, flexloop up exit {}",
        file.ticks,
        file.misses,
        file.stalled_ticks,
        file.missing_samples,
        file.files_left,
        file.exit_code
    );
}
