//! Starting, watching and stopping the loop's processes.
//!
//! Children run in their own process groups (a terminal's Ctrl-C reaches only
//! the supervisor, which then stops them in order: the plant first, so the
//! others see the end of the run and drain) and die with the supervisor
//! (PR_SET_PDEATHSIG), so no process is orphaned.

use flexloop_node::Role;
use flexloop_runtime::shutdown;
use flexloop_transport::{Domain, cleanup_dead_nodes};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// What to start.
#[derive(Debug, Clone)]
pub struct LaunchPlan {
    pub scenario: PathBuf,
    pub prefix: String,
    pub run_dir: PathBuf,
    /// Overrides passed to every process (`--rate`, `--mode`, ...).
    pub overrides: flexloop_node::overrides::OverrideFlags,
    pub with_logger: bool,
    /// Start an idle controller and observer beside the loop (scenario
    /// `supervision.warm_spares`).
    pub warm_spares: bool,
}

/// [`ChildProcess::generation`] of a spare that has served no generation yet.
pub const UNSERVED: u32 = u32::MAX;

/// One started process.
#[derive(Debug)]
pub struct ChildProcess {
    pub role: Role,
    pub pid: i32,
    pub exit: Option<ExitInfo>,
    pub generation: u32,
    /// The scenario file it runs (a swap may give a component another one).
    pub scenario: PathBuf,
    /// Replaced, crashed-and-restarted, or otherwise dealt with: its exit is
    /// not the run's failure.
    pub settled: bool,
    /// A standby controller (not the role's current instance until promoted).
    pub standby: bool,
    /// A warm spare: not serving (see `flexloop_node::spare`).
    pub spare: bool,
    /// A spare that reported itself idle: it takes orders.
    pub idle: bool,
    /// Its stderr file, in the run directory.
    pub stderr_file: String,
}

/// How a child ended and what CPU it used.
#[derive(Debug, Clone, Copy)]
pub struct ExitInfo {
    /// Exit code, or `128 + signal` if killed by a signal.
    pub code: i32,
    pub cpu_ns: u64,
}

pub struct RunningLoop {
    pub plan: LaunchPlan,
    pub children: Vec<ChildProcess>,
    pub started: Instant,
}

fn binary(role: Role) -> std::io::Result<PathBuf> {
    let exe = std::env::current_exe()?;
    let dir = exe.parent().unwrap_or(Path::new("."));
    Ok(dir.join(format!("flexloop-{}", role.name())))
}

/// Starts the processes; on any failure, stops those already started.
pub fn start(plan: LaunchPlan) -> Result<RunningLoop, String> {
    let mut running = RunningLoop {
        plan: plan.clone(),
        children: Vec::new(),
        started: Instant::now(),
    };
    let mut roles = Vec::new();
    if plan.with_logger {
        roles.push((Role::Logger, Joining::No));
    }
    roles.extend([
        (Role::Observer, Joining::No),
        (Role::Controller, Joining::No),
    ]);
    if plan.warm_spares {
        roles.extend([
            (Role::Observer, Joining::AsSpare),
            (Role::Controller, Joining::AsSpare),
        ]);
    }
    roles.push((Role::Plant, Joining::No));
    for (role, joining) in roles {
        let started = if joining == Joining::AsSpare {
            running.start_spare(role)
        } else {
            running.launch(role, &plan.scenario, 0, joining, stderr_name(role, 0))
        };
        match started {
            Ok(_) => {}
            Err(e) => {
                running.stop();
                running.cleanup();
                return Err(e);
            }
        }
    }
    Ok(running)
}

/// The stderr file of a role's instance of `generation`.
pub fn stderr_name(role: Role, generation: u32) -> String {
    if generation == 0 {
        format!("{}.stderr", role.name())
    } else {
        format!("{}.g{generation}.stderr", role.name())
    }
}

/// How a process enters the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Joining {
    /// With the others, at start-up.
    No,
    /// A running loop, in shadow (a swap or restart).
    AsReplacement,
    /// A running loop, as the standby controller.
    AsStandby,
    /// A running loop, in place of an instance that crashed.
    AsRestart,
    /// As a warm spare: ports open, idle until ordered.
    AsSpare,
}

