//! The files the conductor keeps in the run directory: the events file
//! (one JSON line per event) and the list of live processes, published
//! together (the list first) once per tick, before an answer to a request,
//! and after a swap.

use super::decide::Record;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::SupervisorEvent;
use flexloop_runfiles::supervision::Processes;
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
            kind: record.kind.clone(),
            role: record.role.name().to_string(),
            generation: record.generation,
            seq: record.seq,
        });
    }

    /// Rewrites the process list, then appends the events since the last
    /// time: who reads of a process in the events finds it in the list. A
    /// list that cannot be written holds the events back until one can, so
    /// that no event announces what the list does not show.
    pub fn publish(&mut self, processes: Processes) {
        if !self.write_processes(processes) {
            return;
        }
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
    /// sees the old list or the new one); whether the file holds `list` now.
    fn write_processes(&mut self, list: Processes) -> bool {
        if self.processes_written.as_ref() == Some(&list) {
            return true;
        }
        let path = self.run_dir.processes();
        match flexloop_runfiles::json::write_json_atomically(&path, &list) {
            Ok(()) => {
                self.processes_written = Some(list);
                true
            }
            Err(e) => {
                eprintln!("flexloop: {e}; its events wait for it");
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_runfiles::events::{EventKind, Spare, parse_events};
    use flexloop_runfiles::json::read_json;
    use flexloop_runfiles::supervision::ProcessEntry;

    fn list(pids: &[i32]) -> Processes {
        Processes {
            processes: pids
                .iter()
                .map(|pid| ProcessEntry {
                    role: "controller".into(),
                    pid: *pid,
                    duty: "spare".into(),
                    generation: None,
                    scenario: "s.toml".into(),
                })
                .collect(),
            ended: None,
        }
    }

    fn spare_event(pid: i32) -> Record {
        Record {
            kind: EventKind::Spare(Spare { pid }),
            role: flexloop_node::Role::Controller,
            generation: None,
            seq: None,
            clean_dead_nodes: false,
        }
    }

    fn events(dir: &RunDir) -> Vec<SupervisorEvent> {
        parse_events(&std::fs::read_to_string(dir.events()).unwrap_or_default()).unwrap()
    }

    /// A reader that sees an event finds the process it announces in the
    /// list: the list is written first, and an event waits while the list
    /// cannot be written.
    #[test]
    fn an_event_is_never_ahead_of_the_process_list() {
        let dir = std::env::temp_dir().join(format!("flexloop-record-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let run_dir = RunDir::new(&dir);
        let mut files = RunFiles::new(&dir);
        files.publish(list(&[10]));
        files.append(&spare_event(11));
        assert!(events(&run_dir).is_empty(), "an event before its publish");
        // The list's temporary file cannot be made: the list stays old.
        let blocker = dir.join("processes.json.tmp");
        std::fs::create_dir(&blocker).unwrap();
        files.publish(list(&[11]));
        assert!(
            events(&run_dir).is_empty(),
            "the event went ahead of the list"
        );
        let shown: Processes = read_json(&run_dir.processes()).unwrap();
        assert_eq!(shown, list(&[10]));
        std::fs::remove_dir(&blocker).unwrap();
        files.publish(list(&[11]));
        let written = events(&run_dir);
        assert_eq!(written.len(), 1);
        assert_eq!(written[0].kind, EventKind::Spare(Spare { pid: 11 }));
        let shown: Processes = read_json(&run_dir.processes()).unwrap();
        assert_eq!(shown, list(&[11]));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
