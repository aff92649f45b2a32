//! The file-based request/answer protocol between `flexloop swap` or
//! `flexloop set` and the supervisor: a request file in the run's
//! `requests/` folder (`*.request` a swap, `*.set` a set), answered by a file
//! beside it (each written whole, then renamed: never read half-done).

use super::decide::{DRAIN_TIMEOUT, SHADOW_TIMEOUT};
use anyhow::{Context, Result, bail};
use flexloop_node::Role;
use flexloop_runfiles::FileError;
pub use flexloop_runfiles::events::Sender;
use flexloop_runfiles::json::{read_json, write_json_atomically};
use flexloop_runfiles::supervision::{
    self, MeasureAnswer, MeasureRequest, SetAnswer, SetRequest, SwapAnswer,
};
use serde::Serialize;
use serde::de::DeserializeOwned;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Where `flexloop swap` leaves requests for the supervisor and finds answers.
const REQUESTS_DIR: &str = flexloop_runfiles::RunDir::REQUESTS;

/// What a request asks for, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SwapRequest {
    pub role: Role,
    pub scenario: PathBuf,
}

/// The extension of a `flexloop set` request.
const SET_EXTENSION: &str = "set";

/// The extension of a `flexloop measure --running` request.
const MEASURE_EXTENSION: &str = "measure";

/// The extension of `flexloop down`'s note that it asked the loop to stop.
const STOP_EXTENSION: &str = "stop";

/// The sender of the request file at `path` (None if it is gone).
pub fn sender(path: &Path) -> Option<Sender> {
    let uid = std::os::unix::fs::MetadataExt::uid(&std::fs::metadata(path).ok()?);
    // `<stamp>-<pid>.<extension>` (see `ask`).
    let pid = path
        .file_stem()
        .and_then(|s| s.to_str())
        .and_then(|s| s.rsplit_once('-'))
        .and_then(|(_, pid)| pid.parse().ok());
    Some(Sender { pid, uid })
}

/// `flexloop down` leaves a note that it asks the loop to stop (before its
/// signal, which says nothing of who sent it), so that the supervisor's
/// `stop` event names the sender (best effort: the stop goes ahead
/// without it).
pub fn note_stop_request(run_dir: &Path) {
    let dir = run_dir.join(REQUESTS_DIR);
    let _ = std::fs::create_dir_all(&dir);
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let _ = std::fs::write(
        dir.join(format!("{stamp}-{}.{STOP_EXTENSION}", std::process::id())),
        b"",
    );
}

/// The newest stop note's sender, the notes removed.
pub fn take_stop_sender(run_dir: &Path) -> Option<Sender> {
    let mut notes: Vec<PathBuf> = std::fs::read_dir(run_dir.join(REQUESTS_DIR))
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == STOP_EXTENSION))
        .collect();
    notes.sort();
    let newest = notes.last().and_then(|p| sender(p));
    for note in notes {
        let _ = std::fs::remove_file(note);
    }
    newest
}

/// Whether a pending request file is a set (else a swap).
pub fn is_set(path: &Path) -> bool {
    path.extension().is_some_and(|x| x == SET_EXTENSION)
}

/// Whether a pending request file is a measurement's.
pub fn is_measure(path: &Path) -> bool {
    path.extension().is_some_and(|x| x == MEASURE_EXTENSION)
}

/// Reads one measurement request file.
pub fn read_measure(path: &Path) -> Result<MeasureRequest> {
    Ok(read_json(path)?)
}

/// `flexloop measure --running`: as [`request_set`], for a measurement
/// (answered once it is checked and ordered, not when it ends).
pub fn request_measure(run_dir: &Path, request: &MeasureRequest) -> Result<MeasureAnswer> {
    ask(run_dir, MEASURE_EXTENSION, request, SHADOW_TIMEOUT)
        .context("the supervisor did not answer the measurement request")
}

/// Request files waiting for the supervisor (swaps, sets, measurements),
/// oldest first.
pub fn pending(run_dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(run_dir.join(REQUESTS_DIR)) else {
        return Vec::new();
    };
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .is_some_and(|x| x == "request" || x == SET_EXTENSION || x == MEASURE_EXTENSION)
        })
        .collect();
    found.sort();
    found
}

/// Reads one request file.
pub fn read(path: &Path) -> Result<SwapRequest> {
    parse(read_json(path)?)
}

fn parse(request: supervision::SwapRequest) -> Result<SwapRequest> {
    let role = match request.role.as_str() {
        "controller" => Role::Controller,
        "observer" => Role::Observer,
        other => bail!("cannot swap {other:?}: only controller or observer"),
    };
    Ok(SwapRequest {
        role,
        scenario: PathBuf::from(request.scenario),
    })
}

fn answer_path(request: &Path) -> PathBuf {
    request.with_extension("answer")
}

