//! What the kernel says one of the loop's processes is doing
//! (`/proc/PID/stat`, parsed by procfs-core): a process on its way out or
//! stopped sends nothing more, and the supervisor need not wait for its
//! exit report or for the loop's silence to prove it (docs/architecture.md,
//! "Standby, watchdogs and guards").

use procfs_core::FromRead;
use procfs_core::process::{ProcState, Schedstat, Stat, StatFlags};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProcessState {
    /// Running or waiting: nothing the kernel knows of is wrong.
    Live,
    /// In its exit (killed or crashed: the kernel tears its memory down for
    /// milliseconds before it reports the exit), a zombie, or gone.
    Exiting,
    /// Stopped (SIGSTOP, a debugger's stop): it runs no more until continued.
    Stopped,
}

/// How long `pid`'s main thread has waited on a runqueue, ready to run but
/// without a CPU, since it started (`/proc/PID/schedstat`): what tells a
/// process starved on a busy machine from a hung one, which waits for
/// nothing the scheduler could give it.
pub fn runqueue_wait_ns(pid: i32) -> Option<u64> {
    Schedstat::from_file(format!("/proc/{pid}/schedstat"))
        .ok()
        .map(|s| s.run_delay)
}

/// The state of `pid`, as the kernel has it now.
pub fn of(pid: i32) -> ProcessState {
    match Stat::from_file(format!("/proc/{pid}/stat")) {
        Ok(stat) => from_stat(&stat),
        Err(_) => ProcessState::Exiting,
    }
}

fn from_stat(stat: &Stat) -> ProcessState {
    let exiting = stat
        .flags()
        .is_ok_and(|f| f.contains(StatFlags::PF_EXITING));
    match stat.state() {
        _ if exiting => ProcessState::Exiting,
        Ok(ProcState::Zombie | ProcState::Dead) => ProcessState::Exiting,
        Ok(ProcState::Stopped | ProcState::Tracing) => ProcessState::Stopped,
        _ => ProcessState::Live,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::process::Command;
    use std::time::{Duration, Instant};

    fn becomes(pid: i32, state: ProcessState) -> bool {
        let since = Instant::now();
        while since.elapsed() < Duration::from_secs(10) {
            if of(pid) == state {
                return true;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        false
    }

    #[test]
    fn a_process_is_live_then_stopped_then_exiting() {
        let mut child = Command::new("sleep").arg("30").spawn().unwrap();
        let pid = child.id() as i32;
        assert_eq!(of(pid), ProcessState::Live);
        // SAFETY: the pid of the child this test started and has not reaped.
        unsafe { libc::kill(pid, libc::SIGSTOP) };
        assert!(becomes(pid, ProcessState::Stopped));
        // SAFETY: as above.
        unsafe { libc::kill(pid, libc::SIGKILL) };
        // Unreaped, it is a zombie: exiting all the same.
        assert!(becomes(pid, ProcessState::Exiting));
        child.wait().unwrap();
        assert_eq!(of(pid), ProcessState::Exiting);
    }

    #[test]
    fn this_process_is_live() {
        assert_eq!(of(std::process::id() as i32), ProcessState::Live);
    }

    #[test]
    fn a_processs_runqueue_wait_is_read_and_a_gone_one_has_none() {
        assert!(runqueue_wait_ns(std::process::id() as i32).is_some());
        let mut child = Command::new("true").spawn().unwrap();
        let pid = child.id() as i32;
        child.wait().unwrap();
        assert_eq!(runqueue_wait_ns(pid), None);
    }
}
