//! What an instance of a loop component does for the loop, sample by
//! sample: the duty states every controller and observer instance goes
//! through, and the bookkeeping that moves it between them. Pure (no port,
//! no clock, no allocation): [`Standing::on_sample`] runs every sample.

use flexloop_protocol::Joining;
use flexloop_protocol::handover::{ACTIVE, CATCHING_UP, FOLLOWING};

/// An instance's duty for the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Duty {
    /// Every port open, idle until the supervisor's order (see
    /// [`crate::spare`]): started so, or back after a replacement.
    Spare,
    /// A restarted observer stepping through the supervisor's replay of
    /// the measurements since its dead predecessor's last state.
    Replaying,
    /// Following the active instance, publishing nothing, until a boundary
    /// hands it the samples (a swap, a restart, the first instance before
    /// its first sample).
    Shadow,
    /// The standby controller: following, and publishing its commands for
    /// the plant's safe action.
    Standby,
    /// Owns the samples: publishes what the loop uses.
    Active,
    /// Replaced at a boundary, or a standby whose design is no longer the
    /// active one's: leaves the loop (for the spares, or to exit).
    Retiring,
}

impl Duty {
    /// The duty a process enters the loop with.
    pub fn entering(joining: Joining) -> Self {
        match joining {
            Joining::Spare => Duty::Spare,
            Joining::Standby => Duty::Standby,
            Joining::AtStart | Joining::Replacement | Joining::Restart => Duty::Shadow,
        }
    }

    /// How the states it publishes are marked for the others
    /// ([`flexloop_protocol::Handover::shadow`]).
    pub fn handover_mark(self) -> u32 {
        match self {
            Duty::Active => ACTIVE,
            Duty::Replaying => CATCHING_UP,
            Duty::Spare | Duty::Shadow | Duty::Standby | Duty::Retiring => FOLLOWING,
        }
    }

    /// Whether the instance still follows the loop.
    pub fn serves(self) -> bool {
        !matches!(self, Duty::Spare | Duty::Retiring)
    }
}

/// Who owns a sample, as the activation says, and where the instance stands
/// with the measurements before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleOwnership {
    /// The sample this wake-up serves (the newest measurement).
    pub seq: u64,
    /// The oldest measurement of the wake-up (a shadow steps from there).
    pub oldest_seq: u64,
    /// The generation whose output for this sample counts.
    pub owner: u32,
    /// The generation named for the coming boundary.
    pub named: u32,
    /// Nothing left over from following at low priority.
    pub caught_up: bool,
}

/// What a sample changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Step {
    /// The duty for this sample.
    pub duty: Duty,
    /// The duty before it (its first active sample is a takeover).
    pub was: Duty,
    /// Time to move to the loop's CPU and priority (once).
    pub raise_priority: bool,
}

impl Step {
    /// This sample is the instance's first as the active one.
    pub fn takes_over(&self) -> bool {
        self.duty == Duty::Active && self.was != Duty::Active
    }
}

/// One instance's duty and what it counts across samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Standing {
    generation: u32,
    duty: Duty,
    /// On the loop's CPU at its priority: from the start, or since named
    /// for a boundary (a replacement follows off it meanwhile).
    priority_raised: bool,
    next_seq: Option<u64>,
    skipped: u64,
}

impl Standing {
    pub fn new(generation: u32, joining: Joining) -> Self {
        Self {
            generation,
            duty: Duty::entering(joining),
            priority_raised: !joining.is_late(),
            next_seq: None,
            skipped: 0,
        }
    }

    pub fn generation(&self) -> u32 {
        self.generation
    }

    pub fn duty(&self) -> Duty {
        self.duty
    }

    pub fn priority_raised(&self) -> bool {
        self.priority_raised
    }

    /// Measurements this instance never saw.
    pub fn skipped(&self) -> u64 {
        self.skipped
    }

    /// The duty for one sample. A shadow counts as seen every measurement
    /// it steps through (from `oldest_seq`); the active instance answers
    /// the newest only. Once named, or at the latest at its first owned
    /// sample, the instance takes the loop's priority; once another
    /// generation owns the samples after it did, it retires.
    pub fn on_sample(&mut self, s: &SampleOwnership) -> Step {
        let active = s.owner == self.generation;
        if let Some(next) = self.next_seq {
            let first = if active { s.seq } else { s.oldest_seq };
            self.skipped += first.saturating_sub(next);
        }
        self.next_seq = Some(s.seq + 1);
        let raise_priority =
            !self.priority_raised && ((s.named == self.generation && s.caught_up) || active);
        self.priority_raised |= raise_priority;
        let was = self.duty;
        self.duty = match was {
            _ if active => Duty::Active,
            Duty::Active => Duty::Retiring,
            other => other,
        };
        Step {
            duty: self.duty,
            was,
            raise_priority,
        }
    }

    /// A standby retired on the supervisor's order.
    pub fn retire(&mut self) {
        self.duty = Duty::Retiring;
    }

