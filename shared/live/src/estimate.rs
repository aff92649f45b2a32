//! `/measurement/response`, the work off the serving loop: each
//! measurement's plan, the design it is judged against, and its responses
//! over the periods collected so far (docs/live.md, "The measured
//! response"; docs/control.md §14).
//!
//! A planner thread makes the plan of the scenario's `[measure]` and of
//! each one ordered (a `measure` event) from the run directory, as
//! `flexloop measure` does (services/flexloop/run_measurements.rs): each
//! judged against the loop it measures, the scenario as the run started or
//! the supervisor's snapshot at the order. The crest factor's iterations
//! take milliseconds; the design (`LoopDesign`, up to hundreds of ms) is
//! made on a thread of its own while the transient periods run. An estimator thread per measurement takes the
//! periods the server collected and computes the responses with
//! `LoopMeasurement::compute`, the computation `flexloop measure RUN_DIR`
//! makes of the recording: on the same samples it gives the same numbers.

use flexloop_analysis::loop_measurement::{LoopMeasurement, LoopSignals, MIN_COHERENCE};
use flexloop_analysis::loop_report::PEAK_LIMIT_DB;
use flexloop_control::excitation::ExcitationPlan;
use flexloop_design::LoopDesign;
use flexloop_runfiles::RunDir;
use flexloop_scenario::schema::{MeasureSection, MeasureSignal};
use flexloop_scenario::{Overrides, Scenario};
use serde_json::{Value, json};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, RecvTimeoutError, Sender, SyncSender, sync_channel};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};
use std::time::Duration;

/// The most ticks of one segment (transient and measured periods) the
/// server holds to estimate a measurement live: 512 Ki ticks, 52 s of a
/// 10 kHz loop and 16 MB of its four signals. A longer one is told
/// "not estimated live"; `flexloop measure RUN_DIR` computes it from the
/// recording. The scenario check bounds a measurement by the run's
/// duration only, which may be a day or unbounded (`up`).
pub(crate) const MAX_SEGMENT_TICKS: usize = 1 << 19;
/// Collected periods queued for the estimator, in ticks: beyond them (an
/// estimator far behind) the live estimate stops instead of growing.
const QUEUE_TICKS: usize = 1 << 18;
/// Measure events waiting for the planner.
pub(crate) const PLAN_QUEUE: usize = 16;
/// How often a thread waiting for the design looks again.
const DESIGN_POLL: Duration = Duration::from_millis(20);

/// `flexloop measure`'s label of the scenario's own `[measure]`
/// (services/flexloop/run_measurements.rs).
const SCENARIO_LABEL: &str = "scenario";

