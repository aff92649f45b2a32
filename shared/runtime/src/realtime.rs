//! Real-time set-up of a loop process.
//!
//! Each setting is tried on its own; when the kernel refuses one, the process
//! says so once (on stderr, naming the setting and the OS error) and runs on
//! with the rest. The returned [`RealtimeGuard`] holds `/dev/cpu_dma_latency`
//! open for as long as the loop runs: closing it restores the idle states.

use std::fmt;
use std::fs::File;
use std::io::{self, Write};
use thread_priority::{
    RealtimeThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue, ThreadSchedulePolicy,
};

/// What a process asks of the kernel before it enters its loop.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RealtimeSettings {
    /// SCHED_FIFO priority 1..=99; `None` keeps SCHED_OTHER.
    pub fifo_priority: Option<u8>,
    /// Pin the process to this CPU.
    pub cpu: Option<usize>,
    /// Lock every page the process touches, now and later, without
    /// populating what it has not touched (`MCL_ONFAULT`).
    pub lock_memory: bool,
    /// Timer slack in ns (the default 50 µs would blur a 100 µs tick).
    pub timer_slack_ns: Option<u64>,
    /// Hold `/dev/cpu_dma_latency` at 0 µs: idle CPUs poll instead of halting.
    pub hold_cpu_dma_latency: bool,
    /// Populate and lock the process's private memory (heap, stack, code):
    /// no page fault on it in the loop. Shared memory stays populated on
    /// touch only (see [`RealtimeSettings::scheduling_part`]).
    pub prefault_private: bool,
    /// Run anywhere but this CPU (a process starting up beside a running
    /// loop keeps its start-up work off the loop's CPU): applied by the
    /// memory part, replaced by `cpu` in the scheduling part.
    pub avoid_cpu: Option<usize>,
}

impl RealtimeSettings {
    /// The part a process applies first, before it maps any shared memory:
    /// memory locking and timer slack.
    pub fn memory_part(&self) -> RealtimeSettings {
        RealtimeSettings {
            fifo_priority: None,
            cpu: None,
            hold_cpu_dma_latency: false,
            ..self.clone()
        }
    }

    /// The part applied once the process is connected and about to loop:
    /// CPU, priority and wake-up latency. Applied earlier, a replacement
    /// joining a running loop would do its start-up work at real-time
    /// priority on the loop's CPU and stall the loop.
    ///
    /// It also populates the private memory, and only that. The iceoryx2
    /// segments are megabytes (every publisher preallocates its subscribers'
    /// queues) of which the loop touches a few pages: populated and locked
    /// whole, each one costs its readers 0.1–1.3 ms of kernel work when its
    /// publisher goes (measured here: unmapping 1.4 / 2.4 / 11.8 MB of locked
    /// shared memory took 109 / 181 / 1269 µs), which a swap or restart does
    /// inside the loop on a kernel without preemption. Locked on fault, a
    /// segment costs a minor fault per page on first touch and little to unmap.
    pub fn scheduling_part(&self) -> RealtimeSettings {
        RealtimeSettings {
            lock_memory: false,
            timer_slack_ns: None,
            prefault_private: self.lock_memory,
            avoid_cpu: None,
            ..self.clone()
        }
    }
}

/// One setting and how it went.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Applied {
    pub setting: &'static str,
    /// `Err` holds the reason the kernel gave.
    pub outcome: Result<String, RealtimeError>,
}

/// Why the kernel (or the request itself) refused a real-time setting.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RealtimeError {
    /// The system call failed with this `errno`.
    Os(i32),
    /// An I/O failure without an OS error number.
    Io(io::ErrorKind),
    /// The CPU is beyond what an affinity mask can name.
    CpuOutOfRange(usize),
    /// No online CPU is left once this one is avoided.
    NoOtherCpu(usize),
    /// A SCHED_FIFO priority outside the scheduler's range.
    PriorityOutOfRange(u8),
    /// The scheduler refused the policy or priority.
    Scheduler(thread_priority::Error),
}

impl RealtimeError {
    /// The `errno` of the system call that just failed.
    fn last_os_error() -> Self {
        io::Error::last_os_error().into()
    }
}

impl From<io::Error> for RealtimeError {
    fn from(e: io::Error) -> Self {
        match e.raw_os_error() {
            Some(code) => Self::Os(code),
            None => Self::Io(e.kind()),
        }
    }
}

impl fmt::Display for RealtimeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Os(code) => write!(f, "{}", io::Error::from_raw_os_error(*code)),
            Self::Io(kind) => write!(f, "{kind}"),
            Self::CpuOutOfRange(cpu) => write!(f, "cpu {cpu} out of range"),
            Self::NoOtherCpu(cpu) => write!(f, "no CPU besides {cpu}"),
            Self::PriorityOutOfRange(p) => {
                write!(f, "priority {p} is not in the range of [0; 99]")
            }
            // The crate's Debug names the variant, which its Display drops.
            Self::Scheduler(e) => write!(f, "{e:?}"),
        }
    }
}

impl std::error::Error for RealtimeError {}

