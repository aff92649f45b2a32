//! The observer process's work: one step of the observer block per measurement.
//!
//! Processing y(k), u_a(k) moves the block to s(k+1) and yields the estimate
//! for tick k+1: its free response C s(k+1) and its direct gain D. The
//! controller adds D·[y(k+1); u_a(k+1)] itself when y(k+1) arrives, so the
//! observer is never on the critical path between y(k+1) and u(k+1).

use crate::estimation_law::{EstimationLaw, ObserverSetup, SetupError};
use crate::handover::Fingerprint;
use flexloop_control::lti::LtiRunner;
use flexloop_control::scheduled_observer::ScheduledObserver;
use flexloop_design::LoopDesign;
use flexloop_design::reference::Reference;
use flexloop_design::sensor_scan::SensorScan;
use flexloop_design::{ObserverBlock, OutputPrediction};
use flexloop_protocol::{
    Estimate, Handover, MAX_HANDOVER_STATES, MAX_OBSERVER_INPUTS, MAX_OBSERVER_OUTPUTS, MAX_STATES,
    Measurement,
};
use nalgebra::{DMatrix, DVector, DVectorView};

/// The observer of a sensor the structure scans past: its gain follows the
/// position of each tick (docs/control.md §1.4).
struct Scheduled {
    observer: ScheduledObserver,
    scan: SensorScan,
    reference: Reference,
    ts: f64,
    /// Running state [x̂; w; P] for hand-overs (a design whose state does
    /// not fit a hand-over message hands over nothing).
    state: Vec<f64>,
    /// Ticks whose gain could not be scheduled (the previous one stayed).
    errors: u64,
}

pub struct ObserverCore {
    scheduled: Option<Scheduled>,
    block: LtiRunner,
    estimate_map: DMatrix<f64>,
    x_hat: DVector<f64>,
    prediction: OutputPrediction,
    /// ŷ(k|k−1), then the innovation y(k) − ŷ(k|k−1).
    innovation: DVector<f64>,
    n_outputs: usize,
    n_inputs: usize,
    /// Inputs of the block: [y; u_a] or, with extra loop delay, [y; u_a; u_pending].
    n_block_inputs: usize,
    input: [f64; MAX_OBSERVER_INPUTS],
    /// Direct gain laid out as the message wants it, computed once.
    direct: [f64; MAX_OBSERVER_OUTPUTS * MAX_OBSERVER_INPUTS],
    next_seq: u64,
    design_hash: u64,
    /// Fingerprint of the model x̂ is the state of (and of the output
    /// prediction): another design with the same one continues this
    /// observer's estimate at a swap. 0: its estimate cannot be continued
    /// (a scheduled observer, or a block without a leading x̂).
    model_hash: u64,
    /// Samples for an error in the block's state to shrink a millionfold
    /// (see [`settling_samples`]).
    settling_samples: u64,
}

/// An error in an observer block's state decays as the block's state
/// matrix's powers: by ρ(A)^k after k samples, so by a millionfold after
/// ln(1e-6) / ln ρ(A). A millionfold, since a restart mid-scan starts
/// thousands of newtons of u_d away from the loop's (the default scenario:
/// 5 576 N) and must end below its ordinary fraction of a newton. Capped at
/// `cap` (a block with a pole on or near the unit circle never settles).
pub fn settling_samples(a: &nalgebra::DMatrix<f64>, cap: u64) -> u64 {
    match flexloop_control::linalg::spectral_radius(a) {
        // A nilpotent block forgets its state at once.
        Ok(0.0) => 1,
        Ok(rho) if rho < 1.0 => ((1e-6f64).ln() / rho.ln()).ceil().min(cap as f64) as u64,
        _ => cap,
    }
}

/// Why an observer block does not fit the protocol.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ObserverSizeError(pub String);

impl std::fmt::Display for ObserverSizeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ObserverSizeError {}

