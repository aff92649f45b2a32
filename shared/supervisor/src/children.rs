//! The loop's child processes: starting, watching and stopping them (the
//! supervisor's hands; its decisions are the conductor's).
//!
//! Children run in their own process groups (a terminal's Ctrl-C reaches only
//! the supervisor, which then stops them in order: the plant first, so the
//! others see the end of the run and drain) and die with the supervisor
//! (PR_SET_PDEATHSIG), so no process is orphaned.

use anyhow::{Context, Result};
use flexloop_node::Role;
use flexloop_protocol::Joining;
use flexloop_runtime::shutdown;
use flexloop_scenario::{ComponentProgram, ProgramRole, Scenario};
use flexloop_transport::{Domain, cleanup_dead_nodes};
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// How long the processes may take to start the loop, beyond the run's own
/// limit.
const STARTUP_LIMIT: Duration = Duration::from_secs(120);

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

/// One started process, as it was started. What it does now (active,
/// standby, spare; which generation) is the conductor's bookkeeping
/// (`conductor::roster`): a spare takes other duties without a new process.
#[derive(Debug, Clone)]
pub struct ChildProcess {
    pub role: Role,
    pub pid: i32,
    pub exit: Option<ExitInfo>,
    pub joining: Joining,
    /// The generation it was started as (0 for the first ones and spares).
    pub generation: u32,
    /// The scenario file it was started with.
    pub scenario: PathBuf,
    /// Its exit is expected (replaced, restarted, stopped, an idle spare):
    /// not the run's failure. Set by [`RunningLoop::terminate`] and kept in
    /// step with the conductor's view by [`RunningLoop::expect_exit`].
    pub settled: bool,
    /// Its stderr file, in the run directory.
    pub stderr_file: String,
    /// A program of one's own (`controller.exec`, `observer.exec`), not
    /// the built-in process.
    pub program: bool,
}

/// How a child ended and what CPU it used.
#[derive(Debug, Clone, Copy)]
pub struct ExitInfo {
    /// Exit code, or `128 + signal` if killed by a signal.
    pub code: i32,
    pub cpu_ns: u64,
}

/// What one look at the running loop decided: the run's end, or when to
/// look again at the latest (besides every child's exit and wake fd).
#[derive(Debug, Default)]
pub struct Look {
    pub ended: Option<Outcome>,
    pub again_at: Option<Instant>,
}

/// The supervisor's regular look, and the shortest wait it asks for (a
/// silence due now is judged at the next look, not in a spin).
const LOOK: Duration = Duration::from_millis(20);
const MIN_LOOK: Duration = Duration::from_millis(1);

pub struct RunningLoop {
    pub plan: LaunchPlan,
    pub children: Vec<ChildProcess>,
    pub started: Instant,
    /// When the loop was first seen ticking (the conductor says): the run's
    /// time limit counts from here, since start-up has bounds of its own
    /// and takes long in debug builds on a loaded machine (every process,
    /// warm spares included, designs the loop before tick 0).
    pub ticking_since: Option<Instant>,
    /// A pidfd per live child: the supervisor wakes when one exits, not at
    /// its next look (20 ms were 200 held ticks at 10 kHz after a crash).
    exits: Vec<(i32, OwnedFd)>,
}

fn binary(role: Role) -> std::io::Result<PathBuf> {
    let exe = std::env::current_exe()?;
    let dir = exe.parent().unwrap_or(Path::new("."));
    Ok(dir.join(format!("flexloop-{}", role.name())))
}

/// The scenario's own program for `role`, if it names one (`exec` in the
/// controller's or observer's section, docs/components.md); else the
/// built-in process serves.
pub fn own_program(role: Role, scenario: &Path) -> Result<Option<ComponentProgram>> {
    let program_role = match role {
        Role::Controller => ProgramRole::Controller,
        Role::Observer => ProgramRole::Observer,
        Role::Plant | Role::Logger => return Ok(None),
    };
    let text = std::fs::read_to_string(scenario)
        .with_context(|| format!("cannot read {}", scenario.display()))?;
    Ok(Scenario::parse(scenario, &text)?.program(program_role)?)
}

