//! A world-fixed sensor that the thesis chain scans past (docs/control.md §1.4,
//! `plant.sensor_scan`): the position under the sensor follows the scan's
//! reference, so the plant's output row and the observer's C, T_DC and
//! Kalman gain change every tick; B and the AD map do not.
//!
//! The position of tick k is a function of the reference r(k Ts) alone, so
//! the plant and the observer compute it each on their own, without a
//! message. The design is checked frozen at every grid point and halfway
//! between (the loop must be stable wherever the sensor is).

use crate::observer::{empty_observer, flexible_modes_kept, kalman_options, scenario_weights};
use crate::plants::thesis_chain::{chain_modal, sensor_field};
use crate::reference::Reference;
use flexloop_control::closed_loop::{LoopSpec, assemble_loop};
use flexloop_control::design_error::DesignError;
use flexloop_control::discretise::{DiscretiseError, zoh};
use flexloop_control::kalman::{KalmanWeights, NoiseModel, with_noise_model};
use flexloop_control::linalg;
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::modal::{ModalModel, ReducedModel};
use flexloop_control::observer_block::{
    ObserverBlock, ObserverDesign, compile_observer_block, design_modal_observer,
};
use flexloop_control::scheduled_observer::{GainScheduling, ScheduledObserverDesign};
use flexloop_control::scheduling::{KalmanSchedule, ModelSchedule, PositionGrid};
use flexloop_control::step_error::StepError;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DMatrix;
use std::fmt;

/// The sensor's motion and what follows it.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorScan {
    /// Position (node units) when the reference is at the scan's start, and
    /// at its end.
    pub from: f64,
    pub to: f64,
    /// The scan's reference at its start and at its end [m].
    pub r_start: f64,
    pub r_end: f64,
    /// The plant's output row at every node 0..=7 (rows), over the plant's
    /// states (columns); between nodes the rows are interpolated linearly.
    pub node_rows: DMatrix<f64>,
    /// The observer scheduled on the position (None without an observer).
    pub observer: Option<ScheduledObserverDesign>,
}

impl SensorScan {
    /// The position under the sensor when the reference is at `r`.
    pub fn position_at(&self, r: f64) -> f64 {
        let f = ((r - self.r_start) / (self.r_end - self.r_start)).clamp(0.0, 1.0);
        self.from + (self.to - self.from) * f
    }

    /// The position of tick `k` (t = k ts).
    pub fn position_of_tick(&self, reference: &Reference, k: u64, ts: f64) -> f64 {
        self.position_at(reference.sample(k as f64 * ts)[0])
    }

    /// The plant's output row at `position` into `row` (allocation-free;
    /// the same interpolation as `ModalModel::sensor_row_at`).
    pub fn plant_row(&self, position: f64, row: &mut [f64]) {
        let nodes = self.node_rows.nrows();
        let i0 = (position.floor().max(0.0) as usize).min(nodes.saturating_sub(2));
        let frac = position - i0 as f64;
        for (j, v) in row.iter_mut().enumerate() {
            *v = self.node_rows[(i0, j)] * (1.0 - frac) + self.node_rows[(i0 + 1, j)] * frac;
        }
    }
}

