//! The file-based request/answer protocol between `flexloop swap` and the
//! supervisor: a request file in the run's `requests/` folder, answered by a
//! file beside it (each written whole, then renamed: never read half-done).

use super::shell::{DRAIN_TIMEOUT, SHADOW_TIMEOUT};
use anyhow::{Context, Result, bail};
use flexloop_node::Role;
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Where `flexloop swap` leaves requests for the supervisor and finds answers.
const REQUESTS_DIR: &str = flexloop_runfiles::RunDir::REQUESTS;

/// What a request asks for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SwapRequest {
    pub role: Role,
    pub scenario: PathBuf,
}

/// Request files waiting for the supervisor, oldest first.
pub fn pending(run_dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(run_dir.join(REQUESTS_DIR)) else {
        return Vec::new();
    };
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "request"))
        .collect();
    found.sort();
    found
}

/// Reads one request file.
pub fn read(path: &Path) -> Result<SwapRequest> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let request: Value =
        serde_json::from_str(&text).with_context(|| format!("{}", path.display()))?;
    parse(&request)
}

fn parse(request: &Value) -> Result<SwapRequest> {
    let role = match request["role"].as_str() {
        Some("controller") => Role::Controller,
        Some("observer") => Role::Observer,
        other => bail!("cannot swap {other:?}: only controller or observer"),
    };
    let scenario = request["scenario"]
        .as_str()
        .context("request has no scenario")?;
    Ok(SwapRequest {
        role,
        scenario: PathBuf::from(scenario),
    })
}

fn answer_path(request: &Path) -> PathBuf {
    request.with_extension("answer")
}

/// Answers a request (best effort: who asked gives up after a while).
pub fn answer(request: &Path, answer: &Value) {
    let _ = std::fs::remove_file(request);
    let path = answer_path(request);
    let tmp = path.with_extension("answer.tmp");
    if std::fs::write(&tmp, answer.to_string()).is_ok() {
        let _ = std::fs::rename(&tmp, &path);
    }
}

/// `flexloop swap`: leaves a request in the loop's run directory and waits
/// for the supervisor's answer (as long as a swap may take, and then some).
pub fn request_swap(run_dir: &Path, role: &str, scenario: &Path) -> Result<Value> {
    let patience = SHADOW_TIMEOUT + DRAIN_TIMEOUT + Duration::from_secs(10);
    let dir = run_dir.join(REQUESTS_DIR);
    std::fs::create_dir_all(&dir).with_context(|| format!("{}", dir.display()))?;
    let scenario =
        std::fs::canonicalize(scenario).with_context(|| format!("{}", scenario.display()))?;
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let request = dir.join(format!("{stamp}-{}.request", std::process::id()));
    let tmp = request.with_extension("tmp");
    let body = json!({"role": role, "scenario": scenario.display().to_string()});
    std::fs::write(&tmp, body.to_string()).with_context(|| format!("{}", tmp.display()))?;
    std::fs::rename(&tmp, &request).with_context(|| format!("{}", request.display()))?;
    let answer = answer_path(&request);
    let since = Instant::now();
    while since.elapsed() < patience {
        if let Ok(text) = std::fs::read_to_string(&answer) {
            let _ = std::fs::remove_file(&answer);
            return serde_json::from_str(&text).with_context(|| format!("{}", answer.display()));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = std::fs::remove_file(&request);
    bail!("the supervisor did not answer the swap request")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_names_a_swappable_role_and_a_scenario() {
        let ok = parse(&json!({"role": "observer", "scenario": "/s.toml"})).unwrap();
        assert_eq!(ok.role, Role::Observer);
        assert_eq!(ok.scenario, PathBuf::from("/s.toml"));
        let plant = parse(&json!({"role": "plant", "scenario": "/s.toml"})).unwrap_err();
        assert!(
            plant.to_string().contains("only controller or observer"),
            "{plant}"
        );
        let bare = parse(&json!({"role": "controller"})).unwrap_err();
        assert_eq!(bare.to_string(), "request has no scenario");
    }
}
