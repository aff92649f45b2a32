//! The observers of the study's cases on each output, their error poles,
//! and the damping active damping achieves in closed loop (§10.1).

use super::*;

fn damping_options(bandpass_q: Option<f64>) -> DampingOptions {
    DampingOptions {
        increase: vec![DAMPING_INCREASE; 3],
        method: DampingMethod::Automated,
        bandpass_q,
    }
}

/// The extra prediction step of the AD output for a loop delay (§10.1).
fn extra_delay(loop_delay: usize, ad: bool) -> usize {
    usize::from(ad && loop_delay >= 2)
}

pub(super) fn discrete_observer(
    spec: &ThesisDesignSpec,
    output: usize,
    ts: f64,
    loop_delay: usize,
    case: DesignCase,
) -> Result<flexloop_control::observer_block::ModalObserver, DesignError> {
    let opts = ModalObserverOptions {
        ts,
        mc: case.mc(),
        damping: case.ad().map(damping_options),
        q_nu: case.q_nu(),
        weights: None,
        extra_delay_samples: extra_delay(loop_delay, case.ad().is_some()),
        command_deadline: spec.command_deadline(),
    };
    design_modal_observer(&spec.reduced(output)?, &opts)
}

pub(super) fn continuous_observer(
    spec: &ThesisDesignSpec,
    output: usize,
    case: DesignCase,
) -> Result<flexloop_control::observer_block::ContinuousModalObserver, DesignError> {
    let opts = ContinuousObserverOptions {
        mc: case.mc(),
        damping: case.ad().map(damping_options),
        q_nu: case.q_nu(),
        weights: None,
    };
    design_continuous_modal_observer(&spec.reduced(output)?, &opts)
}

fn pole_row(w: f64, zeta: f64) -> Option<PoleRow> {
    let f = w / (2.0 * PI);
    (f.is_finite() && zeta.is_finite()).then_some(PoleRow {
        frequency_hz: f,
        damping: zeta,
    })
}

pub(super) fn observer_poles(spec: &ThesisDesignSpec) -> Result<Vec<PoleRow>, DesignError> {
    let case = DesignCase::McAdBandpass;
    let mut rows: Vec<PoleRow> = match spec.domain {
        DesignDomain::Continuous => {
            let o = continuous_observer(spec, spec.output, case)?;
            let f = &o.model.a - &o.kalman.l * &o.model.c;
            flexloop_control::linalg::eigenvalues(&f)?
                .iter()
                .filter(|s| s.im >= 0.0)
                .filter_map(|s| {
                    let w = s.norm();
                    pole_row(w, if w > 0.0 { -s.re / w } else { 1.0 })
                })
                .collect()
        }
        DesignDomain::Discrete { ts, loop_delay, .. } => {
            let o = discrete_observer(spec, spec.output, ts, loop_delay, case)?;
            let d = &o.design;
            flexloop_control::linalg::eigenvalues(&(&d.model.a - &d.gain * &d.model.c))?
                .iter()
                .filter(|z| z.im >= 0.0 && z.norm() > 0.0)
                .filter_map(|z| {
                    let (w, zeta) = flexloop_control::linalg::discrete_pole_to_continuous(*z, ts);
                    pole_row(w, zeta)
                })
                .collect()
        }
    };
    rows.sort_by(|a, b| a.frequency_hz.total_cmp(&b.frequency_hz));
    Ok(rows)
}

/// Closed-loop damping of the retained flexible modes with AD (band-pass
/// Q = 2) at `spec.ad_check_f_bw`, output `spec.output`.
pub(super) fn ad_damping_check(spec: &ThesisDesignSpec) -> Result<AdDampingCheck, DesignError> {
    let case = DesignCase::AdBandpass;
    let red = spec.reduced(spec.output)?;
    let tuning = PidTuning::single_parameter(spec.mass, spec.ad_check_f_bw)?;
    let (modes, obs_modes) = match spec.domain {
        DesignDomain::Continuous => {
            let plant = spec.plant(spec.output)?.state_space();
            let o = continuous_observer(spec, spec.output, case)?;
            let cl = assemble_continuous_loop(&plant, Some(&o.system), &tuning.continuous()?)?;
            let f = &o.model.a - &o.kalman.l * &o.model.c;
            let obs = flexloop_control::linalg::eigenvalues(&f)?
                .iter()
                .filter(|s| s.im > 0.0)
                .map(|s| (s.norm() / (2.0 * PI), -s.re / s.norm()))
                .collect::<Vec<_>>();
            (continuous_closed_loop_modes(&cl)?, obs)
        }
        DesignDomain::Discrete { ts, loop_delay, .. } => {
            let plant = spec.discrete_plant(spec.output, ts)?;
            let o = discrete_observer(spec, spec.output, ts, loop_delay, case)?;
            let cl = assemble_loop(&LoopSpec {
                plant: &plant,
                observer: Some(&o.block),
                controller: &tuning.discrete(ts)?,
                loop_delay,
            })?;
            let d = &o.design;
            let obs = discrete_modes(&(&d.model.a - &d.gain * &d.model.c), ts)?;
            (closed_loop_modes(&cl)?, obs)
        }
    };
    let freqs = red.modal.frequencies_hz();
    let achieved = least_damped_near(&modes, &freqs[1..], &obs_modes);
    let rows = (1..red.modal.modes())
        .zip(achieved)
        .map(|(i, achieved)| ModeDamping {
            mode: i,
            frequency_hz: freqs[i],
            open_loop: red.modal.zeta[i],
            target: red.modal.zeta[i] + DAMPING_INCREASE,
            achieved,
        })
        .collect();
    Ok(AdDampingCheck {
        f_bw: spec.ad_check_f_bw,
        bandpass_q: BANDPASS_Q,
        modes: rows,
    })
}
