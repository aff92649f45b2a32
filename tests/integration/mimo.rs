//! The MIMO example, the OAT-like model, the two-inertia setup and the
//! lecture's double integrator through the real processes, in lockstep
//! (deterministic): every recorded tick equals the in-process loop of the
//! same design bit for bit, the loop is stable (finite, bounded estimates; the
//! error settles once the motion stops) and it tracks on every axis, within
//! bounds derived from the in-process run.

use crate::util::*;
use flexloop_analysis::{ControlMetrics, MetricsOptions, RunTrace};
use flexloop_components::InProcessLoop;
use flexloop_design::LoopDesign;
use flexloop_recording::LogReader;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::metrics::MetricsFile;
use flexloop_scenario::{Mode, Overrides, Scenario};
use std::time::Duration;

/// One scenario run twice: through the processes and in process.
pub struct Runs {
    pub design: LoopDesign,
    pub ticks: usize,
    pub process: RunTrace,
    pub in_process: RunTrace,
    /// `flexloop run`'s metrics.json and its printed report.
    pub metrics: MetricsFile,
    pub stdout: String,
}

fn run_both(name: &str, duration_s: Option<f64>) -> Runs {
    run_file(&scenario(name), name, duration_s)
}

/// Runs the scenario file `path` through the processes (run directory named
/// after `label`) and in process.
pub fn run_file(path: &std::path::Path, label: &str, duration_s: Option<f64>) -> Runs {
    let dir = temp_dir(&format!("mimo-{label}"));
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(path)
        .args(["--mode", "lockstep", "--no-realtime", "--run-dir"])
        .arg(&dir);
    if let Some(d) = duration_s {
        cmd.args(["--duration", &d.to_string()]);
    }
    let out = run_bounded(cmd, Duration::from_secs(240));
    assert!(out.status.success(), "{}", describe(&out));
    let metrics = metrics(&dir);
    assert_clean(&dir);

    let overrides = Overrides {
        mode: Some(Mode::Lockstep),
        duration_s,
        no_realtime: true,
        ..Overrides::default()
    };
    let s = Scenario::load(path, &overrides).unwrap();
    let design = LoopDesign::from_scenario(&s).unwrap();
    let ticks = s.ticks().unwrap() as usize;
    let log = LogReader::open(&dir.join(RunDir::SAMPLES)).unwrap();
    let process = RunTrace::from_log(&log, design.ts);
    let mut in_process_loop = InProcessLoop::new(&design).unwrap();
    let in_process = RunTrace::simulate(&mut in_process_loop, design.ts, ticks as u64);
    Runs {
        design,
        ticks,
        process,
        in_process,
        metrics,
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
    }
}

impl Runs {
    /// Every tick the log holds is the in-process tick of the same sequence,
    /// bit for bit (the logger may lose samples on a starved machine, and
    /// counts them; it never alters one).
    pub fn assert_bit_exact(&self) {
        let (p, q) = (&self.process, &self.in_process);
        assert_eq!(p.n_outputs, self.design.n_outputs);
        assert_eq!(p.n_inputs, self.design.n_inputs);
        assert!(
            p.rows.len() * 2 >= self.ticks,
            "only {} of {} ticks logged",
            p.rows.len(),
            self.ticks
        );
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
        for (i, row) in p.rows.iter().enumerate() {
            let k = row.seq as usize;
            assert_eq!(q.rows[k].seq, row.seq);
            assert_eq!(
                bits(p.e_true_of(i)),
                bits(q.e_true_of(k)),
                "e_true at tick {k}"
            );
            assert_eq!(bits(p.u_of(i)), bits(q.u_of(k)), "u at tick {k}");
            assert_eq!(bits(p.x_hat(i)), bits(q.x_hat(k)), "x̂ at tick {k}");
        }
    }

    /// Per-axis metrics of the in-process run over the scenario's scan windows.
    pub fn in_process_metrics(&self) -> ControlMetrics {
        let end = self.ticks as f64 * self.design.ts;
        let windows = self.design.reference.scan_windows(end);
        ControlMetrics::compute(&self.in_process, &windows, &MetricsOptions::default())
    }

    /// Stable: every estimate finite, and after the motion the estimate is
    /// no larger than during it (nothing grows).
    pub fn assert_bounded_estimates(&self) {
        let q = &self.in_process;
        let n = q.rows.len();
        let peak = |from: usize, to: usize| {
            (from..to)
                .flat_map(|i| q.x_hat(i).iter())
                .fold(0.0f64, |m, v| {
                    assert!(v.is_finite(), "non-finite estimate");
                    m.max(v.abs())
                })
        };
        let last_tenth = peak(n - n / 10, n);
        assert!(
            last_tenth <= peak(0, n - n / 10) * 1.0001,
            "the estimate grows"
        );
        for i in 0..n {
            assert!(
                q.e_true_of(i)
                    .iter()
                    .chain(q.u_of(i))
                    .all(|v| v.is_finite())
            );
        }
    }

    /// What `flexloop run` printed and wrote names the measured outputs and,
    /// for a MIMO loop, gives every axis its own numbers equal to the
    /// in-process ones when the log is complete.
    fn assert_reported_per_axis(&self, m: &ControlMetrics) {
        for name in &self.design.output_names {
            assert!(
                self.stdout.contains(name.as_str()),
                "{name}:\n{}",
                self.stdout
            );
        }
        let axes = self.metrics.control["axes"].as_array().unwrap();
        assert_eq!(axes.len(), self.design.n_outputs);
        assert_eq!(self.metrics.outputs.len(), axes.len());
        if self.design.n_outputs > 1 {
            assert!(self.stdout.contains("per axis"), "{}", self.stdout);
        }
        if self.process.rows.len() == self.ticks {
            // Equal numbers, up to the last digit serde_json's parser may lose.
            for (json, want) in axes.iter().zip(&m.axes) {
                let got = json["e_true"]["rms"].as_f64().unwrap();
                assert!((got - want.e_true.rms).abs() <= 1e-14 * want.e_true.rms);
            }
        }
    }
}

