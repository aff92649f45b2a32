//! Bad input to the design and per-sample code returns a clear error, never a
//! panic or a NaN: each case checks the error variant and that the message
//! names what is wrong.

use flexloop_control::dare::{DareError, solve_dare};
use flexloop_control::design_error::DesignError;
use flexloop_control::discretise::zoh;
use flexloop_control::io_observer::IoObserver;
use flexloop_control::kalman::{KalmanWeights, steady_state_kalman};
use flexloop_control::lecture::place_observer;
use flexloop_control::lqr::{lqr, lqr_with_integral_action};
use flexloop_control::lti::{DiscreteStateSpace, StateSpaceError};
use flexloop_control::matrix_error::MatrixError;
use flexloop_control::modal::{ModalDamping, ModalModel, ModelError};
use flexloop_control::models::{
    TS_10KHZ, chain, flexible_joint, mimo_example, thesis_chain_modal, thesis_reduced,
};
use flexloop_control::modified_feedforward::modified_feedforward;
use flexloop_control::observer_block::thesis_observer_block;
use flexloop_control::pid::thesis_pid;
use flexloop_control::placement::{robust_place, robust_place_observer};
use flexloop_control::scheduling::{
    InterpolatedKalman, KalmanSchedule, ModelSchedule, PositionGrid, ScheduleError,
    TimeVaryingKalman,
};
use flexloop_control::step_error::StepError;
use flexloop_control::stiffness::{ActiveStiffness, StiffnessMethod};
use nalgebra::{Complex, DMatrix};

/// The message of an error, checked to contain every fragment.
fn says<E: std::fmt::Display>(err: &E, fragments: &[&str]) {
    let msg = err.to_string();
    for f in fragments {
        assert!(msg.contains(f), "message {msg:?} does not mention {f:?}");
    }
}

fn thesis_model() -> DiscreteStateSpace {
    zoh(&thesis_reduced(5).unwrap().state_space(), TS_10KHZ).unwrap()
}

fn real_poles(n: usize) -> Vec<Complex<f64>> {
    (0..n).map(|k| Complex::new(0.1 * k as f64, 0.0)).collect()
}

// --- singular mass matrix ---------------------------------------------------

#[test]
fn singular_mass_matrix() {
    // A massless node in the thesis chain.
    let mut masses = [10.0 / 7.0; 8];
    masses[3] = 0.0;
    let nodal = chain(&masses, &[1e8; 7], ModalDamping::Uniform(0.005), &[0], &[5]).unwrap();
    let err = ModalModel::from_nodal(&nodal).unwrap_err();
    assert_eq!(err, ModelError::MassNotPositiveDefinite);
    says(&err, &["mass matrix", "positive definite"]);
    // A negative mass is refused the same way.
    masses[3] = -1.0;
    let nodal = chain(&masses, &[1e8; 7], ModalDamping::Uniform(0.005), &[0], &[5]).unwrap();
    assert_eq!(
        ModalModel::from_nodal(&nodal),
        Err(ModelError::MassNotPositiveDefinite)
    );
}

// --- unobservable or undetectable pairs --------------------------------------

#[test]
fn undetectable_kalman_design() {
    // Measure only flexible mode 3: the rigid mode (poles at z = 1) is not
    // detectable, so the filter DARE has no stabilising solution.
    let mut model = thesis_model();
    model.c.fill(0.0);
    model.c[(0, 6)] = 0.3;
    let err = steady_state_kalman(&model, &KalmanWeights::thesis(&model)).unwrap_err();
    assert!(
        matches!(
            err,
            DesignError::Dare(DareError::NotStabilising { .. } | DareError::NoConvergence { .. })
        ),
        "{err:?}"
    );
    says(&err, &["DARE"]);
    let msg = err.to_string();
    assert!(
        msg.contains("stabilis") || msg.contains("detectable"),
        "{msg}"
    );
}

#[test]
fn unobservable_pole_placement() {
    // MIMO example seen by one sensor that misses the rotation (rigid mode 2).
    let p = zoh(&mimo_example().unwrap().state_space(), 2e-4).unwrap();
    let mut c = p.c.rows(0, 1).into_owned();
    c.columns_mut(2, 2).fill(0.0);
    let err = robust_place_observer(&p.a, &c, &real_poles(10)).unwrap_err();
    assert_eq!(
        err,
        DesignError::NotObservable {
            rank: 8,
            states: 10
        }
    );
    says(&err, &["not observable", "rank W_o = 8 < 10"]);
    // The SISO lecture path reports the same variant.
    let di = flexloop_control::lecture::lecture_example(0.44).unwrap();
    let c0 = DMatrix::from_row_slice(1, 2, &[0.0, 1.0]); // velocity only
    let err = place_observer(&di.plant.a, &c0, &real_poles(2)).unwrap_err();
    assert!(
        matches!(err, DesignError::NotObservable { rank: 1, states: 2 }),
        "{err:?}"
    );
    says(&err, &["not observable"]);
}

