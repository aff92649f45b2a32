//! Running loops, as files under /tmp/flexloop/loops, so that `flexloop down`
//! and `flexloop status` find the loop a `flexloop up` started elsewhere,
//! and a loop whose supervisor died is found and finished
//! ([`crate::dead_loops`]).

use std::path::PathBuf;

const DIR: &str = "/tmp/flexloop/loops";

/// One running loop: `/tmp/flexloop/loops/<prefix>.json`.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Entry {
    pub prefix: String,
    pub supervisor_pid: i32,
    pub run_dir: PathBuf,
    pub scenario: String,
    /// The CPUs its processes are pinned to (`[realtime]` `cpu`).
    #[serde(default)]
    pub cpus: Vec<usize>,
    /// What the design chose that the file may not say: the PID's f_bw
    /// ("PID f_bw 43.5 Hz (auto)"), for `status`.
    #[serde(default)]
    pub design: Option<String>,
    /// The user who started it: the owner of its registry file (which no
    /// other user can forge), read with the entry, never written.
    #[serde(skip)]
    pub owner: Option<u32>,
}

/// The user this command runs as.
pub fn caller() -> u32 {
    // SAFETY: geteuid has no preconditions and cannot fail.
    unsafe { libc::geteuid() }
}

/// Why a loop may not be changed by this command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NotYours {
    /// No loop of the caller's runs (`others`: how many of other users do).
    None { others: usize },
    /// Several of the caller's run: `--prefix` must name one.
    Several(Vec<String>),
    /// The loop `--prefix` named is another user's.
    Foreign { prefix: String, owner: u32 },
}

impl std::fmt::Display for NotYours {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NotYours::None { others: 0 } => f.write_str("no loop running"),
            NotYours::None { others } => write!(
                f,
                "no loop of yours running ({others} of other users: `flexloop status` reads \
                 them; swap, set and down act only on your own)"
            ),
            NotYours::Several(prefixes) => write!(
                f,
                "several of your loops are running ({}): name one with --prefix",
                prefixes.join(", ")
            ),
            NotYours::Foreign { prefix, owner } => write!(
                f,
                "loop {prefix} was started by another user (uid {owner}): swap, set and down act \
                 only on your own loops (`flexloop status` may read it)"
            ),
        }
    }
}

impl std::error::Error for NotYours {}

/// The loop a swap, set or down of user `caller` acts on: the one
/// `prefix` names if it is the caller's, else the caller's only one.
/// Another user's loop is refused, and without `--prefix` other users'
/// loops are not counted (a foreign swap and a foreign stop were seen).
pub fn to_change(loops: &[Entry], prefix: Option<&str>, caller: u32) -> Result<Entry, NotYours> {
    let own = |e: &&Entry| e.owner.is_none_or(|o| o == caller);
    if let Some(p) = prefix {
        return match loops.iter().find(|e| e.prefix == p) {
            None => Err(NotYours::None { others: 0 }),
            Some(e) if own(&e) => Ok(e.clone()),
            Some(e) => Err(NotYours::Foreign {
                prefix: e.prefix.clone(),
                owner: e.owner.unwrap_or(u32::MAX),
            }),
        };
    }
    let mine: Vec<&Entry> = loops.iter().filter(own).collect();
    match mine.as_slice() {
        [one] => Ok((*one).clone()),
        [] => Err(NotYours::None {
            others: loops.len(),
        }),
        several => Err(NotYours::Several(
            several.iter().map(|e| e.prefix.clone()).collect(),
        )),
    }
}

