//! `/measurement/response`, the serving loop's side: which measurements
//! there are (the scenario's `[measure]`, each `measure` event), and the
//! samples of each one's periods, taken from the measurement messages the
//! server reads anyway and handed to its estimator a whole period at a
//! time (estimate.rs). Per sample this is a copy into a ring and into the
//! period being filled; nothing is computed here, so the serving loop
//! keeps its pace (docs/live.md, "The measured response").
//!
//! The periods are found as `flexloop measure` finds them in the recording
//! (`LoopMeasurement::of_log`): from the first `EXCITING` tick at or after
//! the planned start. The server's reader may skip samples; a period it
//! did not see whole is never estimated: the live estimate stops and says
//! so.

use crate::estimate::{
    Collected, EstimatorHandle, FromWorkers, PLAN_QUEUE, PeriodData, PlanJob, Planned, Stop,
    start_estimator, start_planner, unavailable,
};
use flexloop_control::excitation::ExcitationPlan;
use flexloop_protocol::{Measurement, flags};
use flexloop_runfiles::events::{EventKind, SupervisorEvent};
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::PoisonError;
use std::sync::mpsc::{Receiver, Sender, SyncSender, TrySendError, channel};

/// Samples kept of the newest ticks (1.5 MB; 3.3 s of a 10 kHz loop), so
/// that a measurement whose plan comes after its start (the events are
/// read every 100 ms, and the plan takes milliseconds to make) is followed
/// from its first tick.
const HISTORY: usize = 1 << 15;
/// Measurements followed at once (each has its estimator thread and its
/// buffers); the loop runs one at a time.
const MAX_FOLLOWED: usize = 4;

/// What a measurement's estimate reads of one measurement message.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sample {
    seq: u64,
    exciting: bool,
    excitation: f64,
    u: f64,
    y: f64,
    y_true: f64,
}

impl Sample {
    /// As `LoopSignals::from_measurements` reads it.
    fn of(m: &Measurement) -> Self {
        Self {
            seq: m.seq,
            exciting: m.flags & flags::EXCITING != 0,
            excitation: m.excitation,
            u: m.u_applied[0],
            y: m.y[0],
            y_true: m.y_true[0],
        }
    }
}

/// A plan's ticks: segments one after another, each its transient and
/// measured periods (collected) and its fade-out period (not).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Geometry {
    planned_start: u64,
    n: usize,
    transient: usize,
    /// Periods collected of each segment.
    per_segment: usize,
    segments: usize,
}

impl Geometry {
    fn of(plan: &ExcitationPlan) -> Self {
        Self {
            planned_start: plan.start_tick,
            n: plan.period_samples(),
            transient: plan.transient_periods,
            per_segment: plan.transient_periods + plan.periods,
            segments: plan.segments.len(),
        }
    }

    fn segment_ticks(&self) -> u64 {
        ((self.per_segment + 1) * self.n) as u64
    }

    fn slots(&self) -> usize {
        self.segments * self.per_segment
    }

    /// The first tick with nothing added, had it started as planned.
    fn planned_end(&self) -> u64 {
        self.planned_start + self.segments as u64 * self.segment_ticks()
    }

    /// Ticks from the start to sample `index` of period `slot`.
    fn offset(&self, slot: usize, index: usize) -> u64 {
        let (segment, period) = (slot / self.per_segment, slot % self.per_segment);
        segment as u64 * self.segment_ticks() + (period * self.n + index) as u64
    }

    /// Period `slot` in words.
    fn name(&self, slot: usize) -> String {
        let (segment, period) = (slot / self.per_segment, slot % self.per_segment);
        let which = if period < self.transient {
            format!("transient period {}", period + 1)
        } else {
            format!("measured period {}", period + 1 - self.transient)
        };
        if self.segments > 1 {
            format!("{which} of tone {}", segment + 1)
        } else {
            which
        }
    }
}

enum Step {
    Going,
    /// Collected whole, stopped, or over before the server saw it: the
    /// collector goes, and with it the estimator's queue.
    Ended,
}

/// One measurement's collection: where it started, and the period being
/// filled.
struct Collector {
    geometry: Geometry,
    start: Option<u64>,
    /// The newest tick handed to it.
    previous: Option<u64>,
    /// The server read ticks of its planned span (from its planned start
    /// to its planned end).
    seen: bool,
    slot: usize,
    period: PeriodData,
    estimator: EstimatorHandle,
}

impl Collector {
    fn new(geometry: Geometry, estimator: EstimatorHandle, seen: bool) -> Self {
        Self {
            geometry,
            start: None,
            previous: None,
            seen,
            slot: 0,
            period: PeriodData::with_capacity(geometry.n),
            estimator,
        }
    }

