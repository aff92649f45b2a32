//! One run's iceoryx2 domain: its prefix, its nodes, its cleanup.

use crate::TransportError;
use iceoryx2::prelude::*;
use procfs_core::FromRead;
use procfs_core::process::{ProcState, Stat};
use std::path::{Path, PathBuf};

/// Where iceoryx2 keeps its node, service and port files and its event
/// sockets: on tmpfs, not under its default `/tmp/iceoryx2/`. Every process
/// start creates some twenty of these files and iceoryx2 `fsync`s them; on
/// an ext4 root that was a third of a replacement's start-up CPU (measured:
/// controller 21 → 15 ms, observer 18 → 13 ms), on the CPU beside the loop's.
pub const ROOT_PATH: &str = "/dev/shm/iceoryx2/";
/// iceoryx2's own default, where files of runs before [`ROOT_PATH`] are.
const DEFAULT_ROOT_PATH: &str = "/tmp/iceoryx2";

/// The iceoryx2 configuration of one run, isolated by its prefix.
#[derive(Debug, Clone)]
pub struct Domain {
    config: Config,
    prefix: String,
}

impl Domain {
    /// A domain whose shared-memory and file names all start with `prefix`.
    pub fn new(prefix: &str) -> Result<Self, TransportError> {
        // Quiet iceoryx2's own info/warn lines ("no config file loaded") unless
        // the user asks for them with IOX2_LOG_LEVEL.
        set_log_level_from_env_or(LogLevel::Error);
        let mut config = Config::default();
        config.global.prefix = prefix
            .try_into()
            .map_err(|e| TransportError::new(prefix, "use as iceoryx2 prefix", e))?;
        let root: iceoryx2::prelude::Path = ROOT_PATH
            .try_into()
            .map_err(|e| TransportError::new(ROOT_PATH, "use as iceoryx2 root path", e))?;
        config.global.set_root_path(&root);
        // Dead nodes are the supervisor's to clean ([`cleanup_dead_nodes`]),
        // never a loop process's: iceoryx2 would otherwise list and inspect
        // every node of the run each time a node is created or dropped (1 ms
        // of a replacement's start-up CPU and half its teardown, measured).
        config.global.node.cleanup_dead_nodes_on_creation = false;
        config.global.node.cleanup_dead_nodes_on_destruction = false;
        Ok(Self {
            config,
            prefix: prefix.to_string(),
        })
    }

    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    pub fn config(&self) -> &Config {
        &self.config
    }

    /// A node named `name`. Signal handling stays with the process (flexloop
    /// installs its own handler), so iceoryx2 does not swallow SIGINT.
    pub fn node(&self, name: &str) -> Result<Node<ipc::Service>, TransportError> {
        let node_name: NodeName = name
            .try_into()
            .map_err(|e| TransportError::new(name, "use as node name", e))?;
        NodeBuilder::new()
            .name(&node_name)
            .config(&self.config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| TransportError::new(name, "create node", e))
    }
}

/// Removes what dead processes of this domain left behind; returns how many
/// dead nodes were cleaned. Call it from the supervisor, never from a loop.
pub fn cleanup_dead_nodes(domain: &Domain) -> Result<usize, TransportError> {
    let mut cleaned = 0usize;
    Node::<ipc::Service>::list(domain.config(), |state| {
        if let NodeState::Dead(dead) = state
            && dead.try_remove_stale_resources().is_ok()
        {
            cleaned += 1;
        }
        CallbackProgression::Continue
    })
    .map_err(|e| TransportError::new(domain.prefix(), "list nodes", e))?;
    Ok(cleaned)
}

/// Files of this domain still present in shared memory and under iceoryx2's
/// root path: empty after a clean shutdown of every process of the run.
pub fn leftover_files(domain: &Domain) -> Vec<PathBuf> {
    leftover_files_for_prefix(domain.prefix())
}

