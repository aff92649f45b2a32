//! A hung component is a fault like a dead one (docs/architecture.md,
//! "Standby, watchdogs and guards"): a process that
//! is alive but sends nothing (a deadlock, an endless loop, a stopped
//! process, a law that sleeps) is detected from what the loop shows, not
//! from an exit report that never comes.
//!
//! The evidence is the plant's: a tick whose input it held or whose safe
//! action it applied (`HELD_INPUT`, `FALLBACK`) had no fresh command; the
//! observer's estimates fall behind the ticks. A role is silent when both
//! hold: it has left [`SilenceRule::ticks`] of the loop's ticks without
//! its output, and [`SilenceRule::floor`] of wall time since its last
//! output (ticks the plant marked stalled, a machine stall that froze
//! every process alike, do not count). The tick count is what the loop
//! lost; the floor keeps a machine that merely starved the process (no
//! real-time priority, a loaded CI machine: a process descheduled for tens
//! of milliseconds) from being judged hung. In lockstep the plant waits for each command, so ticks
//! come once a second when the controller is silent (the plant's own miss
//! timeout): the floor alone decides there.
//!
//! The observer is judged first: a silent observer also silences a
//! controller that waits for its estimate (lockstep), and the fault is the
//! observer's.

use flexloop_node::Role;
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Ticks whose count of unstalled ticks is kept, to place an output that
/// arrives after the ticks it covered (one look drains the measurements
/// before the estimates): 1.6 s at 10 kHz, more than one look's worth.
const TICKS_KEPT: usize = 16_384;

/// When a role counts as silent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SilenceRule {
    /// Ticks of the loop without the role's output.
    pub ticks: u64,
    /// Wall time since the role's last output.
    pub floor: Duration,
    /// The plant waits for each command: ticks do not measure silence.
    pub lockstep: bool,
}

impl SilenceRule {
    /// The floor when the loop's processes run at real-time priority: the
    /// tick count alone decides (a machine stall stops every process alike
    /// and its ticks are marked stalled).
    pub const REALTIME_FLOOR: Duration = Duration::ZERO;
    /// Without real-time priority a process may be descheduled for seconds
    /// on a busy machine while the plant ticks on: a controller of a test
    /// loop sharing its CPUs with another loop went 1.9 s without output,
    /// and 0.5 s had it killed as silent.
    pub const SHARED_MACHINE_FLOOR: Duration = Duration::from_secs(3);
    /// In lockstep the plant gives a silent controller 1 s per tick before
    /// it holds (shared/node plant.rs) and ends the run after 10 s of
    /// silence: act well before that.
    pub const LOCKSTEP_FLOOR: Duration = Duration::from_secs(3);
}

/// One role's output as the loop saw it.
#[derive(Debug, Clone, Copy, Default)]
struct Output {
    /// The newest tick the role's output covered.
    seq: Option<u64>,
    /// When that was first seen (stamped at the poll that saw it).
    at: Option<Instant>,
    /// Seen in the poll now being taken, not stamped yet.
    fresh: bool,
}

/// What the loop shows of the controller's and the observer's output.
#[derive(Debug, Default)]
pub struct SilenceWatch {
    newest_tick: Option<u64>,
    /// Unstalled ticks seen so far, and per recent tick that count as of it.
    unstalled: u64,
    counts: VecDeque<(u64, u64)>,
    controller: Output,
    observer: Output,
    /// When the last look was taken.
    looked: Option<Instant>,
}

/// A role found silent: who, and for how long.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Silent {
    pub role: Role,
    /// Ticks of the loop since its last output.
    pub ticks: u64,
    pub since: Duration,
}

impl SilenceWatch {
    /// The plant's tick `seq`; `fresh_command`: the plant applied a command
    /// made for it (it neither held its input nor applied its safe action);
    /// `stalled`: it woke late for it (a machine stall).
    pub fn tick(&mut self, seq: u64, fresh_command: bool, stalled: bool) {
        if self.newest_tick.is_none_or(|n| seq > n) {
            self.unstalled += u64::from(!stalled);
            if self.counts.len() == TICKS_KEPT {
                self.counts.pop_front();
            }
            self.counts.push_back((seq, self.unstalled));
        }
        self.newest_tick = Some(self.newest_tick.map_or(seq, |n| n.max(seq)));
        if fresh_command {
            let c = &mut self.controller;
            c.seq = Some(c.seq.map_or(seq, |s| s.max(seq)));
            c.fresh = true;
        }
    }

    /// The observer's estimate for tick `seq` (made from measurement `seq - 1`).
    pub fn estimate(&mut self, seq: u64) {
        let o = &mut self.observer;
        let covered = seq.saturating_sub(1);
        o.seq = Some(o.seq.map_or(covered, |s| s.max(covered)));
        o.fresh = true;
    }

    /// One look at the channels is over: what it saw is stamped `now`.
    pub fn polled(&mut self, now: Instant) {
        self.looked = Some(now);
        for o in [&mut self.controller, &mut self.observer] {
            if std::mem::take(&mut o.fresh) {
                o.at = Some(now);
            }
        }
    }

