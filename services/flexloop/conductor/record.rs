//! The files the conductor keeps in the run directory: the events file
//! (one JSON line per event) and the list of live processes, published
//! together (the list first) once per tick, before an answer to a request,
//! and after a swap.

use super::decide::Record;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::supervision::{Processes, SupervisorEvent};
use std::io::Write;
use std::path::Path;
use std::time::Instant;

pub struct RunFiles {
    run_dir: RunDir,
    /// Events are stamped with the time since.
    started: Instant,
    /// What `processes.json` holds now: the live processes and what each
    /// does, for `flexloop status` and for tests that must stop one
    /// particular instance.
    processes_written: Option<Processes>,
    /// Events waiting for [`RunFiles::publish`].
    unwritten: Vec<SupervisorEvent>,
}

impl RunFiles {
    pub fn new(run_dir: &Path) -> Self {
        Self {
            run_dir: RunDir::new(run_dir),
            started: Instant::now(),
            processes_written: None,
            unwritten: Vec::new(),
        }
    }

    pub fn run_dir(&self) -> &Path {
        self.run_dir.path()
    }

    /// Stamps one event, for the events file at the next [`RunFiles::publish`].
    pub fn append(&mut self, record: &Record) {
        self.unwritten.push(SupervisorEvent {
            t_s: self.started.elapsed().as_secs_f64(),
            kind: record.kind.to_string(),
            role: record.role.name().to_string(),
            generation: record.generation,
            seq: record.seq,
            detail: record.detail.clone(),
        });
    }

    /// Rewrites the process list, then appends the events since the last
    /// time: who reads of a process in the events finds it in the list.
    pub fn publish(&mut self, processes: Processes) {
        self.write_processes(processes);
        for event in std::mem::take(&mut self.unwritten) {
            self.write_event(&event);
        }
    }

    /// Appends one line to the events file (best effort: an event that
    /// cannot be written is printed instead).
    fn write_event(&self, event: &SupervisorEvent) {
        let line = match serde_json::to_string(event) {
            Ok(line) => line,
            Err(e) => {
                eprintln!("flexloop: event {event:?}: {e}");
                return;
            }
        };
        let written = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.run_dir.events())
            // One write of the whole line: with O_APPEND a reader never sees
            // half of it (`writeln!` writes the pieces of its format apart).
            .and_then(|mut f| f.write_all(format!("{line}\n").as_bytes()));
        if written.is_err() {
            eprintln!("flexloop: event {line}");
        }
    }

    /// Rewrites `processes.json` if the list changed (atomically: a reader
    /// sees the old list or the new one).
    fn write_processes(&mut self, list: Processes) {
        if self.processes_written.as_ref() == Some(&list) {
            return;
        }
        let path = self.run_dir.processes();
        if flexloop_runfiles::json::write_json_atomically(&path, &list).is_ok() {
            self.processes_written = Some(list);
        }
    }
}
