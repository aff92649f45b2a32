//! Time-varying Kalman filter against interpolated steady-state gains on a
//! moving sensor (docs/control.md §3 "TVKF vs scheduled steady-state KF", §5.6 of
//! the thesis: "no significant difference").
//!
//! The chain scans past the world-fixed sensor: the sensor position follows
//! the reference, 0 (ma) at the start of the scenario's scan to 7 (m7) at its
//! end, so C and T_DC change every sample. Both filters are the scenario's
//! observer model (reduced chain, T_DC, noise model when MC is on) at the
//! scheduled position: [`TimeVaryingKalman`] runs the Riccati recursion
//! every sample, [`InterpolatedKalman`] interpolates steady-state gains from
//! a grid. The loop is closed by the scenario's feedback and feedforward on
//! the measured output only (no MC, no AD), so that both filters see exactly
//! the same y and u. The plant is the full 8-mode chain with the sensor row
//! at the exact position and the thesis' noise (σ_w = 10 mN, σ_v = σ_d = 1 nm,
//! the levels the Kalman weights assume), seeded by `plant.seed`.
//!
//! A third filter, the steady-state one frozen at mid-stroke (not scheduled),
//! shows that the comparison can tell filters apart.

use flexloop_components::noise::Gaussian;
use flexloop_control::design_error::DesignError;
use flexloop_control::discretise::zoh;
use flexloop_control::kalman::{KalmanWeights, NoiseModel, with_noise_model};
use flexloop_control::lti::{DiscreteStateSpace, LtiRunner};
use flexloop_control::modal::ModalModel;
use flexloop_control::models::{self, SIGMA_D, SIGMA_V, SIGMA_W};
use flexloop_control::scheduling::{
    InterpolatedKalman, KalmanSchedule, ModelSchedule, PositionGrid, ScheduleError,
    TimeVaryingKalman,
};
use flexloop_design::LoopDesign;
use flexloop_scenario::schema::SENSOR_POSITION_MAX;
use flexloop_scenario::{Scenario, ScenarioError};
use nalgebra::DVector;
use serde::Serialize;
use std::fmt;

#[derive(Debug, Clone, PartialEq)]
pub enum ComparisonError {
    Scenario(ScenarioError),
    Schedule(ScheduleError),
    Design(DesignError),
    /// The reference does not move, so there is nothing to schedule on.
    NoMotion,
    /// A filter step failed (non-finite data, position off the grid).
    Step(String),
}

impl fmt::Display for ComparisonError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Scenario(e) => write!(f, "{e}"),
            Self::Schedule(e) => write!(f, "schedule: {e}"),
            Self::Design(e) => write!(f, "design: {e}"),
            Self::NoMotion => write!(f, "the reference does not move: nothing to schedule"),
            Self::Step(e) => write!(f, "filter step: {e}"),
        }
    }
}

impl std::error::Error for ComparisonError {}

impl From<ScheduleError> for ComparisonError {
    fn from(e: ScheduleError) -> Self {
        Self::Schedule(e)
    }
}

impl From<DesignError> for ComparisonError {
    fn from(e: DesignError) -> Self {
        Self::Design(e)
    }
}

/// What the two schedulings did on the same data; per-state vectors are
/// over the observer states (retained modes as (η, η̇) pairs, then the
/// noise-model state when MC is on).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SchedulingComparison {
    pub ticks: usize,
    pub grid_points: usize,
    /// max_k |x̂_TV − x̂_interp| per state.
    pub max_difference: Vec<f64>,
    /// max_k |x̂_TV| per state.
    pub max_estimate: Vec<f64>,
    /// rms of the estimation error against the plant's modal state (retained
    /// modes only), per state: TVKF, interpolated, unscheduled.
    pub rms_error_tv: Vec<f64>,
    pub rms_error_interpolated: Vec<f64>,
    pub rms_error_frozen: Vec<f64>,
    /// ŷ_flex = C_f(r_p) x̂, what MC subtracts [m]: the largest difference
    /// between the two filters and the largest |ŷ_flex| of the TVKF.
    pub max_yflex_difference: f64,
    pub max_yflex: f64,
}