/// A scan scenario: bit-exact with the in-process loop, stable, and
/// tracking on every axis. `bounds` are the largest scan rms of e_true per
/// output: twice what this design reaches in process, so that a retune that
/// loses the tracking fails while the figures themselves are the in-process
/// ones, which the processes must equal.
pub fn assert_scan_tracks(r: &Runs, bounds: &[f64]) -> ControlMetrics {
    r.assert_bit_exact();
    r.assert_bounded_estimates();
    let m = r.in_process_metrics();
    r.assert_reported_per_axis(&m);
    assert_eq!(m.axes.len(), bounds.len());
    for (axis, (a, bound)) in m.axes.iter().zip(bounds).enumerate() {
        let name = &r.design.output_names[axis];
        let rms = a.rms_e_true_scan.unwrap();
        assert!(rms < *bound, "{name}: scan rms {rms:e}, bound {bound:e}");
        // Settled: once the motion is over the error is a small part of its
        // peak (a growing or ringing loop fails this).
        assert!(
            a.settled_peak_e_true < 0.1 * a.e_true.peak,
            "{name}: settled {:e} vs peak {:e}",
            a.settled_peak_e_true,
            a.e_true.peak
        );
    }
    m
}

#[test]
fn mimo_example_runs_through_the_processes_as_in_process() {
    let r = run_both("mimo-example", None);
    assert_eq!((r.design.n_outputs, r.design.n_inputs), (2, 2));
    // In process: 421 nm on y1 (scanning), 213 nm on y2 (held): the first
    // flexible mode at 161 Hz leaves far more than the thesis chain's 470 Hz.
    let m = assert_scan_tracks(&r, &[1.0e-6, 0.5e-6]);
    // y2 is held while y1 scans: the decoupled feedforward drives both
    // actuators (one mostly: the scan is a rotation about the other).
    assert!(m.inputs.iter().all(|u| u.peak > 10.0), "{:?}", m.inputs);
}

#[test]
fn oat_like_model_runs_through_the_processes_as_in_process() {
    let r = run_both("oat-like", None);
    assert_eq!((r.design.n_outputs, r.design.n_inputs), (3, 3));
    // In process: 63–66 nm on each encoder over a 1 mm heave scan.
    let m = assert_scan_tracks(&r, &[150e-9; 3]);
    // Heave: all three encoders move together and track alike.
    let rms: Vec<f64> = m.axes.iter().map(|a| a.rms_e_true_scan.unwrap()).collect();
    let (lo, hi) = rms
        .iter()
        .fold((f64::MAX, 0.0f64), |(l, h), v| (l.min(*v), h.max(*v)));
    assert!(hi < 1.5 * lo, "{rms:?}");
}

#[test]
fn two_inertia_setup_runs_through_the_processes_as_in_process() {
    let r = run_both("two-inertia", None);
    assert_eq!(r.design.output_unit, "rad");
    assert!(r.stdout.contains("θ1 (load)"), "{}", r.stdout);
    // In process: 0.32 mrad over a 0.17 rad scan with the 5 Hz loop.
    assert_scan_tracks(&r, &[0.6e-3]);
}

#[test]
fn lecture_double_integrator_runs_through_the_processes_as_in_process() {
    let r = run_both("lecture-double-integrator", Some(0.5));
    r.assert_bit_exact();
    r.assert_bounded_estimates();
    let m = r.in_process_metrics();
    r.assert_reported_per_axis(&m);
    // A 1 mm, 2 Hz sine with state feedback and the lecture's feedforward.
    // The sine starts at full speed, so the loop first catches up (peak
    // 47 µm in process); once on the sine the error is nanometres (6 nm in
    // the last tenth in process): the observer and the feedforward track it.
    let a = &m.axes[0];
    assert!(a.e_true.peak < 0.1 * 1e-3, "peak {:e}", a.e_true.peak);
    assert!(
        a.settled_peak_e_true < 1e-3 * a.e_true.peak,
        "settled {:e} vs peak {:e}",
        a.settled_peak_e_true,
        a.e_true.peak
    );
}

#[test]
fn design_reports_name_the_outputs_measured() {
    // MIMO: every output, its sensitivity peaks, the 6 dB rule; the chain
    // with a scanned sensor: that sensor, not y5.
    for (name, outputs) in [
        ("mimo-example", vec!["y1 (x = -0.25 m)", "y2 (x = +0.25 m)"]),
        ("two-inertia", vec!["θ1 (load)"]),
        ("thesis-sensor-scan-ad", vec!["sensor scanned 0 -> 7"]),
    ] {
        let mut cmd = flexloop();
        cmd.arg("design").arg(scenario(name));
        let out = run_bounded(cmd, Duration::from_secs(120));
        assert!(out.status.success(), "{}", describe(&out));
        let text = String::from_utf8_lossy(&out.stdout);
        for o in outputs {
            assert!(text.contains(o), "{name}: no {o} in\n{text}");
        }
        assert!(text.contains("6 dB rule met"), "{name}:\n{text}");
        assert!(!text.contains("output y5"), "{name}:\n{text}");
    }
    let mut cmd = flexloop();
    cmd.args(["design", "--json"]).arg(scenario("oat-like"));
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["loop"]["axes"].as_array().unwrap().len(), 3);
    assert_eq!(v["loop"]["meets_6db_rule"], true);
    assert!(v["study"].is_null());
}
