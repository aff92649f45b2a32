//! The conductor's view of the loop's processes: who serves which role and
//! generation, in which duty, and whether its exit is already dealt with.
//! The supervisor's list holds how each was started; this one what each
//! does now (a warm spare takes other duties without a new process).

use flexloop_node::Role;
use flexloop_protocol::Joining;
use flexloop_runfiles::supervision::{ProcessEntry, Processes};
use std::path::PathBuf;

/// What a live instance does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Duty {
    /// Serves its role (or follows in shadow on its way to serving it).
    Active,
    /// The standby controller: follows the loop, not the role's instance
    /// until promoted.
    Standby,
    /// A warm spare (see `flexloop_node::spare`); `idle` once it reported
    /// itself idle, and only then does it take orders.
    Spare { idle: bool },
}

impl Duty {
    fn joining(joining: Joining) -> Self {
        match joining {
            Joining::Standby => Duty::Standby,
            Joining::Spare => Duty::Spare { idle: false },
            Joining::AtStart | Joining::Replacement | Joining::Restart => Duty::Active,
        }
    }

    fn name(self) -> &'static str {
        match self {
            Duty::Active => "active",
            Duty::Standby => "standby",
            Duty::Spare { .. } => "spare",
        }
    }
}

#[derive(Debug, Clone)]
pub struct Member {
    pub pid: i32,
    pub role: Role,
    /// The generation it serves; `None` for a spare that has served none.
    pub generation: Option<u32>,
    pub duty: Duty,
    /// The scenario file it runs (a swap may give a component another one).
    pub scenario: PathBuf,
    /// Its exit code, once it ended.
    pub exit: Option<i32>,
    /// Replaced, crashed-and-restarted, stopped: its exit is dealt with.
    pub settled: bool,
    /// Its crash is in the events as the run's end (not restarted).
    pub fatal_recorded: bool,
    /// A program of one's own (`exec`), not the built-in process.
    pub program: bool,
    /// It published a state (following in shadow, or serving): it has
    /// followed the loop at least once.
    pub followed: bool,
    /// Why it was judged hung, when more is known than its silence
    /// (`"non-finite output"`: it sent only commands the plant refused).
    pub cause: Option<&'static str>,
    /// Known to be on its way out before its exit report came (the kernel
    /// showed it exiting, or the supervisor killed it as hung): it sends
    /// nothing more, and is dealt with as ended.
    pub ending: Option<Ending>,
    /// Its wait for a CPU at the last look (when, ns waited so far), and
    /// whether it waited for most of the time since the look before: a
    /// process starved on a busy machine is not judged hung.
    pub runqueue_wait: Option<(std::time::Instant, u64)>,
    pub starved: bool,
}

/// How a process's end was found before its exit report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ending {
    /// The kernel showed it in its exit (killed or crashed).
    Exiting,
    /// Judged hung from the loop's silence, and killed.
    Silent,
    /// Found stopped, and killed.
    Stopped,
}

impl Member {
    pub fn alive(&self) -> bool {
        self.exit.is_none() && self.ending.is_none()
    }

    /// Ended other than by a clean exit (an exit found before its report
    /// is a kill or a crash).
    pub fn crashed(&self) -> bool {
        self.exit.map_or(self.ending.is_some(), |code| code != 0)
    }

    /// Judged hung and killed: its exit is a fault of that cause.
    pub fn silenced(&self) -> bool {
        matches!(self.ending, Some(Ending::Silent | Ending::Stopped))
    }

    /// How its end was found, for its `crash` event.
    pub fn found(&self) -> &'static str {
        match self.ending {
            None => "exit report",
            Some(Ending::Exiting) => "exiting",
            Some(Ending::Silent) => "silent",
            Some(Ending::Stopped) => "stopped",
        }
    }

    pub fn spare(&self) -> bool {
        matches!(self.duty, Duty::Spare { .. })
    }

    pub fn standby(&self) -> bool {
        self.duty == Duty::Standby
    }

    /// Not the run's failure if it exits: dealt with, or an idle spare.
    pub fn exit_expected(&self) -> bool {
        self.settled || self.spare()
    }

    fn serves(&self, role: Role, generation: u32) -> bool {
        self.role == role && self.generation == Some(generation)
    }
}