impl SchedulingComparison {
    /// max over states of max|Δx̂| / max|x̂|.
    pub fn max_relative_difference(&self) -> f64 {
        self.max_difference
            .iter()
            .zip(&self.max_estimate)
            .map(|(d, m)| d / m)
            .fold(0.0, f64::max)
    }
}

/// Sensor position (node units) when the reference is at `r`: the stroke of
/// the motion maps onto 0..=7.
fn position_of(r: f64, start: f64, stroke: f64) -> f64 {
    (SENSOR_POSITION_MAX * (r - start) / stroke).clamp(0.0, SENSOR_POSITION_MAX)
}

/// Observer model at `position`: reduced chain under ZOH, D = T_DC, with the
/// scenario's noise model when MC is on (same rule as the scenario design).
fn observer_model(
    s: &Scenario,
    modal: &ModalModel,
    position: f64,
    ts: f64,
) -> Result<(DiscreteStateSpace, KalmanWeights), DesignError> {
    let reduced = modal
        .with_sensor_positions(&[position])?
        .truncate(4, &[4, 5, 6])?;
    let base = zoh(&reduced.state_space(), ts)?;
    let weights = KalmanWeights::thesis(&base);
    let o = &s.observer;
    let q_nu = match o.q_nu {
        Some(0.0) => None,
        Some(q) => Some(q),
        None => Some(if o.ad { 1e3 } else { 0.03 }),
    };
    match (o.mc, q_nu) {
        (true, Some(q)) => with_noise_model(&base, &weights, &NoiseModel::thesis(&base, q)),
        _ => Ok((base, weights)),
    }
}

