//! The observer's flexible output against the plant's (docs/control.md §5.1).
//!
//! Measurement compensation subtracts ŷ_flex = C_f x̂ from y: the output of
//! the flexible modes the observer models (rigid columns zero, no T_DC·u
//! term). What it stands for is the plant's own flexible motion at the
//! sensor, y minus the rigid-body motion. The log does not hold the plant's
//! state, but it holds what drives it: the plant model is linear and modal
//! (rigid modes first, then the flexible ones; see `LoopDesign::plant`), and
//! the log holds the input u_a(k) applied over every interval, so the modal
//! states are rebuilt offline from x(0) = 0 and split into the rigid part
//! and the flexible part. The rebuild is checked against the logged true
//! output: the residual y_true − (rigid + flexible) is zero up to rounding
//! when the run has no force noise (its samples are not logged) and is
//! reported beside the comparison.
//!
//! The observer's reduced model is a truncation of the plant's modal model
//! (same coordinates, the first modes kept), so its estimate is compared
//! twice: with the plant's modes it models (its estimation error proper) and
//! with all flexible modes (what MC would ideally remove; the difference is
//! the motion of the modes it leaves out).

use crate::trace::RunTrace;
use flexloop_design::LoopDesign;
use nalgebra::DVector;

/// Estimated and true flexible output per tick, from tick 0.
#[derive(Debug, Clone, PartialEq)]
pub struct FlexibleComparison {
    pub time_s: Vec<f64>,
    /// The plant's flexible modes at the sensor, rebuilt from u_a: y − rigid motion.
    pub true_flexible: Vec<f64>,
    /// The part of it from the modes the observer models.
    pub true_modelled: Vec<f64>,
    /// Flexible modes the observer models.
    pub modelled_modes: usize,
    /// C_f x̂(k|k−1): the observer's prediction before y(k) arrives.
    pub predicted: Vec<f64>,
    /// ŷ_flex(k) the controller subtracted (with MC): y(k) + e_meas(k) − r(k).
    pub compensation: Option<Vec<f64>>,
    /// rms of y_true − (rigid + flexible) rebuilt: how exact the rebuild is.
    pub residual_rms: f64,
    /// Ticks of the run after the compared ones (the log has a gap there).
    pub ticks_left_out: usize,
}

/// Why a run has no flexible comparison.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NoComparison {
    NoFlexibleModes,
    /// Only single-input single-output runs are traced.
    NotSiso,
    /// The plant model is not block-diagonal between rigid and flexible modes.
    NotModal,
    /// The observer's x̂ does not match its output map (no observer).
    NoEstimate,
    /// The trace does not start at tick 0, where the plant starts at rest.
    NoStart,
    /// The log has a gap within the first ticks: this many from tick 0.
    TooShort(usize),
}

/// Fewer ticks than this before the first gap make no comparison.
pub const MIN_TICKS: usize = 10;

impl std::fmt::Display for NoComparison {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            NoComparison::NoFlexibleModes => f.write_str("the plant has no flexible modes"),
            NoComparison::NotSiso => {
                f.write_str("the comparison covers single-input single-output runs only")
            }
            NoComparison::NotModal => f.write_str("the plant model is not in modal form"),
            NoComparison::NoEstimate => f.write_str("the run has no observer state x̂ to compare"),
            NoComparison::NoStart => f.write_str("the log does not start at tick 0"),
            NoComparison::TooShort(ticks) => write!(
                f,
                "only {ticks} ticks from tick 0 before the first gap in the log (the plant's \
                 state cannot be rebuilt across a gap)"
            ),
        }
    }
}