    fn add(&mut self, s: &Sample) -> Step {
        let previous = self.previous;
        if previous.is_some_and(|p| s.seq <= p) {
            return Step::Going;
        }
        self.previous = Some(s.seq);
        let g = self.geometry;
        let start = match self.start {
            Some(start) => start,
            None => {
                if s.seq < g.planned_start {
                    return Step::Going;
                }
                if s.seq < g.planned_end() {
                    self.seen = true;
                } else if !self.seen {
                    // Over before the server read anything of it.
                    return Step::Ended;
                }
                if !s.exciting {
                    // An ordered one starts once the plant has designed
                    // it, which may be past its planned end: it is found
                    // as `LoopMeasurement::of_log` finds it, from the
                    // first excited tick at or after its planned start.
                    return Step::Going;
                }
                // The first excited tick is the start only if the tick
                // before it was seen (not excited) or it is the planned one.
                if s.seq != g.planned_start && previous != Some(s.seq - 1) {
                    let from = previous.map_or(g.planned_start, |p| (p + 1).max(g.planned_start));
                    return self.stop(
                        format!(
                            "the live server did not see ticks {from} to {} (before the first \
                             excited one it saw), so where the measurement started is not known",
                            s.seq - 1
                        ),
                        s.seq - from,
                    );
                }
                self.start = Some(s.seq);
                if let Err(step) = self.send(Collected::Started { tick: s.seq }) {
                    return step;
                }
                s.seq
            }
        };
        let at = s.seq - start;
        let expected = g.offset(self.slot, self.period.u.len());
        if at < expected {
            // A fade-out between two tones.
            return Step::Going;
        }
        if at > expected {
            let end = g.offset(self.slot, 0) + g.n as u64;
            let missed = at.min(end) - expected;
            return self.stop(
                format!(
                    "the live server's reader missed {missed} samples of the {}, from tick {}",
                    g.name(self.slot),
                    start + expected
                ),
                missed,
            );
        }
        self.period.excitation.push(s.excitation);
        self.period.u.push(s.u);
        self.period.y.push(s.y);
        self.period.y_true.push(s.y_true);
        if self.period.u.len() < g.n {
            return Step::Going;
        }
        let data = std::mem::replace(&mut self.period, PeriodData::with_capacity(g.n));
        let slot = self.slot;
        if let Err(step) = self.send(Collected::Period { slot, data }) {
            return step;
        }
        self.slot += 1;
        if self.slot == g.slots() {
            Step::Ended
        } else {
            Step::Going
        }
    }

    /// To the estimator; a full queue (it is far behind) stops the live
    /// estimate, and a gone estimator (it said why) ends the collection.
    fn send(&mut self, collected: Collected) -> Result<(), Step> {
        match self.estimator.periods.try_send(collected) {
            Ok(()) => Ok(()),
            Err(TrySendError::Full(_)) => Err(self.stop(
                format!(
                    "the estimator fell behind the loop ({} collected periods waited for it)",
                    self.estimator.queue_periods
                ),
                0,
            )),
            Err(TrySendError::Disconnected(_)) => Err(Step::Ended),
        }
    }

    fn stop(&mut self, reason: String, missed_samples: u64) -> Step {
        *self
            .estimator
            .stop
            .lock()
            .unwrap_or_else(PoisonError::into_inner) = Some(Stop {
            reason,
            missed_samples,
        });
        Step::Ended
    }
}

/// The measurements the server follows, and the workers that plan and
/// estimate them.
pub(crate) struct MeasureFeed {
    run_dir: PathBuf,
    planner: Option<SyncSender<PlanJob>>,
    to_feed: Sender<FromWorkers>,
    from_workers: Receiver<FromWorkers>,
    history: VecDeque<Sample>,
    first_seq: Option<u64>,
    followed: Vec<Collector>,
}

impl MeasureFeed {
    /// Starts the planner, with the scenario's own `[measure]` (and the
    /// scenario's design) as its first job.
    pub(crate) fn start(run_dir: &Path, rate_hz: f64) -> Self {
        let (to_feed, from_workers) = channel();
        let planner = match start_planner(run_dir.to_path_buf(), rate_hz, to_feed.clone()) {
            Ok(jobs) => {
                let _ = jobs.try_send(PlanJob::Scenario);
                Some(jobs)
            }
            Err(e) => {
                eprintln!(
                    "flexloop-live: /measurement/response is off: cannot start its planner: {e}"
                );
                None
            }
        };
        Self {
            run_dir: run_dir.to_path_buf(),
            planner,
            to_feed,
            from_workers,
            history: VecDeque::with_capacity(HISTORY),
            first_seq: None,
            followed: Vec::new(),
        }
    }

