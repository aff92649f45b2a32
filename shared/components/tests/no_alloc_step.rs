//! The thesis default design (`scenarios/default.toml`: Kalman observer with
//! noise model, MC + AD, PID, modified feedforward) runs its per-sample path
//! (plant tick, observer step, controller step, as lockstep runs them) without
//! one allocation. The global allocator aborts the test process on any
//! allocation inside `assert_no_alloc`, in debug and release builds alike (the
//! workspace turns off the crate's `disable_release`); the last test checks
//! that the guard really is armed in the profile it was built in.

use assert_no_alloc::{AllocDisabler, assert_no_alloc};
use flexloop_components::InProcessLoop;
use flexloop_design::LoopDesign;
use flexloop_scenario::{Overrides, Scenario};
use std::path::PathBuf;
use std::process::Command;

#[global_allocator]
static ALLOCATOR: AllocDisabler = AllocDisabler;

/// 0.5 s at 10 kHz: the scan starts at 10 ms, so most of it is in motion.
const TICKS: usize = 5000;

fn default_scenario() -> Scenario {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/default.toml");
    Scenario::load(&path, &Overrides::default()).unwrap()
}

/// Runs `TICKS` lockstep ticks inside the guard; returns the loop and the
/// largest |u_ff|, |u_d| and |ŷ_flex| seen, to show every part was working.
fn run_guarded(design: &LoopDesign) -> (InProcessLoop, [f64; 3]) {
    let mut l = InProcessLoop::new(design).unwrap();
    let mut peaks = [0.0f64; 3];
    assert_no_alloc(|| {
        for _ in 0..TICKS {
            l.tick();
            let parts = [
                l.command.u_ff[0],
                l.command.u_d[0],
                l.used_estimate.free[0] + l.used_estimate.direct[0] * l.measurement.y[0],
            ];
            for (peak, v) in peaks.iter_mut().zip(parts) {
                *peak = peak.max(v.abs());
            }
        }
    });
    (l, peaks)
}

#[test]
fn thesis_default_loop_does_not_allocate() {
    let s = default_scenario();
    assert!(s.observer.mc && s.observer.ad, "default is MC + AD");
    assert_eq!(s.controller.feedforward_form, "modified");
    let design = LoopDesign::from_scenario(&s).unwrap();
    assert!(design.feedback.is_some() && design.modified_feedforward.is_some());
    let (l, [u_ff, u_d, y_flex]) = run_guarded(&design);
    assert!(
        u_ff > 0.0 && u_d > 0.0 && y_flex > 0.0,
        "{u_ff} {u_d} {y_flex}"
    );
    assert_eq!(l.plant.counters.misses, 0);
    assert_eq!(l.next_tick(), TICKS as u64);
}

/// The default scenario with Gaussian disturbances in the plant (its other
/// per-sample branch).
fn with_noise() -> Scenario {
    let mut s = default_scenario();
    s.plant.force_noise = 0.01;
    s.plant.sensor_noise = 1e-9;
    s.plant.reference_noise = 1e-9;
    s
}

#[test]
fn thesis_default_with_noise_does_not_allocate() {
    let s = with_noise();
    s.validate().unwrap();
    let design = LoopDesign::from_scenario(&s).unwrap();
    let (l, [u_ff, u_d, y_flex]) = run_guarded(&design);
    assert!(
        u_ff > 0.0 && u_d > 0.0 && y_flex > 0.0,
        "{u_ff} {u_d} {y_flex}"
    );
    assert_eq!(l.plant.counters.misses, 0);
}

#[test]
fn thesis_extra_delay_does_not_allocate() {
    // One more sample of loop delay: the observer block takes u_pending and the
    // plant runs its delay line. The modified feedforward refuses extra delay,
    // so this one uses the plain four-gain filter.
    let mut s = with_noise();
    s.controller.extra_delay_samples = 1;
    s.controller.feedforward_form = "plain".into();
    s.validate().unwrap();
    let design = LoopDesign::from_scenario(&s).unwrap();
    assert_eq!(design.observer.extra_delay_samples, 1);
    let (l, [u_ff, u_d, y_flex]) = run_guarded(&design);
    assert!(
        u_ff > 0.0 && u_d > 0.0 && y_flex > 0.0,
        "{u_ff} {u_d} {y_flex}"
    );
    assert_eq!(l.plant.counters.misses, 0);
}