impl ObserverCore {
    /// The observer the design runs: the fixed block, or the one scheduled
    /// on a scanned sensor's position.
    pub fn for_design(design: &LoopDesign) -> Result<Self, ObserverSizeError> {
        let mut core = Self::new(
            &design.observer,
            &design.output_prediction,
            design.n_outputs,
            design.n_inputs,
        )?;
        if let Some(scan) = &design.sensor_scan
            && let Some(o) = &scan.observer
        {
            let p0 = scan.position_of_tick(&design.reference, 0, design.ts);
            let observer = ScheduledObserver::new(o.clone(), p0)
                .map_err(|e| ObserverSizeError(format!("scheduled observer: {e}")))?;
            if o.block_states() > MAX_STATES || o.block_inputs() != core.n_block_inputs {
                return Err(ObserverSizeError(format!(
                    "scheduled observer has {} states and {} inputs (at most {MAX_STATES}; the loop has {})",
                    o.block_states(),
                    o.block_inputs(),
                    core.n_block_inputs
                )));
            }
            core.design_hash = Fingerprint::default()
                .bytes(&core.design_hash.to_le_bytes())
                .matrix(o.schedule.models().a())
                .number(scan.from)
                .number(scan.to)
                .number(o.schedule.models().grid().step())
                .number(f64::from(u8::from(
                    o.gains == flexloop_control::scheduled_observer::GainScheduling::TimeVarying,
                )))
                .value();
            // Its gain follows the sensor: its estimate is its own.
            core.model_hash = 0;
            core.scheduled = Some(Scheduled {
                state: vec![0.0; observer.state_len()],
                observer,
                scan: scan.clone(),
                reference: design.reference.clone(),
                ts: design.ts,
                errors: 0,
            });
        }
        Ok(core)
    }

    /// Ticks whose scheduled gain could not be updated (0 for a fixed observer).
    pub fn schedule_errors(&self) -> u64 {
        self.scheduled.as_ref().map_or(0, |s| s.errors)
    }

    pub fn new(
        block: &ObserverBlock,
        prediction: &OutputPrediction,
        n_outputs: usize,
        n_inputs: usize,
    ) -> Result<Self, ObserverSizeError> {
        let sys = &block.system;
        let n_block_inputs = n_outputs + n_inputs * (1 + block.extra_delay_samples);
        if sys.inputs() != n_block_inputs || sys.outputs() != n_outputs + n_inputs {
            return Err(ObserverSizeError(format!(
                "observer block has {} inputs and {} outputs, the loop needs {} and {}",
                sys.inputs(),
                sys.outputs(),
                n_block_inputs,
                n_outputs + n_inputs
            )));
        }
        if n_block_inputs > MAX_OBSERVER_INPUTS
            || sys.outputs() > MAX_OBSERVER_OUTPUTS
            || block.estimate_map.nrows() > MAX_STATES
        {
            return Err(ObserverSizeError(format!(
                "observer too large for the protocol ({} signals, {} states; at most {} and {})",
                n_block_inputs,
                block.estimate_map.nrows(),
                MAX_OBSERVER_INPUTS,
                MAX_STATES
            )));
        }
        if block.estimate_map.ncols() != sys.states() {
            return Err(ObserverSizeError(format!(
                "estimate map has {} columns, the block {} states",
                block.estimate_map.ncols(),
                sys.states()
            )));
        }
        let n_est = block.estimate_map.nrows();
        if prediction.c.shape() != (n_outputs, n_est)
            || prediction.d.shape() != (n_outputs, n_inputs)
        {
            return Err(ObserverSizeError(format!(
                "output prediction is {:?} and {:?}, the loop needs ({n_outputs}, {n_est}) and ({n_outputs}, {n_inputs})",
                prediction.c.shape(),
                prediction.d.shape()
            )));
        }
        let mut direct = [0.0; MAX_OBSERVER_OUTPUTS * MAX_OBSERVER_INPUTS];
        for i in 0..sys.outputs() {
            for j in 0..sys.inputs() {
                direct[i * MAX_OBSERVER_INPUTS + j] = sys.d[(i, j)];
            }
        }
        let design_hash = Fingerprint::default()
            .system(sys)
            .matrix(&block.estimate_map)
            .matrix(&prediction.c)
            .matrix(&prediction.d)
            .value();
        // x̂ must be the block's leading states (s = [x̂; w], the layout of
        // flexloop_control::observer_block) for another design to take it.
        let leading = n_est <= sys.states()
            && block.estimate_map.ncols() == sys.states()
            && (0..n_est).all(|i| {
                (0..sys.states())
                    .all(|j| block.estimate_map[(i, j)] == if i == j { 1.0 } else { 0.0 })
            });
        let model_hash = match &block.model {
            Some(model) if leading && n_est > 0 && model.states() == n_est => {
                Fingerprint::default()
                    .system(model)
                    .matrix(&prediction.c)
                    .matrix(&prediction.d)
                    .value()
            }
            _ => 0,
        };
        // At most a second of samples.
        let cap = if sys.ts > 0.0 {
            (1.0 / sys.ts).ceil() as u64
        } else {
            1
        };
        Ok(Self {
            scheduled: None,
            design_hash,
            model_hash,
            settling_samples: settling_samples(&sys.a, cap),
            x_hat: DVector::zeros(n_est),
            prediction: prediction.clone(),
            innovation: DVector::zeros(n_outputs),
            estimate_map: block.estimate_map.clone(),
            block: LtiRunner::new(sys.clone()),
            n_outputs,
            n_inputs,
            n_block_inputs,
            input: [0.0; MAX_OBSERVER_INPUTS],
            direct,
            next_seq: 0,
        })
    }