#[test]
fn unreachable_pole_placement() {
    let p = zoh(&mimo_example().unwrap().state_space(), 2e-4).unwrap();
    let mut b = p.b.columns(0, 1).into_owned();
    b.rows_mut(2, 2).fill(0.0);
    let err = robust_place(&p.a, &b, &real_poles(10)).unwrap_err();
    assert_eq!(
        err,
        DesignError::NotReachable {
            rank: 8,
            states: 10
        }
    );
    says(&err, &["not reachable", "rank W_c = 8 < 10"]);
}

#[test]
fn schedule_names_the_bad_position() {
    // A sensor that, at one grid point, sees no rigid motion: that point's
    // Kalman design fails and the error names the position.
    let base = thesis_model();
    let grid = PositionGrid::new(0.0, 0.005, 5).unwrap();
    let models = ModelSchedule::new(grid, KalmanWeights::thesis(&base), |pos| {
        let mut m = base.clone();
        if (pos - 0.01).abs() < 1e-12 {
            m.c.fill(0.0);
            m.c[(0, 6)] = 0.3;
        }
        Ok(m)
    })
    .unwrap();
    let err = KalmanSchedule::design(models).unwrap_err();
    assert!(
        matches!(&err, ScheduleError::AtPosition { position, error: DesignError::Dare(_) }
            if (*position - 0.01).abs() < 1e-12),
        "{err:?}"
    );
    says(&err, &["at scheduling position 0.01", "DARE"]);
}

// --- DARE without a stabilising solution -------------------------------------

#[test]
fn dare_without_stabilising_solution() {
    // Unstable mode (z = 1.5) that B cannot reach.
    let a = DMatrix::from_row_slice(2, 2, &[1.5, 0.0, 0.0, 0.5]);
    let b = DMatrix::from_column_slice(2, 1, &[0.0, 1.0]);
    let q = DMatrix::identity(2, 2);
    let r = DMatrix::from_element(1, 1, 1.0);
    let err = solve_dare(&a, &b, &q, &r).unwrap_err();
    assert!(
        matches!(
            err,
            DareError::NotStabilising { .. } | DareError::NoConvergence { .. }
        ),
        "{err:?}"
    );
    says(&err, &["DARE"]);
    // lqr names the mode before trying the DARE.
    let via_lqr = lqr(&a, &b, &q, &r).unwrap_err();
    assert!(
        matches!(via_lqr, DesignError::InvalidParameter(_)),
        "{via_lqr:?}"
    );
    says(
        &via_lqr,
        &[
            "not stabilisable",
            "z = 1.500000",
            "no stabilising solution",
        ],
    );
    // Integral action on a plant with a zero at z = 1 (no DC gain).
    let plant = DiscreteStateSpace::new(
        DMatrix::from_element(1, 1, 0.5),
        DMatrix::from_element(1, 1, 1.0),
        DMatrix::from_element(1, 1, -0.5),
        DMatrix::from_element(1, 1, 1.0),
        0.1,
    )
    .unwrap();
    let one = DMatrix::identity(1, 1);
    let err = lqr_with_integral_action(&plant, &one, &one, &one).unwrap_err();
    assert!(matches!(err, DesignError::InvalidParameter(_)), "{err:?}");
    says(&err, &["not stabilisable", "z = 1.000000"]);
    // R not positive definite (a reachable pair, so the DARE's own check).
    let b2 = DMatrix::identity(2, 2);
    let err = lqr(&a, &b2, &q, &(-DMatrix::<f64>::identity(2, 2))).unwrap_err();
    assert_eq!(err, DesignError::Dare(DareError::RNotPositiveDefinite));
    says(&err, &["R is not positive definite"]);
}

// --- non-finite numbers -----------------------------------------------------