    /// `role`'s output starts again from `now` (a new instance serves it:
    /// a restart, a swap), whatever the last one left.
    pub fn restart_clock(&mut self, role: Role, now: Instant) {
        let o = match role {
            Role::Controller => &mut self.controller,
            Role::Observer => &mut self.observer,
            _ => return,
        };
        o.seq = self.newest_tick.or(o.seq);
        o.at = Some(now);
        o.fresh = false;
    }

    /// Unstalled ticks since `role`'s last output (0 before its first).
    pub fn ticks_without(&self, role: Role) -> u64 {
        let o = match role {
            Role::Controller => &self.controller,
            Role::Observer => &self.observer,
            _ => return 0,
        };
        o.seq.map_or(0, |seq| self.unstalled_after(seq))
    }

    /// Unstalled ticks after tick `seq` (all those seen, if it is older
    /// than those kept).
    fn unstalled_after(&self, seq: u64) -> u64 {
        let i = self.counts.partition_point(|&(s, _)| s <= seq);
        match i.checked_sub(1).and_then(|i| self.counts.get(i)) {
            Some(&(_, count)) => self.unstalled - count,
            None => self.unstalled,
        }
    }

    /// When a role silent now (the plant's watchdog has acted on it: two
    /// ticks or more without its output) is due to be judged under `rule`,
    /// at `period` per tick: its silent ticks counted on from the last look,
    /// and no sooner than its floor. None when no role is silent, or one is
    /// due already (the regular look judges it).
    pub fn due(&self, rule: &SilenceRule, period: Duration) -> Option<Instant> {
        let looked = self.looked?;
        [&self.observer, &self.controller]
            .into_iter()
            .filter_map(|o| {
                let (seq, at) = (o.seq?, o.at?);
                let ticks = self.unstalled_after(seq);
                if rule.lockstep || ticks < 2 || ticks >= rule.ticks {
                    return None;
                }
                let by_ticks = looked + period * u32::try_from(rule.ticks - ticks).ok()?;
                Some(by_ticks.max(at + rule.floor))
            })
            .min()
    }