    /// The estimate for tick 0, before any measurement (initial state).
    pub fn initial(&mut self, out: &mut Estimate) {
        self.fill(0, out);
    }

    /// Processes measurement k and fills the estimate for tick k+1 (all but
    /// the timestamps, which the caller sets).
    pub fn step(&mut self, m: &Measurement, out: &mut Estimate) {
        let (ny, nu) = (self.n_outputs, self.n_inputs);
        self.input[..ny].copy_from_slice(&m.y[..ny]);
        self.input[ny..ny + nu].copy_from_slice(&m.u_applied[..nu]);
        if self.n_block_inputs > ny + nu {
            self.input[ny + nu..ny + 2 * nu].copy_from_slice(&m.u_pending[..nu]);
        }
        if let Some(sched) = &mut self.scheduled {
            let next = sched
                .scan
                .position_of_tick(&sched.reference, m.seq + 1, sched.ts);
            if sched
                .observer
                .advance(
                    &self.input[..self.n_block_inputs],
                    next,
                    self.innovation.as_mut_slice(),
                )
                .is_err()
            {
                sched.errors += 1;
            }
            self.fill(m.seq + 1, out);
            out.innovation[..ny].copy_from_slice(self.innovation.as_slice());
            out.source_tick_ns = m.tick_ns;
            out.source_published_ns = m.published_ns;
            return;
        }
        // Innovation of y(k) against x̂(k|k−1), which `x_hat` holds from the last fill.
        let u_applied = DVectorView::from_slice(&m.u_applied[..nu], nu);
        self.innovation
            .gemv(1.0, &self.prediction.c, &self.x_hat, 0.0);
        self.innovation
            .gemv(1.0, &self.prediction.d, &u_applied, 1.0);
        for i in 0..ny {
            self.innovation[i] = m.y[i] - self.innovation[i];
        }
        self.block.advance(&self.input[..self.n_block_inputs]);
        self.fill(m.seq + 1, out);
        out.innovation[..ny].copy_from_slice(self.innovation.as_slice());
        out.source_tick_ns = m.tick_ns;
        out.source_published_ns = m.published_ns;
    }

    /// Fingerprint of the observer design.
    pub fn design_hash(&self) -> u64 {
        self.design_hash
    }

    /// Fingerprint of the model its estimate x̂ is the state of; 0 when
    /// another design cannot continue its estimate.
    pub fn model_hash(&self) -> u64 {
        self.model_hash
    }

    /// Writes the block state into `out` (none if it is too large to hand over).
    pub fn save(&self, out: &mut Handover) {
        let x = match &self.scheduled {
            Some(sched) => sched.state.as_slice(),
            None => self.block.state(),
        };
        out.design_hash = self.design_hash;
        out.carried_hash = 0;
        out.carried_at = 0;
        out.carried_len = 0;
        if x.len() > MAX_HANDOVER_STATES {
            out.n_states = 0;
            out.design_hash = 0;
            return;
        }
        out.n_states = x.len() as u32;
        out.n_inputs = self.n_inputs as u32;
        out.state[..x.len()].copy_from_slice(x);
        if self.model_hash != 0 {
            // x̂ leads the block state (checked in `new`).
            out.carried_hash = self.model_hash;
            out.carried_len = self.x_hat.len() as u32;
        }
    }

