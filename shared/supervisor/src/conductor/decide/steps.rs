//! The core's answers at each step of bringing an instance in: how to
//! engage it, how a crashed role comes back, whether a new instance follows,
//! whether the loop passed a boundary, and why it all failed if it did.

use flexloop_node::Role;
use flexloop_protocol::Handover;
use std::path::PathBuf;
use std::time::Duration;

/// How a component is brought into the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Engagement {
    /// Order this idle warm spare.
    Order(i32),
    /// A spare of the role is still starting: worth waiting for (a new
    /// process would open ports while the loop runs).
    WaitForSpare,
    /// Start a new process.
    Start,
}

/// How a crashed component comes back.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RestartPlan {
    /// The standby controller `generation`, following the loop, takes over
    /// at a boundary ahead.
    Promote { generation: u32 },
    /// A new instance (or a spare) as `generation`; it owns the samples from
    /// `owns_from` at once, if the dead one served any.
    Fresh {
        scenario: PathBuf,
        generation: u32,
        owns_from: Option<u64>,
        /// The crashed program's scenario, when `scenario` is the built-in
        /// design it is rolled back to.
        rolled_back_from: Option<PathBuf>,
    },
    /// A new logger: it only listens, nothing to hand over.
    Logger { scenario: PathBuf, generation: u32 },
}

/// Where a new instance stands on its way into the loop.
#[derive(Debug, Clone)]
pub enum ShadowStep {
    /// It follows the loop (in shadow, or already serving: a restart).
    Following,
    /// Not yet; `hand_over`: the dead predecessor's last state, which the
    /// shell publishes for it (a dead publisher hands nothing over itself).
    Waiting {
        hand_over: Option<Box<Handover>>,
    },
    Failed(Failure),
}

/// Where the loop stands on its way past a boundary.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DrainStep {
    /// Past the boundary and the samples measured after it, the replaced
    /// instance gone (exited, or a spare again).
    Passed,
    Waiting,
    RunEnded,
}

/// How a standby told to retire is dealt with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Retirement {
    /// Order it to become a spare (it keeps its ports).
    Order,
    /// Stop it (no warm spares).
    Stop,
}

/// A standby of the new controller design to start, and the old ones it
/// replaces once it follows.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Renewal {
    pub scenario: PathBuf,
    pub generation: u32,
    /// (pid, generation) of the standbys of another design.
    pub old: Vec<(i32, u32)>,
}

/// Why a swap or restart did not happen.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Failure {
    /// Another swap, restart or standby's start is under way.
    Busy,
    /// Advanced with no sequence under way (a shell's mistake).
    NoSequence,
    NoInstanceToRestart,
    NotRunning(Role),
    RunEndedBeforeFollowing,
    RunEndedBeforeSwitch,
    /// The loop never ticked: nothing to swap into.
    LoopNotTicking(Duration),
    /// The new instance did not follow the loop in time.
    NotFollowing {
        role: Role,
        timeout: Duration,
    },
    /// The loop did not pass the boundary in time.
    NotPassed {
        from_seq: u64,
        timeout: Duration,
    },
    /// A command could not be carried out, and why.
    Carrying(String),
    /// The loop has not ticked yet: nothing to measure.
    NotTickingYet,
    /// A measurement of the loop runs until this sample.
    Measuring {
        until: u64,
    },
    /// A measurement asked for while a swap, restart or standby's start
    /// changes the loop.
    Changing,
    /// The new instance exited before it followed the loop.
    NewInstanceExited {
        role: Role,
        generation: u32,
        pid: i32,
        code: i32,
    },
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::Busy => write!(
                f,
                "another swap, restart or standby's start is under way; the order waits for its end"
            ),
            Failure::NoSequence => write!(f, "no swap or restart is under way"),
            Failure::NoInstanceToRestart => write!(f, "no instance to restart"),
            Failure::NotRunning(role) => write!(f, "no running flexloop-{}", role.name()),
            Failure::RunEndedBeforeFollowing => {
                write!(f, "the run ended before the replacement followed it")
            }
            Failure::RunEndedBeforeSwitch => write!(f, "the run ended before the switch"),
            Failure::LoopNotTicking(timeout) => write!(
                f,
                "the loop did not start within {timeout:?}: nothing to swap into"
            ),
            Failure::NotFollowing { role, timeout } => write!(
                f,
                "the new flexloop-{} did not follow the loop within {timeout:?}",
                role.name()
            ),
            Failure::NotPassed { from_seq, timeout } => write!(
                f,
                "the loop did not pass the switch at sample {from_seq} within {timeout:?}"
            ),
            Failure::Carrying(why) => write!(f, "{why}"),
            Failure::NotTickingYet => write!(f, "the loop has not ticked yet: nothing to measure"),
            Failure::Changing => write!(
                f,
                "a swap, restart or standby's start is changing the loop: a measurement would \
                 span two loops; ask again once it ended"
            ),
            Failure::Measuring { until } => write!(
                f,
                "a measurement of the loop runs until sample {until}: it would measure another \
                 loop; ask again once it ended"
            ),
            Failure::NewInstanceExited {
                role,
                generation,
                code,
                ..
            } => write!(
                f,
                "the new flexloop-{} (generation {generation}) exited with {code} before it followed the loop",
                role.name()
            ),
        }
    }
}

impl std::error::Error for Failure {}