/// `flexloop measure`'s label of a measurement ordered to start at
/// `start_seq`: the name of its folder.
fn ordered_label(start_seq: u64) -> String {
    RunDir::new("")
        .ordered_measurement(start_seq)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// What the planner is asked to plan.
pub(crate) enum PlanJob {
    /// The scenario's own `[measure]`.
    Scenario,
    /// One ordered on the running loop: its `measure` event.
    Ordered { table: String, start_seq: u64 },
}

impl PlanJob {
    fn label(&self) -> String {
        match self {
            PlanJob::Scenario => SCENARIO_LABEL.to_string(),
            PlanJob::Ordered { start_seq, .. } => ordered_label(*start_seq),
        }
    }
}

/// What the workers hand to the serving loop.
pub(crate) enum FromWorkers {
    /// A measurement to follow.
    Planned(Box<Planned>),
    /// A message for `/measurement/response`.
    Publish(String),
}

/// The design of one scenario text, filled once by its thread.
type DesignCell = Arc<OnceLock<Result<Arc<LoopDesign>, String>>>;

/// A measurement to follow: its plan and the design it is judged against.
pub(crate) struct Planned {
    pub label: String,
    pub plan: ExcitationPlan,
    design: DesignCell,
}

/// The planner: a thread that plans each job in turn. Its jobs' sender,
/// or why it could not start.
pub(crate) fn start_planner(
    run_dir: PathBuf,
    rate_hz: f64,
    out: Sender<FromWorkers>,
) -> std::io::Result<SyncSender<PlanJob>> {
    let (jobs, receive) = sync_channel::<PlanJob>(PLAN_QUEUE);
    std::thread::Builder::new()
        .name("live-measure-plan".into())
        .spawn(move || {
            let mut planner = Planner {
                run_dir,
                rate_hz,
                designed: None,
            };
            for job in receive {
                let sent = match planner.plan(&job) {
                    Ok(Some(planned)) => out.send(FromWorkers::Planned(Box::new(planned))),
                    Ok(None) => Ok(()),
                    Err(reason) => out.send(FromWorkers::Publish(unavailable(
                        &job.label(),
                        &reason,
                        &planner.run_dir,
                    ))),
                };
                if sent.is_err() {
                    return;
                }
            }
        })?;
    Ok(jobs)
}

struct Planner {
    run_dir: PathBuf,
    rate_hz: f64,
    /// The last scenario designed (its file and text: a relative model
    /// file is found from the file), and its design (being) made.
    designed: Option<(PathBuf, String, DesignCell)>,
}

impl Planner {
    /// The loop `job` measures, as `flexloop measure` judges it: the
    /// scenario's own `[measure]` the scenario the run started with, an
    /// ordered one the supervisor's snapshot at its order (else the
    /// scenario as it stands); at the loop's rate, and checked, as every
    /// command checks it. Its duration is not the loop's (the server is not
    /// told it): the measurement was checked against that when the loop
    /// started or it was ordered.
    fn scenario(&self, job: &PlanJob) -> Result<(Scenario, String), String> {
        let dir = RunDir::new(&self.run_dir);
        let file = match job {
            PlanJob::Scenario => dir.scenario_copy(),
            PlanJob::Ordered { start_seq, .. } => [
                dir.measured_scenario(*start_seq),
                dir.scenario_now(),
                dir.scenario_copy(),
            ]
            .into_iter()
            .find(|p| p.is_file())
            .unwrap_or_else(|| dir.scenario_copy()),
        };
        let text = flexloop_scenario::load::read_scenario_text(&file).map_err(|e| e.to_string())?;
        let overrides = Overrides {
            rate_hz: Some(self.rate_hz),
            duration_s: Some(0.0),
            no_realtime: true,
            ..Overrides::default()
        };
        let scenario = Scenario::from_text(&file, &text, &overrides).map_err(|e| e.to_string())?;
        Ok((scenario, text))
    }

    /// The design of `scenario` (whose file reads `text`): the one being
    /// made if file and text are the same, else a new one, on its own
    /// thread.
    fn design(&mut self, scenario: &Scenario, text: &str) -> DesignCell {
        if let Some((file, designed, cell)) = &self.designed
            && *file == scenario.source
            && designed == text
        {
            return Arc::clone(cell);
        }
        let cell: DesignCell = Arc::new(OnceLock::new());
        let filled = Arc::clone(&cell);
        let source = scenario.source.clone();
        let scenario = scenario.clone();
        let spawned = std::thread::Builder::new()
            .name("live-measure-design".into())
            .spawn(move || {
                let designed = std::panic::catch_unwind(|| LoopDesign::from_scenario(&scenario))
                    .map_err(|_| "the loop's design failed unexpectedly".to_string())
                    .and_then(|d| d.map(Arc::new).map_err(|e| e.to_string()));
                let _ = filled.set(designed);
            });
        if let Err(e) = spawned {
            let _ = cell.set(Err(format!("cannot start the design's thread: {e}")));
        }
        self.designed = Some((source, text.to_string(), Arc::clone(&cell)));
        cell
    }

    fn plan(&mut self, job: &PlanJob) -> Result<Option<Planned>, String> {
        let (scenario, text) = self.scenario(job)?;
        let (section, start_seq) = match job {
            PlanJob::Scenario => match &scenario.measure {
                Some(section) => (section.clone(), None),
                None => return Ok(None),
            },
            PlanJob::Ordered { table, start_seq } => (
                MeasureSection::from_table(table).map_err(|e| {
                    format!(
                        "{}: the [measure] of the measurement ordered at tick {start_seq}: {e}",
                        RunDir::new(&self.run_dir).events().display()
                    )
                })?,
                Some(*start_seq),
            ),
        };
        within_live_bounds(&section, self.rate_hz)?;
        // Started now, it is usually there by the first measured period
        // (the transient ones come first).
        let design = self.design(&scenario, &text);
        let mut measured = scenario;
        measured.timing.duration_s = 0.0;
        measured.measure = Some(section);
        let mut plan = measured
            .measurement_plan()
            .map_err(|e| e.to_string())?
            .ok_or_else(|| "the measurement has no plan".to_string())?;
        if let Some(start) = start_seq {
            // The supervisor's start (its table's `start_s` says the same
            // in seconds).
            plan.start_tick = start;
        }
        Ok(Some(Planned {
            label: job.label(),
            plan,
            design,
        }))
    }
}

/// Refuses, before the excitation is designed, a measurement whose segment
/// (or a stepped sine's tones, each a period of samples) the server would
/// not hold.
fn within_live_bounds(section: &MeasureSection, rate_hz: f64) -> Result<(), String> {
    let n = section.period_samples_at(rate_hz);
    let segment = (section.transient_periods + section.periods).saturating_mul(n);
    let tones = if section.signal == MeasureSignal::SteppedSine {
        section.lines.saturating_mul(n)
    } else {
        n
    };
    if segment.max(tones) > MAX_SEGMENT_TICKS {
        return Err(format!(
            "not estimated live: {} periods of {n} samples (and a stepped sine's tones) are more \
             than the {MAX_SEGMENT_TICKS} samples the live server holds of a measurement",
            section.transient_periods + section.periods
        ));
    }
    Ok(())
}

/// Told by the collector when the live estimate cannot go on.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Stop {
    pub reason: String,
    pub missed_samples: u64,
}