/// Runs the scenario's scan with the sensor sweeping 0 → 7 and both
/// schedulings on the same data; the grid has `grid_step` node units
/// between points (0.25: 29 points, as the thesis' 5 mm grid).
pub fn compare_scheduling(
    s: &Scenario,
    grid_step: f64,
) -> Result<SchedulingComparison, ComparisonError> {
    let design = LoopDesign::from_scenario(s).map_err(ComparisonError::Scenario)?;
    let ts = design.ts;
    let reference = &design.reference;
    let end_s = reference.end_s().ok_or(ComparisonError::NoMotion)?;
    let start_r = reference.sample(0.0)[0];
    let stroke = reference.sample(end_s + ts)[0] - start_r;
    if !(stroke.is_finite() && stroke.abs() > 0.0) {
        return Err(ComparisonError::NoMotion);
    }
    let modal = models::thesis_chain_modal().map_err(DesignError::from)?;
    let grid = PositionGrid::covering(0.0, SENSOR_POSITION_MAX, grid_step)?;
    let (_, weights) = observer_model(s, &modal, 0.0, ts)?;
    let schedule = ModelSchedule::new(grid, weights.clone(), |p| {
        observer_model(s, &modal, p, ts).map(|(m, _)| m)
    })?;
    let mid = 0.5 * SENSOR_POSITION_MAX;
    let frozen_model = schedule.model_at(mid)?;
    let frozen = ModelSchedule::new(grid, weights, |_| Ok(frozen_model.clone()))?;
    let mut interpolated = InterpolatedKalman::new(KalmanSchedule::design(schedule.clone())?);
    let mut unscheduled = InterpolatedKalman::new(KalmanSchedule::design(frozen)?);
    let mut tv = TimeVaryingKalman::from_steady_state(schedule, 0.0)?;
    let n = tv.estimate().len();
    let n_modal = 2 * 4; // retained modes: rigid + 3 flexible

    // Plant: the full chain, sensor row set per sample.
    let plant = zoh(&modal.state_space(), ts).map_err(DesignError::from)?;
    let mut x = DVector::<f64>::zeros(plant.states());
    let mut x_next = x.clone();
    let mut feedback = design.feedback.clone().map(LtiRunner::new);
    let gains = design.feedforward[0];
    let delay = design.loop_delay_samples as usize;
    // u_c of the last `delay` ticks, oldest first: the plant applies
    // u_c(k − delay) over [t_k, t_k+1).
    let mut issued = vec![0.0; delay.max(1)];
    let mut noise = Gaussian::new(s.plant.seed);
    let ticks = ((end_s / ts).ceil() as usize) + 1;

    let mut max_difference = vec![0.0f64; n];
    let mut max_estimate = vec![0.0f64; n];
    let mut sq = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    let (mut max_yflex_difference, mut max_yflex) = (0.0f64, 0.0f64);
    let mut cf = DVector::<f64>::zeros(n);
    for k in 0..ticks {
        let t = k as f64 * ts;
        let d = reference.sample(t);
        let position = position_of(d[0], start_r, stroke);
        // Compare the estimates x̂(k|k−1) before this tick's update.
        let (a, b, c) = (
            tv.estimate(),
            interpolated.estimate(),
            unscheduled.estimate(),
        );
        let row = modal
            .sensor_row_at(position)
            .map_err(|e| ComparisonError::Design(e.into()))?;
        // C_f(r_p): the flexible columns of the reduced model's C.
        for i in 1..4 {
            cf[2 * i] = row[(0, i)];
        }
        let (mut yf_a, mut yf_b) = (0.0, 0.0);
        for j in 0..n {
            max_difference[j] = max_difference[j].max((a[j] - b[j]).abs());
            max_estimate[j] = max_estimate[j].max(a[j].abs());
            if j < n_modal {
                for (acc, est) in sq.iter_mut().zip([a, b, c]) {
                    acc[j] += (x[j] - est[j]).powi(2);
                }
                yf_a += cf[j] * a[j];
                yf_b += cf[j] * b[j];
            }
        }
        max_yflex_difference = max_yflex_difference.max((yf_a - yf_b).abs());
        max_yflex = max_yflex.max(yf_a.abs());

        // y_meas(k) = y − v + d at the exact sensor position.
        let y: f64 = (0..modal.modes()).map(|i| row[(0, i)] * x[2 * i]).sum();
        let y_meas = y + SIGMA_V * noise.sample() + SIGMA_D * noise.sample();
        let u_applied = issued[0];
        // u_c(k): feedback on e_meas plus the feedforward of the tick it applies at.
        let ahead = reference.sample(t + delay as f64 * ts);
        let u_ff: f64 = gains.iter().zip(&ahead).map(|(g, v)| g * v).sum();
        let u_fb = feedback
            .as_mut()
            .map_or(0.0, |f| f.step(&[d[0] - y_meas])[0]);
        issued.remove(0);
        issued.push((u_fb + u_ff).clamp(-design.input_limit, design.input_limit));

        for f in [&mut interpolated, &mut unscheduled] {
            f.step(position, &[y_meas], &[u_applied])
                .map_err(|e| ComparisonError::Step(e.to_string()))?;
        }
        tv.step(position, &[y_meas], &[u_applied])
            .map_err(|e| ComparisonError::Step(e.to_string()))?;
        let w = SIGMA_W * noise.sample();
        x_next.gemv(1.0, &plant.a, &x, 0.0);
        x_next.axpy(u_applied + w, &plant.b.column(0), 1.0);
        std::mem::swap(&mut x, &mut x_next);
    }
    let rms = |v: &[f64]| -> Vec<f64> {
        v.iter()
            .enumerate()
            .map(|(j, s)| {
                if j < n_modal {
                    (s / ticks as f64).sqrt()
                } else {
                    f64::NAN
                }
            })
            .collect()
    };
    Ok(SchedulingComparison {
        ticks,
        grid_points: grid.points(),
        max_difference,
        max_estimate,
        rms_error_tv: rms(&sq[0]),
        rms_error_interpolated: rms(&sq[1]),
        rms_error_frozen: rms(&sq[2]),
        max_yflex_difference,
        max_yflex,
    })
}
