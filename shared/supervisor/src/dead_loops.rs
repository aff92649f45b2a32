//! Loops whose supervisor died (kill -9 of `flexloop up`, a machine's OOM
//! killer): the next `up`, `down` or `status` finds them through the
//! registry, waits for their processes to go (they die with the supervisor),
//! removes their shared memory, finishes their run directory (sample files
//! closed, the summary written, `processes.json` marked ended) and says so.
//! Shared memory of a prefix no registered loop owns (a test that failed
//! before stopping its loop) is removed once its supervisor's pid is gone.

use crate::finish::finish_recording;
use crate::registry::{self, Entry};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::json::{read_json, write_json_atomically};
use flexloop_runfiles::supervision::Processes;
use std::time::{Duration, Instant};

/// How long a dead loop's processes get to end on their own (the logger
/// drains and finishes its files on the SIGTERM its supervisor's death sent).
const OWN_END: Duration = Duration::from_secs(10);
/// How long to wait for another command finishing the same loop.
const OTHER_FINISHER: Duration = Duration::from_secs(60);

/// Finishes every dead loop and removes every dead prefix's files; returns
/// what it did, one line each (`command`: who did it, for `processes.json`).
pub fn finish_dead_loops(command: &str) -> Vec<String> {
    let mut said = Vec::new();
    for entry in registry::dead() {
        match registry::claim(&entry) {
            Some(claim) => {
                said.extend(finish(&entry, command));
                drop(claim);
            }
            None => wait_for_other_finisher(&entry.prefix),
        }
    }
    // Prefixes of loops another command is finishing are its to clean.
    let finishing: Vec<String> = flexloop_transport::dead_prefixes()
        .into_iter()
        .filter(|p| registry::being_finished(p))
        .collect();
    for prefix in flexloop_transport::dead_prefixes() {
        if finishing.contains(&prefix) {
            continue;
        }
        let files = flexloop_transport::leftover_files_for_prefix(&prefix).len();
        flexloop_transport::remove_leftovers(&prefix);
        said.push(format!(
            "removed {files} shared-memory files of dead loop {prefix} (its supervisor is gone)"
        ));
    }
    said
}

/// Waits (bounded) until the command finishing `prefix`'s loop is done, so
/// that what this command reads next is finished.
fn wait_for_other_finisher(prefix: &str) {
    let since = Instant::now();
    while registry::being_finished(prefix) && since.elapsed() < OTHER_FINISHER {
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn finish(entry: &Entry, command: &str) -> Vec<String> {
    let mut said = Vec::new();
    let killed = end_processes(&entry.prefix, &entry.run_dir);
    let files = flexloop_transport::leftover_files_for_prefix(&entry.prefix).len();
    flexloop_transport::remove_leftovers(&entry.prefix);
    let mut what = format!(
        "loop {} ({}) lost its supervisor (pid {}): removed its {files} shared-memory files",
        entry.scenario, entry.prefix, entry.supervisor_pid
    );
    if killed > 0 {
        what.push_str(&format!(
            "; {killed} of its processes outlived it and were killed"
        ));
    }
    said.push(what);
    let run_dir = RunDir::new(&entry.run_dir);
    said.extend(finish_recording(&run_dir));
    if mark_ended(&run_dir, entry, command) {
        said.push(format!("{}: marked ended", run_dir.processes().display()));
    }
    said.push(format!("run directory {}", entry.run_dir.display()));
    said
}

/// Waits for the processes of `prefix` to end (bounded), then kills those
/// left; how many it had to kill. A program of one's own may not end with
/// its supervisor (the SIGTERM its death sends is the program's to handle:
/// a hung one, a stopped one, one that sleeps in its law does not), so it
/// is ended here too.
fn end_processes(prefix: &str, run_dir: &std::path::Path) -> usize {
    let since = Instant::now();
    while !processes_of(prefix, run_dir).is_empty() && since.elapsed() < OWN_END {
        std::thread::sleep(Duration::from_millis(50));
    }
    let left = processes_of(prefix, run_dir);
    for pid in &left {
        // SAFETY: a process whose command line names this dead loop's prefix.
        unsafe { libc::kill(*pid, libc::SIGKILL) };
    }
    let since = Instant::now();
    while !processes_of(prefix, run_dir).is_empty() && since.elapsed() < Duration::from_secs(2) {
        std::thread::sleep(Duration::from_millis(20));
    }
    left.len()
}

/// Live loop processes started with `--prefix <prefix>`: the built-in ones
/// (`flexloop-<role>`), and programs of one's own, whatever their name,
/// by the flags every loop process is started with (`--prefix <prefix>
/// --run-dir <run_dir>`); not `flexloop down --prefix <prefix>` itself.
fn processes_of(prefix: &str, run_dir: &std::path::Path) -> Vec<i32> {
    let run_dir = std::path::absolute(run_dir).unwrap_or_else(|_| run_dir.to_path_buf());
    let run_dir = run_dir.as_os_str().as_encoded_bytes();
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    dir.flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<i32>().ok())
        .filter(|pid| registry::alive(*pid))
        .filter(|pid| {
            let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
            let args: Vec<&[u8]> = cmdline.split(|b| *b == 0).collect();
            let program = args
                .first()
                .map(|a| a.rsplit(|b| *b == b'/').next().unwrap_or(a));
            let flag =
                |name: &[u8], value: &[u8]| args.windows(2).any(|w| w[0] == name && w[1] == value);
            flag(b"--prefix", prefix.as_bytes())
                && (program.is_some_and(|p| p.starts_with(b"flexloop-"))
                    || flag(b"--run-dir", run_dir))
        })
        .collect()
}

/// Rewrites the dead loop's `processes.json` (its supervisor left its last
/// list of live processes there) as ended; whether there was one.
fn mark_ended(run_dir: &RunDir, entry: &Entry, command: &str) -> bool {
    let path = run_dir.processes();
    let Ok(list) = read_json::<Processes>(&path) else {
        return false;
    };
    if list.ended.is_some() {
        return false;
    }
    let ended = Processes {
        processes: Vec::new(),
        ended: Some(format!(
            "its supervisor (pid {}) died; `flexloop {command}` (pid {}) finished the run",
            entry.supervisor_pid,
            std::process::id()
        )),
    };
    write_json_atomically(&path, &ended).is_ok()
}