/// What the collector hands to a measurement's estimator.
pub(crate) enum Collected {
    /// The measurement's first tick: its first `EXCITING` one at or after
    /// the planned start.
    Started { tick: u64 },
    /// Period `slot` (segment after segment, each its transient then its
    /// measured periods), every sample of it.
    Period { slot: usize, data: PeriodData },
}

/// One period of the signals `flexloop measure` reads (`LoopSignals`).
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct PeriodData {
    pub excitation: Vec<f64>,
    pub u: Vec<f64>,
    pub y: Vec<f64>,
    pub y_true: Vec<f64>,
}

impl PeriodData {
    pub fn with_capacity(n: usize) -> Self {
        Self {
            excitation: Vec::with_capacity(n),
            u: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            y_true: Vec::with_capacity(n),
        }
    }
}

/// A measurement's estimator: its thread, the queue the collector fills
/// and the slot where the collector says why it stopped.
pub(crate) struct EstimatorHandle {
    pub periods: SyncSender<Collected>,
    pub stop: Arc<Mutex<Option<Stop>>>,
    /// Periods the queue holds at most.
    pub queue_periods: usize,
}

/// Starts the estimator of `planned`: it publishes through `out` and ends
/// (dropping the measurement's buffers) when the measurement is done, has
/// stopped, or its collector is gone.
pub(crate) fn start_estimator(
    planned: Planned,
    run_dir: PathBuf,
    out: Sender<FromWorkers>,
) -> std::io::Result<EstimatorHandle> {
    let queue_periods = (QUEUE_TICKS / planned.plan.period_samples().max(1)).clamp(2, 64);
    let (periods, receive) = sync_channel(queue_periods);
    let stop = Arc::new(Mutex::new(None));
    let told = Arc::clone(&stop);
    std::thread::Builder::new()
        .name("live-measure".into())
        .spawn(move || {
            let mut estimator = Estimator::new(planned, run_dir, out);
            estimator.run(&receive, &told);
        })?;
    Ok(EstimatorHandle {
        periods,
        stop,
        queue_periods,
    })
}

struct Estimator {
    label: String,
    plan: ExcitationPlan,
    design: DesignCell,
    run_dir: PathBuf,
    out: Sender<FromWorkers>,
    /// The first `EXCITING` tick.
    start: Option<u64>,
    /// The segment `record` holds, from its first tick.
    segment: usize,
    record: LoopSignals,
    /// The next period expected.
    next_slot: usize,
    /// Periods measured (after the transient ones) of `segment`.
    measured: usize,
    /// A stepped sine's tones computed so far, each on its own.
    tones: Vec<LoopMeasurement>,
    /// Measured periods of the last message.
    published: usize,
    /// The last message, which a stop repeats (the estimate over the
    /// periods before the miss is not wrong).
    last: Option<Value>,
}

enum Outcome {
    Going,
    /// Done, stopped or impossible: the estimator ends.
    Ended,
}

impl Estimator {
    fn new(planned: Planned, run_dir: PathBuf, out: Sender<FromWorkers>) -> Self {
        Self {
            label: planned.label,
            plan: planned.plan,
            design: planned.design,
            run_dir,
            out,
            start: None,
            segment: 0,
            record: LoopSignals::default(),
            next_slot: 0,
            measured: 0,
            tones: Vec::new(),
            published: 0,
            last: None,
        }
    }

    fn per_segment(&self) -> usize {
        self.plan.transient_periods + self.plan.periods
    }

    fn total_periods(&self) -> usize {
        self.plan.segments.len() * self.plan.periods
    }

    /// A stepped sine's tones are estimated one by one, each once all its
    /// periods are in; one periodic signal after each period.
    fn per_tone(&self) -> bool {
        self.plan.segments.len() > 1
    }

