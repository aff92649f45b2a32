//! Running loops, as files under /tmp/flexloop/loops, so that `flexloop down`
//! and `flexloop status` find the loop a `flexloop up` started elsewhere.

use std::path::PathBuf;

const DIR: &str = "/tmp/flexloop/loops";

/// One running loop: `/tmp/flexloop/loops/<prefix>.json`.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Entry {
    pub prefix: String,
    pub supervisor_pid: i32,
    pub run_dir: PathBuf,
    pub scenario: String,
}

fn path(prefix: &str) -> PathBuf {
    PathBuf::from(DIR).join(format!("{prefix}.json"))
}

pub fn register(entry: &Entry) -> std::io::Result<()> {
    std::fs::create_dir_all(DIR)?;
    std::fs::write(path(&entry.prefix), serde_json::to_string(entry)?)
}

pub fn unregister(prefix: &str) {
    let _ = std::fs::remove_file(path(prefix));
}

/// Alive and not a zombie (an exited supervisor whose parent has not reaped
/// it yet has stopped all the same).
fn alive(pid: i32) -> bool {
    // SAFETY: signal 0 only checks that the process exists.
    if pid <= 0 || unsafe { libc::kill(pid, 0) } != 0 {
        return false;
    }
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let state = stat
        .rsplit_once(") ")
        .and_then(|(_, rest)| rest.chars().next());
    state != Some('Z')
}

/// Loops whose supervisor is alive; stale entries are removed.
pub fn list() -> Vec<Entry> {
    let Ok(dir) = std::fs::read_dir(DIR) else {
        return Vec::new();
    };
    let mut entries = Vec::new();
    for file in dir.flatten() {
        let Ok(text) = std::fs::read_to_string(file.path()) else {
            continue;
        };
        // Half written (its supervisor is writing it now): skipped, not removed.
        let Ok(entry) = serde_json::from_str::<Entry>(&text) else {
            continue;
        };
        if alive(entry.supervisor_pid) {
            entries.push(entry);
        } else {
            let _ = std::fs::remove_file(file.path());
        }
    }
    entries.sort_by(|a, b| a.prefix.cmp(&b.prefix));
    entries
}

/// Running loops with `prefix`, or all of them.
pub fn matching(prefix: Option<&str>) -> Vec<Entry> {
    list()
        .into_iter()
        .filter(|e| prefix.is_none_or(|p| e.prefix == p))
        .collect()
}

/// Asks a loop's supervisor to stop and waits (bounded) until it is gone.
pub fn stop(entry: &Entry, wait: std::time::Duration) -> bool {
    // SAFETY: the pid is the supervisor's, checked alive just before.
    unsafe { libc::kill(entry.supervisor_pid, libc::SIGTERM) };
    let since = std::time::Instant::now();
    while alive(entry.supervisor_pid) && since.elapsed() < wait {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    !alive(entry.supervisor_pid)
}