impl FlexibleComparison {
    /// `mc`: the run's observer compensates the measurement (its ŷ_flex is
    /// nonzero only then).
    pub fn compute(design: &LoopDesign, trace: &RunTrace, mc: bool) -> Result<Self, NoComparison> {
        let n_flexible = 2 * design.flexible_modes.len();
        if n_flexible == 0 {
            return Err(NoComparison::NoFlexibleModes);
        }
        if design.n_inputs != 1 || design.n_outputs != 1 {
            return Err(NoComparison::NotSiso);
        }
        let plant = &design.plant;
        let n = plant.states();
        let n_rigid = n.checked_sub(n_flexible).ok_or(NoComparison::NotModal)?;
        let coupled = (0..n)
            .any(|i| (0..n).any(|j| (i < n_rigid) != (j < n_rigid) && plant.a[(i, j)] != 0.0));
        if coupled {
            return Err(NoComparison::NotModal);
        }
        // The observer's model keeps the plant's rigid modes first (a
        // truncation of the same modal model); its C_f is C_o without them.
        let c_o = &design.output_prediction.c;
        if c_o.nrows() == 0 || c_o.ncols() != trace.n_states || c_o.ncols() < n_rigid {
            return Err(NoComparison::NoEstimate);
        }
        let c_f: Vec<f64> = (0..c_o.ncols())
            .map(|j| if j < n_rigid { 0.0 } else { c_o[(0, j)] })
            .collect();
        // The leading states whose output columns agree are the modes both
        // models share (a pair per mode: position, velocity).
        let shared = (0..c_o.ncols().min(n))
            .take_while(|&j| {
                let (a, b) = (c_o[(0, j)], plant.c[(0, j)]);
                (a - b).abs() <= 1e-9 * a.abs().max(b.abs())
            })
            .count()
            / 2
            * 2;
        if shared < n_rigid {
            return Err(NoComparison::NotModal);
        }
        if trace.rows.first().map(|r| r.seq) != Some(0) {
            return Err(NoComparison::NoStart);
        }
        let contiguous = trace
            .rows
            .iter()
            .enumerate()
            .take_while(|(i, r)| r.seq == *i as u64)
            .count();
        if contiguous < MIN_TICKS {
            return Err(NoComparison::TooShort(contiguous));
        }

        let b_u = plant.b.column(0).into_owned();
        // With a command deadline the plant runs z = x − G_new u_a and the
        // observer's x̂ is ẑ: both are moved back by G_new u_a(k), the input
        // present at t_k (docs/deadline.md); the observer's by its MC row's
        // direct gain on u_a, C_f G_new (zero without a deadline).
        let g_new = design
            .plant_g_new
            .as_ref()
            .map_or_else(|| DVector::zeros(n), |g| g.column(0).into_owned());
        let ny = design.n_outputs;
        let predicted_from_u = design
            .observer
            .system
            .d
            .get((0, ny))
            .copied()
            .unwrap_or(0.0);
        let mut z = DVector::<f64>::zeros(n);
        let mut x = DVector::<f64>::zeros(n);
        let mut next = DVector::<f64>::zeros(n);
        let mut out = Self {
            time_s: Vec::with_capacity(contiguous),
            true_flexible: Vec::with_capacity(contiguous),
            true_modelled: Vec::with_capacity(contiguous),
            modelled_modes: (shared - n_rigid) / 2,
            predicted: Vec::with_capacity(contiguous),
            compensation: mc.then(|| Vec::with_capacity(contiguous)),
            residual_rms: 0.0,
            ticks_left_out: trace.rows.len() - contiguous,
        };
        let mut residual_sq = 0.0;
        for (i, row) in trace.rows[..contiguous].iter().enumerate() {
            x.copy_from(&z);
            x.axpy(row.u_applied, &g_new, 1.0);
            let rigid: f64 = (0..n_rigid).map(|j| plant.c[(0, j)] * x[j]).sum();
            let modelled: f64 = (n_rigid..shared).map(|j| plant.c[(0, j)] * x[j]).sum();
            let left_out: f64 = (shared..n).map(|j| plant.c[(0, j)] * x[j]).sum();
            let flexible = modelled + left_out;
            residual_sq += (row.y_true - rigid - flexible).powi(2);
            out.time_s.push(trace.time(row));
            out.true_flexible.push(flexible);
            out.true_modelled.push(modelled);
            out.predicted.push(
                c_f.iter()
                    .zip(trace.x_hat(i))
                    .map(|(c, x)| c * x)
                    .sum::<f64>()
                    + predicted_from_u * row.u_applied,
            );
            if let Some(c) = &mut out.compensation {
                c.push(row.y + row.e_meas - row.r);
            }
            // z(k+1) = A z(k) + B_u u_a(k) (z = x without a deadline).
            next.gemv(1.0, &plant.a, &z, 0.0);
            next.axpy(row.u_applied, &b_u, 1.0);
            std::mem::swap(&mut z, &mut next);
        }
        out.residual_rms = (residual_sq / contiguous.max(1) as f64).sqrt();
        Ok(out)
    }

    /// rms of `estimate` − `truth`.
    pub fn rms_difference(estimate: &[f64], truth: &[f64]) -> f64 {
        rms(estimate.iter().zip(truth).map(|(e, t)| e - t))
    }

