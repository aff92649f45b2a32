//! What goes into the decision core (events) and what comes out (actions).

use crate::children::Outcome;
use crate::process_state::ProcessState;
use flexloop_node::Role;
use flexloop_protocol::Joining;
use flexloop_protocol::{Handover, MAX_INPUTS};
use flexloop_runfiles::events::EventKind;
use std::path::PathBuf;
use std::time::Instant;

/// What happened, as the shell saw it (a state by reference: it is large,
/// and kept only if it is an active instance's newest).
#[derive(Debug, Clone)]
pub enum Event<'a> {
    /// A process was started (by the supervisor at start-up, or on an
    /// action of this core).
    Launched {
        pid: i32,
        role: Role,
        generation: u32,
        joining: Joining,
        scenario: PathBuf,
        /// A program of one's own, not the built-in process.
        program: bool,
    },
    /// A process ended with `code` (`128 + signal` if killed).
    Exited { pid: i32, code: i32, now: Instant },
    /// A process reported itself an idle spare (a new spare, or an instance
    /// replaced at a boundary).
    SpareIdle { pid: i32 },
    /// A command for sample `seq` on the loop's command channel, from
    /// `generation`; `finite`: every input of it is a number.
    Command {
        seq: u64,
        generation: u32,
        finite: bool,
    },
    /// The plant's sample `seq`: the command it applied over it and its
    /// value; `fresh`: a command made for it (the plant neither held its
    /// input nor applied its safe action); `answered_late`: the active
    /// controller's command came, but too late to apply (after its tick,
    /// or its command deadline): a late controller, not a silent one;
    /// `stalled`: the plant woke late for it (a machine stall).
    Applied {
        seq: u64,
        command_seq: u64,
        u: [f64; MAX_INPUTS],
        fresh: bool,
        answered_late: bool,
        stalled: bool,
    },
    /// The observer's estimate for `seq` (it follows the measurement of `seq - 1`).
    Estimate { seq: u64 },
    /// A state published by an instance of `role` (active or in shadow).
    State { role: Role, state: &'a Handover },
    /// The plant published its last sample.
    EndOfRun,
    /// The shell finished one look at the channels.
    Polled { now: Instant },
    /// What the kernel shows of a live process of the loop (the shell looks
    /// at those [`super::Core::watched_processes`] names).
    ProcessState {
        pid: i32,
        state: ProcessState,
        /// How long it has waited for a CPU since it started (ns), if known.
        runqueue_wait_ns: Option<u64>,
        now: Instant,
    },
    /// One stage of the supervisor's tick (every 20 ms).
    Tick { now: Instant, stage: Stage },
}

/// The supervisor's tick comes in stages, each decided once the previous
/// one's actions are carried out: a restart may take the spare, a standby may
/// be a spare, and the next stage must see that.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// The restarts whose back-off is over.
    Restarts,
    /// Standbys told to retire that did not become spares in time.
    Retiring,
    /// A live controller or observer that went silent (hung).
    Silence,
    /// The standby controller, if one is to be kept.
    Standby,
    /// A warm spare of each role, if they are kept.
    Spares,
}

impl Stage {
    pub const IN_ORDER: [Stage; 5] = [
        Stage::Silence,
        Stage::Restarts,
        Stage::Retiring,
        Stage::Standby,
        Stage::Spares,
    ];
}

/// What the shell is to do.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// Restart `role` now (its back-off is over): the shell runs the
    /// restart, asking [`Core::plan_restart`] and the steps after it.
    Restart(Role),
    /// Start a warm spare of `role`; report with [`Core::spare_started`].
    StartSpare(Role),
    /// Bring up a standby controller; report with [`Core::standby_engaged`].
    StartStandby { scenario: PathBuf, generation: u32 },
    /// Stop the process (its exit is dealt with already).
    Stop(i32),
    /// Kill the hung process (SIGKILL: a stopped or deadlocked process
    /// handles no SIGTERM); its exit is then dealt with as a crash's.
    Kill(i32),
    /// Append a line to the run's events file.
    Record(Record),
    /// The run cannot go on.
    EndRun(Outcome),
}

/// One line of the run's events file, less its time stamp (the shell's).
#[derive(Debug, Clone, PartialEq)]
pub struct Record {
    pub kind: EventKind,
    pub role: Role,
    pub generation: Option<u32>,
    /// The loop's newest sample when it was decided.
    pub seq: Option<u64>,
    /// A process died: its node's shared memory is to be cleaned (now that
    /// no live process uses it; never from inside the loop), after the
    /// restart it brings is under way.
    pub clean_dead_nodes: bool,
}