/// Keeps `/dev/cpu_dma_latency` open; dropping it releases the request.
#[derive(Debug, Default)]
pub struct RealtimeGuard {
    _dma_latency: Option<File>,
    pub applied: Vec<Applied>,
}

impl RealtimeGuard {
    /// A one-line summary of what is in force, e.g. for run metadata.
    pub fn summary(&self) -> String {
        let parts: Vec<String> = self
            .applied
            .iter()
            .map(|a| match &a.outcome {
                Ok(v) => format!("{}={v}", a.setting),
                Err(_) => format!("{}=refused", a.setting),
            })
            .collect();
        if parts.is_empty() {
            "none".into()
        } else {
            parts.join(" ")
        }
    }
}

/// Applies `settings` to the calling thread and process; never fails.
///
/// `role` names the process in the one-line warnings.
pub fn apply(role: &str, settings: &RealtimeSettings) -> RealtimeGuard {
    let mut guard = RealtimeGuard::default();
    let mut note = |setting: &'static str, outcome: Result<String, RealtimeError>| {
        if let Err(reason) = &outcome {
            eprintln!("flexloop-{role}: {setting} refused ({reason}); running without it");
        }
        guard.applied.push(Applied { setting, outcome });
    };

    if settings.lock_memory {
        // SAFETY: plain syscall with constant flags.
        let rc =
            unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE | libc::MCL_ONFAULT) };
        note("mlockall", os_result(rc == 0, "on fault".into()));
    }
    if let Some(cpu) = settings.avoid_cpu {
        // Quietly: on a one-CPU machine there is nowhere else to go.
        let _ = avoid_cpu(cpu);
    }
    if settings.prefault_private {
        note(
            "prefault",
            prefault_private_memory().map(|kib| format!("{kib}KiB")),
        );
    }
    if let Some(slack) = settings.timer_slack_ns {
        // SAFETY: PR_SET_TIMERSLACK takes an unsigned long value.
        let rc = unsafe { libc::prctl(libc::PR_SET_TIMERSLACK, slack as libc::c_ulong, 0, 0, 0) };
        note("timer_slack", os_result(rc == 0, format!("{slack}ns")));
    }
    if let Some(cpu) = settings.cpu {
        note("cpu", pin_to_cpu(cpu).map(|_| cpu.to_string()));
    }
    if let Some(priority) = settings.fifo_priority {
        note(
            "priority",
            set_fifo_priority(priority).map(|_| format!("fifo:{priority}")),
        );
    }
    if settings.hold_cpu_dma_latency {
        match open_dma_latency() {
            Ok(file) => {
                guard._dma_latency = Some(file);
                note("cpu_dma_latency", Ok("0us".into()));
            }
            Err(e) => note("cpu_dma_latency", Err(e)),
        }
    }
    guard
}

/// Stack the loop may use beyond what start-up touched.
const STACK_RESERVE: usize = 256 * 1024;

/// Populates and locks every private mapping (code, data, heap, stack) and
/// a stack reserve; returns the KiB locked. Shared mappings are left alone.
fn prefault_private_memory() -> Result<usize, RealtimeError> {
    touch_stack_reserve();
    let maps = std::fs::read_to_string("/proc/self/maps")?;
    let mut locked = 0usize;
    for region in maps.lines().filter_map(PrivateRegion::parse) {
        // SAFETY: the range is a mapping of this process, read from its own
        // maps file; mlock only pins pages, it changes no contents. A range
        // unmapped since then makes mlock fail with ENOMEM, which is skipped.
        if unsafe { libc::mlock(region.start as *const libc::c_void, region.len) } == 0 {
            locked += region.len;
        }
    }
    Ok(locked / 1024)
}

#[inline(never)]
fn touch_stack_reserve() {
    let reserve = [1u8; STACK_RESERVE];
    std::hint::black_box(&reserve);
}

/// A readable private mapping from a `/proc/self/maps` line.
#[derive(Debug, PartialEq, Eq)]
struct PrivateRegion {
    start: usize,
    len: usize,
}

impl PrivateRegion {
    fn parse(line: &str) -> Option<PrivateRegion> {
        let mut fields = line.split_whitespace();
        let (start, end) = fields.next()?.split_once('-')?;
        let perms = fields.next()?.as_bytes();
        let name = line.split_whitespace().nth(5).unwrap_or("");
        // Kernel-provided pages cannot be locked.
        if perms.len() < 4 || perms[0] != b'r' || perms[3] != b'p' || name.starts_with("[v") {
            return None;
        }
        let start = usize::from_str_radix(start, 16).ok()?;
        let end = usize::from_str_radix(end, 16).ok()?;
        (end > start).then_some(PrivateRegion {
            start,
            len: end - start,
        })
    }
}

fn os_result(ok: bool, value: String) -> Result<String, RealtimeError> {
    if ok {
        Ok(value)
    } else {
        Err(RealtimeError::last_os_error())
    }
}