    pub fn rms(values: &[f64]) -> f64 {
        rms(values.iter().copied())
    }
}

fn rms(values: impl Iterator<Item = f64>) -> f64 {
    let (n, sq) = values.fold((0usize, 0.0), |(n, sq), v| (n + 1, sq + v * v));
    if n == 0 { 0.0 } else { (sq / n as f64).sqrt() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_components::InProcessLoop;
    use flexloop_scenario::{Overrides, Scenario};
    use std::path::PathBuf;

    fn run(name: &str, force_noise: f64, ticks: u64) -> (LoopDesign, RunTrace, bool) {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../scenarios")
            .join(format!("{name}.toml"));
        let mut s = Scenario::load(&path, &Overrides::default()).unwrap();
        s.plant.force_noise = force_noise;
        let design = LoopDesign::from_scenario(&s).unwrap();
        let mut l = InProcessLoop::new(&design).unwrap();
        let trace = RunTrace::simulate(&mut l, design.ts, ticks);
        (design, trace, s.observer.mc)
    }

    #[test]
    fn the_rebuilt_plant_matches_the_logged_output_and_the_observer_tracks_it() {
        let (design, trace, mc) = run("thesis-mc-ad-redesigned", 0.0, 2_000);
        let c = FlexibleComparison::compute(&design, &trace, mc).unwrap();
        assert_eq!(c.true_flexible.len(), 2_000);
        assert_eq!(c.ticks_left_out, 0);
        // Exact up to rounding: the rigid motion is millimetres, the residual
        // far below a picometre.
        assert!(c.residual_rms < 1e-13, "{}", c.residual_rms);
        // The scan excites the flexible modes (nanometres) ...
        let true_rms = FlexibleComparison::rms(&c.true_flexible);
        assert!(true_rms > 1e-10, "{true_rms}");
        // ... the observer models three of the seven ...
        assert_eq!(c.modelled_modes, 3);
        // ... and follows them: its prediction and the compensation it
        // applies are far closer to them than zero is, and closer to them
        // than to all seven modes.
        let modelled_rms = FlexibleComparison::rms(&c.true_modelled);
        let compensation = c.compensation.as_ref().unwrap();
        for estimate in [&c.predicted, compensation] {
            let own = FlexibleComparison::rms_difference(estimate, &c.true_modelled);
            let all = FlexibleComparison::rms_difference(estimate, &c.true_flexible);
            assert!(own < 0.1 * modelled_rms, "{own} vs {modelled_rms}");
            assert!(own < all, "{own} vs {all}");
        }
    }

    #[test]
    fn unlogged_force_noise_shows_in_the_residual() {
        let (design, trace, mc) = run("thesis-mc-ad-redesigned", 0.01, 2_000);
        let c = FlexibleComparison::compute(&design, &trace, mc).unwrap();
        assert!(c.residual_rms > 1e-12, "{}", c.residual_rms);
    }

    #[test]
    fn without_mc_there_is_no_compensation_and_a_rigid_plant_has_nothing_to_compare() {
        let (design, trace, mc) = run("thesis-ad", 0.0, 500);
        assert!(!mc);
        let c = FlexibleComparison::compute(&design, &trace, mc).unwrap();
        assert!(c.compensation.is_none());
        let (design, trace, mc) = run("lecture-double-integrator", 0.0, 100);
        assert_eq!(
            FlexibleComparison::compute(&design, &trace, mc),
            Err(NoComparison::NoFlexibleModes)
        );
    }

    #[test]
    fn a_trace_with_a_gap_is_compared_up_to_it() {
        let (design, mut trace, mc) = run("thesis-mc-ad-redesigned", 0.0, 300);
        trace.rows.remove(200);
        let n = trace.n_states;
        trace.x_hat.drain(200 * n..201 * n);
        let c = FlexibleComparison::compute(&design, &trace, mc).unwrap();
        assert_eq!(c.true_flexible.len(), 200);
        assert_eq!(c.ticks_left_out, 99);
        let mut early_gap = trace.clone();
        early_gap.rows.remove(5);
        early_gap.x_hat.drain(5 * n..6 * n);
        assert_eq!(
            FlexibleComparison::compute(&design, &early_gap, mc),
            Err(NoComparison::TooShort(5))
        );
        trace.rows.remove(0);
        trace.x_hat.drain(..n);
        assert_eq!(
            FlexibleComparison::compute(&design, &trace, mc),
            Err(NoComparison::NoStart)
        );
    }
}