#[test]
fn non_finite_numbers() {
    let err = DiscreteStateSpace::new(
        DMatrix::from_element(1, 1, f64::NAN),
        DMatrix::zeros(1, 1),
        DMatrix::zeros(1, 1),
        DMatrix::zeros(1, 1),
        1e-4,
    )
    .unwrap_err();
    assert_eq!(err, StateSpaceError::Matrix(MatrixError::NonFinite("A")));
    says(&err, &["matrix A", "non-finite"]);
    let mut nodal = flexible_joint();
    nodal.stiffness[(0, 1)] = f64::INFINITY;
    let err = ModalModel::from_nodal(&nodal).unwrap_err();
    assert_eq!(err, ModelError::Matrix(MatrixError::NonFinite("stiffness")));
    says(&err, &["stiffness", "non-finite"]);
    // LQ weight with a NaN.
    let model = thesis_model();
    let mut q = DMatrix::identity(8, 8);
    q[(2, 2)] = f64::NAN;
    let err = lqr(&model.a, &model.b, &q, &DMatrix::identity(1, 1)).unwrap_err();
    assert_eq!(
        err,
        DesignError::Matrix(MatrixError::NonFinite("LQ state weight Q"))
    );
    says(&err, &["LQ state weight Q", "non-finite"]);
    // A requested pole.
    let mut poles = real_poles(8);
    poles[1] = Complex::new(0.2, f64::NAN);
    let err = robust_place(&model.a, &model.b, &poles).unwrap_err();
    assert_eq!(
        err,
        DesignError::Matrix(MatrixError::NonFinite("requested pole"))
    );
    // A stiffness ratio.
    let red = thesis_reduced(5).unwrap().modal;
    let err = ActiveStiffness::design(&red, &[f64::NAN, 1.0, 1.0], StiffnessMethod::Automated)
        .unwrap_err();
    says(&err, &["frequency ratio", "non-finite"]);
    // A scheduling grid.
    let err = PositionGrid::new(f64::NAN, 0.005, 29).unwrap_err();
    assert!(matches!(err, ScheduleError::InvalidGrid(_)));
    says(&err, &["grid", "finite"]);
}

#[test]
fn non_finite_samples_are_refused_and_leave_the_state_alone() {
    let base = thesis_model();
    let grid = PositionGrid::new(0.0, 0.005, 3).unwrap();
    let models =
        ModelSchedule::new(grid, KalmanWeights::thesis(&base), |_| Ok(base.clone())).unwrap();
    let mut ss = InterpolatedKalman::new(KalmanSchedule::design(models.clone()).unwrap());
    let mut tv = TimeVaryingKalman::from_steady_state(models, 0.0).unwrap();
    let before = tv.covariance().clone();
    let err = tv.step(f64::NAN, &[0.0], &[0.0]).unwrap_err();
    assert_eq!(err, StepError::NonFinite("scheduling position"));
    says(&err, &["scheduling position", "non-finite"]);
    assert_eq!(
        ss.step(0.0, &[0.0], &[f64::NAN]),
        Err(StepError::NonFinite("u"))
    );
    let err = ss.step(0.02, &[0.0], &[0.0]).unwrap_err();
    assert!(matches!(err, StepError::PositionOutOfRange { .. }));
    says(&err, &["position 0.02", "[0, 0.01]"]);
    assert_eq!(tv.covariance(), &before);
    assert!(tv.estimate().iter().chain(ss.estimate()).all(|v| *v == 0.0));
}

// --- mismatched dimensions --------------------------------------------------

#[test]
fn mismatched_dimensions() {
    let model = thesis_model();
    // Γ with the wrong number of rows.
    let err = lqr(
        &model.a,
        &DMatrix::zeros(7, 1),
        &DMatrix::identity(8, 8),
        &DMatrix::identity(1, 1),
    )
    .unwrap_err();
    assert!(matches!(
        err,
        DesignError::Matrix(MatrixError::DimensionMismatch { what: "Γ", .. })
    ));
    says(&err, &["Γ is 7x1 but must be 8x1"]);
    // Pole count.
    let err = robust_place(&model.a, &model.b, &real_poles(7)).unwrap_err();
    assert!(matches!(
        err,
        DesignError::Matrix(MatrixError::DimensionMismatch { .. })
    ));
    says(&err, &["pole list", "7x1 but must be 8x1"]);
    // Correction filter with 3 inputs for 1 output.
    let err = IoObserver::state_correction(
        model.clone(),
        DiscreteStateSpace::gain(DMatrix::zeros(8, 3), model.ts).unwrap(),
    )
    .unwrap_err();
    assert!(matches!(
        err,
        DesignError::Matrix(MatrixError::DimensionMismatch { .. })
    ));
    says(&err, &["correction filter", "innovation"]);
    // Stiffness ratios for 2 of 3 flexible modes.
    let red = thesis_reduced(5).unwrap().modal;
    let err = ActiveStiffness::design(&red, &[1.5, 1.0], StiffnessMethod::Automated).unwrap_err();
    says(
        &err,
        &["frequency ratio per flexible mode", "2x1 but must be 3x1"],
    );
    // A controller with 2 outputs for a 1-input loop.
    let obs = thesis_observer_block(5, TS_10KHZ, true, false, Some(0.03), 0).unwrap();
    let two = DiscreteStateSpace::gain(DMatrix::zeros(2, 1), TS_10KHZ).unwrap();
    let err = modified_feedforward(&obs.block, &two, 1).unwrap_err();
    says(&err, &["controller C_fb", "2x1 but must be 1x1"]);
    let _ = thesis_pid(35.5, TS_10KHZ).unwrap();
    // A schedule whose model grows a sensor along the grid.
    let modal = thesis_chain_modal().unwrap();
    let grid = PositionGrid::new(0.0, 1.0, 3).unwrap();
    let err = ModelSchedule::new(grid, KalmanWeights::thesis(&model), |pos| {
        let sensors: Vec<f64> = if pos > 0.5 { vec![1.0, 2.0] } else { vec![1.0] };
        let red = modal.with_sensor_positions(&sensors)?.truncate(4, &[])?;
        Ok(zoh(&red.state_space(), TS_10KHZ)?)
    })
    .unwrap_err();
    assert!(matches!(
        err,
        ScheduleError::StructureChanges {
            what: "the model dimensions",
            ..
        }
    ));
    says(&err, &["the model dimensions", "position 1"]);
    // Slices of the wrong length in a per-sample call.
    let grid = PositionGrid::new(0.0, 0.005, 3).unwrap();
    let models =
        ModelSchedule::new(grid, KalmanWeights::thesis(&model), |_| Ok(model.clone())).unwrap();
    let mut f = InterpolatedKalman::new(KalmanSchedule::design(models).unwrap());
    let err = f.step(0.0, &[0.0, 0.0], &[0.0]).unwrap_err();
    assert_eq!(
        err,
        StepError::Length {
            what: "y",
            expected: 1,
            found: 2
        }
    );
    says(&err, &["y has 2 entries but must have 1"]);
}