    /// The role found silent at `now` under `rule`, the observer first
    /// (its silence silences a controller that waits for it). Nothing
    /// before a role's first output: start-up is not silence.
    pub fn silent(&self, rule: &SilenceRule, now: Instant) -> Option<Silent> {
        let newest = self.newest_tick?;
        let judge = |role: Role, o: &Output| {
            let (seq, at) = (o.seq?, o.at?);
            let ticks = self.unstalled_after(seq);
            let since = now.saturating_duration_since(at);
            let enough_ticks = if rule.lockstep {
                ticks >= 1
            } else {
                ticks >= rule.ticks
            };
            let floor = if rule.lockstep {
                rule.floor.max(SilenceRule::LOCKSTEP_FLOOR)
            } else {
                rule.floor
            };
            (enough_ticks && since >= floor).then_some(Silent { role, ticks, since })
        };
        if let Some(s) = judge(Role::Observer, &self.observer) {
            return Some(s);
        }
        // A controller waiting for a late estimate is not the fault.
        let observer_behind = self
            .observer
            .seq
            .is_some_and(|s| newest.saturating_sub(s) > 1);
        if observer_behind && rule.lockstep {
            return None;
        }
        judge(Role::Controller, &self.controller)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RULE: SilenceRule = SilenceRule {
        ticks: 20,
        floor: Duration::ZERO,
        lockstep: false,
    };

    fn run(watch: &mut SilenceWatch, from: u64, to: u64, commands: bool, estimates: bool) {
        for seq in from..to {
            watch.tick(seq, commands, false);
            if estimates {
                watch.estimate(seq + 1);
            }
        }
    }

    #[test]
    fn a_loop_whose_roles_answer_every_tick_is_not_silent() {
        let t0 = Instant::now();
        let mut w = SilenceWatch::default();
        run(&mut w, 0, 1_000, true, true);
        w.polled(t0);
        assert_eq!(w.silent(&RULE, t0 + Duration::from_secs(5)), None);
    }

    #[test]
    fn start_up_is_not_silence() {
        let t0 = Instant::now();
        let mut w = SilenceWatch::default();
        // Ticks before any command or estimate (the chain is coming up).
        run(&mut w, 0, 500, false, false);
        w.polled(t0);
        assert_eq!(w.silent(&RULE, t0 + Duration::from_secs(5)), None);
    }

    #[test]
    fn a_controller_whose_commands_stop_is_silent_after_the_ticks() {
        let t0 = Instant::now();
        let mut w = SilenceWatch::default();
        run(&mut w, 0, 100, true, true);
        w.polled(t0);
        // Held ticks, estimates still coming (realtime: the observer wakes
        // on measurements).
        run(&mut w, 100, 119, false, true);
        w.polled(t0 + Duration::from_millis(2));
        assert_eq!(w.silent(&RULE, t0 + Duration::from_millis(2)), None);
        run(&mut w, 119, 121, false, true);
        w.polled(t0 + Duration::from_millis(3));
        let s = w.silent(&RULE, t0 + Duration::from_millis(3)).unwrap();
        assert_eq!((s.role, s.ticks), (Role::Controller, 21));
        // The floor: on a shared machine not before its wall time.
        let shared = SilenceRule {
            floor: Duration::from_millis(500),
            ..RULE
        };
        assert_eq!(w.silent(&shared, t0 + Duration::from_millis(3)), None);
        assert!(w.silent(&shared, t0 + Duration::from_millis(500)).is_some());
    }

    #[test]
    fn a_silent_observer_is_judged_before_the_controller_it_starves() {
        let t0 = Instant::now();
        let mut w = SilenceWatch::default();
        run(&mut w, 0, 100, true, true);
        w.polled(t0);
        run(&mut w, 100, 200, false, false);
        w.polled(t0 + Duration::from_millis(10));
        let s = w.silent(&RULE, t0 + Duration::from_millis(10)).unwrap();
        assert_eq!(s.role, Role::Observer);
        // Its last estimate (for tick 100) covered measurement 99.
        assert_eq!(s.ticks, 100);
    }

    #[test]
    fn in_lockstep_the_wall_time_decides() {
        let t0 = Instant::now();
        let lockstep = SilenceRule {
            lockstep: true,
            ..RULE
        };
        let mut w = SilenceWatch::default();
        run(&mut w, 0, 100, true, true);
        w.polled(t0);
        // The plant held one tick after waiting its second; estimates on.
        run(&mut w, 100, 101, false, true);
        w.polled(t0 + Duration::from_secs(1));
        assert_eq!(w.silent(&lockstep, t0 + Duration::from_secs(2)), None);
        let s = w.silent(&lockstep, t0 + Duration::from_secs(3)).unwrap();
        assert_eq!(s.role, Role::Controller);
        // A controller waiting for a silent observer is not the fault.
        let mut v = SilenceWatch::default();
        run(&mut v, 0, 100, true, true);
        v.polled(t0);
        run(&mut v, 100, 103, false, false);
        v.polled(t0 + Duration::from_secs(3));
        let s = v.silent(&lockstep, t0 + Duration::from_secs(4)).unwrap();
        assert_eq!(s.role, Role::Observer);
    }

    #[test]
    fn ticks_the_plant_marked_stalled_do_not_count() {
        let t0 = Instant::now();
        let mut w = SilenceWatch::default();
        run(&mut w, 0, 100, true, true);
        w.polled(t0);
        // A machine stall: 500 late ticks, the controller not yet answered.
        for seq in 100..600 {
            w.tick(seq, false, true);
            w.estimate(seq + 1);
        }
        for seq in 600..610 {
            w.tick(seq, false, false);
            w.estimate(seq + 1);
        }
        w.polled(t0 + Duration::from_millis(50));
        assert_eq!(w.silent(&RULE, t0 + Duration::from_millis(50)), None);
        for seq in 610..625 {
            w.tick(seq, false, false);
            w.estimate(seq + 1);
        }
        w.polled(t0 + Duration::from_millis(60));
        let s = w.silent(&RULE, t0 + Duration::from_millis(60)).unwrap();
        assert_eq!((s.role, s.ticks), (Role::Controller, 25));
    }

    #[test]
    fn a_silence_under_way_is_due_when_its_ticks_will_have_passed() {
        let t0 = Instant::now();
        let period = Duration::from_micros(100);
        let mut w = SilenceWatch::default();
        run(&mut w, 0, 100, true, true);
        w.polled(t0);
        assert_eq!(w.due(&RULE, period), None, "nothing silent");
        // 5 silent ticks of the rule's 20: due 15 ticks after this look.
        run(&mut w, 100, 105, false, true);
        w.polled(t0 + Duration::from_micros(500));
        assert_eq!(
            w.due(&RULE, period),
            Some(t0 + Duration::from_micros(500) + 15 * period)
        );
        // Not before the floor on a shared machine.
        let shared = SilenceRule {
            floor: Duration::from_millis(500),
            ..RULE
        };
        assert_eq!(
            w.due(&shared, period),
            Some(t0 + Duration::from_millis(500))
        );
        // Due already: the regular look judges it.
        run(&mut w, 105, 125, false, true);
        w.polled(t0 + Duration::from_millis(3));
        assert_eq!(w.due(&RULE, period), None);
    }

    #[test]
    fn a_new_instance_starts_its_own_clock() {
        let t0 = Instant::now();
        let mut w = SilenceWatch::default();
        run(&mut w, 0, 100, true, true);
        w.polled(t0);
        run(&mut w, 100, 200, false, true);
        w.polled(t0 + Duration::from_millis(10));
        assert!(w.silent(&RULE, t0 + Duration::from_millis(10)).is_some());
        // Restarted: judged again only once it too leaves the ticks.
        w.restart_clock(Role::Controller, t0 + Duration::from_millis(10));
        assert_eq!(w.silent(&RULE, t0 + Duration::from_millis(11)), None);
        run(&mut w, 200, 205, true, true);
        w.polled(t0 + Duration::from_millis(12));
        assert_eq!(w.silent(&RULE, t0 + Duration::from_millis(12)), None);
    }
}