    /// Steps through measurements outside [`Standing::on_sample`] (a
    /// replay), into `duty`, the last of them `last_seq`.
    pub fn replayed(&mut self, last_seq: u64, duty: Duty) {
        self.next_seq = Some(last_seq + 1);
        self.duty = duty;
    }

    /// Marks a restart's replay under way.
    pub fn replaying(&mut self) {
        self.duty = Duty::Replaying;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(seq: u64, owner: u32, named: u32) -> SampleOwnership {
        SampleOwnership {
            seq,
            oldest_seq: seq,
            owner,
            named,
            caught_up: true,
        }
    }

    #[test]
    fn each_way_of_joining_enters_its_duty() {
        assert_eq!(Duty::entering(Joining::AtStart), Duty::Shadow);
        assert_eq!(Duty::entering(Joining::Replacement), Duty::Shadow);
        assert_eq!(Duty::entering(Joining::Restart), Duty::Shadow);
        assert_eq!(Duty::entering(Joining::Standby), Duty::Standby);
        assert_eq!(Duty::entering(Joining::Spare), Duty::Spare);
        assert!(!Duty::Spare.serves() && !Duty::Retiring.serves());
        assert!(Duty::Replaying.serves() && Duty::Standby.serves());
    }

    #[test]
    fn the_first_instance_is_active_at_once_and_at_priority_from_the_start() {
        let mut s = Standing::new(0, Joining::AtStart);
        assert!(s.priority_raised());
        let step = s.on_sample(&sample(0, 0, 0));
        assert_eq!(step.duty, Duty::Active);
        assert!(step.takes_over() && !step.raise_priority);
        let step = s.on_sample(&sample(1, 0, 0));
        assert!(!step.takes_over());
    }

    #[test]
    fn a_replacement_follows_takes_priority_when_named_and_caught_up_then_takes_over() {
        let mut s = Standing::new(1, Joining::Replacement);
        assert!(!s.priority_raised());
        assert_eq!(s.on_sample(&sample(10, 0, 0)).duty, Duty::Shadow);
        // Named, but a backlog left over: not yet.
        let behind = SampleOwnership {
            caught_up: false,
            ..sample(11, 0, 1)
        };
        assert!(!s.on_sample(&behind).raise_priority);
        let step = s.on_sample(&sample(12, 0, 1));
        assert!(step.raise_priority && step.duty == Duty::Shadow);
        let step = s.on_sample(&sample(13, 1, 1));
        assert!(step.takes_over() && !step.raise_priority);
    }

    #[test]
    fn an_owned_sample_raises_the_priority_even_unnamed_or_behind() {
        let mut s = Standing::new(2, Joining::Restart);
        let step = s.on_sample(&SampleOwnership {
            caught_up: false,
            ..sample(5, 2, 0)
        });
        assert!(step.raise_priority && step.takes_over());
    }

    #[test]
    fn the_active_instance_retires_when_another_owns_the_samples() {
        let mut s = Standing::new(0, Joining::AtStart);
        s.on_sample(&sample(0, 0, 0));
        let step = s.on_sample(&sample(1, 1, 1));
        assert_eq!((step.was, step.duty), (Duty::Active, Duty::Retiring));
        assert!(!s.duty().serves());
    }

    #[test]
    fn a_standby_stands_by_until_promoted_or_retired() {
        let mut s = Standing::new(3, Joining::Standby);
        assert_eq!(s.on_sample(&sample(7, 0, 0)).duty, Duty::Standby);
        assert_eq!(Duty::Standby.handover_mark(), FOLLOWING);
        let mut promoted = s;
        assert!(promoted.on_sample(&sample(8, 3, 3)).takes_over());
        s.retire();
        assert_eq!(s.duty(), Duty::Retiring);
    }

    #[test]
    fn skipped_measurements_count_from_where_a_shadow_steps_or_the_active_answers() {
        let mut shadow = Standing::new(1, Joining::Replacement);
        shadow.on_sample(&sample(0, 0, 0));
        // A shadow steps through 3..=5: 1 and 2 never seen.
        shadow.on_sample(&SampleOwnership {
            oldest_seq: 3,
            ..sample(5, 0, 0)
        });
        assert_eq!(shadow.skipped(), 2);
        let mut active = Standing::new(0, Joining::AtStart);
        active.on_sample(&sample(0, 0, 0));
        // The active instance answers 5 only: 1 to 4 count.
        active.on_sample(&SampleOwnership {
            oldest_seq: 3,
            ..sample(5, 0, 0)
        });
        assert_eq!(active.skipped(), 4);
    }

    #[test]
    fn a_replay_goes_on_from_its_last_sample() {
        let mut s = Standing::new(4, Joining::Restart);
        s.replaying();
        assert_eq!(s.duty().handover_mark(), CATCHING_UP);
        s.replayed(99, Duty::Active);
        let step = s.on_sample(&sample(100, 4, 4));
        assert_eq!(s.skipped(), 0);
        assert!(!step.takes_over(), "active since the replay");
        assert_eq!(Duty::Active.handover_mark(), ACTIVE);
    }
}
