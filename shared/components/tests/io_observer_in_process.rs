//! The input–output observer (`observer.design = "io"`, docs/control.md
//! §12.2) in the loop, lockstep in one process on the thesis chain: with the
//! Kalman gain as its correction it is the Kalman observer, and with a
//! dynamic K(z) it runs the equations an offline simulation runs.

use flexloop_components::InProcessLoop;
use flexloop_control::discretise::zoh;
use flexloop_control::io_observer::{IoObserver, observer_based_correction};
use flexloop_control::kalman::{KalmanWeights, steady_state_kalman};
use flexloop_control::lqr::lqr;
use flexloop_control::models::thesis_reduced;
use flexloop_design::LoopDesign;
use flexloop_scenario::{Overrides, Scenario};
use nalgebra::{DMatrix, DVector};
use std::path::Path;

/// 0.3 s at 10 kHz: the scan starts at 0.01 s and moves the chain.
const TICKS: usize = 3000;

fn shipped(name: &str) -> (std::path::PathBuf, String) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    let text = std::fs::read_to_string(&path).unwrap();
    (path, text)
}

fn design(path: &Path, text: &str) -> LoopDesign {
    let s = Scenario::from_text(path, text, &Overrides::default()).unwrap();
    LoopDesign::from_scenario(&s).unwrap()
}

#[test]
fn observer_based_correction_is_the_kalman_predictor_in_lockstep() {
    // The default scenario: thesis chain y5, MC + AD, noise model, 10 kHz.
    let (path, kalman_text) = shipped("default");
    let io_text = kalman_text.replace(
        "design = \"kalman\"",
        "design = \"io\"\ncorrection = \"observer-based\"",
    );
    assert_ne!(io_text, kalman_text);
    let (kalman, io) = (design(&path, &kalman_text), design(&path, &io_text));
    let n = kalman.observer.estimate_map.nrows();
    assert_eq!(io.observer.estimate_map.nrows(), n);
    let mut a = InProcessLoop::new(&kalman).unwrap();
    let mut b = InProcessLoop::new(&io).unwrap();
    let mut largest = 0.0f64;
    for k in 0..TICKS {
        a.tick();
        b.tick();
        let (xa, xb) = (&a.estimate.x_hat[..n], &b.estimate.x_hat[..n]);
        let scale = xa.iter().fold(1e-300f64, |m, v| m.max(v.abs()));
        largest = largest.max(scale);
        for (i, (p, q)) in xa.iter().zip(xb).enumerate() {
            assert!(
                (p - q).abs() <= 1e-12 * scale,
                "tick {k}, state {i}: {p} vs {q}"
            );
        }
        assert_eq!(a.command.u[0], b.command.u[0], "tick {k}");
    }
    // The chain moved: the comparison was not of zeros.
    assert!(largest > 1e-9, "{largest}");
}

/// A TOML array of rows holding `m` exactly (Rust's `{:?}` of an f64 reads
/// back to the same number).
fn toml_matrix(m: &DMatrix<f64>) -> String {
    let rows: Vec<String> = (0..m.nrows())
        .map(|i| {
            let row: Vec<String> = (0..m.ncols()).map(|j| format!("{:?}", m[(i, j)])).collect();
            format!("[{}]", row.join(", "))
        })
        .collect();
    format!("[{}]", rows.join(", "))
}

