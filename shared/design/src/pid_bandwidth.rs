//! The PID's tuning parameter f_bw: the number `controller.bandwidth_hz`
//! gives, or for `"auto"` the largest f_bw that meets the 6 dB rule and
//! keeps the closed loop stable on the scenario's own loop (its plant under
//! ZOH, its observer, its loop delay, its notches; docs/control.md §6, §10.1).
//!
//! The search is the one the thesis study makes per case
//! ([`DiscreteBandwidthProblem`]): the plant's and observer's responses once
//! on a grid refined around every lightly damped pole, then for each f_bw
//! the closed-form PID, the peaks of |S^I| and |S^O| and the closed loop's
//! eigenvalues. f_bw runs over the 0.5 Hz grid from 0.5 Hz (the resolution
//! of the thesis' and docs/control.md §10.1's tables), in 4 Hz strides up to
//! the first value that fails, then in 0.5 Hz steps; the result is the
//! largest grid value below which every visited value passes. The rule is
//! the strict one: every peak ≤ 6 dB, no tolerance. |T_{r→e_true}| is not
//! bounded (the thesis bounds it only in its "MC + r→e" case).

use crate::feedback::FeedbackPlan;
use crate::plants::Parts;
use flexloop_control::bandwidth::DiscreteBandwidthProblem;
use flexloop_control::design_error::DesignError;
use flexloop_control::lti::DiscreteStateSpace;
use flexloop_control::observer_block::ObserverBlock;
use flexloop_scenario::{PidBandwidth, Scenario, ScenarioError};
use std::f64::consts::PI;

/// The 6 dB rule's limit on the peaks of |S^I| and |S^O| (docs/control.md §6).
pub const PEAK_LIMIT_DB: f64 = 6.0;
/// The resolution of the search [Hz].
pub const STEP_HZ: f64 = 0.5;
/// The stride of its first pass [Hz].
const COARSE_STEP_HZ: f64 = 4.0;

/// The f_bw a loop's PID runs, and whether the design chose it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PidBandwidthChoice {
    pub hz: f64,
    /// `controller.bandwidth_hz = "auto"`: `hz` is the search's result.
    pub auto: bool,
}

/// One SISO loop as the search sees it.
pub struct SisoLoop<'a> {
    /// Input u (the command), output the measured y, sampled.
    pub plant: &'a DiscreteStateSpace,
    /// The observer block, None without one.
    pub observer: Option<&'a ObserverBlock>,
    /// Samples from y(k) to the tick u_c(k) is applied at.
    pub loop_delay: usize,
    /// The mass the Table 3.3 tuning is made on [kg].
    pub mass: f64,
    /// Notches as asked [Hz] (pre-warped as the running controller's).
    pub notches_hz: &'a [f64],
}

impl SisoLoop<'_> {
    /// The bandwidth problem of this loop under the 6 dB rule.
    pub fn problem(&self) -> Result<DiscreteBandwidthProblem, DesignError> {
        let notches: Vec<f64> = self.notches_hz.iter().map(|hz| 2.0 * PI * hz).collect();
        DiscreteBandwidthProblem::new(
            vec![self.plant.clone()],
            vec![self.observer.cloned()],
            self.loop_delay,
            self.mass,
            PEAK_LIMIT_DB,
            false,
        )?
        .with_notches(&notches)
    }

    /// The largest f_bw on the 0.5 Hz grid (module doc) meeting the rule
    /// with a stable loop; None if 0.5 Hz already fails.
    pub fn largest_bandwidth(&self) -> Result<Option<f64>, DesignError> {
        let f_stop = search_limit_hz(self.plant.ts);
        self.problem()?
            .max_bandwidth_refined(STEP_HZ, f_stop, COARSE_STEP_HZ, STEP_HZ)
    }
}

/// The top of the search: the PID's low-pass sits at 3 f_bw and must stay
/// below Nyquist, so f_bw < f_s / 6 (on the 0.5 Hz grid).
pub fn search_limit_hz(ts: f64) -> f64 {
    ((1.0 / (6.0 * ts)) / STEP_HZ).floor() * STEP_HZ - STEP_HZ
}

/// The mass a single-axis PID is tuned on [kg]: the plan's mass, or for a
/// PID "decoupled" over one axis (u = γ C₁ υ e, C₁ tuned on 1/s², the
/// two-inertia setup) γυ, since the Table 3.3 PID scales with its mass.
/// None for several axes.
pub fn siso_mass(plan: &FeedbackPlan) -> Option<f64> {
    match plan {
        FeedbackPlan::Mass(m) => Some(*m),
        FeedbackPlan::Decoupled { gamma, upsilon } if gamma.len() == 1 && upsilon.len() == 1 => {
            Some(gamma[(0, 0)] * upsilon[(0, 0)]).filter(|m| m.is_finite() && *m > 0.0)
        }
        FeedbackPlan::Decoupled { .. } => None,
    }
}

/// The observer block as the search takes it: None when it has no states
/// (`observer.design = "none"`).
pub fn observer_of(block: &ObserverBlock) -> Option<&ObserverBlock> {
    (block.system.states() > 0).then_some(block)
}

/// `controller.bandwidth_hz` resolved for the PID of `parts` (None without
/// PID feedback): the number given, or the search's result for `"auto"`.
/// `"auto"` on a PID decoupled over several axes is refused, naming the
/// field: the search tunes one SISO loop.
pub fn resolve(
    s: &Scenario,
    parts: &Parts,
    loop_delay: usize,
) -> Result<Option<PidBandwidthChoice>, ScenarioError> {
    if s.controller.feedback != "pid" {
        return Ok(None);
    }
    let field = "controller.bandwidth_hz";
    let err = |reason: String| ScenarioError::new(&s.source, Some(field), reason);
    match s.controller.bandwidth_hz {
        PidBandwidth::Hz(hz) => Ok(Some(PidBandwidthChoice { hz, auto: false })),
        PidBandwidth::Auto => {
            let Some(mass) = siso_mass(&parts.feedback) else {
                return Err(err(format!(
                    "\"auto\" tunes one SISO loop; the PID of `{}` is decoupled over {} axes: \
                     give f_bw in Hz",
                    s.plant.model,
                    parts.plant_u.outputs()
                )));
            };
            let siso = SisoLoop {
                // Tuned on the model the loop is designed on.
                plant: parts.design_plant(),
                observer: observer_of(&parts.observer),
                loop_delay,
                mass,
                notches_hz: &s.controller.notches_hz,
            };
            match siso.largest_bandwidth() {
                Ok(Some(hz)) => Ok(Some(PidBandwidthChoice { hz, auto: true })),
                Ok(None) => Err(err(format!(
                    "\"auto\": no f_bw from {STEP_HZ} Hz up meets the 6 dB rule with a stable \
                     loop at this loop delay ({loop_delay} sample{}): the observer or the \
                     notches alone break it; see `flexloop design`",
                    if loop_delay == 1 { "" } else { "s" }
                ))),
                Err(e) => Err(err(format!("\"auto\": bandwidth search: {e}"))),
            }
        }
    }
}