/// What to start for `role` joining as `joining` with `scenario`: its own
/// program, or the built-in process in the supervisor's working directory.
/// A spare is always built-in: it serves whatever scenario the next order
/// names.
fn program_for(role: Role, scenario: &Path, joining: Joining) -> Result<ComponentProgram> {
    if joining != Joining::Spare
        && let Some(mut program) = own_program(role, scenario)?
    {
        // Its own arguments first, then flexloop's after a `--`
        // (flexloop_node::flexloop_args).
        program.args.push("--".into());
        return Ok(program);
    }
    let here = std::env::current_dir().context("cannot read the working directory")?;
    Ok(ComponentProgram {
        program: binary(role)?,
        args: Vec::new(),
        workdir: here,
    })
}

/// Starts the processes; on any failure, stops those already started.
pub fn start(plan: LaunchPlan) -> Result<RunningLoop> {
    let mut running = RunningLoop {
        plan: plan.clone(),
        children: Vec::new(),
        started: Instant::now(),
        ticking_since: None,
        exits: Vec::new(),
    };
    for (role, joining) in start_order(plan.with_logger, plan.warm_spares) {
        let started = if joining == Joining::Spare {
            running.start_spare(role)
        } else {
            running.launch(role, &plan.scenario, 0, joining)
        };
        if let Err(e) = started {
            running.stop();
            running.cleanup();
            return Err(e);
        }
    }
    Ok(running)
}