fn spawn(
    plan: &LaunchPlan,
    role: Role,
    scenario: &Path,
    generation: u32,
    joining: Joining,
    stderr_file: &str,
) -> std::io::Result<i32> {
    let stderr = std::fs::File::create(plan.run_dir.join(stderr_file))?;
    let mut cmd = Command::new(binary(role)?);
    if generation > 0 {
        cmd.arg("--generation").arg(generation.to_string());
    }
    match joining {
        Joining::No => {}
        Joining::AsReplacement => {
            cmd.arg("--join");
        }
        Joining::AsStandby => {
            cmd.arg("--standby");
        }
        Joining::AsRestart => {
            cmd.arg("--restart");
        }
        Joining::AsSpare => {
            cmd.arg("--spare");
        }
    }
    cmd.arg("--scenario")
        .arg(scenario)
        .arg("--prefix")
        .arg(&plan.prefix)
        .arg("--run-dir")
        .arg(&plan.run_dir)
        .args(plan.overrides.to_args())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(stderr)
        .process_group(0);
    // SAFETY: prctl is async-signal-safe and touches no Rust state.
    unsafe {
        cmd.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let child = cmd.spawn()?;
    // Reaped by pid with wait4 (for its CPU time), not through `Child`.
    Ok(child.id() as i32)
}

impl RunningLoop {
    /// Reaps children that ended; returns true if any ended this call.
    pub fn reap(&mut self) -> bool {
        let mut any = false;
        for child in self.children.iter_mut().filter(|c| c.exit.is_none()) {
            let mut status = 0;
            // SAFETY: zeroed rusage is valid; wait4 only writes it.
            let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
            let rc = unsafe { libc::wait4(child.pid, &mut status, libc::WNOHANG, &mut usage) };
            if rc == child.pid {
                let code = if libc::WIFEXITED(status) {
                    libc::WEXITSTATUS(status)
                } else {
                    128 + libc::WTERMSIG(status)
                };
                let cpu_ns = flexloop_runtime::usage::timeval_ns(usage.ru_utime)
                    + flexloop_runtime::usage::timeval_ns(usage.ru_stime);
                child.exit = Some(ExitInfo { code, cpu_ns });
                any = true;
            } else if rc < 0 {
                // Not our child any more (cannot happen): record it as gone.
                child.exit = Some(ExitInfo {
                    code: -1,
                    cpu_ns: 0,
                });
                any = true;
            }
        }
        any
    }

    pub fn alive(&self) -> usize {
        self.children.iter().filter(|c| c.exit.is_none()).count()
    }

    /// The role's current instance: the one alive, standbys and spares
    /// aside, or else the newest that ended (a crashed one, to restart).
    pub fn child(&self, role: Role) -> Option<&ChildProcess> {
        let serving = |c: &&ChildProcess| c.role == role && !c.standby && !c.spare;
        let mut newest = self.children.iter().rev().filter(serving);
        newest
            .clone()
            .find(|c| c.exit.is_none())
            .or_else(|| newest.next())
    }

    /// Starts a warm spare of `role` (observer or controller).
    pub fn start_spare(&mut self, role: Role) -> Result<i32, String> {
        let count = self.children.iter().filter(|c| c.role == role).count();
        let scenario = self.plan.scenario.clone();
        let stderr_file = format!("{}.spare{count}.stderr", role.name());
        self.launch(role, &scenario, 0, Joining::AsSpare, stderr_file)
    }

    /// Spawns a process and records it (a spare as one that has served no
    /// generation yet).
    fn launch(
        &mut self,
        role: Role,
        scenario: &Path,
        generation: u32,
        joining: Joining,
        stderr_file: String,
    ) -> Result<i32, String> {
        let pid = spawn(
            &self.plan,
            role,
            scenario,
            generation,
            joining,
            &stderr_file,
        )
        .map_err(|e| format!("cannot start flexloop-{}: {e}", role.name()))?;
        let spare = joining == Joining::AsSpare;
        self.children.push(ChildProcess {
            role,
            pid,
            exit: None,
            generation: if spare { UNSERVED } else { generation },
            scenario: scenario.to_path_buf(),
            settled: false,
            standby: joining == Joining::AsStandby,
            spare,
            idle: false,
            stderr_file,
        });
        Ok(pid)
    }

    /// Starts another instance of `role` that joins the running loop (swap
    /// or restart) as generation `generation`.
    pub fn start_replacement(
        &mut self,
        role: Role,
        scenario: &Path,
        generation: u32,
    ) -> Result<i32, String> {
        self.start_joining(role, scenario, generation, Joining::AsReplacement)
    }

    /// Starts another instance of `role` in place of one that crashed.
    pub fn start_restart(
        &mut self,
        role: Role,
        scenario: &Path,
        generation: u32,
    ) -> Result<i32, String> {
        self.start_joining(role, scenario, generation, Joining::AsRestart)
    }

    /// Starts a standby controller that follows the running loop.
    pub fn start_standby(&mut self, scenario: &Path, generation: u32) -> Result<i32, String> {
        self.start_joining(Role::Controller, scenario, generation, Joining::AsStandby)
    }

    fn start_joining(
        &mut self,
        role: Role,
        scenario: &Path,
        generation: u32,
        joining: Joining,
    ) -> Result<i32, String> {
        self.launch(
            role,
            scenario,
            generation,
            joining,
            stderr_name(role, generation),
        )
    }

    /// Stops one child by pid (one we started and have not reaped).
    pub fn terminate(&mut self, pid: i32) {
        if let Some(c) = self.children.iter_mut().find(|c| c.pid == pid) {
            c.settled = true;
            if c.exit.is_none() {
                // SAFETY: a pid we started and have not reaped, so not reused.
                unsafe { libc::kill(pid, libc::SIGTERM) };
            }
        }
    }

    /// Watches until the run ends by itself, a child fails, `limit` passes or
    /// a termination signal arrives; the caller then stops and cleans up.
    /// `tick` is called every 20 ms, after reaping and before judging exits:
    /// it may settle a child's exit (a restart) or end the run.
    pub fn watch(
        &mut self,
        limit: Option<Duration>,
        mut tick: impl FnMut(&mut RunningLoop) -> Option<Outcome>,
    ) -> Outcome {
        let mut outcome = Outcome::Completed;
        loop {
            self.reap();
            if shutdown::requested() {
                outcome = Outcome::Interrupted;
                break;
            }
            if let Some(ended) = tick(self) {
                outcome = ended;
                break;
            }
            // An idle spare's crash is never the run's failure (the
            // conductor records it and starts another).
            if let Some(failed) = self
                .children
                .iter()
                .find(|c| !c.settled && !c.spare && c.exit.is_some_and(|e| e.code != 0))
            {
                outcome = Outcome::ChildFailed(failed.role, failed.exit.map_or(-1, |e| e.code));
                break;
            }
            if self.child(Role::Plant).is_some_and(|p| p.exit.is_some()) {
                break;
            }
            if limit.is_some_and(|l| self.started.elapsed() > l) {
                outcome = Outcome::TimedOut;
                break;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        outcome
    }

    /// Stops the plant, lets the others drain, then terminates stragglers.
    pub fn stop(&mut self) {
        self.signal_role(Role::Plant, libc::SIGTERM);
        self.wait_all_for(Duration::from_secs(3));
        for child in self.children.iter().filter(|c| c.exit.is_none()) {
            // SAFETY: a pid we started and have not reaped, so not reused.
            unsafe { libc::kill(child.pid, libc::SIGTERM) };
        }
        self.wait_all_for(Duration::from_secs(3));
        for child in self.children.iter().filter(|c| c.exit.is_none()) {
            unsafe { libc::kill(child.pid, libc::SIGKILL) };
        }
        self.wait_all_for(Duration::from_secs(3));
    }

    fn signal_role(&self, role: Role, signal: i32) {
        if let Some(c) = self.child(role).filter(|c| c.exit.is_none()) {
            // SAFETY: a pid we started and have not reaped.
            unsafe { libc::kill(c.pid, signal) };
        }
    }

    fn wait_all_for(&mut self, limit: Duration) {
        let since = Instant::now();
        while self.alive() > 0 && since.elapsed() < limit {
            self.reap();
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// Removes what the run left in shared memory (dead nodes' resources and
    /// the per-prefix management file), once no process of the run is alive.
    pub fn cleanup(&mut self) {
        if self.alive() > 0 {
            return;
        }
        if let Ok(domain) = Domain::new(&self.plan.prefix) {
            let _ = cleanup_dead_nodes(&domain);
        }
        flexloop_transport::remove_leftovers(&self.plan.prefix);
    }

    /// The last lines each failed child wrote to stderr.
    pub fn failure_report(&self) -> String {
        let mut out = String::new();
        for c in &self.children {
            let path = self.plan.run_dir.join(&c.stderr_file);
            let text = std::fs::read_to_string(&path).unwrap_or_default();
            let code = c.exit.map_or("running".to_string(), |e| e.code.to_string());
            if !text.trim().is_empty() || c.exit.is_some_and(|e| e.code != 0) {
                out.push_str(&format!("  {} (exit {code}):\n", c.role.name()));
                for line in text
                    .lines()
                    .rev()
                    .take(5)
                    .collect::<Vec<_>>()
                    .into_iter()
                    .rev()
                {
                    out.push_str(&format!("    {line}\n"));
                }
            }
        }
        out
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    Completed,
    Interrupted,
    TimedOut,
    ChildFailed(Role, i32),
}