/// Pins the calling thread to `cpu`.
pub fn pin_to_cpu(cpu: usize) -> Result<(), RealtimeError> {
    // SAFETY: cpu_set_t is plain data; CPU_SET bounds-checks against its size.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        if cpu >= libc::CPU_SETSIZE as usize {
            return Err(RealtimeError::CpuOutOfRange(cpu));
        }
        libc::CPU_SET(cpu, &mut set);
        if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
            return Err(RealtimeError::last_os_error());
        }
    }
    Ok(())
}

/// Leaves real time before the process ends. Its teardown (unmapping and
/// unlocking megabytes of shared memory) is long kernel work; on a kernel
/// without preemption, done at real-time priority on the loop's CPU it stalls
/// the loop for milliseconds (measured at every swap before this). Best
/// effort: each step that fails is skipped.
pub fn step_down(loop_cpu: Option<usize>) {
    step_aside(loop_cpu);
    // SAFETY: plain syscall.
    unsafe { libc::munlockall() };
}

/// As [`step_down`], but the memory stays locked: for a replaced instance
/// that stays on as a warm spare and may serve the loop again.
pub fn step_aside(loop_cpu: Option<usize>) {
    // SCHED_OTHER at nice 0 (the crate's portable priority 0 would be nice 19).
    // SAFETY: plain syscalls on the calling thread with a valid parameter.
    unsafe {
        let param = libc::sched_param { sched_priority: 0 };
        libc::sched_setscheduler(0, libc::SCHED_OTHER, &param);
        libc::setpriority(libc::PRIO_PROCESS, 0, 0);
    }
    // Off the loop's CPU at once (a mask without the current CPU migrates
    // the process now).
    let _ = match loop_cpu {
        Some(cpu) => avoid_cpu(cpu),
        None => Ok(()),
    };
}

/// SCHED_FIFO at `priority` for the calling thread.
pub fn set_fifo_priority(priority: u8) -> Result<(), RealtimeError> {
    let value = ThreadPriorityValue::try_from(priority)
        .map_err(|_| RealtimeError::PriorityOutOfRange(priority))?;
    thread_priority::set_thread_priority_and_policy(
        thread_priority::thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    )
    .map_err(RealtimeError::Scheduler)
}

/// Lets the calling thread run on every online CPU but `cpu` (refused if
/// that leaves none).
pub fn avoid_cpu(cpu: usize) -> Result<(), RealtimeError> {
    let online = online_cpus().min(libc::CPU_SETSIZE as usize);
    if online < 2 || cpu >= online {
        return Err(RealtimeError::NoOtherCpu(cpu));
    }
    // SAFETY: cpu_set_t is plain data; CPU_SET bounds-checks against its size.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        for other in (0..online).filter(|c| *c != cpu) {
            libc::CPU_SET(other, &mut set);
        }
        if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
            return Err(RealtimeError::last_os_error());
        }
    }
    Ok(())
}

/// CPUs online on this machine (whatever this thread's affinity allows).
pub fn online_cpus() -> usize {
    // SAFETY: sysconf is a plain query.
    (unsafe { libc::sysconf(libc::_SC_NPROCESSORS_ONLN) }).max(1) as usize
}

/// Number of CPUs this process may run on.
pub fn available_cpus() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
}

fn open_dma_latency() -> Result<File, RealtimeError> {
    let mut file = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/cpu_dma_latency")?;
    // The PM-QoS interface takes a binary s32 in microseconds.
    file.write_all(&0i32.to_ne_bytes())?;
    Ok(file)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_readable_private_mappings_are_prefaulted() {
        let heap = "55d0c0a00000-55d0c0a21000 rw-p 00000000 00:00 0    [heap]";
        assert_eq!(
            PrivateRegion::parse(heap),
            Some(PrivateRegion {
                start: 0x55d0c0a00000,
                len: 0x21000
            })
        );
        let segment = "7f00a0000000-7f00a0b40000 rw-s 00000000 00:1a 42 /dev/shm/iox2_x.data";
        assert_eq!(PrivateRegion::parse(segment), None);
        let guard = "7f00a0000000-7f00a0001000 ---p 00000000 00:00 0";
        assert_eq!(PrivateRegion::parse(guard), None);
        let vvar = "7ffd1c3f0000-7ffd1c3f4000 r--p 00000000 00:00 0    [vvar]";
        assert_eq!(PrivateRegion::parse(vvar), None);
        assert_eq!(PrivateRegion::parse("garbage"), None);
    }

    #[test]
    fn empty_settings_apply_nothing() {
        let guard = apply("test", &RealtimeSettings::default());
        assert!(guard.applied.is_empty());
        assert_eq!(guard.summary(), "none");
    }

    #[test]
    fn impossible_cpu_is_refused_not_fatal() {
        let guard = apply(
            "test",
            &RealtimeSettings {
                cpu: Some(100_000),
                timer_slack_ns: Some(1),
                ..Default::default()
            },
        );
        let cpu = guard.applied.iter().find(|a| a.setting == "cpu").unwrap();
        assert!(cpu.outcome.is_err());
        let slack = guard
            .applied
            .iter()
            .find(|a| a.setting == "timer_slack")
            .unwrap();
        assert_eq!(slack.outcome, Ok("1ns".into()));
    }
}
