//! flexloop-control: the control maths of flexloop, with no IPC and no clock.
//!
//! Design-time code (model building, discretisation, observer and controller
//! design) may allocate. The per-sample types ([`lti::LtiRunner`]) are sized in
//! their constructors and allocate nothing in their `step` methods.
//!
//! Typical thesis set-up at 10 kHz (docs/control.md §10.1):
//! * plant: [`models::thesis_plant_discrete`] (8 modes, exact ZOH);
//! * observer: [`observer_block::thesis_observer_block`] (Kalman predictor on
//!   the reduced model with MC and/or AD), layout in [`observer_block`];
//! * controller: [`pid::thesis_pid`] (Tustin PID + low-pass, input e_meas);
//! * set-point and feedforward: [`setpoint::Setpoint`], [`feedforward`].
//!
//! A user's own plant enters as a lumped network ([`lumped_network`]), a
//! second-order model M, D, K, B, C ([`second_order`]), or a first-order
//! state space ([`real_modal_form`], from discrete time through
//! [`zoh_inverse`]); each becomes a [`modal::ModalModel`], errors in
//! [`plant_model_error`].
//!
//! A plant measured on the running loop ([`multisine`], [`frf`]) is fitted
//! with a modal model by [`modal_fit`], which also gives it as a continuous
//! state space to write as a plant file.

pub mod lti;

pub mod bandwidth;
pub mod closed_loop;
pub mod continuous;
pub mod damping;
pub mod dare;
pub mod design_error;
pub mod discretise;
pub mod excitation;
pub mod feedforward;
pub mod freq;
pub mod frf;
mod in_place;
pub mod io_observer;
pub mod kalman;
pub mod lecture;
pub mod linalg;
pub mod lqr;
pub mod lumped_network;
pub mod matrix_error;
pub mod modal;
pub mod modal_fit;
pub mod models;
pub mod modified_feedforward;
pub mod multisine;
pub mod observer_block;
pub mod pid;
pub mod placement;
pub mod plant_model_error;
pub mod real_modal_form;
pub mod scheduled_observer;
pub mod scheduling;
pub mod second_order;
pub mod setpoint;
pub mod step_error;
pub mod stiffness;
pub mod zoh_inverse;