/// A process of the supervisor's: no stdin, `stderr` to its file, its own
/// process group (a Ctrl-C at the terminal reaches the supervisor alone,
/// which stops the others in order), and SIGTERM when the supervisor dies
/// (PR_SET_PDEATHSIG), so that none is orphaned.
pub fn tied_to_supervisor(cmd: &mut Command, stderr: std::fs::File) {
    cmd.stdin(Stdio::null()).stderr(stderr).process_group(0);
    // SAFETY: prctl is async-signal-safe and touches no Rust state.
    unsafe {
        cmd.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

/// The order the processes start in: the listeners first (the logger, then
/// the observer, the controller and their spares), the plant last, since it
/// waits for each of them before its first sample.
pub fn start_order(with_logger: bool, warm_spares: bool) -> Vec<(Role, Joining)> {
    let mut order = Vec::new();
    if with_logger {
        order.push((Role::Logger, Joining::AtStart));
    }
    order.extend([
        (Role::Observer, Joining::AtStart),
        (Role::Controller, Joining::AtStart),
    ]);
    if warm_spares {
        order.extend([
            (Role::Observer, Joining::Spare),
            (Role::Controller, Joining::Spare),
        ]);
    }
    order.push((Role::Plant, Joining::AtStart));
    order
}

/// The stderr file of a role's instance of `generation`.
pub fn stderr_name(role: Role, generation: u32) -> String {
    if generation == 0 {
        format!("{}.stderr", role.name())
    } else {
        format!("{}.g{generation}.stderr", role.name())
    }
}

/// The command-line flag that tells a new process how it joins the loop.
fn join_flag(joining: Joining) -> Option<&'static str> {
    match joining {
        Joining::AtStart => None,
        Joining::Replacement => Some("--join"),
        Joining::Restart => Some("--restart"),
        Joining::Standby => Some("--standby"),
        Joining::Spare => Some("--spare"),
    }
}

/// A descriptor that becomes readable when `pid` exits (Linux 5.3+); `None`
/// on an older kernel, where the supervisor finds exits at its next look.
fn open_pidfd(pid: i32) -> Option<OwnedFd> {
    // SAFETY: pidfd_open takes a pid and flags and returns a new descriptor.
    let fd = unsafe { libc::syscall(libc::SYS_pidfd_open, pid, 0) };
    // SAFETY: a descriptor just returned to this process, owned by nobody else.
    (fd >= 0).then(|| unsafe { OwnedFd::from_raw_fd(fd as i32) })
}

fn spawn(
    plan: &LaunchPlan,
    role: Role,
    scenario: &Path,
    generation: u32,
    joining: Joining,
    stderr_file: &str,
) -> Result<(i32, bool)> {
    let own = joining != Joining::Spare && own_program(role, scenario)?.is_some();
    let program = program_for(role, scenario, joining)?;
    let stderr_path = plan.run_dir.join(stderr_file);
    let stderr = std::fs::File::create(&stderr_path)
        .with_context(|| format!("cannot create {}", stderr_path.display()))?;
    let mut cmd = Command::new(&program.program);
    // Absolute: a program runs in its own working directory.
    let scenario = std::path::absolute(scenario).context("the scenario's path")?;
    let run_dir = std::path::absolute(&plan.run_dir).context("the run directory's path")?;
    cmd.args(&program.args).current_dir(&program.workdir);
    if generation > 0 {
        cmd.arg("--generation").arg(generation.to_string());
    }
    if let Some(flag) = join_flag(joining) {
        cmd.arg(flag);
    }
    cmd.arg("--scenario")
        .arg(scenario)
        .arg("--prefix")
        .arg(&plan.prefix)
        .arg("--run-dir")
        .arg(&run_dir)
        .args(plan.overrides.to_args())
        .stdout(Stdio::null());
    tied_to_supervisor(&mut cmd, stderr);
    let child = cmd
        .spawn()
        .with_context(|| format!("cannot start {}", program.program.display()))?;
    // Reaped by pid with wait4 (for its CPU time), not through `Child`.
    Ok((child.id() as i32, own))
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
                let cpu_ns = flexloop_runtime::usage::timeval_ns(usage.ru_utime)
                    + flexloop_runtime::usage::timeval_ns(usage.ru_stime);
                child.exit = Some(ExitInfo {
                    code: exit_code(status),
                    cpu_ns,
                });
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

    /// Starts a warm spare of `role` (observer or controller).
    pub fn start_spare(&mut self, role: Role) -> Result<i32> {
        let scenario = self.plan.scenario.clone();
        self.launch(role, &scenario, 0, Joining::Spare)
    }

    /// Spawns a process of `role` that joins the loop as `joining` with
    /// `generation`, and records it.
    pub fn launch(
        &mut self,
        role: Role,
        scenario: &Path,
        generation: u32,
        joining: Joining,
    ) -> Result<i32> {
        let stderr_file = if joining == Joining::Spare {
            let count = self.children.iter().filter(|c| c.role == role).count();
            format!("{}.spare{count}.stderr", role.name())
        } else {
            stderr_name(role, generation)
        };
        let (pid, program) = spawn(
            &self.plan,
            role,
            scenario,
            generation,
            joining,
            &stderr_file,
        )
        .with_context(|| format!("cannot start flexloop-{}", role.name()))?;
        self.children.push(ChildProcess {
            role,
            pid,
            exit: None,
            joining,
            generation,
            scenario: scenario.to_path_buf(),
            // An idle spare's exit is never the run's failure.
            settled: joining == Joining::Spare,
            stderr_file,
            program,
        });
        if let Some(fd) = open_pidfd(pid) {
            self.exits.push((pid, fd));
        }
        Ok(pid)
    }

    /// Sleeps until a child exits, one of `wake_fds` is readable, a signal
    /// arrives or `limit` passes.
    fn wait_for_an_exit(&mut self, limit: Duration, wake_fds: &[RawFd]) {
        let ended: Vec<i32> = self
            .children
            .iter()
            .filter(|c| c.exit.is_some())
            .map(|c| c.pid)
            .collect();
        // A reaped child's pidfd stays readable: it would wake every time.
        self.exits.retain(|(pid, _)| !ended.contains(pid));
        let mut fds: Vec<libc::pollfd> = self
            .exits
            .iter()
            .map(|(_, fd)| fd.as_raw_fd())
            .chain(wake_fds.iter().copied())
            .map(|fd| libc::pollfd {
                fd,
                events: libc::POLLIN,
                revents: 0,
            })
            .collect();
        let timeout_ms = limit.as_millis().min(i32::MAX as u128) as i32;
        // SAFETY: `fds` holds `fds.len()` initialised entries. An error or a
        // signal only ends the wait early: the caller looks again.
        unsafe { libc::poll(fds.as_mut_ptr(), fds.len() as libc::nfds_t, timeout_ms) };
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

    /// Kills one child by pid (one we started and have not reaped) with
    /// SIGKILL, which a stopped or hung process cannot ignore; its exit is
    /// not expected: the conductor deals with it as a crash.
    pub fn kill(&mut self, pid: i32) {
        if let Some(c) = self.children.iter().find(|c| c.pid == pid)
            && c.exit.is_none()
        {
            // SAFETY: a pid we started and have not reaped, so not reused.
            unsafe { libc::kill(pid, libc::SIGKILL) };
        }
    }

    /// Says whether the exit of `pid` is expected (not the run's failure).
    pub fn expect_exit(&mut self, pid: i32, expected: bool) {
        if let Some(c) = self.children.iter_mut().find(|c| c.pid == pid) {
            c.settled = expected;
        }
    }

    /// Watches until the run ends by itself, a child fails, `limit` passes (from
    /// tick 0, start-up aside) or a termination signal arrives; the caller then stops and cleans up.
    /// `tick` is called every 20 ms (sooner when it names an instant to look
    /// again: a silence due to be judged), as soon as a child exits and when
    /// one of `wake_fds` (the plant's silence alarm) is readable, after
    /// reaping and before judging exits: it may settle a child's exit (a
    /// restart) or end the run, and it must consume what made a wake fd
    /// readable.
    pub fn watch(
        &mut self,
        limit: Option<Duration>,
        wake_fds: &[RawFd],
        mut tick: impl FnMut(&mut RunningLoop) -> Look,
    ) -> Outcome {
        loop {
            self.reap();
            if shutdown::requested() {
                return Outcome::Interrupted;
            }
            let look = tick(self);
            if let Some(ended) = look.ended {
                return ended;
            }
            let timed_out = limit.is_some_and(|l| match self.ticking_since {
                Some(t) => t.elapsed() > l,
                None => self.started.elapsed() > l + STARTUP_LIMIT,
            });
            if let Some(ended) = verdict(&self.children, timed_out) {
                return ended;
            }
            let wait = look.again_at.map_or(LOOK, |at| {
                at.saturating_duration_since(Instant::now())
                    .clamp(MIN_LOOK, LOOK)
            });
            self.wait_for_an_exit(wait, wake_fds);
        }
    }

    /// Stops the plant, lets the others drain, then terminates stragglers.
    pub fn stop(&mut self) {
        for step in STOP_SEQUENCE {
            let targets: Vec<i32> = self
                .children
                .iter()
                .filter(|c| c.exit.is_none() && step.targets.includes(c.role))
                .map(|c| c.pid)
                .collect();
            for pid in targets {
                // SAFETY: a pid we started and have not reaped, so not reused.
                unsafe { libc::kill(pid, step.signal) };
            }
            self.wait_all_for(step.wait);
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

/// An exit status as a code: the exit code, or `128 + signal` if killed by
/// a signal (as a shell reports it).
fn exit_code(status: i32) -> i32 {
    if libc::WIFEXITED(status) {
        libc::WEXITSTATUS(status)
    } else {
        128 + libc::WTERMSIG(status)
    }
}

/// What the exits seen so far mean for the run, after the conductor's tick
/// had its say: the first unexpected failure ends it, so does the plant's
/// end (the loop is over), then the time limit.
pub fn verdict(children: &[ChildProcess], timed_out: bool) -> Option<Outcome> {
    if let Some(failed) = children
        .iter()
        .find(|c| !c.settled && c.exit.is_some_and(|e| e.code != 0))
    {
        return Some(Outcome::ChildFailed(
            failed.role,
            failed.exit.map_or(-1, |e| e.code),
        ));
    }
    if children
        .iter()
        .any(|c| c.role == Role::Plant && c.exit.is_some())
    {
        return Some(Outcome::Completed);
    }
    timed_out.then_some(Outcome::TimedOut)
}

/// Whom one step of [`RunningLoop::stop`] signals.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StopTargets {
    Plant,
    Everyone,
}

impl StopTargets {
    fn includes(self, role: Role) -> bool {
        self == StopTargets::Everyone || role == Role::Plant
    }
}

struct StopStep {
    targets: StopTargets,
    signal: i32,
    /// How long the processes get to exit before the next step.
    wait: Duration,
}

/// The plant first, so that the others see the end of the run and drain
/// (the logger finishes its files); then whoever is left, then by force.
const STOP_SEQUENCE: [StopStep; 3] = [
    StopStep {
        targets: StopTargets::Plant,
        signal: libc::SIGTERM,
        wait: Duration::from_secs(3),
    },
    StopStep {
        targets: StopTargets::Everyone,
        signal: libc::SIGTERM,
        wait: Duration::from_secs(3),
    },
    StopStep {
        targets: StopTargets::Everyone,
        signal: libc::SIGKILL,
        wait: Duration::from_secs(3),
    },
];

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    Completed,
    Interrupted,
    TimedOut,
    ChildFailed(Role, i32),
}

#[cfg(test)]
mod tests {
    use super::*;

    fn child(role: Role, pid: i32, exit: Option<i32>, settled: bool) -> ChildProcess {
        ChildProcess {
            role,
            pid,
            exit: exit.map(|code| ExitInfo { code, cpu_ns: 0 }),
            joining: Joining::AtStart,
            generation: 0,
            scenario: PathBuf::from("s.toml"),
            settled,
            stderr_file: String::new(),
            program: false,
        }
    }

    #[test]
    fn the_plant_starts_last_and_the_logger_first() {
        let order = start_order(true, true);
        assert_eq!(order.first(), Some(&(Role::Logger, Joining::AtStart)));
        assert_eq!(order.last(), Some(&(Role::Plant, Joining::AtStart)));
        assert_eq!(
            order.iter().filter(|(_, j)| *j == Joining::Spare).count(),
            2
        );
        let bare = start_order(false, false);
        assert_eq!(
            bare,
            [
                (Role::Observer, Joining::AtStart),
                (Role::Controller, Joining::AtStart),
                (Role::Plant, Joining::AtStart)
            ]
        );
    }

    #[test]
    fn the_plant_is_stopped_first_and_force_comes_last() {
        assert_eq!(STOP_SEQUENCE[0].targets, StopTargets::Plant);
        assert!(!STOP_SEQUENCE[0].targets.includes(Role::Logger));
        assert_eq!(STOP_SEQUENCE[1].signal, libc::SIGTERM);
        assert_eq!(STOP_SEQUENCE[2].signal, libc::SIGKILL);
        assert!(
            STOP_SEQUENCE[1..]
                .iter()
                .all(|s| s.targets.includes(Role::Logger))
        );
    }

    #[test]
    fn an_unexpected_failure_ends_the_run_an_expected_one_does_not() {
        let running = [child(Role::Plant, 1, None, false)];
        assert_eq!(verdict(&running, false), None);
        let crashed = [
            child(Role::Plant, 1, None, false),
            child(Role::Observer, 2, Some(137), false),
        ];
        assert_eq!(
            verdict(&crashed, false),
            Some(Outcome::ChildFailed(Role::Observer, 137))
        );
        let restarted = [
            child(Role::Plant, 1, None, false),
            child(Role::Observer, 2, Some(137), true),
        ];
        assert_eq!(verdict(&restarted, false), None);
        // A clean exit is no failure, whoever it is.
        let clean = [
            child(Role::Plant, 1, None, false),
            child(Role::Logger, 3, Some(0), false),
        ];
        assert_eq!(verdict(&clean, false), None);
    }

    #[test]
    fn the_plant_ending_completes_the_run_unless_someone_failed() {
        let done = [child(Role::Plant, 1, Some(0), false)];
        assert_eq!(verdict(&done, false), Some(Outcome::Completed));
        let failed = [child(Role::Plant, 1, Some(1), false)];
        assert_eq!(
            verdict(&failed, false),
            Some(Outcome::ChildFailed(Role::Plant, 1))
        );
        let running = [child(Role::Plant, 1, None, false)];
        assert_eq!(verdict(&running, true), Some(Outcome::TimedOut));
        assert_eq!(verdict(&done, true), Some(Outcome::Completed));
    }

    #[test]
    fn a_signal_reads_as_128_plus_its_number() {
        // Wait statuses as the kernel encodes them: exit code in bits 8..16,
        // a terminating signal in bits 0..7.
        assert_eq!(exit_code(3 << 8), 3);
        assert_eq!(exit_code(libc::SIGKILL), 128 + libc::SIGKILL);
    }

    #[test]
    fn each_late_way_of_joining_has_its_flag() {
        assert_eq!(join_flag(Joining::AtStart), None);
        assert!(
            Joining::ALL
                .into_iter()
                .all(|j| join_flag(j).is_some() == j.is_late())
        );
        assert_eq!(join_flag(Joining::Spare), Some("--spare"));
        assert_eq!(join_flag(Joining::Restart), Some("--restart"));
        assert_eq!(stderr_name(Role::Observer, 0), "observer.stderr");
        assert_eq!(stderr_name(Role::Observer, 3), "observer.g3.stderr");
    }
}