#[test]
fn dynamic_correction_from_arrays_runs_the_offline_equations_in_lockstep() {
    // The observer's model as the design reduces the chain for y5 (rigid
    // mode + 3 flexible, T_DC of the rest), ZOH at 10 kHz.
    let ts = 1e-4;
    let model = zoh(&thesis_reduced(5).unwrap().state_space(), ts).unwrap();
    let n = model.states();
    // K(z) = (A − BF − LC, L, F, 0) by separation: a Kalman L and an LQ F.
    let l = steady_state_kalman(&model, &KalmanWeights::thesis(&model))
        .unwrap()
        .l;
    let q = model.c.transpose() * &model.c * 1e12 + DMatrix::identity(n, n) * 1e-6;
    let f = lqr(&model.a, &model.b, &q, &DMatrix::identity(1, 1))
        .unwrap()
        .gain;
    let k = observer_based_correction(&model, &f, &l).unwrap();
    let io = IoObserver::input_correction(model.clone(), k.clone()).unwrap();
    assert!(io.radius() < 1.0 && io.filter_radius().unwrap() < 1.0);
    let nk = k.states();
    assert_eq!(nk, n);

    let (path, text) = shipped("default");
    let text = text.replace("design = \"kalman\"", "design = \"io\"").replace(
        "q_nu = 1000.0\n",
        &format!(
            "[observer.correction_arrays]\nA_K = {}\nB_K = {}\nC_K = {}\nD_K = {}\nts = {ts:?}\n",
            toml_matrix(&k.a),
            toml_matrix(&k.b),
            toml_matrix(&k.c),
            toml_matrix(&k.d)
        ),
    );
    // The table ends the [observer] section: the fields after q_nu move up.
    let text = text.replace("damping_increase = 0.035\nbandpass_q = 2.0\n", "");
    let text = text.replace(
        "design = \"io\"\n",
        "design = \"io\"\ndamping_increase = 0.035\nbandpass_q = 2.0\n",
    );
    let d = design(&path, &text);
    assert_eq!(d.observer.estimate_map.nrows(), n + nk);
    let mut lp = InProcessLoop::new(&d).unwrap();

    // The offline simulation: plain nalgebra on the logged y(k) and u_a(k).
    let (a, b, c, dd) = (&model.a, &model.b, &model.c, &model.d);
    let mut x = DVector::<f64>::zeros(n);
    let mut w = DVector::<f64>::zeros(nk);
    let mut largest = 0.0f64;
    for tick in 0..TICKS {
        lp.tick();
        let y = DVector::from_column_slice(&lp.measurement.y[..1]);
        let u = DVector::from_column_slice(&lp.measurement.u_applied[..1]);
        let rho = &y - c * &x - dd * &u;
        let nu = &k.c * &w + &k.d * &rho;
        x = a * &x + b * &u + b * &nu;
        w = &k.a * &w + &k.b * &rho;
        let got = &lp.estimate.x_hat[..n + nk];
        let want: Vec<f64> = x.iter().chain(w.iter()).copied().collect();
        let scale = want.iter().fold(1e-300f64, |m, v| m.max(v.abs()));
        largest = largest.max(scale);
        for (i, (g, e)) in got.iter().zip(&want).enumerate() {
            assert!(
                (g - e).abs() <= 1e-9 * scale,
                "tick {tick}, state {i}: loop {g} vs offline {e}"
            );
        }
    }
    assert!(largest > 1e-9, "{largest}");
    // Stable: the loop tracked the scan, the estimate followed the plant.
    let e_true = (lp.command.r[0] - lp.measurement.y_true[0]).abs();
    assert!(e_true < 1e-7, "tracking error {e_true} m");
    let innovation = lp.estimate.innovation[0].abs();
    assert!(innovation < 1e-8, "innovation {innovation} m");
}

#[test]
fn the_flexible_joint_population_runs_with_the_io_observer() {
    // 20 s at 200 Hz of the joint's sine on both hubs, with the scenarios'
    // force and sensor noise: the estimate follows the hubs on every member.
    for name in [
        "flexible-joint",
        "flexible-joint-k080",
        "flexible-joint-k120",
    ] {
        let (path, text) = shipped(name);
        let d = design(&path, &text);
        let mut l = InProcessLoop::new(&d).unwrap();
        let ticks = 4000;
        let (mut innovation, mut tracking) = (0.0f64, 0.0f64);
        for k in 0..ticks {
            l.tick();
            if k >= ticks / 2 {
                for i in 0..2 {
                    innovation = innovation.max(l.estimate.innovation[i].abs());
                    tracking = tracking.max((l.command.r[i] - l.measurement.y_true[i]).abs());
                }
            }
        }
        // The innovation stays at the sensor noise (σ 0.1 mrad, the largest
        // of 4000 draws is about 4 σ); the hubs follow the 0.2 rad sine.
        assert!(innovation < 1e-3, "{name}: innovation {innovation} rad");
        assert!(tracking < 0.02, "{name}: tracking error {tracking} rad");
        assert_eq!(l.plant.counters.misses, 0, "{name}");
    }
}