/// Reads one set request file.
pub fn read_set(path: &Path) -> Result<SetRequest> {
    Ok(read_json(path)?)
}

/// Answers a request (best effort: who asked gives up after a while).
pub fn answer(request: &Path, answer: &impl Serialize) {
    let _ = std::fs::remove_file(request);
    let _ = write_json_atomically(&answer_path(request), answer);
}

/// `flexloop swap`: leaves a request in the loop's run directory and waits
/// for the supervisor's answer (as long as a swap may take, and then some).
pub fn request_swap(run_dir: &Path, role: &str, scenario: &Path) -> Result<SwapAnswer> {
    let scenario =
        std::fs::canonicalize(scenario).with_context(|| format!("{}", scenario.display()))?;
    let body = supervision::SwapRequest {
        role: role.to_string(),
        scenario: scenario.display().to_string(),
    };
    ask(run_dir, "request", &body, SHADOW_TIMEOUT + DRAIN_TIMEOUT)
        .context("the supervisor did not answer the swap request")
}

/// `flexloop set`: as [`request_swap`], for a set (up to two swaps: the
/// observer's and the controller's).
pub fn request_set(run_dir: &Path, request: &SetRequest) -> Result<SetAnswer> {
    ask(
        run_dir,
        SET_EXTENSION,
        request,
        2 * (SHADOW_TIMEOUT + DRAIN_TIMEOUT),
    )
    .context("the supervisor did not answer the set request")
}

/// Leaves `body` as a request file with `extension` and waits up to
/// `longest` (plus 10 s) for the answer.
fn ask<A: DeserializeOwned>(
    run_dir: &Path,
    extension: &str,
    body: &impl Serialize,
    longest: Duration,
) -> Result<A> {
    let patience = longest + Duration::from_secs(10);
    let dir = run_dir.join(REQUESTS_DIR);
    std::fs::create_dir_all(&dir).with_context(|| format!("{}", dir.display()))?;
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let request = dir.join(format!("{stamp}-{}.{extension}", std::process::id()));
    // Atomically: the supervisor lists request files and reads them whole.
    write_json_atomically(&request, body)?;
    let answer = answer_path(&request);
    let since = Instant::now();
    while since.elapsed() < patience {
        match read_json::<A>(&answer) {
            Ok(read) => {
                let _ = std::fs::remove_file(&answer);
                return Ok(read);
            }
            // Not there yet (it appears whole, by a rename).
            Err(FileError::Io { .. }) => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => {
                let _ = std::fs::remove_file(&answer);
                return Err(e).context("the supervisor's answer");
            }
        }
    }
    let _ = std::fs::remove_file(&request);
    bail!("no answer within {patience:?}")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(text: &str) -> Result<SwapRequest> {
        let dir = std::env::temp_dir().join(format!("flexloop-request-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("{}.request", text.len()));
        std::fs::write(&path, text).unwrap();
        let read = read(&path);
        let _ = std::fs::remove_dir_all(&dir);
        read
    }

    #[test]
    fn a_request_names_a_swappable_role_and_a_scenario() {
        let ok = request(r#"{"role": "observer", "scenario": "/s.toml"}"#).unwrap();
        assert_eq!(ok.role, Role::Observer);
        assert_eq!(ok.scenario, PathBuf::from("/s.toml"));
        let plant = request(r#"{"role": "plant", "scenario": "/s.toml"}"#).unwrap_err();
        assert!(
            plant.to_string().contains("only controller or observer"),
            "{plant}"
        );
        let bare = request(r#"{"role": "controller"}"#).unwrap_err();
        let message = format!("{bare:#}");
        assert!(
            message.contains(".request") && message.contains("missing field `scenario`"),
            "{message}"
        );
    }

    #[test]
    fn swaps_and_sets_wait_in_one_queue_oldest_first() {
        let run = std::env::temp_dir().join(format!("flexloop-pending-{}", std::process::id()));
        let dir = run.join(REQUESTS_DIR);
        std::fs::create_dir_all(&dir).unwrap();
        for name in ["2-1.set", "1-1.request", "3-1.answer", "0-1.json.tmp"] {
            std::fs::write(dir.join(name), "{}").unwrap();
        }
        let found = pending(&run);
        let _ = std::fs::remove_dir_all(&run);
        assert_eq!(found, vec![dir.join("1-1.request"), dir.join("2-1.set")]);
        assert!(is_set(&found[1]) && !is_set(&found[0]));
    }

    #[test]
    fn an_answer_replaces_its_request_and_reads_back() {
        let dir = std::env::temp_dir().join(format!("flexloop-answer-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let request = dir.join("1-2.request");
        std::fs::write(&request, "{}").unwrap();
        answer(&request, &SwapAnswer::refused("no spare".into()));
        assert!(!request.exists());
        let back: SwapAnswer = read_json(&answer_path(&request)).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(back, SwapAnswer::refused("no spare".into()));
    }
}
