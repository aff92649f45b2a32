//! flexloop-control: the control maths of flexloop, with no IPC and no clock.
//!
//! Design-time code (model building, discretisation, observer and controller
//! design) may allocate. The per-sample types ([`lti::LtiRunner`]) are sized in
//! their constructors and allocate nothing in their `step` methods.

pub mod lti;