    /// A line of `events.jsonl`: a `measure` event is planned.
    pub(crate) fn event(&mut self, line: &str) {
        let Some(planner) = &self.planner else {
            return;
        };
        let Ok(event) = serde_json::from_str::<SupervisorEvent>(line) else {
            return;
        };
        if let EventKind::Measure(ordered) = event.kind {
            let start_seq = ordered.outcome.start_seq;
            let job = PlanJob::Ordered {
                table: ordered.outcome.table,
                start_seq,
            };
            if planner.try_send(job).is_err() {
                eprintln!(
                    "flexloop-live: the measurement ordered at tick {start_seq} is not followed \
                     live: {PLAN_QUEUE} others wait to be planned"
                );
            }
        }
    }

    /// A measurement message the server read.
    pub(crate) fn sample(&mut self, m: &Measurement) {
        let s = Sample::of(m);
        self.first_seq.get_or_insert(s.seq);
        if self.history.len() == HISTORY {
            self.history.pop_front();
        }
        self.history.push_back(s);
        self.followed
            .retain_mut(|c| matches!(c.add(&s), Step::Going));
    }

    /// The workers' news: measurements to follow, messages to publish.
    pub(crate) fn poll(&mut self, publish: &mut impl FnMut(String)) {
        while let Ok(news) = self.from_workers.try_recv() {
            match news {
                FromWorkers::Publish(json) => publish(json),
                FromWorkers::Planned(planned) => self.follow(*planned, publish),
            }
        }
    }

