//! Least-squares feedforward gains from a recorded run (docs/control.md §7, the
//! data-based update the thesis uses in place of its reference [54]).
//!
//! The run recorded e_true with the gains Θ₀ it used. Changing the gains by
//! ΔΘ changes e_true by the loop's response to ΔΘ·[r⁗ r⃛ r̈ ṙ], which is
//! linear; the loop the run used gives those four responses. So
//! ΔΘ = argmin ‖e_rec + R ΔΘ‖ over the recorded ticks, and Θ = Θ₀ + ΔΘ.
//! The recorded error carries everything the model does not (noise,
//! disturbances, timing misses), which is what makes this data-based.
//! With Appendix A's modified feedforward the gains act on u0 before its
//! block, and the responses are taken through it.

use crate::metrics::SignalStats;
use crate::trace::RunTrace;
use flexloop_control::feedforward::{FeedforwardGains, FitError, fit_gains};
use flexloop_control::lti::LtiRunner;
use flexloop_design::LoopDesign;
use serde::Serialize;

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FittedFeedforward {
    pub snap: f64,
    pub jerk: f64,
    pub acc: f64,
    pub vel: f64,
    /// rms of e_true over the fitted ticks, as recorded and as predicted
    /// with the new gains.
    pub rms_before: f64,
    pub rms_after_predicted: f64,
    pub samples: usize,
}

/// Fits the four gains on the ticks of `trace` (all of them: the whole
/// trajectory, as the thesis fits over 0–0.19 s).
pub fn fit_from_run(design: &LoopDesign, trace: &RunTrace) -> Result<FittedFeedforward, FitError> {
    let Some(cl) = &design.closed_loop else {
        return Err(FitError::NoClosedLoop);
    };
    let ny = design.n_outputs;
    let e_true_index = 2 * ny;
    let u_ff_index = 2 * ny;
    let delay = design.loop_delay_samples as u64;
    let Some(last_seq) = trace.rows.iter().map(|r| r.seq).max() else {
        return Err(FitError::BadLength {
            rows: 0,
            targets: 0,
        });
    };
    // Response of e_true to each regressor fed as u_ff, tick by tick.
    let mut responses = vec![vec![0.0; last_seq as usize + 1]; 4];
    let mut input = vec![0.0; cl.inputs()];
    for (basis, response) in responses.iter_mut().enumerate() {
        let mut run = LtiRunner::new(cl.clone());
        // With the modified form the gains act on u0, which passes through
        // Appendix A's block (its reference input is fixed: it does not move).
        let mut modified = design.modified_feedforward.clone().map(LtiRunner::new);
        let mut modified_input = vec![0.0; modified.as_ref().map_or(0, |m| m.system().inputs())];
        for (k, out) in response.iter_mut().enumerate() {
            // At the instant the command acts (the controller's
            // `fill_feedforward_input`): a loop delay on, or t_k + τ_d.
            let t = match design.command_deadline_s {
                Some(tau) => k as f64 * design.ts + tau,
                None => (k as u64 + delay) as f64 * design.ts,
            };
            let d = design.reference.sample(t);
            // Regressor order [snap, jerk, acc, vel].
            let u0 = [d[4], d[3], d[2], d[1]][basis];
            input[u_ff_index] = match &mut modified {
                Some(block) => {
                    modified_input[0] = u0;
                    block.step(&modified_input)[0]
                }
                None => u0,
            };
            *out = run.step(&input)[e_true_index];
        }
    }
    let rows: Vec<[f64; 4]> = trace
        .rows
        .iter()
        .map(|r| {
            let k = r.seq as usize;
            // fit_gains minimises ‖target − rows·θ‖: rows = −R, target = e_rec.
            [
                -responses[0][k],
                -responses[1][k],
                -responses[2][k],
                -responses[3][k],
            ]
        })
        .collect();
    let recorded: Vec<f64> = trace.rows.iter().map(|r| r.e_true()).collect();
    let delta = fit_gains(&rows, &recorded)?;
    let after = rows.iter().zip(&recorded).map(|(row, e)| {
        e - (row[0] * delta.snap + row[1] * delta.jerk + row[2] * delta.acc + row[3] * delta.vel)
    });
    let [_, vel, acc, jerk, snap] = design.feedforward[0];
    let gains = FeedforwardGains {
        snap: snap + delta.snap,
        jerk: jerk + delta.jerk,
        acc: acc + delta.acc,
        vel: vel + delta.vel,
    };
    Ok(FittedFeedforward {
        snap: gains.snap,
        jerk: gains.jerk,
        acc: gains.acc,
        vel: gains.vel,
        rms_before: SignalStats::of(recorded.iter().copied()).rms,
        rms_after_predicted: SignalStats::of(after).rms,
        samples: recorded.len(),
    })
}
