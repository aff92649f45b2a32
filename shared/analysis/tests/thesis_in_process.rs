//! The thesis scenarios shipped in `scenarios/`, run by the in-process loop
//! (the same cores as the processes, in lockstep): Table 3.7 at 10 kHz with
//! one sample of loop delay (docs/control.md §10.1) and the damping AD achieves.

use flexloop_analysis::feedforward_fit::fit_from_run;
use flexloop_analysis::modal_damping::modal_damping;
use flexloop_analysis::{ControlMetrics, MetricsOptions, RunTrace};
use flexloop_components::InProcessLoop;
use flexloop_design::LoopDesign;
use flexloop_scenario::schema::FeedforwardSection;
use flexloop_scenario::{Overrides, Scenario};
use std::path::PathBuf;

fn scenario(name: &str) -> Scenario {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    Scenario::load(&path, &Overrides::default()).unwrap()
}

fn run(s: &Scenario) -> (LoopDesign, RunTrace) {
    let design = LoopDesign::from_scenario(s).unwrap();
    let mut l = InProcessLoop::new(&design).unwrap();
    let trace = RunTrace::simulate(&mut l, design.ts, s.ticks().unwrap());
    (design, trace)
}

/// Fits the feedforward on a first run (mass only), reruns with the fitted
/// gains, and returns the scan rms of e_true [nm], the fitted Θ_acc and the
/// second run.
fn fitted_scan_rms(name: &str) -> (f64, f64, LoopDesign, RunTrace) {
    let mut s = scenario(name);
    s.controller.feedforward = None;
    let (design, trace) = run(&s);
    let fit = fit_from_run(&design, &trace).unwrap();
    s.controller.feedforward = Some(FeedforwardSection {
        snap: fit.snap,
        jerk: fit.jerk,
        acc: fit.acc,
        vel: fit.vel,
    });
    let (design, trace) = run(&s);
    let windows = design.reference.scan_windows(s.timing.duration_s);
    let m = ControlMetrics::compute(&trace, &windows, &MetricsOptions::default());
    (m.rms_e_true_scan.unwrap() * 1e9, fit.acc, design, trace)
}

fn scan_rms_as_shipped(name: &str) -> f64 {
    let s = scenario(name);
    let (design, trace) = run(&s);
    let windows = design.reference.scan_windows(s.timing.duration_s);
    let m = ControlMetrics::compute(&trace, &windows, &MetricsOptions::default());
    m.rms_e_true_scan.unwrap() * 1e9
}

#[test]
fn shipped_scenarios_reproduce_table_3_7_at_10_khz() {
    // docs/control.md §10.1, bold column (one sample of loop delay, predictor);
    // the redesigned cases at the largest f_bw meeting the 6 dB rule there.
    let targets = [
        ("thesis-original", 8.46),
        ("thesis-mc", 10.98),
        ("thesis-ad", 2.66),
        ("thesis-mc-ad", 2.47),
        ("thesis-mc-redesigned", 11.01),
        ("thesis-ad-redesigned", 2.62),
        ("thesis-mc-ad-redesigned", 2.39),
    ];
    let rms: Vec<f64> = targets
        .iter()
        .map(|(n, _)| scan_rms_as_shipped(n))
        .collect();
    for ((name, target), got) in targets.iter().zip(&rms) {
        assert!((got - target).abs() < 0.1 * target, "{name}: {got} nm");
    }
    // The thesis' ordering: MC alone worse than the original, AD and MC+AD
    // about 3x better, the redesigned MC+AD better still (2.4 nm: within the
    // 6 dB rule at one sample of delay it gains less than the thesis' 2.1).
    assert!(rms[1] > rms[0]);
    assert!(rms[2] < rms[0] / 2.5 && rms[3] < rms[0] / 2.5);
    assert!(rms[6] < rms[3] && rms[6] < 2.45);
}

#[test]
fn the_fit_through_the_modified_feedforward_recovers_the_mc_result() {
    // From the mass alone, one fit through Appendix A's block reaches §10.1.
    let (rms, acc, _, _) = fitted_scan_rms("thesis-mc");
    assert!((rms - 10.98).abs() < 0.1 * 10.98, "{rms}");
    assert!((acc - 12.5).abs() < 0.1, "{acc}");
}

#[test]
fn original_loop_reproduces_table_3_7_and_the_fit_finds_the_mass() {
    let (rms, acc, _, trace) = fitted_scan_rms("thesis-original");
    // docs/control.md §10.1, bold column: 8.46 nm; the fit: Θ_acc = m = 12.5 kg.
    assert!((rms - 8.46).abs() < 0.1 * 8.46, "{rms}");
    assert!((acc - 12.5).abs() < 5e-4, "{acc}");
    assert_eq!(trace.rows.len(), 3000);
}

#[test]
fn active_damping_reproduces_table_3_7_and_its_damping() {
    let (rms, _, design, trace) = fitted_scan_rms("thesis-ad");
    // §10.1: 2.66 nm; AD about 3x better than the original 8.46 nm.
    assert!((rms - 2.66).abs() < 0.1 * 2.66, "{rms}");
    // Damping of flexible modes 1–3: 0.051 / 0.047 / 0.042 with the damping
    // force from x̂(k+1|k); 0.043 / 0.021 / 0.005 if it were one sample old.
    let damping = modal_damping(&design, Some(&trace), 0.202, 0.3);
    for (mode, want) in damping.iter().zip([0.051, 0.047, 0.042]) {
        let model = mode.closed_loop_model.unwrap();
        let identified = mode.identified.unwrap();
        assert!((model - want).abs() < 0.003, "{damping:?}");
        assert!((identified - want).abs() < 0.004, "{damping:?}");
    }
}

#[test]
fn without_active_damping_the_modes_keep_their_own_damping() {
    let (_, _, design, trace) = fitted_scan_rms("thesis-original");
    let damping = modal_damping(&design, Some(&trace), 0.202, 0.3);
    // The identification agrees with the closed-loop model (ζ near 0.005
    // above the 37 Hz loop). Mode 3 is left out: without AD its ring-down at
    // y5 is not separated from the lightly damped neighbours here (identified
    // −0.002 against the model's 0.005); with AD it is (see the AD test).
    for (i, mode) in damping.iter().enumerate().filter(|(i, _)| *i != 2) {
        let identified = mode.identified.unwrap();
        let model = mode.closed_loop_model.unwrap();
        assert!(
            (identified - model).abs() < 0.0015,
            "mode {}: {damping:?}",
            i + 1
        );
    }
}

/// With each command applied on arrival (docs/deadline.md) the fit takes its
/// regressors at the instant the command acts, t_k + τ_d, as the
/// controller does: fitted from the mass alone, the 30 µs MC case scans
/// as with its shipped gains, and the fit finds the rigid mass.
#[test]
fn the_feedforward_fit_holds_with_a_command_deadline() {
    let (fitted, acc, _, _) = fitted_scan_rms("thesis-mc-deadline-30us");
    let shipped = scan_rms_as_shipped("thesis-mc-deadline-30us");
    assert!(
        (fitted - shipped).abs() < 0.02 * shipped,
        "{fitted} vs {shipped} nm"
    );
    assert!((acc - 12.5).abs() < 1e-3, "Θ_acc {acc}");
}