    fn run(&mut self, periods: &Receiver<Collected>, stop: &Mutex<Option<Stop>>) {
        loop {
            let stopped = stop.lock().unwrap_or_else(PoisonError::into_inner).take();
            if let Some(stop) = stopped {
                self.stopped(&stop);
                return;
            }
            // Until the design is there, it is looked for now and then.
            let received = if self.design.get().is_some() {
                periods.recv().map_err(|_| RecvTimeoutError::Disconnected)
            } else {
                periods.recv_timeout(DESIGN_POLL)
            };
            let next = match received {
                Ok(next) => Some(next),
                Err(RecvTimeoutError::Timeout) => None,
                // The collector is gone: the measurement ended (its last
                // period is in), stopped (said in the slot), or the server
                // stops.
                Err(RecvTimeoutError::Disconnected) => {
                    let stopped = stop.lock().unwrap_or_else(PoisonError::into_inner).take();
                    if let Some(stop) = stopped {
                        self.stopped(&stop);
                    } else if self.start.is_some() && self.wait_for_design().is_some() {
                        // Collected whole before the design was there:
                        // estimated now, period by period as ever.
                        self.advance();
                    }
                    return;
                }
            };
            let outcome = match next {
                Some(Collected::Started { tick }) => {
                    self.start = Some(tick);
                    Outcome::Going
                }
                Some(Collected::Period { slot, data }) => self.period(slot, data),
                None => self.advance(),
            };
            if let Outcome::Ended = outcome {
                return;
            }
        }
    }

    fn design(&self) -> Option<Result<Arc<LoopDesign>, String>> {
        self.design.get().cloned()
    }

    /// Waits for the design (a stepped sine's next tone would otherwise
    /// need a second segment's buffers); None if it failed (said).
    fn wait_for_design(&mut self) -> Option<Arc<LoopDesign>> {
        loop {
            match self.design() {
                Some(Ok(design)) => return Some(design),
                Some(Err(reason)) => {
                    self.publish(unavailable(
                        &self.label,
                        &format!("the loop's design: {reason}"),
                        &self.run_dir,
                    ));
                    return None;
                }
                None => std::thread::sleep(DESIGN_POLL),
            }
        }
    }

    fn period(&mut self, slot: usize, data: PeriodData) -> Outcome {
        if self.start.is_none() {
            return Outcome::Going;
        }
        if slot != self.next_slot {
            // The collector hands periods in order; one out of order would
            // make the record wrong.
            self.stopped(&Stop {
                reason: format!(
                    "period {slot} came where period {} was expected",
                    self.next_slot
                ),
                missed_samples: 0,
            });
            return Outcome::Ended;
        }
        let segment = slot / self.per_segment();
        if segment != self.segment {
            // A stepped sine's next tone: the previous one is computed
            // before its buffers go.
            if self.tones.len() < self.segment + 1 {
                if self.wait_for_design().is_none() {
                    return Outcome::Ended;
                }
                if let Outcome::Ended = self.advance() {
                    return Outcome::Ended;
                }
            }
            self.segment = segment;
            self.record = LoopSignals::default();
            self.measured = 0;
        }
        if self.record.u.is_empty() {
            let ticks = self.per_segment() * self.plan.period_samples();
            for signal in [
                &mut self.record.excitation,
                &mut self.record.u,
                &mut self.record.y,
                &mut self.record.y_true,
            ] {
                signal.reserve_exact(ticks);
            }
        }
        self.record.excitation.extend(data.excitation);
        self.record.u.extend(data.u);
        self.record.y.extend(data.y);
        self.record.y_true.extend(data.y_true);
        self.next_slot += 1;
        let j = slot % self.per_segment();
        if j >= self.plan.transient_periods {
            self.measured = j + 1 - self.plan.transient_periods;
        }
        self.advance()
    }