    fn follow(&mut self, planned: Planned, publish: &mut impl FnMut(String)) {
        let geometry = Geometry::of(&planned.plan);
        if self
            .first_seq
            .is_some_and(|first| first >= geometry.planned_end())
        {
            // Over before the server read its first sample.
            return;
        }
        if self.followed.len() >= MAX_FOLLOWED {
            publish(unavailable(
                &planned.label,
                &format!("the live server follows at most {MAX_FOLLOWED} measurements at once"),
                &self.run_dir,
            ));
            return;
        }
        // One ordered while an earlier one had not started replaces it
        // in the plant (shared/node/src/measure_orders.rs): that one will
        // not run, and its collector must not take the new one's ticks.
        let later = geometry.planned_start;
        self.followed.retain_mut(|c| {
            let replaced = c.start.is_none() && c.geometry.planned_end() <= later;
            if replaced {
                c.stop(
                    format!(
                        "the loop had not started it when the measurement planned at tick \
                         {later} was ordered"
                    ),
                    0,
                );
            }
            !replaced
        });
        let label = planned.label.clone();
        let estimator = match start_estimator(planned, self.run_dir.clone(), self.to_feed.clone()) {
            Ok(estimator) => estimator,
            Err(e) => {
                publish(unavailable(
                    &label,
                    &format!("cannot start its estimator's thread: {e}"),
                    &self.run_dir,
                ));
                return;
            }
        };
        let seen = self
            .first_seq
            .is_some_and(|first| first < geometry.planned_end());
        let mut collector = Collector::new(geometry, estimator, seen);
        // The ticks it may have started at, from the tick before its
        // planned start, as far back as the ring goes.
        let from = geometry.planned_start.saturating_sub(1);
        for s in self.history.iter().filter(|s| s.seq >= from) {
            if let Step::Ended = collector.add(s) {
                return;
            }
        }
        self.followed.push(collector);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc::sync_channel;
    use std::sync::{Arc, Mutex};

    fn geometry() -> Geometry {
        Geometry {
            planned_start: 100,
            n: 4,
            transient: 1,
            per_segment: 3,
            segments: 2,
        }
    }

    fn collector(queue: usize) -> (Collector, std::sync::mpsc::Receiver<Collected>) {
        let (periods, receive) = sync_channel(queue);
        let estimator = EstimatorHandle {
            periods,
            stop: Arc::new(Mutex::new(None)),
            queue_periods: queue,
        };
        (Collector::new(geometry(), estimator, false), receive)
    }

    fn sample(seq: u64, exciting: bool) -> Sample {
        Sample {
            seq,
            exciting,
            excitation: seq as f64,
            u: -(seq as f64),
            y: 0.5 * seq as f64,
            y_true: 0.25 * seq as f64,
        }
    }

    fn stop_of(c: &Collector) -> Option<Stop> {
        c.estimator.stop.lock().unwrap().clone()
    }

    #[test]
    fn periods_are_collected_from_the_first_excited_tick_and_fade_outs_skipped() {
        let (mut c, receive) = collector(64);
        // Started 3 ticks after its plan (an ordered one waits for the
        // plant's design): segments of (3 + 1) x 4 ticks from tick 103.
        let mut ended = false;
        for seq in 90..200 {
            let exciting = (103..103 + 32).contains(&seq);
            if let Step::Ended = c.add(&sample(seq, exciting)) {
                ended = true;
                break;
            }
        }
        assert!(ended);
        assert_eq!(stop_of(&c), None);
        let got: Vec<Collected> = receive.try_iter().collect();
        let Collected::Started { tick } = got[0] else {
            panic!("not started first");
        };
        assert_eq!(tick, 103);
        let periods: Vec<(usize, &PeriodData)> = got[1..]
            .iter()
            .map(|c| match c {
                Collected::Period { slot, data } => (*slot, data),
                Collected::Started { .. } => panic!("started twice"),
            })
            .collect();
        assert_eq!(periods.len(), 6);
        // Tone 2's first period starts after tone 1's three and its fade-out.
        let (slot, data) = periods[3];
        assert_eq!(slot, 3);
        assert_eq!(data.excitation, vec![119.0, 120.0, 121.0, 122.0]);
        assert_eq!(data.u, vec![-119.0, -120.0, -121.0, -122.0]);
        assert_eq!(data.y_true, vec![29.75, 30.0, 30.25, 30.5]);
    }

    #[test]
    fn a_missed_sample_of_a_period_stops_the_estimate_with_the_count() {
        let (mut c, receive) = collector(64);
        let mut step = Step::Going;
        for seq in (99..140).filter(|s| !(110..113).contains(s)) {
            step = c.add(&sample(seq, seq >= 100));
            if let Step::Ended = step {
                break;
            }
        }
        assert!(matches!(step, Step::Ended));
        let stop = stop_of(&c).unwrap();
        // Ticks 110, 111 of period 3 (ticks 108..112) were not seen.
        assert_eq!(stop.missed_samples, 2, "{stop:?}");
        assert!(stop.reason.contains("measured period 2"), "{stop:?}");
        // The two whole periods before it were handed on.
        assert_eq!(receive.try_iter().count(), 3);
    }

    #[test]
    fn a_start_the_server_did_not_see_is_not_guessed() {
        let (mut c, _receive) = collector(64);
        // Its first ticks went by unseen: 105 is excited, 104 was not seen.
        assert!(matches!(c.add(&sample(98, false)), Step::Going));
        assert!(matches!(c.add(&sample(105, true)), Step::Ended));
        let stop = stop_of(&c).unwrap();
        assert_eq!(stop.missed_samples, 5, "{stop:?}");
        // A measurement over before the server saw any of it ends quietly.
        let (mut c, _receive) = collector(64);
        assert!(matches!(c.add(&sample(500, false)), Step::Ended));
        assert_eq!(stop_of(&c), None);
        // One the plant started late, after its planned end (ticks 100 to
        // 132), is followed from its first excited tick.
        let (mut c, receive) = collector(64);
        for seq in 90..160 {
            assert!(matches!(c.add(&sample(seq, seq >= 150)), Step::Going));
        }
        let Some(Collected::Started { tick }) = receive.try_iter().next() else {
            panic!("not started");
        };
        assert_eq!(tick, 150);
    }

    #[test]
    fn an_estimator_far_behind_stops_the_estimate_instead_of_queueing_more() {
        let (mut c, _receive) = collector(2);
        let mut step = Step::Going;
        for seq in 100..140 {
            step = c.add(&sample(seq, true));
            if let Step::Ended = step {
                break;
            }
        }
        assert!(matches!(step, Step::Ended));
        assert!(stop_of(&c).unwrap().reason.contains("fell behind"));
    }

    #[test]
    fn the_history_holds_the_newest_ticks_only() {
        let mut feed = MeasureFeed {
            run_dir: PathBuf::new(),
            planner: None,
            to_feed: channel().0,
            from_workers: channel().1,
            history: VecDeque::with_capacity(HISTORY),
            first_seq: None,
            followed: Vec::new(),
        };
        let mut m = Measurement::default();
        for seq in 0..(HISTORY as u64 + 10) {
            m.seq = seq;
            feed.sample(&m);
        }
        assert_eq!(feed.history.len(), HISTORY);
        assert_eq!(feed.history.front().unwrap().seq, 10);
        assert_eq!(feed.first_seq, Some(0));
        assert!(feed.history.capacity() <= 2 * HISTORY);
    }
}