#[derive(Debug, Default)]
pub struct Roster {
    /// In the order they started.
    members: Vec<Member>,
}

impl Roster {
    pub fn add(
        &mut self,
        pid: i32,
        role: Role,
        generation: u32,
        joining: Joining,
        scenario: PathBuf,
        program: bool,
    ) {
        self.members.push(Member {
            pid,
            role,
            generation: (joining != Joining::Spare).then_some(generation),
            duty: Duty::joining(joining),
            scenario,
            exit: None,
            settled: false,
            fatal_recorded: false,
            program,
            followed: false,
            cause: None,
            runqueue_wait: None,
            starved: false,
            ending: None,
        });
    }

    pub fn knows(&self, pid: i32) -> bool {
        self.get(pid).is_some()
    }

    pub fn get(&self, pid: i32) -> Option<&Member> {
        self.members.iter().find(|m| m.pid == pid)
    }

    pub fn get_mut(&mut self, pid: i32) -> Option<&mut Member> {
        self.members.iter_mut().find(|m| m.pid == pid)
    }

    pub fn iter(&self) -> impl DoubleEndedIterator<Item = &Member> {
        self.members.iter()
    }

    pub fn iter_mut(&mut self) -> impl Iterator<Item = &mut Member> {
        self.members.iter_mut()
    }

    /// The role's current instance: the one alive, standbys and spares
    /// aside, or else the newest that ended (a crashed one, to restart).
    pub fn serving(&self, role: Role) -> Option<&Member> {
        let serving = |m: &&Member| m.role == role && m.duty == Duty::Active;
        let mut newest = self.members.iter().rev().filter(serving);
        newest.clone().find(|m| m.alive()).or_else(|| newest.next())
    }

    /// The first instance that serves (or was to serve) `role` as `generation`.
    pub fn of_generation(&self, role: Role, generation: u32) -> Option<&Member> {
        self.members.iter().find(|m| m.serves(role, generation))
    }

    /// Whether every instance of `role` that served `generation` is gone
    /// (exited, or back to being a spare).
    pub fn generation_gone(&self, role: Role, generation: u32) -> bool {
        self.members
            .iter()
            .filter(|m| m.serves(role, generation))
            .all(|m| !m.alive() || m.spare())
    }

    /// The generation after every one the role has served.
    pub fn next_generation(&self, role: Role) -> u32 {
        self.members
            .iter()
            .filter(|m| m.role == role)
            .filter_map(|m| m.generation)
            .map(|g| g + 1)
            .max()
            .unwrap_or(1)
    }

    /// A live spare of `role` that reported itself idle.
    pub fn idle_spare(&self, role: Role) -> Option<i32> {
        self.members
            .iter()
            .find(|m| m.role == role && m.duty == Duty::Spare { idle: true } && m.alive())
            .map(|m| m.pid)
    }

    /// Whether a spare of `role` is still starting (alive, not idle yet).
    pub fn spare_starting(&self, role: Role) -> bool {
        self.members
            .iter()
            .any(|m| m.role == role && m.duty == Duty::Spare { idle: false } && m.alive())
    }

    pub fn has_live_spare(&self, role: Role) -> bool {
        self.members
            .iter()
            .any(|m| m.role == role && m.spare() && m.alive())
    }

    pub fn has_live_standby(&self) -> bool {
        self.members.iter().any(|m| m.standby() && m.alive())
    }

    /// The live processes and their duties, as `processes.json` lists them.
    pub fn processes(&self) -> Processes {
        let processes = self
            .members
            .iter()
            .filter(|m| m.alive())
            .map(|m| ProcessEntry {
                role: m.role.name().to_string(),
                pid: m.pid,
                duty: m.duty.name().to_string(),
                generation: m.generation,
                scenario: m.scenario.display().to_string(),
            })
            .collect();
        Processes {
            processes,
            ended: None,
        }
    }
}