    /// Takes over the block state of an identical design, whose next estimate
    /// is for `from.seq + 1`; false (and nothing changed) otherwise.
    pub fn load(&mut self, from: &Handover) -> bool {
        if let Some(sched) = &mut self.scheduled {
            let n = sched.state.len();
            if from.design_hash != self.design_hash
                || from.n_states as usize != n
                || n > MAX_HANDOVER_STATES
                || from.state[..n].iter().any(|v| !v.is_finite())
            {
                return false;
            }
            let next = sched
                .scan
                .position_of_tick(&sched.reference, from.seq + 1, sched.ts);
            if sched.observer.set_state(&from.state[..n], next).is_err() {
                return false;
            }
            sched.state.copy_from_slice(&from.state[..n]);
            let n = self.x_hat.len();
            let x = sched.observer.estimate();
            self.x_hat.as_mut_slice().copy_from_slice(&x[..n]);
            self.next_seq = from.seq + 1;
            return true;
        }
        let n = self.block.state().len();
        if from.design_hash != self.design_hash {
            return self.continue_estimate(from);
        }
        if from.n_states as usize != n
            || n > MAX_HANDOVER_STATES
            || from.state[..n].iter().any(|v| !v.is_finite())
        {
            return false;
        }
        self.block.set_state(&from.state[..n]);
        // x̂ feeds the next innovation: recompute it from the new state.
        let s = DVectorView::from_slice(self.block.state(), n);
        self.x_hat.gemv(1.0, &self.estimate_map, &s, 0.0);
        self.next_seq = from.seq + 1;
        true
    }

    /// Another design on the same model (another Kalman gain, damping or
    /// band-pass): its x̂ continues the running observer's estimate, and
    /// the rest of its block (the active damping's K(z)) keeps its own
    /// state, which has followed that estimate in shadow. So at the
    /// boundary the command changes by what the designs differ in, not by
    /// an estimate started from zero mid-scan. False (nothing changed) for
    /// another model.
    fn continue_estimate(&mut self, from: &Handover) -> bool {
        let n_est = self.x_hat.len();
        let (at, len) = (from.carried_at as usize, from.carried_len as usize);
        let handed = (from.n_states as usize).min(MAX_HANDOVER_STATES);
        if self.model_hash == 0
            || from.carried_hash != self.model_hash
            || len != n_est
            || at.checked_add(len).is_none_or(|end| end > handed)
            || from.state[at..at + len].iter().any(|v| !v.is_finite())
        {
            return false;
        }
        // x̂ is the block's leading states (`new`): the same numbers.
        self.block.set_leading_state(&from.state[at..at + len]);
        self.x_hat
            .as_mut_slice()
            .copy_from_slice(&from.state[at..at + len]);
        self.next_seq = from.seq + 1;
        true
    }

    /// Sequence the next estimate will carry.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    fn fill(&mut self, seq: u64, out: &mut Estimate) {
        let n_out = self.n_outputs + self.n_inputs;
        out.seq = seq;
        out.n_outputs = self.n_outputs as u32;
        out.n_inputs = self.n_inputs as u32;
        out.n_states = self.x_hat.len() as u32;
        if let Some(sched) = &mut self.scheduled {
            // Free part and direct gain at this tick's position.
            sched
                .observer
                .outputs(&mut out.free[..n_out], &mut out.direct, MAX_OBSERVER_INPUTS);
            sched.observer.write_state(&mut sched.state);
            let n = self.x_hat.len();
            let x = sched.observer.estimate();
            self.x_hat.as_mut_slice().copy_from_slice(&x[..n]);
            out.x_hat[..self.x_hat.len()].copy_from_slice(self.x_hat.as_slice());
            self.next_seq = seq + 1;
            return;
        }
        let free = self.block.free_output();
        out.free[..n_out].copy_from_slice(&free[..n_out]);
        out.direct = self.direct;
        let n = self.block.state().len();
        let s = DVectorView::from_slice(self.block.state(), n);
        self.x_hat.gemv(1.0, &self.estimate_map, &s, 0.0);
        out.x_hat[..self.x_hat.len()].copy_from_slice(self.x_hat.as_slice());
        self.next_seq = seq + 1;
    }
}

/// The built-in observer, on the API a user's observer is written against.
impl EstimationLaw for ObserverCore {
    fn new(setup: &ObserverSetup<'_>) -> Result<Self, SetupError> {
        ObserverCore::for_design(setup.design)
            .map_err(|e| SetupError::Unsupported(format!("observer design: {e}")))
    }

    fn initial(&mut self, out: &mut Estimate) {
        ObserverCore::initial(self, out);
    }

    fn step(&mut self, m: &Measurement, out: &mut Estimate) {
        ObserverCore::step(self, m, out);
    }

    fn save(&self, out: &mut Handover) {
        ObserverCore::save(self, out);
    }

    fn load(&mut self, from: &Handover) -> bool {
        ObserverCore::load(self, from)
    }

    fn settling_samples(&self) -> Option<u64> {
        Some(self.settling_samples)
    }
}