    /// Computes and publishes what the periods in allow, once the design
    /// is there: each further period of one periodic signal (every count
    /// in turn, so that the messages do not depend on when the design came),
    /// each further tone of a stepped sine.
    fn advance(&mut self) -> Outcome {
        let (Some(start), Some(designed)) = (self.start, self.design()) else {
            return Outcome::Going;
        };
        let design = match designed {
            Ok(design) => design,
            Err(reason) => {
                self.publish(unavailable(
                    &self.label,
                    &format!("the loop's design: {reason}"),
                    &self.run_dir,
                ));
                return Outcome::Ended;
            }
        };
        if self.per_tone() {
            if self.measured < self.plan.periods || self.tones.len() > self.segment {
                return Outcome::Going;
            }
            let tone = self.part(
                self.segment..self.segment + 1,
                start + self.segment as u64 * self.plan.segment_ticks(),
                self.plan.periods,
            );
            match LoopMeasurement::compute(&design, &tone, &self.record) {
                Ok(m) => self.tones.push(m),
                Err(e) => {
                    // `flexloop measure` refuses the whole for it too.
                    self.publish_estimate("failed", None, Some(e.to_string()));
                    return Outcome::Ended;
                }
            }
            let done = self.tones.len() * self.plan.periods;
            if let Some(joined) = self.joined() {
                self.publish_estimate(self.state(done), Some((&joined, done)), None);
            }
            return self.ended_if_done(done);
        }
        while self.published < self.measured {
            let done = self.published + 1;
            let sofar = self.part(0..1, start, done);
            match LoopMeasurement::compute(&design, &sofar, &self.record) {
                Ok(m) => self.publish_estimate(self.state(done), Some((&m, done)), None),
                // Every period so far touched the actuator's limit, or a
                // sample is not a number: said, and the next period may do.
                Err(e) => {
                    let state = match self.state(done) {
                        "done" => "failed",
                        going => going,
                    };
                    self.publish_estimate(state, None, Some(e.to_string()));
                }
            }
            self.published = done;
        }
        self.ended_if_done(self.published)
    }

    /// The plan of `segments` from `start_tick`, `periods` of each
    /// measured: what the periods in make of the whole.
    fn part(
        &self,
        segments: std::ops::Range<usize>,
        start_tick: u64,
        periods: usize,
    ) -> ExcitationPlan {
        ExcitationPlan {
            point: self.plan.point,
            shape: self.plan.shape,
            segments: self.plan.segments[segments].to_vec(),
            start_tick,
            transient_periods: self.plan.transient_periods,
            periods,
        }
    }

    fn state(&self, done: usize) -> &'static str {
        if done >= self.total_periods() {
            "done"
        } else {
            "measuring"
        }
    }

    fn ended_if_done(&self, done: usize) -> Outcome {
        if done >= self.total_periods() {
            Outcome::Ended
        } else {
            Outcome::Going
        }
    }

    /// The stepped sine's tones so far as one measurement, their lines in
    /// the order they ran (as `LoopMeasurement::compute` joins them).
    fn joined(&self) -> Option<LoopMeasurement> {
        let mut tones = self.tones.iter();
        let first = tones.next()?.clone();
        let mut joined = LoopMeasurement {
            plan: self.part(
                0..self.tones.len(),
                first.plan.start_tick,
                self.plan.periods,
            ),
            ..first
        };
        for (i, tone) in tones.enumerate() {
            let tone_index = i + 1;
            for (all, more) in joined.responses.iter_mut().zip(&tone.responses) {
                all.measured
                    .frequencies_hz
                    .extend(&more.measured.frequencies_hz);
                all.measured.response.extend(&more.measured.response);
                all.measured.coherence.extend(&more.measured.coherence);
                all.predicted = match (all.predicted.take(), &more.predicted) {
                    (Some(mut lines), Some(more)) => {
                        lines.extend(more);
                        Some(lines)
                    }
                    _ => None,
                };
            }
            joined.periods_used += tone.periods_used;
            joined.periods_saturated.extend(
                tone.periods_saturated
                    .iter()
                    .map(|p| tone_index * self.plan.periods + p),
            );
        }
        Some(joined)
    }

    fn base(&self, state: &str) -> Value {
        json!({
            "measurement": self.label,
            "state": state,
            "start_tick": self.start,
            "planned_start_tick": self.plan.start_tick,
            "point": self.plan.point.name(),
            "signal": self.plan.shape.name(),
            "period_samples": self.plan.period_samples(),
            "transient_periods": self.plan.transient_periods,
            "periods_done": 0,
            "periods_total": self.total_periods(),
        })
    }

    fn publish_estimate(
        &mut self,
        state: &str,
        estimate: Option<(&LoopMeasurement, usize)>,
        note: Option<String>,
    ) {
        let mut message = self.base(state);
        if let Some((m, done)) = estimate {
            message["periods_done"] = json!(done);
            fill(&mut message, m);
        } else if let Some(last) = &self.last {
            message["periods_done"] = last["periods_done"].clone();
        }
        if let Some(note) = note {
            message["note"] = json!(note);
        }
        if estimate.is_some() {
            self.last = Some(message.clone());
        }
        self.publish(message.to_string());
    }

    /// The live estimate stops: the last one (over the periods before the
    /// miss) stands, marked, with why and where the whole one comes from.
    fn stopped(&mut self, stop: &Stop) {
        eprintln!(
            "flexloop-live: the live estimate of measurement {} stopped: {}",
            self.label, stop.reason
        );
        let mut message = self.last.clone().unwrap_or_else(|| self.base("stopped"));
        message["state"] = json!("stopped");
        message["start_tick"] = json!(self.start);
        message["missed_samples"] = json!(stop.missed_samples);
        message["note"] = json!(format!(
            "the live estimate stopped: {}; `flexloop measure {}` computes the measurement from \
             the recording",
            stop.reason,
            self.run_dir.display()
        ));
        self.publish(message.to_string());
    }

    fn publish(&self, json: String) {
        let _ = self.out.send(FromWorkers::Publish(json));
    }
}

