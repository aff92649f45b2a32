//! A sensor the thesis chain scans past, through the real processes in
//! lockstep: the plant's output row and the observer's Kalman gain follow
//! the position every tick, bit for bit as the in-process loop, with the
//! gain interpolated from steady-state ones or from the Riccati recursion
//! (the thesis: no significant difference).

use crate::mimo::{assert_scan_tracks, run_file};
use crate::util::*;
use flexloop_analysis::{ControlMetrics, MetricsOptions, RunTrace};
use flexloop_components::{InProcessLoop, ObserverCore};
use flexloop_design::LoopDesign;
use flexloop_scenario::{Overrides, Scenario};

#[test]
fn a_scanned_sensor_schedules_the_observer_across_the_processes() {
    let interpolated = run_file(
        &scenario("thesis-sensor-scan-ad"),
        "sensor-scan-interpolated",
        None,
    );
    assert!(interpolated.design.sensor_scan.is_some());
    // In process: 184 nm (the y5 feedforward's snap gain is not scheduled).
    let m_int = assert_scan_tracks(&interpolated, &[400e-9]);
    assert!(
        interpolated.stdout.contains("sensor scanned 0 -> 7"),
        "{}",
        interpolated.stdout
    );

    let dir = temp_dir("sensor-scan-tv-file");
    let path = scenario_variant(
        &dir,
        "thesis-sensor-scan-ad",
        "thesis-sensor-scan-ad-tv.toml",
        &[(
            "\nscheduling = \"interpolated\"",
            "\nscheduling = \"time-varying\"",
        )],
        "",
    );
    let time_varying = run_file(&path, "sensor-scan-tv", None);
    let m_tv = assert_scan_tracks(&time_varying, &[400e-9]);
    // The two schedulings give the same tracking (the thesis' §5.6), but
    // they are different filters: the runs are not identical.
    let (a, b) = (
        m_int.rms_e_true_scan.unwrap(),
        m_tv.rms_e_true_scan.unwrap(),
    );
    assert!(
        (a - b).abs() < 1e-3 * a,
        "interpolated {a:e}, time-varying {b:e}"
    );
    assert_ne!(
        interpolated.in_process.x_hat, time_varying.in_process.x_hat,
        "the schedulings ran the same filter"
    );

    // The scan matters: with the sensor held where the scan starts the run's
    // error is another (over the run; the scan windows differ by 2 %).
    let mut fixed =
        Scenario::load(&scenario("thesis-sensor-scan-ad"), &Overrides::default()).unwrap();
    fixed.plant.sensor_scan = None;
    fixed.set_sensor_position(0.0);
    fixed.validate().unwrap();
    let design = LoopDesign::from_scenario(&fixed).unwrap();
    let mut l = InProcessLoop::new(&design).unwrap();
    let trace = RunTrace::simulate(&mut l, design.ts, fixed.ticks().unwrap());
    let windows = design.reference.scan_windows(fixed.timing.duration_s);
    let held = ControlMetrics::compute(&trace, &windows, &MetricsOptions::default());
    let (c, d) = (held.e_true.rms, m_int.e_true.rms);
    assert!((c - d).abs() > 0.1 * d, "held {c:e} vs scanned {d:e}");

    // The schedule matters: the same scan with the observer frozen where the
    // scan starts (its fixed block) predicts the moving sensor far worse.
    let design = &interpolated.design;
    let mut frozen = InProcessLoop::new(design).unwrap();
    frozen.observer = ObserverCore::new(
        &design.observer,
        &design.output_prediction,
        design.n_outputs,
        design.n_inputs,
    )
    .unwrap();
    let trace = RunTrace::simulate(&mut frozen, design.ts, interpolated.ticks as u64);
    let windows = design.reference.scan_windows(1.0);
    let frozen = ControlMetrics::compute(&trace, &windows, &MetricsOptions::default());
    let (scheduled_std, frozen_std) = (m_int.innovation.std, frozen.innovation.std);
    assert!(
        frozen_std > 10.0 * scheduled_std,
        "innovation std: scheduled {scheduled_std:e}, frozen {frozen_std:e}"
    );
}