/// The scan of `s` (None when its sensor does not move). `frozen_plant` is
/// the plant as designed at the scan's start; `feedback` the controller.
pub fn design_sensor_scan(
    s: &Scenario,
    ts: f64,
    extra_delay: usize,
    reference: &Reference,
    feedback: Option<&DiscreteStateSpace>,
) -> Result<Option<SensorScan>, ScenarioError> {
    let Some([from, to]) = s.plant.sensor_scan else {
        return Ok(None);
    };
    let field = sensor_field(s);
    let err = |reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let Reference::Scan {
        setpoint, start_s, ..
    } = reference
    else {
        return Err(err(
            "the sensor follows a scan; the reference is not one".into()
        ));
    };
    let r_start = reference.sample(*start_s)[0];
    let r_end = reference.sample(start_s + setpoint.duration())[0];
    let chain = chain_modal(s)?;
    let shapes = chain
        .shapes
        .clone()
        .ok_or_else(|| err("the chain has no mode shapes".into()))?;
    let modes = chain.modes();
    let mut node_rows = DMatrix::zeros(shapes.nrows(), 2 * modes);
    for i in 0..shapes.nrows() {
        for j in 0..modes {
            node_rows[(i, 2 * j)] = shapes[(i, j)];
        }
    }
    let plant_at = |p: f64| -> Result<DiscreteStateSpace, ScenarioError> {
        let m = chain
            .with_sensor_positions(&[p])
            .map_err(|e| err(e.to_string()))?;
        zoh(&m.state_space(), ts).map_err(|e| err(format!("ZOH: {e}")))
    };
    let (lo, hi) = (from.min(to), from.max(to));
    let step = s.observer.scheduling_step;
    let points = (((hi - lo) / step).ceil() as usize).max(1) + 1;
    let grid = PositionGrid::new(lo, (hi - lo) / (points - 1) as f64, points)
        .map_err(|e| err(e.to_string()))?;
    let observer = match s.observer.design.as_str() {
        "kalman" => Some(scheduled_observer(s, ts, extra_delay, &chain, grid)?),
        _ => None,
    };
    let scan = SensorScan {
        from,
        to,
        r_start,
        r_end,
        node_rows,
        observer,
    };
    // Frozen at every grid point and halfway between: a stable loop (with
    // both laws built-in; a program's is not flexloop's to analyse).
    let Some(feedback) = feedback else {
        return Ok(Some(scan));
    };
    let zero_observer = empty_observer(ts, 1, 1, extra_delay).map_err(|e| err(e.to_string()))?;
    for i in 0..2 * points - 1 {
        // Clamped: rounding may carry the last point past the scan's end.
        let p = (lo + (hi - lo) * i as f64 / (2 * (points - 1)) as f64).min(hi);
        let plant = plant_at(p)?;
        let block = match &scan.observer {
            Some(o) => frozen_block(o, p).map_err(|e| err(format!("at position {p}: {e}")))?,
            None => zero_observer.clone(),
        };
        let cl = assemble_loop(&LoopSpec {
            plant: &plant,
            observer: Some(&block),
            controller: feedback,
            loop_delay: 1 + extra_delay,
        })
        .map_err(|e| err(format!("closed loop at position {p}: {e}")))?;
        let radius = linalg::spectral_radius(&cl.a)
            .map_err(|e| err(format!("closed-loop eigenvalues at position {p}: {e}")))?;
        if radius.is_nan() || radius >= 1.0 {
            return Err(err(format!(
                "the closed loop is unstable with the sensor at {p:.3} (spectral radius \
                 {radius:.6}): narrow the scan or retune"
            )));
        }
    }
    Ok(Some(scan))
}