#[test]
fn a_command_applied_on_arrival_does_not_allocate() {
    // The plant's two-piece sample (the held input through D = C G_new),
    // the observer's estimate at t_k + τ_d, the feedforward at that instant.
    let mut s = with_noise();
    s.timing.command_deadline_us = Some(30.0);
    s.validate().unwrap();
    let design = LoopDesign::from_scenario(&s).unwrap();
    assert_eq!(design.command_deadline_s, Some(30e-6));
    let (l, [u_ff, u_d, y_flex]) = run_guarded(&design);
    assert!(
        u_ff > 0.0 && u_d > 0.0 && y_flex > 0.0,
        "{u_ff} {u_d} {y_flex}"
    );
    assert_eq!(l.plant.counters.misses, 0);
}

fn shipped(name: &str) -> Scenario {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(format!("{name}.toml"));
    Scenario::load(&path, &Overrides::default()).unwrap()
}

#[test]
fn mimo_loops_do_not_allocate() {
    // Every input and output of the 3x3 OAT-like loop and the 2x2 example:
    // decoupled PID, MC + AD, modified feedforward, per-output reference.
    for name in ["oat-like", "mimo-example"] {
        let design = LoopDesign::from_scenario(&shipped(name)).unwrap();
        assert!(design.n_inputs > 1 && design.n_outputs > 1);
        let (l, [u_ff, u_d, _]) = run_guarded(&design);
        assert!(u_ff > 0.0 && u_d > 0.0, "{name}: {u_ff} {u_d}");
        assert_eq!(l.plant.counters.misses, 0);
    }
}

#[test]
fn a_scheduled_observer_does_not_allocate() {
    // A sensor the chain scans past: the plant's output row and the
    // observer's gain (interpolated, then the Riccati recursion) every tick.
    for scheduling in ["interpolated", "time-varying"] {
        let mut s = shipped("thesis-sensor-scan-ad");
        s.observer.scheduling = scheduling.into();
        s.observer.mc = true;
        s.validate().unwrap();
        let design = LoopDesign::from_scenario(&s).unwrap();
        assert!(design.sensor_scan.is_some());
        let (l, [u_ff, u_d, y_flex]) = run_guarded(&design);
        assert!(
            u_ff > 0.0 && u_d > 0.0 && y_flex > 0.0,
            "{scheduling}: {u_ff} {u_d} {y_flex}"
        );
        assert_eq!(l.observer.schedule_errors(), 0);
    }
}

/// Set only by [`the_guard_aborts_on_an_allocation`] for its child process.
const CANARY: &str = "FLEXLOOP_NO_ALLOC_CANARY";

/// Allocates inside the guard when [`CANARY`] is set (and so aborts); does
/// nothing in an ordinary run.
#[test]
fn canary_allocates_inside_the_guard() {
    if std::env::var_os(CANARY).is_some() {
        let v = assert_no_alloc(|| std::hint::black_box(vec![1u8; 16]));
        assert_eq!(v.len(), 16, "unreachable: the allocation above must abort");
    }
}

#[test]
fn the_guard_aborts_on_an_allocation() {
    // Without this, a build where the guard is compiled out (release with
    // assert_no_alloc's default `disable_release`) would pass the tests above without checking anything.
    let out = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "canary_allocates_inside_the_guard",
            "--test-threads=1",
        ])
        .env(CANARY, "1")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "the canary's allocation went through"
    );
    assert!(
        stderr.contains("memory allocation of 16 bytes failed"),
        "the canary failed for another reason: {stderr}"
    );
}

