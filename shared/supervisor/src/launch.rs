//! Launching a loop: the scenario found and checked, the run directory
//! made, the processes started, supervised and stopped, and the loop
//! registered meanwhile so that `down`, `status` and `swap` find it. Every
//! command that runs a loop (`up`, `run`, `bench`, `positions`) goes
//! through [`prepare`] and [`supervise`].

use crate::children::{self, LaunchPlan, Outcome, RunningLoop};
use crate::conductor::{Conductor, Switch};
use crate::{progress, registry};
use anyhow::{Context, anyhow, bail};
use flexloop_node::overrides::OverrideFlags;
use flexloop_runfiles::RunDir;
use flexloop_scenario::{Mode, Overrides, Scenario};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// What a loop is started from.
#[derive(Debug, Clone)]
pub struct LoopArgs {
    pub scenario: PathBuf,
    pub overrides: Overrides,
    pub run_dir: Option<PathBuf>,
}

/// A scenario given by path, or by name from the scenarios directory.
pub fn resolve_scenario(given: Option<PathBuf>) -> anyhow::Result<PathBuf> {
    let dirs = scenario_dirs();
    let Some(given) = given else {
        return dirs
            .iter()
            .map(|d| d.join("default.toml"))
            .find(|p| p.is_file())
            .ok_or_else(|| anyhow!("no scenario given and no scenarios/default.toml found"));
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

/// A shipped scenario by name; an error if there is none.
pub fn named_scenario(name: &str) -> anyhow::Result<PathBuf> {
    let path = resolve_scenario(Some(PathBuf::from(name)))?;
    if path.is_file() {
        Ok(path)
    } else {
        bail!("scenario `{name}` not found in scenarios/")
    }
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

/// A loop ready to start: the validated scenario, its design and what to launch.
pub struct Prepared {
    pub scenario: Scenario,
    pub design: flexloop_design::LoopDesign,
    pub overrides: Overrides,
    pub plan: LaunchPlan,
    /// Serve the loop live (`up --live`): started once the loop runs,
    /// stopped before its processes are.
    pub live: Option<flexloop_live::LiveOptions>,
}

impl Prepared {
    pub fn run_dir(&self) -> RunDir {
        RunDir::new(&self.plan.run_dir)
    }
}

/// Validates the scenario and designs it before anything starts, then makes
/// the run directory.
pub fn prepare(args: &LoopArgs) -> anyhow::Result<Prepared> {
    let flexloop_design::acceptance::Accepted { scenario, design } =
        flexloop_design::acceptance::accept(
            &args.scenario,
            &args.overrides,
            flexloop_runtime::realtime::online_cpus(),
        )?;
    let run_dir = match &args.run_dir {
        Some(d) => d.clone(),
        None => stamped_run_dir(&scenario.name),
    };
    let in_run_dir = || format!("run directory {}", run_dir.display());
    let earlier = RunDir::new(&run_dir).earlier_run_files();
    if !earlier.is_empty() {
        bail!(
            "run directory {} holds the files of an earlier run ({}): a new run there would \
             mix them into its own; give another --run-dir or remove them",
            run_dir.display(),
            match earlier.len() {
                n @ 5.. => format!("{} and {} more", earlier[..4].join(", "), n - 4),
                _ => earlier.join(", "),
            }
        );
    }
    std::fs::create_dir_all(&run_dir).with_context(in_run_dir)?;
    let probe = run_dir.join(".writable");
    std::fs::write(&probe, b"")
        .context("not writable")
        .with_context(in_run_dir)?;
    let _ = std::fs::remove_file(probe);
    // The scenario as it ran, so that the run can be analysed and refitted later.
    write_scenario_copy(
        &args.scenario,
        &scenario,
        &RunDir::new(&run_dir).scenario_copy(),
    )
    .context("cannot copy the scenario")
    .with_context(in_run_dir)?;
    copy_model_file(&scenario, &run_dir).with_context(in_run_dir)?;
    report_dead_prefixes();
    let prefix = format!("flx{}_", std::process::id());
    Ok(Prepared {
        plan: LaunchPlan {
            scenario: args.scenario.clone(),
            prefix,
            run_dir,
            overrides: OverrideFlags::from(&args.overrides),
            with_logger: scenario.logger.enabled,
            warm_spares: scenario.supervision.warm_spares,
        },
        scenario,
        design,
        overrides: args.overrides.clone(),
        live: None,
    })
}

/// The run's copy of the scenario: the file as it is (comments kept) when
/// its relative paths hold from the run directory too; otherwise (a model
/// file outside the scenario's directory, `../plant.npz`; a program of
/// one's own, its path and working directory) its TOML with those paths
/// made absolute, so that `run`'s metrics, `report` and `fit-ff`, which
/// read the copy, find them. (A model file inside the scenario's directory
/// is copied beside it: [`copy_model_file`].)
fn write_scenario_copy(source: &Path, scenario: &Scenario, copy: &Path) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(source)?;
    let leaves = |file: &Option<PathBuf>| {
        file.as_ref().is_some_and(|f| {
            f.is_relative()
                && !f
                    .components()
                    .all(|c| matches!(c, std::path::Component::Normal(_)))
        })
    };
    let programs = scenario.controller.exec.is_some() || scenario.observer.exec.is_some();
    if !programs
        && !leaves(&scenario.plant.file)
        && !leaves(&scenario.plant.design_file)
        && !leaves(&scenario.observer.correction_file)
    {
        std::fs::write(copy, text)?;
        return Ok(());
    }
    let mut table: toml::Table = toml::from_str(&text)?;
    flexloop_scenario::plant_description::anchor_files(&mut table, &std::path::absolute(source)?);
    // A file inside the scenario's directory is copied: its relative path
    // finds the copy.
    for (section, key, file) in [
        ("plant", "file", &scenario.plant.file),
        ("plant", "design_file", &scenario.plant.design_file),
        (
            "observer",
            "correction_file",
            &scenario.observer.correction_file,
        ),
    ] {
        if let Some(file) = file
            .as_ref()
            .filter(|f| f.is_relative() && !leaves(&Some((*f).clone())))
            && let Some(toml::Value::Table(section)) = table.get_mut(section)
        {
            section.insert(key.into(), toml::Value::String(file.display().to_string()));
        }
    }
    let header = format!(
        "# {} as it ran, its paths outside the run directory made absolute.\n",
        source.display()
    );
    std::fs::write(copy, header + &toml::to_string(&table)?)?;
    Ok(())
}

/// The plant's model file, its design model and the IO observer's
/// correction file beside the run's copy of the scenario, where the copy's
/// relative `plant.file`, `plant.design_file` and `observer.correction_file`
/// find them (`run`, `report` and `fit-ff`
/// design the run again from the copy). An absolute path, or one leaving the
/// scenario's directory, is read where it is.
fn copy_model_file(scenario: &Scenario, run_dir: &Path) -> anyhow::Result<()> {
    let files = [
        (&scenario.plant.file, scenario.plant_file_path()),
        (&scenario.plant.design_file, scenario.design_file_path()),
        (
            &scenario.observer.correction_file,
            scenario.correction_file_path(),
        ),
    ];
    for (file, from) in files {
        let (Some(file), Some(from)) = (file, from) else {
            continue;
        };
        let inside = file
            .components()
            .all(|c| matches!(c, std::path::Component::Normal(_)));
        if !inside {
            continue;
        }
        let to = run_dir.join(file);
        if let Some(dir) = to.parent() {
            std::fs::create_dir_all(dir)?;
        }
        std::fs::copy(&from, &to)
            .with_context(|| format!("cannot copy the model file {}", from.display()))?;
    }
    Ok(())
}

/// A loop that ran to its end.
pub struct Finished {
    pub running: RunningLoop,
    /// The swaps and restarts made.
    pub switches: Vec<Switch>,
}

/// Starts the loop, registers it while it runs (so that `flexloop down`,
/// `status` and `swap` find it) and supervises it until the end, with
/// `hook` called every 20 ms beside the conductor (bench swaps, CPU
/// snapshots).
pub fn supervise(
    prepared: Prepared,
    hook: impl FnMut(&mut RunningLoop, &mut Conductor) -> Option<Outcome>,
) -> anyhow::Result<Finished> {
    let entry = registry::Entry {
        prefix: prepared.plan.prefix.clone(),
        supervisor_pid: std::process::id() as i32,
        // Absolute: another command in another directory finishes a loop
        // whose supervisor died, and finds its processes by it.
        run_dir: std::path::absolute(&prepared.plan.run_dir)
            .unwrap_or_else(|_| prepared.plan.run_dir.clone()),
        scenario: prepared.scenario.name.clone(),
        cpus: pinned_cpus(&prepared.scenario),
        owner: None,
        // What serves each role, in the words `status` prints until a
        // swap or set changes the loop (then it designs the scenario as it
        // stands: a large model's design takes seconds, not worth redoing
        // for every `status` of an unchanged loop).
        design: Some(format!(
            "controller: {}\nobserver: {}",
            flexloop_analysis::loop_report::controller_words(&prepared.scenario, &prepared.design),
            flexloop_analysis::loop_report::observer_words(&prepared.scenario, &prepared.design)
        )),
    };
    warn_about_shared_cpus(&entry);
    registry::register(&entry).context("cannot register the loop")?;
    let result = run_to_the_end(prepared, hook);
    registry::unregister(&entry.prefix);
    result
}

/// The CPUs the loop's processes are pinned to, in order, once each.
fn pinned_cpus(scenario: &Scenario) -> Vec<usize> {
    let rt = &scenario.realtime;
    let mut cpus: Vec<usize> = [&rt.plant, &rt.observer, &rt.controller, &rt.logger]
        .iter()
        .filter_map(|p| p.cpu)
        .collect();
    cpus.sort_unstable();
    cpus.dedup();
    cpus
}

/// Says so when another running loop is pinned to a CPU this one pins to:
/// two loops on one CPU stall each other (97–98 % of ticks stalled, seen).
fn warn_about_shared_cpus(entry: &registry::Entry) {
    let others = registry::list();
    for (other, cpus) in registry::sharing_cpus(&entry.cpus, &others) {
        let list: Vec<String> = cpus.iter().map(usize::to_string).collect();
        eprintln!(
            "flexloop: WARNING: loop {} ({}, supervisor {}) is already pinned to CPU {} too: \
             both loops will stall each other; stop it (`flexloop down --prefix {}`) or pin \
             this one elsewhere ([realtime] cpu)",
            other.scenario,
            other.prefix,
            other.supervisor_pid,
            list.join(", "),
            other.prefix
        );
    }
}

fn run_to_the_end(
    prepared: Prepared,
    mut hook: impl FnMut(&mut RunningLoop, &mut Conductor) -> Option<Outcome>,
) -> anyhow::Result<Finished> {
    let limit = prepared
        .scenario
        .ticks()
        .map(|_| Duration::from_secs_f64(prepared.scenario.timing.duration_s * 3.0 + 30.0));
    let rate_hz = prepared.scenario.timing.rate_hz;
    let prefix = prepared.plan.prefix.clone();
    let run_dir = prepared.run_dir();
    let mut conductor = Conductor::open(
        &prefix,
        run_dir.path(),
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
    let mut live_pending = prepared.live.clone();
    let mut live_server: Option<crate::live_server::LiveServer> = None;
    let mut running = children::start(prepared.plan)?;
    let mut progress = progress::Progress::open(&prefix);
    let wake_fds = conductor.wake_fds();
    let outcome = running.watch(limit, &wake_fds, |running| {
        progress.show(rate_hz);
        let outcome = conductor
            .tick(running)
            .or_else(|| hook(running, &mut conductor));
        // The live server starts once the loop ticks: its reader then joins
        // services the loop's processes made and connected, never their
        // start-up handshake (which counts readers). The loop runs on
        // without it rather than stop for it (`up` checked the address
        // before anything started).
        if running.ticking_since.is_some()
            && let Some(options) = live_pending.take()
        {
            live_server =
                crate::live_server::LiveServer::spawn(&options, &prefix, run_dir.path(), rate_hz)
                    .inspect_err(|e| eprintln!("flexloop: the live view is off: {e:#}"))
                    .ok();
        }
        if let Some(server) = live_server.as_mut() {
            server.poll();
        }
        children::Look {
            ended: outcome,
            again_at: conductor.next_look(),
        }
    });
    if matches!(outcome, Outcome::Interrupted) {
        conductor.note_stop();
    }
    let switches = std::mem::take(&mut conductor.switches);
    // Our own nodes go first: cleanup removes every file of the prefix.
    drop(progress);
    drop(conductor);
    if let Some(server) = live_server.as_mut() {
        server.stop();
    }
    running.stop();
    running.cleanup();
    // It lists live processes: there are none now.
    let _ = std::fs::remove_file(run_dir.processes());
    for line in crate::finish::finish_recording(&run_dir) {
        eprintln!("flexloop: {line}");
    }
    match outcome {
        Outcome::ChildFailed(role, code) => Err(anyhow!(
            "flexloop-{} failed (exit {code}); all processes stopped\n{}",
            role.name(),
            running.failure_report()
        )),
        Outcome::TimedOut => Err(anyhow!(
            "the run did not end in time; all processes stopped\n{}",
            running.failure_report()
        )),
        _ => Ok(Finished { running, switches }),
    }
}

/// `runs/<stamp>-<kind>-<pid>`, for a run or a command's results.
pub fn stamped_run_dir(kind: &str) -> PathBuf {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    PathBuf::from("runs").join(format!("{stamp}-{kind}-{}", std::process::id()))
}

/// Finishes the loops whose supervisor died (killed, or a test that failed
/// before stopping its loop) and removes their shared memory, and says so.
pub fn report_dead_prefixes() {
    for line in crate::dead_loops::finish_dead_loops("up") {
        eprintln!("flexloop: {line}");
    }
}