/// The estimate's lines and responses into `message`, as arrays a plot
/// draws against `frequencies_hz`.
fn fill(message: &mut Value, m: &LoopMeasurement) {
    let frequencies = m.plan.frequencies_hz();
    message["log10_frequencies_hz"] =
        json!(frequencies.iter().map(|f| f.log10()).collect::<Vec<_>>());
    message["frequencies_hz"] = json!(frequencies);
    let mut responses = serde_json::Map::new();
    for r in &m.responses {
        let mut one = json!({
            "meaning": r.meaning,
            "magnitude_db": r.measured.magnitude_db(),
            "phase_deg": r.measured.response.iter().map(|h| h.arg().to_degrees()).collect::<Vec<_>>(),
            "coherence": r.measured.coherence,
        });
        if let Some(predicted) = &r.predicted {
            one["model_magnitude_db"] = json!(
                predicted
                    .iter()
                    .map(|h| 20.0 * h.norm().log10())
                    .collect::<Vec<_>>()
            );
            one["model_phase_deg"] = json!(
                predicted
                    .iter()
                    .map(|h| h.arg().to_degrees())
                    .collect::<Vec<_>>()
            );
        }
        responses.insert(r.name.to_string(), one);
    }
    message["responses"] = Value::Object(responses);
    message["periods_used"] = json!(m.periods_used);
    message["periods_saturated"] = json!(m.periods_saturated);
    let sensitivity = m.sensitivity();
    let rule = m.rule();
    let model = sensitivity.predicted_peak_db();
    message["sensitivity"] = json!({
        "response": sensitivity.name,
        "peak_db": rule.map(|r| r.0),
        "peak_hz": rule.map(|r| r.1),
        "keeps_6db_rule": rule.map(|r| r.2),
        "limit_db": PEAK_LIMIT_DB,
        "min_coherence": MIN_COHERENCE,
        "model_peak_db": model.map(|m| m.0),
        "model_peak_hz": model.map(|m| m.1),
    });
}

