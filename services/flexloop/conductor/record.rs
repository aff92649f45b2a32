//! The files the conductor keeps in the run directory: the events file
//! (one JSON line per event) and the list of live processes, published
//! together (the list first) once per tick, before an answer to a request,
//! and after a swap.

use super::decide::Record;
use serde_json::{Value, json};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

const EVENTS_FILE: &str = flexloop_runfiles::RunDir::EVENTS;
/// The live processes and what each does (active, standby, spare), rewritten
/// whenever that changes: for `flexloop status` and for tests that must
/// stop one particular instance.
const PROCESSES_FILE: &str = flexloop_runfiles::RunDir::PROCESSES;

pub struct RunFiles {
    run_dir: PathBuf,
    /// Events are stamped with the time since.
    started: Instant,
    /// What [`PROCESSES_FILE`] holds now.
    processes_written: Value,
    /// Event lines waiting for [`RunFiles::publish`].
    unwritten: Vec<Value>,
}

impl RunFiles {
    pub fn new(run_dir: &Path) -> Self {
        Self {
            run_dir: run_dir.to_path_buf(),
            started: Instant::now(),
            processes_written: Value::Null,
            unwritten: Vec::new(),
        }
    }

    pub fn run_dir(&self) -> &Path {
        &self.run_dir
    }

    /// Stamps one event, for the events file at the next [`RunFiles::publish`].
    pub fn append(&mut self, record: &Record) {
        self.unwritten.push(json!({
            "t_s": self.started.elapsed().as_secs_f64(),
            "kind": record.kind,
            "role": record.role.name(),
            "generation": record.generation,
            "seq": record.seq,
            "detail": record.detail,
        }));
    }

    /// Rewrites the process list, then appends the events since the last
    /// time: who reads of a process in the events finds it in the list.
    pub fn publish(&mut self, processes: Value) {
        self.write_processes(processes);
        for line in std::mem::take(&mut self.unwritten) {
            self.write_event(&line);
        }
    }

    /// Appends one line to the events file (best effort: an event that
    /// cannot be written is printed instead).
    fn write_event(&self, line: &Value) {
        let written = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.run_dir.join(EVENTS_FILE))
            // One write of the whole line: with O_APPEND a reader never sees
            // half of it (`writeln!` writes the pieces of its format apart).
            .and_then(|mut f| f.write_all(format!("{line}\n").as_bytes()));
        if written.is_err() {
            eprintln!("flexloop: event {line}");
        }
    }

    /// Rewrites [`PROCESSES_FILE`] if the list changed (atomically: a reader
    /// sees the old list or the new one).
    fn write_processes(&mut self, list: Value) {
        if list == self.processes_written {
            return;
        }
        let path = self.run_dir.join(PROCESSES_FILE);
        if flexloop_runfiles::json::write_json_atomically(&path, &list).is_ok() {
            self.processes_written = list;
        }
    }
}