/// The running loops among `others` whose processes are pinned to any of
/// `cpus`, each with the CPUs both use.
pub fn sharing_cpus<'a>(cpus: &[usize], others: &'a [Entry]) -> Vec<(&'a Entry, Vec<usize>)> {
    others
        .iter()
        .filter_map(|other| {
            let shared: Vec<usize> = cpus
                .iter()
                .copied()
                .filter(|c| other.cpus.contains(c))
                .collect();
            (!shared.is_empty()).then_some((other, shared))
        })
        .collect()
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

/// Alive and not on its way out (an exited supervisor whose parent has not
/// reaped it yet has stopped all the same).
pub fn alive(pid: i32) -> bool {
    // SAFETY: signal 0 only checks that the process exists.
    if pid <= 0 || unsafe { libc::kill(pid, 0) } != 0 {
        return false;
    }
    crate::process_state::of(pid) != crate::process_state::ProcessState::Exiting
}

/// Every registered loop, its supervisor alive or not.
fn entries() -> Vec<Entry> {
    let Ok(dir) = std::fs::read_dir(DIR) else {
        return Vec::new();
    };
    let mut entries = Vec::new();
    for file in dir.flatten() {
        // `<prefix>.json` only: a claimed entry is being finished.
        if file.path().extension().is_none_or(|e| e != "json") {
            continue;
        }
        let Ok(text) = std::fs::read_to_string(file.path()) else {
            continue;
        };
        // Half written (its supervisor is writing it now): skipped.
        let Ok(mut entry) = serde_json::from_str::<Entry>(&text) else {
            continue;
        };
        entry.owner = std::os::unix::fs::MetadataExt::uid(&match file.metadata() {
            Ok(m) => m,
            Err(_) => continue,
        })
        .into();
        entries.push(entry);
    }
    entries.sort_by(|a, b| a.prefix.cmp(&b.prefix));
    entries
}

/// Loops whose supervisor is alive.
pub fn list() -> Vec<Entry> {
    entries()
        .into_iter()
        .filter(|e| alive(e.supervisor_pid))
        .collect()
}

/// Loops whose supervisor died without unregistering them.
pub fn dead() -> Vec<Entry> {
    entries()
        .into_iter()
        .filter(|e| !alive(e.supervisor_pid))
        .collect()
}

/// A dead loop's entry, taken by the one command that finishes it.
pub struct Claim {
    path: PathBuf,
}

impl Drop for Claim {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

fn claim_path(prefix: &str, pid: u32) -> PathBuf {
    PathBuf::from(DIR).join(format!("{prefix}.json.finishing.{pid}"))
}

/// Takes a dead loop's entry (a rename: of two commands that try at once,
/// one gets it); none if another command has it. Dropping the claim
/// removes the entry.
pub fn claim(entry: &Entry) -> Option<Claim> {
    let path = claim_path(&entry.prefix, std::process::id());
    std::fs::rename(self::path(&entry.prefix), &path)
        .ok()
        .map(|()| Claim { path })
}

/// Whether a live command is finishing the loop of `prefix` now.
pub fn being_finished(prefix: &str) -> bool {
    let Ok(dir) = std::fs::read_dir(DIR) else {
        return false;
    };
    let head = format!("{prefix}.json.finishing.");
    dir.flatten().any(|f| {
        let name = f.file_name().to_string_lossy().into_owned();
        match name
            .strip_prefix(&head)
            .and_then(|pid| pid.parse::<i32>().ok())
        {
            Some(pid) if alive(pid) => true,
            Some(_) => {
                // Its finisher died: the entry comes back for the next one.
                let _ = std::fs::rename(f.path(), path(prefix));
                false
            }
            None => false,
        }
    })
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

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(prefix: &str, cpus: &[usize]) -> Entry {
        Entry {
            prefix: prefix.into(),
            supervisor_pid: 1,
            run_dir: PathBuf::from("r"),
            scenario: "s".into(),
            cpus: cpus.to_vec(),
            design: None,
            owner: Some(1000),
        }
    }

    #[test]
    fn changes_act_on_the_callers_own_loop_only() {
        let mut theirs = entry("b_", &[]);
        theirs.owner = Some(2000);
        let loops = [entry("a_", &[]), theirs];
        // Without --prefix: the caller's only loop, whatever others run.
        assert_eq!(to_change(&loops, None, 1000).unwrap().prefix, "a_");
        assert_eq!(to_change(&loops, None, 2000).unwrap().prefix, "b_");
        // Another user's, named: refused with its owner.
        assert_eq!(
            to_change(&loops, Some("b_"), 1000).unwrap_err(),
            NotYours::Foreign {
                prefix: "b_".into(),
                owner: 2000
            }
        );
        // None of the caller's: said, with the others counted.
        assert_eq!(
            to_change(&loops, None, 3000).unwrap_err(),
            NotYours::None { others: 2 }
        );
        let both = [entry("a_", &[]), entry("c_", &[])];
        assert!(matches!(
            to_change(&both, None, 1000),
            Err(NotYours::Several(p)) if p == ["a_", "c_"]
        ));
        assert_eq!(to_change(&both, Some("c_"), 1000).unwrap().prefix, "c_");
        assert!(to_change(&both, Some("z_"), 1000).is_err());
    }

    #[test]
    fn loops_pinned_to_the_same_cpus_are_found_with_the_cpus_they_share() {
        let others = [entry("a_", &[0, 1]), entry("b_", &[2, 3]), entry("c_", &[])];
        let found = sharing_cpus(&[1, 2], &others);
        let found: Vec<(&str, Vec<usize>)> = found
            .iter()
            .map(|(e, cpus)| (e.prefix.as_str(), cpus.clone()))
            .collect();
        assert_eq!(found, vec![("a_", vec![1]), ("b_", vec![2])]);
        assert!(sharing_cpus(&[], &others).is_empty());
        assert!(sharing_cpus(&[5], &others).is_empty());
    }

    #[test]
    fn an_entry_written_before_cpus_were_recorded_reads_as_pinned_nowhere() {
        let old = r#"{"prefix":"p_","supervisor_pid":1,"run_dir":"r","scenario":"s"}"#;
        let read: Entry = serde_json::from_str(old).unwrap();
        assert!(read.cpus.is_empty());
    }
}