/// A measurement the server does not estimate live, and why.
pub(crate) fn unavailable(label: &str, reason: &str, run_dir: &Path) -> String {
    json!({
        "measurement": label,
        "state": "unavailable",
        "note": format!(
            "{reason}; `flexloop measure {}` computes the measurement from the recording",
            run_dir.display()
        ),
    })
    .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_control::excitation::{ExcitationShape, InjectionPoint, ScheduledExcitation};
    use flexloop_control::multisine::{Multisine, MultisineSpec, Phases};
    use std::sync::mpsc::channel;

    const RATE: f64 = 10_000.0;
    const N: usize = 200;

    /// The lecture's loop (a double integrator under state feedback): a
    /// design to judge against, made in milliseconds.
    fn design() -> Arc<LoopDesign> {
        let file = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../scenarios/lecture-double-integrator.toml");
        let scenario = Scenario::load(&file, &Overrides::default()).unwrap();
        Arc::new(LoopDesign::from_scenario(&scenario).unwrap())
    }

    fn plan(shape: ExcitationShape) -> ExcitationPlan {
        let spec = MultisineSpec {
            rate_hz: RATE,
            period_samples: N,
            f_min_hz: 50.0,
            f_max_hz: 2_000.0,
            max_lines: 6,
            amplitude: 1.0,
            phases: Phases::Schroeder,
        };
        let signal = Multisine::design(&spec).unwrap();
        let segments = match shape {
            ExcitationShape::SteppedSine => signal
                .bins
                .iter()
                .map(|&b| Multisine::tone(RATE, N, b, 1.0))
                .collect(),
            _ => vec![signal],
        };
        ExcitationPlan {
            point: InjectionPoint::PlantInput,
            shape,
            segments,
            start_tick: 1_000,
            transient_periods: 2,
            periods: 3,
        }
    }

    /// Signals of the plan's ticks: the excitation as the plant adds it,
    /// and outputs that are any deterministic, periodic-plus-noise
    /// function of it (the estimate reads records, not a loop).
    fn signals(plan: &ExcitationPlan, start: u64) -> LoopSignals {
        let mut scheduled = ScheduledExcitation::new(&ExcitationPlan {
            start_tick: start,
            ..plan.clone()
        });
        let mut s = LoopSignals::default();
        let mut previous = 0.0;
        for k in start..start + (plan.stop_tick() - plan.start_tick) {
            let d = scheduled.value_at(k);
            let noise = 1e-3 * ((k * 7919 % 1013) as f64 / 1013.0 - 0.5);
            s.excitation.push(d);
            s.u.push(-0.4 * previous + noise);
            s.y.push(0.7 * d + 0.2 * previous + noise);
            s.y_true.push(0.7 * d + 0.2 * previous);
            previous = d;
        }
        s
    }

    /// The plan's periods as the collector hands them, started `delay`
    /// ticks after its plan: the start and each period.
    fn collected(plan: &ExcitationPlan, delay: u64) -> (u64, Vec<(usize, PeriodData)>) {
        let start = plan.start_tick + delay;
        let all = signals(plan, start);
        let per_segment = plan.transient_periods + plan.periods;
        let periods = (0..plan.segments.len() * per_segment)
            .map(|slot| {
                let from = (slot / per_segment) * (per_segment + 1) * N + (slot % per_segment) * N;
                let cut = |v: &[f64]| v[from..from + N].to_vec();
                let data = PeriodData {
                    excitation: cut(&all.excitation),
                    u: cut(&all.u),
                    y: cut(&all.y),
                    y_true: cut(&all.y_true),
                };
                (slot, data)
            })
            .collect();
        (start, periods)
    }

    fn messages(published: &Receiver<FromWorkers>) -> Vec<Value> {
        published
            .try_iter()
            .map(|p| match p {
                FromWorkers::Publish(json) => serde_json::from_str(&json).unwrap(),
                FromWorkers::Planned(_) => panic!("an estimator plans nothing"),
            })
            .collect()
    }

    /// Runs an estimator over the plan's periods, started `delay` ticks
    /// after its plan, as the collector hands them: its messages.
    fn estimated(plan: &ExcitationPlan, delay: u64) -> Vec<Value> {
        let cell: DesignCell = Arc::new(OnceLock::new());
        let _ = cell.set(Ok(design()));
        let (out, published) = channel();
        let mut estimator = Estimator::new(
            Planned {
                label: "at-1000".into(),
                plan: plan.clone(),
                design: cell,
            },
            PathBuf::from("/runs/x"),
            out,
        );
        let (start, periods) = collected(plan, delay);
        estimator.start = Some(start);
        let slots = periods.len();
        for (slot, data) in periods {
            let outcome = estimator.period(slot, data);
            assert_eq!(
                matches!(outcome, Outcome::Ended),
                slot + 1 == slots,
                "slot {slot}"
            );
        }
        messages(&published)
    }

    /// A measurement short beside its design (a lockstep loop is fast)
    /// is collected whole before the design is there: every count is
    /// estimated once it comes, the same messages.
    #[test]
    fn a_measurement_collected_before_its_design_is_estimated_once_it_comes() {
        let plan = plan(ExcitationShape::Multisine);
        let cell: DesignCell = Arc::new(OnceLock::new());
        let (out, published) = channel();
        let planned = Planned {
            label: "at-1000".into(),
            plan: plan.clone(),
            design: Arc::clone(&cell),
        };
        let handle = start_estimator(planned, PathBuf::from("/runs/x"), out).unwrap();
        let (start, periods) = collected(&plan, 0);
        handle
            .periods
            .send(Collected::Started { tick: start })
            .unwrap();
        for (slot, data) in periods {
            handle
                .periods
                .send(Collected::Period { slot, data })
                .unwrap();
        }
        // The collection ended; then the design comes.
        drop(handle);
        let _ = cell.set(Ok(design()));
        let mut got = Vec::new();
        while got.len() < 3 {
            match published.recv_timeout(Duration::from_secs(120)) {
                Ok(FromWorkers::Publish(json)) => {
                    got.push(serde_json::from_str::<Value>(&json).unwrap())
                }
                _ => panic!("{} messages, then none", got.len()),
            }
        }
        let done: Vec<&Value> = got.iter().map(|m| &m["periods_done"]).collect();
        assert_eq!(done, [1, 2, 3]);
        assert_is_the_whole(&plan, 0, &got[2]);
    }

    /// The last message is `LoopMeasurement::compute` over the whole
    /// record (what `flexloop measure` computes from the recording).
    fn assert_is_the_whole(plan: &ExcitationPlan, delay: u64, last: &Value) {
        let start = plan.start_tick + delay;
        let whole = ExcitationPlan {
            start_tick: start,
            ..plan.clone()
        };
        let m = LoopMeasurement::compute(&design(), &whole, &signals(plan, start)).unwrap();
        // Equal but for the last bit serde_json's parser may round
        // differently from the number printed.
        let close = |shown: &Value, computed: &[f64], what: &str| {
            let shown = shown.as_array().unwrap();
            assert_eq!(shown.len(), computed.len(), "{what}");
            for (a, b) in shown.iter().zip(computed) {
                let a = a.as_f64().unwrap();
                assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0), "{what}: {a} {b}");
            }
        };
        close(&last["frequencies_hz"], &plan.frequencies_hz(), "lines");
        for r in &m.responses {
            let shown = &last["responses"][r.name];
            close(&shown["magnitude_db"], &r.measured.magnitude_db(), r.name);
            close(&shown["coherence"], &r.measured.coherence, r.name);
        }
        let (db, hz, keeps) = m.rule().unwrap();
        close(&json!([last["sensitivity"]["peak_db"]]), &[db], "peak");
        close(
            &json!([last["sensitivity"]["peak_hz"]]),
            &[hz],
            "peak's line",
        );
        assert_eq!(last["sensitivity"]["keeps_6db_rule"], json!(keeps));
        assert_eq!(last["start_tick"], json!(start));
        assert_eq!(last["state"], "done");
    }

    #[test]
    fn one_periodic_signal_is_estimated_after_each_period_and_ends_as_the_whole() {
        let plan = plan(ExcitationShape::Multisine);
        let messages = estimated(&plan, 7);
        let done: Vec<u64> = messages
            .iter()
            .map(|m| m["periods_done"].as_u64().unwrap())
            .collect();
        assert_eq!(done, [1, 2, 3]);
        assert_eq!(messages[0]["state"], "measuring");
        assert!(messages[0]["responses"]["S_i"]["model_magnitude_db"].is_array());
        assert_is_the_whole(&plan, 7, messages.last().unwrap());
    }

    #[test]
    fn a_stepped_sine_is_estimated_tone_by_tone_and_ends_as_the_whole() {
        let plan = plan(ExcitationShape::SteppedSine);
        let tones = plan.segments.len();
        assert!(tones > 2);
        let messages = estimated(&plan, 0);
        assert_eq!(messages.len(), tones);
        for (i, m) in messages.iter().enumerate() {
            assert_eq!(m["periods_done"], json!((i + 1) * 3));
            assert_eq!(m["frequencies_hz"].as_array().unwrap().len(), i + 1);
        }
        assert_is_the_whole(&plan, 0, messages.last().unwrap());
    }

    #[test]
    fn a_stop_keeps_the_last_estimate_and_says_where_the_whole_one_comes_from() {
        let plan = plan(ExcitationShape::Multisine);
        let (out, published) = channel();
        let cell: DesignCell = Arc::new(OnceLock::new());
        let _ = cell.set(Err("no design".into()));
        let mut estimator = Estimator::new(
            Planned {
                label: "scenario".into(),
                plan,
                design: cell,
            },
            PathBuf::from("/runs/x"),
            out,
        );
        estimator.stopped(&Stop {
            reason: "its reader missed 3 samples".into(),
            missed_samples: 3,
        });
        let Ok(FromWorkers::Publish(json)) = published.try_recv() else {
            panic!("nothing published");
        };
        let message: Value = serde_json::from_str(&json).unwrap();
        assert_eq!(message["state"], "stopped");
        assert_eq!(message["missed_samples"], 3);
        assert_eq!(message["periods_done"], 0);
        let note = message["note"].as_str().unwrap();
        assert!(
            note.contains("missed 3 samples") && note.contains("`flexloop measure /runs/x`"),
            "{note}"
        );
    }

    #[test]
    fn a_measurement_too_long_to_hold_is_refused_before_it_is_designed() {
        let mut section = MeasureSection::from_table(
            "[measure]\npoint = \"plant-input\"\nf_min_hz = 0.01\nf_max_hz = 100\namplitude = 1\n",
        )
        .unwrap();
        let refused = within_live_bounds(&section, RATE).unwrap_err();
        assert!(refused.contains("not estimated live"), "{refused}");
        section.f_min_hz = 10.0;
        assert_eq!(within_live_bounds(&section, RATE), Ok(()));
        section.signal = MeasureSignal::SteppedSine;
        section.lines = 128;
        section.f_min_hz = 1.0;
        assert!(within_live_bounds(&section, RATE).is_err());
    }
}