// --- MIMO pieces that do not fit together ------------------------------------

#[test]
fn a_mimo_observer_on_a_siso_plant_is_refused() {
    use flexloop_control::closed_loop::{LoopSpec, assemble_loop};
    use flexloop_control::observer_block::{ModalObserverOptions, design_modal_observer};
    // The 2x2 example's observer (rigid + 2 flexible, T_DC of the third)
    // closed around the SISO thesis chain.
    let mimo = mimo_example().unwrap();
    let reduced = mimo.truncate(4, &[4]).unwrap();
    let mut options = ModalObserverOptions::thesis_mc_ad(TS_10KHZ, 2);
    options.damping.as_mut().unwrap().increase = vec![0.045; 2];
    let observer = design_modal_observer(&reduced, &options).unwrap();
    let plant = zoh(
        &thesis_chain_modal()
            .unwrap()
            .select_outputs(&[4])
            .unwrap()
            .state_space(),
        TS_10KHZ,
    )
    .unwrap();
    let err = assemble_loop(&LoopSpec {
        plant: &plant,
        observer: Some(&observer.block),
        controller: &thesis_pid(35.5, TS_10KHZ).unwrap(),
        loop_delay: 1,
    })
    .unwrap_err();
    assert!(
        matches!(
            err,
            DesignError::Matrix(MatrixError::DimensionMismatch { .. })
        ),
        "{err:?}"
    );
    says(&err, &["observer block (n_y, n_u)", "2x2 but must be 1x1"]);
    // Rigid-body decoupling needs as many actuators and sensors as rigid modes.
    let err = thesis_chain_modal()
        .unwrap()
        .rigid_body_decoupled()
        .unwrap_err();
    says(&err, &["rigid-body decoupling", "1x7 but must be 1x1"]);
}

#[test]
fn a_scheduled_observer_with_a_foreign_damping_map_is_refused() {
    use flexloop_control::scheduled_observer::{
        GainScheduling, ScheduledObserver, ScheduledObserverDesign,
    };
    let model = thesis_model();
    let grid = PositionGrid::new(0.0, 0.5, 3).unwrap();
    let models =
        ModelSchedule::new(grid, KalmanWeights::thesis(&model), |_| Ok(model.clone())).unwrap();
    let design = ScheduledObserverDesign {
        schedule: KalmanSchedule::design(models).unwrap(),
        flexible_columns: Some(2..8),
        // K(z) for two inputs on a one-input model.
        feedback: Some(DiscreteStateSpace::gain(DMatrix::zeros(2, 8), TS_10KHZ).unwrap()),
        extra_delay_samples: 0,
        gains: GainScheduling::Interpolated,
    };
    let err = ScheduledObserver::new(design.clone(), 0.0).unwrap_err();
    says(&err, &["K(z)", "2x8 but must be 1x8"]);
    // Columns for MC beyond the state, and a start off the grid.
    let wide = ScheduledObserverDesign {
        feedback: None,
        flexible_columns: Some(2..9),
        ..design.clone()
    };
    says(
        &ScheduledObserver::new(wide, 0.0).unwrap_err(),
        &["flexible columns"],
    );
    let fine = ScheduledObserverDesign {
        feedback: None,
        ..design
    };
    says(
        &ScheduledObserver::new(fine, 2.0).unwrap_err(),
        &["scheduling position 2", "[0, 1]"],
    );
}
