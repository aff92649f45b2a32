//! A run's files finished once none of its processes runs: sample files a
//! killed logger left open are closed, and `summary.json` covers the whole
//! run when several loggers recorded it (a restarted logger writes its own
//! files) or when none could write it (killed with the supervisor). The
//! supervisor does this at the end of every run; `up`, `down` and `status`
//! do it for the loops whose supervisor died ([`crate::dead_loops`]).

use flexloop_analysis::run_log::{describe_outages, joined_summary};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::json::{read_json, write_json_atomically};

/// Closes and joins what needs it; returns what it did, one line each.
pub fn finish_recording(run_dir: &RunDir) -> Vec<String> {
    let mut said = close_sample_files(run_dir);
    let files = run_dir.sample_files();
    if files.is_empty() {
        // No logger ran.
        return said;
    }
    let written: Option<flexloop_runfiles::RunSummary> = read_json(&run_dir.summary()).ok();
    let complete = match &written {
        // The only logger's own summary, or a join of every generation.
        Some(s) if s.generations.is_empty() => files.len() == 1,
        Some(s) => s.generations.len() == files.len(),
        None => false,
    };
    if complete {
        said.extend(written.as_ref().and_then(stopped_recording));
        return said;
    }
    match joined_summary(run_dir.path()) {
        Ok(summary) => {
            said.extend(stopped_recording(&summary));
            let path = run_dir.summary();
            match write_json_atomically(&path, &summary) {
                Ok(()) => said.push(format!(
                    "{}: the run's summary over {} logger generation{} ({} ticks: {} recorded, {} lost); {}",
                    path.display(),
                    summary.generations.len(),
                    if summary.generations.len() == 1 { "" } else { "s" },
                    summary.ticks,
                    summary.samples.measurement,
                    summary.gaps.measurement,
                    describe_outages(&summary.outages)
                )),
                Err(e) => said.push(format!("cannot write the run's summary: {e}")),
            }
        }
        Err(e) => said.push(format!("cannot rebuild the run's summary: {e}")),
    }
    said
}

/// The recording stopped before the run ended (a write failed: a full
/// disk): said, with how much of it the file holds, since the loop went on
/// and `up` would otherwise end as if nothing happened.
fn stopped_recording(summary: &flexloop_runfiles::RunSummary) -> Option<String> {
    let file = &summary.recording.sample_file;
    let stopped_generation = summary.generations.iter().find(|g| g.state == "stopped");
    if !file.stopped() && stopped_generation.is_none() {
        return None;
    }
    let name = stopped_generation.map_or(summary.recording.file.as_str(), |g| g.file.as_str());
    Some(format!(
        "the recording stopped before the run ended: {name} holds {} of the {} messages the logger \
         received ({}); the loop ran on, and the summary's counts are the logger's, not the file's",
        file.stored_messages,
        file.messages,
        file.error.as_deref().unwrap_or("a write failed"),
    ))
}

/// Closes the sample files of a run whose logger was killed before it
/// finished them (a restarted logger writes its own), so that every MCAP
/// reader opens them; finished files are left as they are.
fn close_sample_files(run_dir: &RunDir) -> Vec<String> {
    let mut said = Vec::new();
    for (_, path) in run_dir.sample_files() {
        match flexloop_recording::mcap_repair::repair_file(&path) {
            Ok(c) if c.already_complete => {}
            Ok(c) => said.push(format!(
                "{}: the logger did not finish it; closed after its last complete chunk ({} messages in {} chunks kept, {} bytes of torn data cut)",
                path.display(),
                c.messages,
                c.chunks,
                c.cut_bytes
            )),
            Err(e) => said.push(format!("{}: cannot close it: {e}", path.display())),
        }
    }
    said
}