/// Same as [`leftover_files`], by prefix only (for tests and `flexloop down`).
pub fn leftover_files_for_prefix(prefix: &str) -> Vec<PathBuf> {
    let mut found = Vec::new();
    // The shared memory and, below it, ROOT_PATH.
    collect_prefixed(Path::new("/dev/shm"), prefix, &mut found, 0);
    collect_prefixed(Path::new(DEFAULT_ROOT_PATH), prefix, &mut found, 0);
    found
}

/// Deletes every file of `prefix` (see [`leftover_files_for_prefix`]). Only
/// for when no process of that prefix is alive any more.
pub fn remove_leftovers(prefix: &str) {
    for path in leftover_files_for_prefix(prefix) {
        let _ = if path.is_dir() {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        // A node's directory is named by its id, not by the prefix: it goes
        // with its last file (it stayed behind, empty, after every incident).
        if let Some(node_dir) = path.parent()
            && in_nodes_dir(node_dir)
        {
            let _ = std::fs::remove_dir(node_dir);
        }
    }
}

/// Whether `dir` is one node's directory under iceoryx2's `nodes/`.
fn in_nodes_dir(dir: &Path) -> bool {
    dir.parent()
        .and_then(Path::file_name)
        .is_some_and(|name| name == "nodes")
}

/// How old an empty node directory must be to be someone's leftover: a
/// node being created makes its directory and fills it within
/// microseconds.
const EMPTY_NODE_DIR_AGE: std::time::Duration = std::time::Duration::from_secs(60);

/// Removes the empty node directories older than a minute (left, before
/// [`remove_leftovers`] removed them too, by every run that lost a
/// process); returns how many.
fn remove_stale_node_dirs() -> usize {
    let mut removed = 0;
    for root in [Path::new(ROOT_PATH), Path::new(DEFAULT_ROOT_PATH)] {
        let Ok(entries) = std::fs::read_dir(root.join("nodes")) else {
            continue;
        };
        for entry in entries.flatten() {
            let old = entry
                .metadata()
                .and_then(|m| m.modified())
                .ok()
                .and_then(|t| t.elapsed().ok())
                .is_some_and(|age| age > EMPTY_NODE_DIR_AGE);
            // `remove_dir` refuses a directory that is not empty.
            if old && std::fs::remove_dir(entry.path()).is_ok() {
                removed += 1;
            }
        }
    }
    removed
}

/// Removes the files of every run prefix (`flx<pid>_`, `flxsweep<pid>_`)
/// whose supervisor `<pid>` is no longer alive: a supervisor killed with
/// SIGKILL, or a test that failed before stopping its loop, never ran its own
/// clean-up. Returns the prefixes cleaned. A live pid's files are never
/// touched, so loops running beside this one are safe.
pub fn remove_dead_prefixes() -> Vec<String> {
    let dead = dead_prefixes();
    for prefix in &dead {
        remove_leftovers(prefix);
    }
    remove_stale_node_dirs();
    dead
}

/// The run prefixes with files in shared memory whose supervisor `<pid>`
/// is gone (or a zombie: it has stopped all the same).
pub fn dead_prefixes() -> Vec<String> {
    let mut dead = Vec::new();
    for dir in [Path::new("/dev/shm"), Path::new(DEFAULT_ROOT_PATH)] {
        let Ok(entries) = std::fs::read_dir(dir) else {
            continue;
        };
        for entry in entries.flatten() {
            if let Some(prefix) = run_prefix(&entry.file_name().to_string_lossy())
                && !dead.contains(&prefix)
            {
                dead.push(prefix);
            }
        }
    }
    dead.retain(|prefix| {
        let pid = prefix
            .trim_start_matches("flxsweep")
            .trim_start_matches("flx")
            .trim_end_matches('_');
        // procfs-core parses the line (a process's name may hold ") ").
        match Stat::from_file(Path::new("/proc").join(pid).join("stat")) {
            Err(_) => true,
            Ok(stat) => matches!(stat.state(), Ok(ProcState::Zombie)),
        }
    });
    dead.sort();
    dead
}

/// `flx<digits>_` or `flxsweep<digits>_` at the start of `name`.
fn run_prefix(name: &str) -> Option<String> {
    let rest = name
        .strip_prefix("flxsweep")
        .or_else(|| name.strip_prefix("flx"))?;
    let digits = rest.bytes().take_while(u8::is_ascii_digit).count();
    (digits > 0 && rest.as_bytes().get(digits) == Some(&b'_'))
        .then(|| name[..name.len() - rest.len() + digits + 1].to_string())
}

fn collect_prefixed(dir: &Path, prefix: &str, found: &mut Vec<PathBuf>, depth: usize) {
    // Bounded depth: iceoryx2's tree is three levels deep.
    if depth > 4 {
        return;
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let named = entry.file_name().to_string_lossy().starts_with(prefix);
        if path.is_dir() {
            if named {
                found.push(path.clone());
            }
            collect_prefixed(&path, prefix, found, depth + 1);
        } else if named {
            found.push(path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A prefix whose supervisor is gone, or a zombie, is dead; one whose
    /// supervisor runs is not.
    #[test]
    fn a_prefix_is_dead_once_its_supervisor_is_gone_or_a_zombie() {
        let mut zombie = std::process::Command::new("true").spawn().unwrap();
        let gone = {
            let mut child = std::process::Command::new("true").spawn().unwrap();
            let pid = child.id();
            child.wait().unwrap();
            pid
        };
        // Not reaped: a zombie once it has exited (bounded wait).
        let since = std::time::Instant::now();
        while !matches!(
            Stat::from_file(format!("/proc/{}/stat", zombie.id())).and_then(|s| s.state()),
            Ok(ProcState::Zombie)
        ) {
            assert!(since.elapsed() < std::time::Duration::from_secs(10));
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        let pids = [std::process::id(), zombie.id(), gone];
        let files: Vec<PathBuf> = pids
            .iter()
            .map(|pid| Path::new("/dev/shm").join(format!("flx{pid}_dead_prefix_test")))
            .collect();
        for file in &files {
            std::fs::write(file, b"").unwrap();
        }
        let dead = dead_prefixes();
        for file in &files {
            let _ = std::fs::remove_file(file);
        }
        zombie.wait().unwrap();
        let prefix = |pid: u32| format!("flx{pid}_");
        assert!(!dead.contains(&prefix(pids[0])), "{dead:?}");
        assert!(dead.contains(&prefix(pids[1])), "a zombie: {dead:?}");
        assert!(dead.contains(&prefix(pids[2])), "gone: {dead:?}");
    }

    /// The node directories holding a file of `prefix`.
    fn node_dirs_of(prefix: &str) -> Vec<PathBuf> {
        leftover_files_for_prefix(prefix)
            .into_iter()
            .filter_map(|p| p.parent().map(Path::to_path_buf))
            .filter(|d| in_nodes_dir(d))
            .collect()
    }

    #[test]
    fn a_dead_nodes_directory_goes_with_its_files() {
        let prefix = format!("flxtest{}nodedir_", std::process::id());
        let domain = Domain::new(&prefix).unwrap();
        // A node whose process "died": its files stay.
        std::mem::forget(domain.node("lost").unwrap());
        let dirs = node_dirs_of(&prefix);
        assert!(!dirs.is_empty(), "the node has a directory of its own");
        remove_leftovers(&prefix);
        assert!(leftover_files_for_prefix(&prefix).is_empty());
        for dir in dirs {
            assert!(!dir.exists(), "{} is left", dir.display());
        }
    }

    #[test]
    fn run_prefixes_are_recognised_and_nothing_else() {
        assert_eq!(
            run_prefix("flx632_9204dd_node.0_10_0.global_mgmt").as_deref(),
            Some("flx632_")
        );
        assert_eq!(run_prefix("flxsweep77_x").as_deref(), Some("flxsweep77_"));
        assert_eq!(run_prefix("flx_x"), None);
        assert_eq!(run_prefix("flx12x_"), None);
        assert_eq!(run_prefix("iceoryx2"), None);
    }
}