/// The scenario's Kalman observer on the reduced chain at every grid
/// position (same model, weights, MC, AD and noise model as the fixed design).
fn scheduled_observer(
    s: &Scenario,
    ts: f64,
    extra_delay: usize,
    chain: &ModalModel,
    grid: PositionGrid,
) -> Result<ScheduledObserverDesign, ScenarioError> {
    let field = sensor_field(s);
    let err = |reason: String| ScenarioError::new(&s.source, Some(field), reason);
    let keep = flexible_modes_kept(s, 3, 7)?;
    let compensate: Vec<usize> = (1 + keep..7).collect();
    // A grid position past the scan's end by rounding is its end.
    let [from, to] = s.plant.sensor_scan.unwrap_or([grid.start(), grid.end()]);
    let (lo, hi) = (from.min(to), from.max(to));
    let reduced_at = |p: f64| -> Result<ReducedModel, ScenarioError> {
        chain
            .with_sensor_positions(&[p.clamp(lo, hi)])
            .and_then(|m| m.truncate(1 + keep, &compensate))
            .map_err(|e| err(e.to_string()))
    };
    let start = reduced_at(grid.start())?;
    // The scenario's Kalman weights (B, and so G, does not move with the sensor).
    let weights_given = scenario_weights(s, &start, ts, None)?;
    let options = kalman_options(s, ts, extra_delay, &start, weights_given.clone())?;
    // K(z) acts on the modal velocities through φ_a: the same at every position.
    let designed = design_modal_observer(&start, &options).map_err(|e| {
        ScenarioError::new(&s.source, Some("observer"), format!("Kalman observer: {e}"))
    })?;
    let augmented = |reduced: &ReducedModel| -> Result<(DiscreteStateSpace, KalmanWeights), ScheduledBlockError> {
        let base = zoh(&reduced.state_space(), ts).map_err(ScheduledBlockError::Sampling)?;
        let weights = match &weights_given {
            Some(w) => KalmanWeights {
                g: base.b.clone(),
                q: w.q.clone(),
                r: w.r.clone(),
            },
            None => KalmanWeights::thesis(&base),
        };
        match (options.mc, options.q_nu) {
            (true, Some(q)) => Ok(with_noise_model(
                &base,
                &weights,
                &NoiseModel::thesis(&base, q),
            )?),
            _ => Ok((base, weights)),
        }
    };
    let (_, weights) = augmented(&start).map_err(|e| err(e.to_string()))?;
    let models = ModelSchedule::new(grid, weights, |p| {
        let reduced = reduced_at(p).map_err(|e| DesignError::InvalidParameter(e.reason.clone()))?;
        augmented(&reduced)
            .map(|(m, _)| m)
            .map_err(|e| DesignError::InvalidParameter(e.to_string()))
    })
    .map_err(|e| err(e.to_string()))?;
    let schedule = KalmanSchedule::design(models).map_err(|e| err(e.to_string()))?;
    let n_t = 2 * start.modal.modes();
    Ok(ScheduledObserverDesign {
        schedule,
        flexible_columns: options.mc.then_some(2 * start.modal.n_rigid..n_t),
        feedback: designed.design.feedback.clone(),
        extra_delay_samples: extra_delay,
        gains: match s.observer.scheduling.as_str() {
            "time-varying" => GainScheduling::TimeVarying,
            _ => GainScheduling::Interpolated,
        },
    })
}

/// The scheduled observer frozen at `position` as a fixed block (for the
/// design checks and the closed loop of the analyses).
pub fn frozen_block(
    o: &ScheduledObserverDesign,
    position: f64,
) -> Result<ObserverBlock, ScheduledBlockError> {
    let models = o.schedule.models();
    let mut m = o.schedule.matrices();
    o.schedule
        .interpolate(position, &mut m)
        .map_err(ScheduledBlockError::Interpolation)?;
    let n = models.states();
    let model = DiscreteStateSpace::new(models.a().clone(), m.b, m.c.clone(), m.d, models.ts())
        .map_err(DesignError::from)?;
    let compensation = o.flexible_columns.clone().map(|cols| {
        let mut c = DMatrix::zeros(m.c.nrows(), n);
        for j in cols {
            c.column_mut(j).copy_from(&m.c.column(j));
        }
        c
    });
    compile_observer_block(
        &ObserverDesign {
            model,
            gain: m.l,
            compensation,
            feedback: o.feedback.clone(),
        },
        o.extra_delay_samples,
    )
    .map_err(ScheduledBlockError::Design)
}

/// Why the scheduled observer could not be built or frozen at a position.
#[derive(Debug, Clone, PartialEq)]
pub enum ScheduledBlockError {
    /// The reduced model at a position could not be sampled (ZOH).
    Sampling(DiscretiseError),
    /// The schedule could not be interpolated at the position.
    Interpolation(StepError),
    /// A design step (noise model, observer block) refused.
    Design(DesignError),
}

impl fmt::Display for ScheduledBlockError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Sampling(e) => write!(f, "ZOH: {e}"),
            Self::Interpolation(e) => write!(f, "{e}"),
            Self::Design(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for ScheduledBlockError {}

impl From<DesignError> for ScheduledBlockError {
    fn from(e: DesignError) -> Self {
        Self::Design(e)
    }
}