/// The hand-over path runs every sample too: each active instance saves its
/// state, a shadow loads it (a retuned observer the estimate alone), the
/// plant reads the activation, and a retuned replacement shifts its
/// integrator once.
#[test]
fn hand_over_path_does_not_allocate() {
    use flexloop_components::{ControllerCore, ObserverCore};
    use flexloop_protocol::{Activation, Command, Estimate, Handover};
    let design = LoopDesign::from_scenario(&default_scenario()).unwrap();
    let mut l = InProcessLoop::new(&design).unwrap();
    let mut shadow_controller = ControllerCore::new(&design, 1);
    let mut shadow_observer = ObserverCore::new(
        &design.observer,
        &design.output_prediction,
        design.n_outputs,
        design.n_inputs,
    )
    .unwrap();
    // A retuned observer (same model) continues the estimate instead.
    let mut retuned = default_scenario();
    retuned.observer.damping_increase = 0.05;
    let mut retuned_observer =
        ObserverCore::for_design(&LoopDesign::from_scenario(&retuned).unwrap()).unwrap();
    let mut retuned_estimate = Box::<Estimate>::default();
    let mut continued = 0;
    let mut controller_state = Box::<Handover>::default();
    let mut observer_state = Box::<Handover>::default();
    let mut shadow_command = Box::<Command>::default();
    let mut shadow_estimate = Box::<Estimate>::default();
    let activation = Activation {
        controller_from_seq: TICKS as u64 / 2,
        controller_generation: 1,
        ..Activation::INITIAL
    };
    let mut loaded = 0;
    assert_no_alloc(|| {
        for _ in 0..TICKS {
            l.plant.set_activation(&activation);
            let m = l.measurement;
            if shadow_controller.load(&controller_state) {
                loaded += 1;
            }
            shadow_observer.load(&observer_state);
            if retuned_observer.load(&observer_state) {
                continued += 1;
            }
            retuned_observer.step(&m, &mut retuned_estimate);
            shadow_controller.step(&m, &l.estimate, &mut shadow_command);
            shadow_observer.step(&m, &mut shadow_estimate);
            l.tick();
            l.controller.save(&mut controller_state);
            controller_state.seq = l.measurement.seq;
            l.observer.save(&mut observer_state);
            observer_state.seq = l.measurement.seq;
        }
        shadow_controller.shift_output(&[1.0]);
        shadow_controller.fast_forward(2 * TICKS as u64);
    });
    assert!(loaded > TICKS / 2, "the shadow took over the state");
    assert!(
        continued > TICKS / 2,
        "the retuned observer continued the estimate"
    );
}

#[test]
fn an_io_observer_does_not_allocate() {
    // The input-output observer compiles into the same block form: MC, AD
    // and the step are the Kalman observer's (docs/control.md §12.3).
    let mut s = default_scenario();
    s.observer.design = "io".into();
    s.observer.correction = Some("observer-based".into());
    s.validate().unwrap();
    let design = LoopDesign::from_scenario(&s).unwrap();
    let (l, [u_ff, u_d, y_flex]) = run_guarded(&design);
    assert!(
        u_ff > 0.0 && u_d > 0.0 && y_flex > 0.0,
        "{u_ff} {u_d} {y_flex}"
    );
    assert_eq!(l.plant.counters.misses, 0);
}

/// The plant (and at the reference the controller) running a scenario's
/// `[measure]` (docs/control.md §14), at each point and of each signal: through the excitation's fade in, its
/// periods, its fade out (a stepped sine's from tone to tone) and after it.
#[test]
fn an_excited_plant_does_not_allocate() {
    let points = ["plant-input", "sensor", "reference"];
    let signals = ["multisine", "swept-sine", "stepped-sine"];
    for (point, signal) in points.iter().flat_map(|p| signals.map(|s| (*p, s))) {
        let mut s = default_scenario();
        // A stepped sine's two tones of a transient and a measured period
        // with their fade-outs: 0.05 s + 2 × 3 periods of 500.
        let (lines, periods) = if signal == "stepped-sine" {
            (2, 1)
        } else {
            (30, 3)
        };
        let text = format!(
            "point = \"{point}\"\nsignal = \"{signal}\"\nf_min_hz = 20.0\n\
             f_max_hz = 2000.0\nlines = {lines}\nperiod_samples = 500\namplitude = 1e-7\n\
             transient_periods = 1\nperiods = {periods}\nstart_s = 0.05"
        );
        s.measure = Some(toml::from_str(&text).unwrap());
        if point == "plant-input" {
            s.measure.as_mut().unwrap().amplitude = 0.05 * s.plant.input_limit;
        }
        s.validate().unwrap();
        let design = LoopDesign::from_scenario(&s).unwrap();
        let plan = design.measurement.clone().unwrap();
        // Past the fade out: 0.05 s + 5 periods = 3000 ticks (3500 stepped).
        assert!(plan.end_tick() < TICKS as u64, "{signal}");
        let mut l = InProcessLoop::new(&design).unwrap();
        let mut largest = 0.0_f64;
        assert_no_alloc(|| {
            for _ in 0..TICKS {
                l.tick();
                largest = largest.max(l.plant.excitation().abs());
            }
        });
        assert!(largest > 0.0, "{point} {signal}");
        assert_eq!(
            l.plant.excitation(),
            0.0,
            "{point} {signal}: off after the fade out"
        );
        assert_eq!(l.plant.counters.misses, 0);
    }
}
