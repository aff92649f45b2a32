//! The observer block of the loop: one [`DiscreteStateSpace`] that holds a
//! predictor-form observer plus its measurement-compensation (MC) and
//! active-damping (AD) outputs, timed for one sample of loop delay
//! (docs/control.md §3 "Synchronization", §5, §10.1). What follows is that
//! block ([`compile_observer_block`]); a block for commands applied on
//! arrival ([`compile_observer_block_on_arrival`], docs/deadline.md) keeps
//! the layout, but u_a(k) is the input present at t_k, ŷ_flex has a direct
//! gain on it and u_d comes from the estimate at t_k + τ_d.
//!
//! # Layout
//! Inputs, per tick k:
//! * `[0, n_y)`: y(k), the measured outputs;
//! * `[n_y, n_y + n_u)`: u_a(k), the input the plant actually applies over
//!   [t_k, t_{k+1}) (the TOTAL u = u_fb + u_ff + u_d computed one tick earlier);
//! * only with `extra_delay_samples = 1`: `[n_y + n_u, n_y + 2 n_u)`:
//!   u_pending(k), the input already issued that the plant will apply over
//!   [t_{k+1}, t_{k+2}) (with two samples of loop delay, u_c(k−1)).
//!
//! Outputs:
//! * `[0, n_y)`: ŷ_flex(k) = C_f x̂(k|k−1), the flexible part of the output
//!   (rigid columns zero, no T_DC term); subtract it from y(k) (MC). Zero when
//!   MC is off. It depends only on the state, so it is known one tick ahead
//!   (`LtiRunner::free_output`).
//! * `[n_y, n_y + n_u)`: u_d(k) = K(z) x̂(k+1|k) (or x̂(k+2|k) with the extra
//!   delay): the damping force to ADD to the controller output u_c(k), which
//!   the loop applies over [t_{k+1}, t_{k+2}). Zero when AD is off.
//!
//! Block state s(k) = [x̂(k|k−1); w(k)] with w the states of K(z); the
//! estimate is x̂(k|k−1) = `estimate_map` · s(k). The predictor is affine in
//! (y(k), u_a(k)), so the block's D matrix carries that direct dependence.
//!
//! # Continuous counterpart
//! [`design_continuous_modal_observer`] builds the same observer in
//! continuous time (CARE Kalman gain, static or band-passed K(s)), as one
//! [`ContinuousStateSpace`] with inputs [y; u] and outputs [ŷ_flex; u_d]:
//! the thesis's own setting, used by the continuous bandwidth checks of
//! docs/control.md §9 ([`crate::bandwidth::ContinuousBandwidthProblem`]).
//!
//! # Q_ν
//! `q_nu` is always the thesis value (a continuous intensity, 0.03 or 10³);
//! the discrete design converts it to Q_ν Ts² per sample
//! ([`crate::kalman::NoiseModel::thesis`]).

use crate::continuous::ContinuousStateSpace;
use crate::damping::{ActiveDamping, DampingMethod};
use crate::design_error::{DesignError, check_matrix};
use crate::discretise::{hold_for, zoh, zoh_split};
use crate::kalman::{
    ContinuousKalmanGains, KalmanGains, KalmanWeights, NoiseModel, steady_state_kalman,
    steady_state_kalman_continuous, with_noise_model, with_noise_model_continuous,
};
use crate::lti::DiscreteStateSpace;
use crate::matrix_error::MatrixError;
use crate::modal::ReducedModel;
use nalgebra::DMatrix;

/// A predictor-form observer and what it drives.
#[derive(Debug, Clone, PartialEq)]
pub struct ObserverDesign {
    /// Observer model (A_o, B_o, C_o, D_o), D_o = T_DC; may include
    /// noise-model or disturbance states.
    pub model: DiscreteStateSpace,
    /// Predictor gain L (n_o × n_y): x̂(k+1|k) = (A − LC) x̂ + (B − LD) u + L y.
    pub gain: DMatrix<f64>,
    /// C_f (n_y × n_o) for MC, or None (MC off).
    pub compensation: Option<DMatrix<f64>>,
    /// K(z): map from the estimate (n_o inputs) to u_d (n_u outputs), or None
    /// (AD off).
    pub feedback: Option<DiscreteStateSpace>,
}

/// A compiled observer block (see the module doc for the layout).
#[derive(Debug, Clone, PartialEq)]
pub struct ObserverBlock {
    pub system: DiscreteStateSpace,
    /// x̂(k|k−1) = estimate_map · s(k).
    pub estimate_map: DMatrix<f64>,
    /// The model x̂ is the state of (A_o, B_o, C_o, D_o); None where the
    /// block carries no estimate. Another design on the same model (other
    /// gain, damping or band-pass) may continue this block's x̂.
    pub model: Option<DiscreteStateSpace>,
    pub n_y: usize,
    pub n_u: usize,
    pub extra_delay_samples: usize,
}

/// Compiles a design into one discrete state space (module doc).
pub fn compile_observer_block(
    design: &ObserverDesign,
    extra_delay_samples: usize,
) -> Result<ObserverBlock, DesignError> {
    if extra_delay_samples > 1 {
        return Err(DesignError::InvalidParameter(format!(
            "extra_delay_samples {extra_delay_samples} (0 or 1)"
        )));
    }
    let m = &design.model;
    let (n, ny, nu) = (m.states(), m.outputs(), m.inputs());
    let n_in = ny + nu * (1 + extra_delay_samples);
    let Predictor { cf, fb, f, g_in } = predictor(design, n_in)?;
    // The estimate fed to K(z): v = H_x x̂ + H_in in.
    let (h_x, h_in) = if extra_delay_samples == 0 {
        (f.clone(), g_in.clone())
    } else {
        // x̂(k+2|k) = A x̂(k+1|k) + B u_pending(k).
        let mut h_in = &m.a * &g_in;
        h_in.view_mut((0, ny + nu), (n, nu)).copy_from(&m.b);
        (&m.a * &f, h_in)
    };
    let parts = BlockParts {
        f,
        g_in,
        h_x,
        h_in,
        compensation: cf,
        compensation_in: DMatrix::zeros(ny, n_in),
    };
    assemble_block(design, &fb, parts, extra_delay_samples)
}

/// The command applied on arrival (docs/control.md §10.1): u_c(k)
/// acts from t_k + τ, the input present at t_k, u_a(k) = u_c(k−1), until
/// then. The observer's model is then the split plant's delayed-input form
/// ([`crate::discretise::SplitHold::delayed_input_form`]), whose state is
/// z = x − G_new u_a; these are the pieces that turn its estimate back into
/// the plant's state at the instants MC and AD need.
#[derive(Debug, Clone, PartialEq)]
pub struct OnArrival {
    /// G_new (n_o × n_u): x̂ = ẑ + G_new u_a.
    pub g_new: DMatrix<f64>,
    /// e^{A τ} (n_o × n_o) and ∫₀^τ e^{As} ds B (n_o × n_u) of the model:
    /// the state moved from t_k to t_k + τ under u_a(k).
    pub e_tau: DMatrix<f64>,
    pub gamma_tau: DMatrix<f64>,
    /// Kalman filter gain M (n_o × n_y): ẑ(k|k) = ẑ(k|k−1) + M (y(k) − ŷ(k|k−1)).
    pub filter_gain: DMatrix<f64>,
}

/// Compiles a design whose model is the delayed-input form of a split
/// plant (see [`OnArrival`]). Inputs [y(k); u_a(k)], outputs as for
/// [`compile_observer_block`]:
/// * ŷ_flex(k) = C_f x̂(k|k−1) = C_f (ẑ(k|k−1) + G_new u_a(k));
/// * u_d(k) = K(z) x̂(t_k + τ), the estimate at the instant u_c(k) starts to
///   act: e^{Aτ} x̂(k|k) + Γ_τ u_a(k), x̂(k|k) = ẑ(k|k) + G_new u_a(k).
///
/// At τ = Ts (G_new = 0, e^{Aτ} = A, Γ_τ = B, L = A M) this is exactly the
/// one-sample block of [`compile_observer_block`].
pub fn compile_observer_block_on_arrival(
    design: &ObserverDesign,
    on_arrival: &OnArrival,
) -> Result<ObserverBlock, DesignError> {
    let m = &design.model;
    let (n, ny, nu) = (m.states(), m.outputs(), m.inputs());
    check_matrix(&on_arrival.g_new, "G_new", n, nu)?;
    check_matrix(&on_arrival.e_tau, "e^{Aτ}", n, n)?;
    check_matrix(&on_arrival.gamma_tau, "Γ_τ", n, nu)?;
    check_matrix(&on_arrival.filter_gain, "filter gain M", n, ny)?;
    let n_in = ny + nu;
    let Predictor { cf, fb, f, g_in } = predictor(design, n_in)?;
    let (e, mg) = (&on_arrival.e_tau, &on_arrival.filter_gain);
    // v = e^{Aτ} [(I − M C) ẑ + M y + (G_new − M D) u_a] + Γ_τ u_a.
    let h_x = e * (DMatrix::identity(n, n) - mg * &m.c);
    let mut h_in = DMatrix::zeros(n, n_in);
    h_in.view_mut((0, 0), (n, ny)).copy_from(&(e * mg));
    h_in.view_mut((0, ny), (n, nu))
        .copy_from(&(e * (&on_arrival.g_new - mg * &m.d) + &on_arrival.gamma_tau));
    let mut compensation_in = DMatrix::zeros(ny, n_in);
    compensation_in
        .view_mut((0, ny), (ny, nu))
        .copy_from(&(&cf * &on_arrival.g_new));
    let parts = BlockParts {
        f,
        g_in,
        h_x,
        h_in,
        compensation: cf,
        compensation_in,
    };
    assemble_block(design, &fb, parts, 0)
}

/// The pieces every block starts from: C_f (zero with MC off), K(z), and
/// the predictor x̂(k+1|k) = F x̂ + G_in in over `n_in` block inputs (y and
/// u_a in the first ones; later inputs enter only the damping estimate).
struct Predictor {
    cf: DMatrix<f64>,
    fb: DiscreteStateSpace,
    f: DMatrix<f64>,
    g_in: DMatrix<f64>,
}

fn predictor(design: &ObserverDesign, n_in: usize) -> Result<Predictor, DesignError> {
    let m = &design.model;
    let (n, ny, nu) = (m.states(), m.outputs(), m.inputs());
    check_matrix(&design.gain, "observer gain L", n, ny)?;
    let cf = match &design.compensation {
        Some(c) => {
            check_matrix(c, "C_f", ny, n)?;
            c.clone()
        }
        None => DMatrix::zeros(ny, n),
    };
    let fb = damping_block(design)?;
    let l = &design.gain;
    let f = &m.a - l * &m.c;
    let mut g_in = DMatrix::zeros(n, n_in);
    g_in.view_mut((0, 0), (n, ny)).copy_from(l);
    g_in.view_mut((0, ny), (n, nu))
        .copy_from(&(&m.b - l * &m.d));
    Ok(Predictor { cf, fb, f, g_in })
}

/// K(z) of the design, or a zero gain (AD off).
fn damping_block(design: &ObserverDesign) -> Result<DiscreteStateSpace, DesignError> {
    let m = &design.model;
    let (n, nu) = (m.states(), m.inputs());
    match &design.feedback {
        Some(k) => {
            if k.inputs() != n || k.outputs() != nu {
                return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                    what: "K(z) (outputs x inputs)",
                    expected: (nu, n),
                    found: (k.outputs(), k.inputs()),
                }));
            }
            if (k.ts - m.ts).abs() > 1e-12 * m.ts {
                return Err(DesignError::InvalidParameter(
                    "K(z) and observer sample periods differ".into(),
                ));
            }
            Ok(k.clone())
        }
        None => Ok(DiscreteStateSpace::gain(DMatrix::zeros(nu, n), m.ts)?),
    }
}

/// The affine maps a block is made of: x̂(k+1|k) = F x̂ + G_in in, the
/// estimate fed to K(z) v = H_x x̂ + H_in in, and ŷ_flex = C_f x̂ + D_f in.
struct BlockParts {
    f: DMatrix<f64>,
    g_in: DMatrix<f64>,
    h_x: DMatrix<f64>,
    h_in: DMatrix<f64>,
    compensation: DMatrix<f64>,
    compensation_in: DMatrix<f64>,
}

/// One state space [x̂; w] from the affine maps and K(z).
fn assemble_block(
    design: &ObserverDesign,
    fb: &DiscreteStateSpace,
    p: BlockParts,
    extra_delay_samples: usize,
) -> Result<ObserverBlock, DesignError> {
    let m = &design.model;
    let (n, ny, nu) = (m.states(), m.outputs(), m.inputs());
    let n_in = p.g_in.ncols();
    let nw = fb.states();
    let mut a = DMatrix::zeros(n + nw, n + nw);
    a.view_mut((0, 0), (n, n)).copy_from(&p.f);
    a.view_mut((n, 0), (nw, n)).copy_from(&(&fb.b * &p.h_x));
    a.view_mut((n, n), (nw, nw)).copy_from(&fb.a);
    let mut b = DMatrix::zeros(n + nw, n_in);
    b.view_mut((0, 0), (n, n_in)).copy_from(&p.g_in);
    b.view_mut((n, 0), (nw, n_in)).copy_from(&(&fb.b * &p.h_in));
    let mut c = DMatrix::zeros(ny + nu, n + nw);
    c.view_mut((0, 0), (ny, n)).copy_from(&p.compensation);
    c.view_mut((ny, 0), (nu, n)).copy_from(&(&fb.d * &p.h_x));
    c.view_mut((ny, n), (nu, nw)).copy_from(&fb.c);
    let mut d = DMatrix::zeros(ny + nu, n_in);
    d.view_mut((0, 0), (ny, n_in)).copy_from(&p.compensation_in);
    d.view_mut((ny, 0), (nu, n_in))
        .copy_from(&(&fb.d * &p.h_in));
    let mut estimate_map = DMatrix::zeros(n, n + nw);
    estimate_map.view_mut((0, 0), (n, n)).fill_with_identity();
    Ok(ObserverBlock {
        system: DiscreteStateSpace::new(a, b, c, d, m.ts)?,
        estimate_map,
        model: Some(m.clone()),
        n_y: ny,
        n_u: nu,
        extra_delay_samples,
    })
}

/// Active-damping options for [`design_modal_observer`].
#[derive(Debug, Clone, PartialEq)]
pub struct DampingOptions {
    /// Increase of ζ per retained flexible mode (thesis: 0.035 each).
    pub increase: Vec<f64>,
    pub method: DampingMethod,
    /// Band-pass Q (thesis: 2) or None.
    pub bandpass_q: Option<f64>,
}

/// Options of the Kalman-based MC/AD observer (docs/control.md §11.1 item 3).
#[derive(Debug, Clone, PartialEq)]
pub struct ModalObserverOptions {
    pub ts: f64,
    /// Measurement compensation on.
    pub mc: bool,
    /// Active damping, or None.
    pub damping: Option<DampingOptions>,
    /// Noise model U = B_t with the thesis intensity Q_ν = q_nu I (0.03 …
    /// 10³, continuous units; converted to q_nu Ts² per sample), or None.
    /// Dropped automatically when MC is off (§4.3: "drop ẑ when only AD").
    pub q_nu: Option<f64>,
    /// Kalman weights, or None for the thesis weights (G = B, Q = σ_w²,
    /// R = σ_v² + σ_d²).
    pub weights: Option<KalmanWeights>,
    pub extra_delay_samples: usize,
    /// τ [s] when the command acts on arrival, from t_k + τ (see
    /// [`OnArrival`]); None: one whole sample of loop delay.
    pub command_deadline: Option<f64>,
}

impl ModalObserverOptions {
    /// The thesis MC+AD observer at `ts`: MC on, AD to +0.035 on every retained
    /// flexible mode with (3.31) and band-pass Q = 2, noise model Q_ν = 10³.
    pub fn thesis_mc_ad(ts: f64, n_flex: usize) -> Self {
        Self {
            ts,
            mc: true,
            damping: Some(DampingOptions {
                increase: vec![0.035; n_flex],
                method: DampingMethod::Automated,
                bandpass_q: Some(2.0),
            }),
            q_nu: Some(1e3),
            weights: None,
            extra_delay_samples: 0,
            command_deadline: None,
        }
    }
}

/// Designed observer: the block plus the pieces it was made of.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalObserver {
    pub block: ObserverBlock,
    pub design: ObserverDesign,
    pub kalman: KalmanGains,
    pub damping: Option<ActiveDamping>,
}

/// Kalman observer on a reduced modal model (ZOH at `ts`, D = T_DC) with
/// optional MC, AD and noise model, compiled into an [`ObserverBlock`].
pub fn design_modal_observer(
    reduced: &ReducedModel,
    options: &ModalObserverOptions,
) -> Result<ModalObserver, DesignError> {
    let continuous = reduced.state_space();
    // The process noise and the noise model enter as a force held over
    // whole samples (G = U = Γ) whenever the command itself acts.
    let plain = zoh(&continuous, options.ts)?;
    let weights = match &options.weights {
        Some(w) => w.clone(),
        None => KalmanWeights::thesis(&plain),
    };
    let base = match options.command_deadline {
        None => plain.clone(),
        Some(tau) => {
            if options.extra_delay_samples != 0 {
                return Err(DesignError::InvalidParameter(
                    "a command applied on arrival has no extra sample of delay to predict over"
                        .into(),
                ));
            }
            zoh_split(&continuous, options.ts, tau)?.delayed_input_form(
                &continuous.c,
                &continuous.d,
                options.ts,
            )?
        }
    };
    let n_t = base.states();
    let (model, weights) = match (options.mc, options.q_nu) {
        (true, Some(q_nu)) => {
            check_q_nu(q_nu)?;
            with_noise_model(&base, &weights, &NoiseModel::thesis(&plain, q_nu))?
        }
        _ => (base, weights),
    };
    let n_o = model.states();
    let kalman = steady_state_kalman(&model, &weights)?;
    let compensation = if options.mc {
        let mut c = DMatrix::zeros(model.outputs(), n_o);
        c.view_mut((0, 0), (model.outputs(), n_t))
            .copy_from(&reduced.flexible_output_matrix());
        Some(c)
    } else {
        None
    };
    let (feedback, damping) = match &options.damping {
        Some(d) => {
            let ad = ActiveDamping::design(&reduced.modal, &d.increase, d.method, d.bandpass_q)?;
            (Some(ad.to_discrete(n_o, options.ts)?), Some(ad))
        }
        None => (None, None),
    };
    let design = ObserverDesign {
        model,
        gain: kalman.l.clone(),
        compensation,
        feedback,
    };
    let block = match options.command_deadline {
        None => compile_observer_block(&design, options.extra_delay_samples)?,
        Some(tau) => {
            let on_arrival =
                on_arrival_pieces(&continuous, options.ts, tau, &design.model, &kalman)?;
            compile_observer_block_on_arrival(&design, &on_arrival)?
        }
    };
    Ok(ModalObserver {
        block,
        design,
        kalman,
        damping,
    })
}

/// [`OnArrival`] for a reduced model `continuous` whose discrete observer
/// model `model` may carry noise-model states after its own (a force held
/// over the sample, U = Γ: over τ it moves the state by Γ_τ).
fn on_arrival_pieces(
    continuous: &ContinuousStateSpace,
    ts: f64,
    tau: f64,
    model: &DiscreteStateSpace,
    kalman: &KalmanGains,
) -> Result<OnArrival, DesignError> {
    let (n, nu) = (continuous.states(), continuous.inputs());
    let n_o = model.states();
    let split = zoh_split(continuous, ts, tau)?;
    let (e, gamma) = hold_for(continuous, tau)?;
    let mut g_new = DMatrix::zeros(n_o, nu);
    g_new.view_mut((0, 0), (n, nu)).copy_from(&split.g_new);
    let mut e_tau = DMatrix::identity(n_o, n_o);
    e_tau.view_mut((0, 0), (n, n)).copy_from(&e);
    if n_o > n {
        if n_o - n != nu {
            return Err(DesignError::InvalidParameter(format!(
                "an observer applied on arrival takes one noise state per input, not {}",
                n_o - n
            )));
        }
        e_tau.view_mut((0, n), (n, nu)).copy_from(&gamma);
    }
    let mut gamma_tau = DMatrix::zeros(n_o, nu);
    gamma_tau.view_mut((0, 0), (n, nu)).copy_from(&gamma);
    Ok(OnArrival {
        g_new,
        e_tau,
        gamma_tau,
        filter_gain: kalman.m.clone(),
    })
}

fn check_q_nu(q_nu: f64) -> Result<(), DesignError> {
    if q_nu.is_finite() && q_nu > 0.0 {
        Ok(())
    } else {
        Err(DesignError::InvalidParameter(format!(
            "noise-model Q_ν {q_nu} must be positive and finite"
        )))
    }
}

/// Options of the continuous-time MC/AD observer.
#[derive(Debug, Clone, PartialEq)]
pub struct ContinuousObserverOptions {
    /// Measurement compensation on.
    pub mc: bool,
    /// Active damping, or None.
    pub damping: Option<DampingOptions>,
    /// Noise model U = B_t, intensity Q_ν = q_nu I (only with MC), or None.
    pub q_nu: Option<f64>,
    /// Kalman intensities, or None for the thesis values.
    pub weights: Option<KalmanWeights>,
}

/// A continuous Kalman observer with its MC and AD outputs.
#[derive(Debug, Clone, PartialEq)]
pub struct ContinuousModalObserver {
    /// States [x̂; w] (w: band-pass states), inputs [y (n_y); u (n_u)],
    /// outputs [ŷ_flex = C_f x̂ (n_y); u_d = K(s) x̂ (n_u)], D = 0:
    /// x̂̇ = (A − L C) x̂ + (B − L D_o) u + L y. `u` is the total plant input.
    pub system: ContinuousStateSpace,
    /// Observer model (A, B, C, D_o = T_DC), with noise-model states if any.
    pub model: ContinuousStateSpace,
    pub kalman: ContinuousKalmanGains,
    pub damping: Option<ActiveDamping>,
}

/// Continuous Kalman observer on a reduced modal model with optional MC,
/// AD (static (3.31)/(3.32) gains or band-passed) and noise model.
pub fn design_continuous_modal_observer(
    reduced: &ReducedModel,
    options: &ContinuousObserverOptions,
) -> Result<ContinuousModalObserver, DesignError> {
    let base = reduced.state_space();
    let weights = match &options.weights {
        Some(w) => w.clone(),
        None => KalmanWeights::thesis_continuous(&base),
    };
    let n_t = base.states();
    let (model, weights) = match (options.mc, options.q_nu) {
        (true, Some(q_nu)) => {
            check_q_nu(q_nu)?;
            with_noise_model_continuous(
                &base,
                &weights,
                &NoiseModel::on_continuous_inputs(&base, q_nu),
            )?
        }
        _ => (base, weights),
    };
    let kalman = steady_state_kalman_continuous(&model, &weights)?;
    let (n_o, ny, nu) = (model.states(), model.outputs(), model.inputs());
    let mut cf = DMatrix::zeros(ny, n_o);
    if options.mc {
        cf.view_mut((0, 0), (ny, n_t))
            .copy_from(&reduced.flexible_output_matrix());
    }
    let (k, damping) = match &options.damping {
        Some(d) => {
            let ad = ActiveDamping::design(&reduced.modal, &d.increase, d.method, d.bandpass_q)?;
            (ad.to_continuous(n_o)?, Some(ad))
        }
        None => (ContinuousStateSpace::gain(DMatrix::zeros(nu, n_o)), None),
    };
    let l = &kalman.l;
    let nw = k.states();
    let mut a = DMatrix::zeros(n_o + nw, n_o + nw);
    a.view_mut((0, 0), (n_o, n_o))
        .copy_from(&(&model.a - l * &model.c));
    a.view_mut((n_o, 0), (nw, n_o)).copy_from(&k.b);
    a.view_mut((n_o, n_o), (nw, nw)).copy_from(&k.a);
    let mut b = DMatrix::zeros(n_o + nw, ny + nu);
    b.view_mut((0, 0), (n_o, ny)).copy_from(l);
    b.view_mut((0, ny), (n_o, nu))
        .copy_from(&(&model.b - l * &model.d));
    let mut c = DMatrix::zeros(ny + nu, n_o + nw);
    c.view_mut((0, 0), (ny, n_o)).copy_from(&cf);
    c.view_mut((ny, 0), (nu, n_o)).copy_from(&k.d);
    c.view_mut((ny, n_o), (nu, nw)).copy_from(&k.c);
    let system = ContinuousStateSpace::new(a, b, c, DMatrix::zeros(ny + nu, ny + nu))?;
    Ok(ContinuousModalObserver {
        system,
        model,
        kalman,
        damping,
    })
}

/// The thesis SISO observer block for output y_i (1..=7) at `ts`: reduced
/// model (rigid + 3 flexible, T_DC of modes 4–6), thesis Kalman weights,
/// MC on/off, AD (+0.035 on the 3 flexible modes by (3.31), band-pass Q = 2)
/// on/off, noise model Q_ν = `q_nu` when MC is on (thesis: 0.03 or 10³).
/// Inputs [y(k); u_a(k)], outputs [ŷ_flex(k); u_d(k)] (module doc).
pub fn thesis_observer_block(
    output: usize,
    ts: f64,
    mc: bool,
    ad: bool,
    q_nu: Option<f64>,
    extra_delay_samples: usize,
) -> Result<ModalObserver, DesignError> {
    let reduced = crate::models::thesis_reduced(output)?;
    let options = ModalObserverOptions {
        ts,
        mc,
        damping: ad.then(|| DampingOptions {
            increase: vec![0.035; 3],
            method: DampingMethod::Automated,
            bandpass_q: Some(2.0),
        }),
        q_nu,
        weights: None,
        extra_delay_samples,
        command_deadline: None,
    };
    design_modal_observer(&reduced, &options)
}

/// The lecture observer with a constant input-disturbance estimate
/// (docs/control.md §12.1): model Φe = [[Φ, Γ], [0, I]], Γe = [Γ; 0], Ce = [C 0],
/// predictor gain [K; K_w], and u_sf = −L x̂(k+1|k) − v̂(k+1|k) on the u_d
/// slot (so the controller simply adds u_d). ŷ_flex is zero.
pub fn state_feedback_observer_block(
    plant: &DiscreteStateSpace,
    state_gain: &DMatrix<f64>,
    observer_gain: &DMatrix<f64>,
    disturbance_gain: &DMatrix<f64>,
    extra_delay_samples: usize,
) -> Result<ObserverBlock, DesignError> {
    let (n, m, p) = (plant.states(), plant.inputs(), plant.outputs());
    check_matrix(state_gain, "state-feedback gain L", m, n)?;
    check_matrix(observer_gain, "observer gain K", n, p)?;
    check_matrix(disturbance_gain, "disturbance gain K_w", m, p)?;
    let mut a = DMatrix::zeros(n + m, n + m);
    a.view_mut((0, 0), (n, n)).copy_from(&plant.a);
    a.view_mut((0, n), (n, m)).copy_from(&plant.b);
    a.view_mut((n, n), (m, m)).fill_with_identity();
    let mut b = DMatrix::zeros(n + m, m);
    b.view_mut((0, 0), (n, m)).copy_from(&plant.b);
    let mut c = DMatrix::zeros(p, n + m);
    c.view_mut((0, 0), (p, n)).copy_from(&plant.c);
    let model = DiscreteStateSpace::new(a, b, c, plant.d.clone(), plant.ts)?;
    let mut gain = DMatrix::zeros(n + m, p);
    gain.view_mut((0, 0), (n, p)).copy_from(observer_gain);
    gain.view_mut((n, 0), (m, p)).copy_from(disturbance_gain);
    let mut k = DMatrix::zeros(m, n + m);
    k.view_mut((0, 0), (m, n)).copy_from(&(-state_gain));
    k.view_mut((0, n), (m, m))
        .copy_from(&(-DMatrix::<f64>::identity(m, m)));
    let design = ObserverDesign {
        model,
        gain,
        compensation: None,
        feedback: Some(DiscreteStateSpace::gain(k, plant.ts)?),
    };
    compile_observer_block(&design, extra_delay_samples)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::closed_loop::{LoopSpec, assemble_loop, closed_loop_modes};
    use crate::models::{TS_10KHZ, thesis_plant, thesis_reduced};
    use crate::pid::thesis_pid;

    /// Closed-loop damping of flexible modes 1..3 (thesis chain, y5, ZOH at
    /// 10 kHz, PID f_bw 35.5, AD +0.035 by (3.31)). Poles of the observer
    /// error dynamics are excluded; of the rest near each mode, the least
    /// damped is the structural mode (the band-pass poles sit at ζ ≈ 0.2).
    fn ad_damping(bandpass: Option<f64>, delay: usize, extra: usize) -> Vec<f64> {
        let plant = zoh(&thesis_plant(5).unwrap().state_space(), TS_10KHZ).unwrap();
        let red = thesis_reduced(5).unwrap();
        let opts = ModalObserverOptions {
            ts: TS_10KHZ,
            mc: false,
            damping: Some(DampingOptions {
                increase: vec![0.035; 3],
                method: DampingMethod::Automated,
                bandpass_q: bandpass,
            }),
            q_nu: None,
            weights: None,
            extra_delay_samples: extra,
            command_deadline: None,
        };
        let obs = design_modal_observer(&red, &opts).unwrap();
        let pid = thesis_pid(35.5, TS_10KHZ).unwrap();
        let cl = assemble_loop(&LoopSpec {
            plant: &plant,
            observer: Some(&obs.block),
            controller: &pid,
            loop_delay: delay,
        })
        .unwrap();
        let modes = closed_loop_modes(&cl).unwrap();
        let f = &obs.design;
        let obs_modes =
            crate::closed_loop::discrete_modes(&(&f.model.a - &f.gain * &f.model.c), TS_10KHZ)
                .unwrap();
        red.modal.frequencies_hz()[1..]
            .iter()
            .map(|&fm| {
                modes
                    .iter()
                    .filter(|(f, _)| (f - fm).abs() < 0.05 * fm)
                    .filter(|(f, z)| {
                        !obs_modes
                            .iter()
                            .any(|(fo, zo)| (f - fo).abs() < 0.2 && (z - zo).abs() < 1e-3)
                    })
                    .map(|(_, z)| *z)
                    .fold(f64::INFINITY, f64::min)
            })
            .collect()
    }

    #[test]
    fn active_damping_achieves_reference_damping_with_one_sample_delay() {
        // docs/control.md §10.1: 0.051 / 0.047 / 0.042 (band-pass Q = 2, 1 sample).
        let z = ad_damping(Some(2.0), 1, 0);
        for (g, w) in z.iter().zip([0.051, 0.047, 0.042]) {
            assert!((g - w).abs() < 0.003, "{z:?}");
        }
        // Two samples of loop delay with the extra prediction step recovers it.
        let z2 = ad_damping(Some(2.0), 2, 1);
        for (g, w) in z2.iter().zip(&z) {
            assert!((g - w).abs() < 0.002, "{z2:?} vs {z:?}");
        }
        // Using an estimate one sample too old: 0.043 / 0.021 / 0.005 (§10.1).
        let late = ad_damping(Some(2.0), 2, 0);
        for (g, w) in late.iter().zip([0.043, 0.021, 0.005]) {
            assert!((g - w).abs() < 0.003, "{late:?}");
        }
        // Two samples too old: mode 3 unstable at ζ ≈ −0.017.
        let later = ad_damping(Some(2.0), 3, 0);
        assert!((later[2] + 0.017).abs() < 0.003, "{later:?}");
    }

    #[test]
    fn block_runs_the_predictor_equations() {
        use crate::lti::LtiRunner;
        let red = thesis_reduced(3).unwrap();
        let mut opts = ModalObserverOptions::thesis_mc_ad(TS_10KHZ, 3);
        opts.damping.as_mut().unwrap().bandpass_q = None;
        let obs = design_modal_observer(&red, &opts).unwrap();
        let d = &obs.design;
        let k = d.feedback.as_ref().unwrap().d.clone();
        let cf = d.compensation.as_ref().unwrap();
        assert_eq!(obs.block.system.inputs(), 2);
        assert_eq!(obs.block.system.outputs(), 2);
        let mut run = LtiRunner::new(obs.block.system.clone());
        let n = d.model.states();
        let mut xh = nalgebra::DVector::zeros(n);
        for k_ in 0..50 {
            let y = 1e-6 * (k_ as f64 * 0.3).sin();
            let u = 0.5 * (k_ as f64 * 0.17).cos();
            let yf_free = run.free_output()[0];
            let out = run.step(&[y, u]).to_vec();
            let xn = (&d.model.a - &d.gain * &d.model.c) * &xh
                + (&d.model.b - &d.gain * &d.model.d) * u
                + &d.gain * y;
            let yf = (cf * &xh)[(0, 0)];
            let ud = (&k * &xn)[(0, 0)];
            assert!((out[0] - yf).abs() <= 1e-9 * yf.abs().max(1e-15));
            assert_eq!(out[0], yf_free);
            assert!(
                (out[1] - ud).abs() <= 1e-9 * ud.abs().max(1e-12),
                "{} vs {ud}",
                out[1]
            );
            xh = xn;
            let est = &obs.block.estimate_map * nalgebra::DVector::from_column_slice(run.state());
            assert!((est - &xh).amax() <= 1e-9 * xh.amax().max(1e-15));
        }
        // Rigid columns of C_f are zero.
        assert_eq!(cf[(0, 0)], 0.0);
        assert!(compile_observer_block(&obs.design, 2).is_err());
    }

    #[test]
    fn continuous_observer_layout_and_integral_action() {
        use crate::freq::freq_response_continuous;
        let red = thesis_reduced(5).unwrap();
        let opts = ContinuousObserverOptions {
            mc: true,
            damping: Some(DampingOptions {
                increase: vec![0.035; 3],
                method: DampingMethod::Automated,
                bandpass_q: Some(2.0),
            }),
            q_nu: Some(1e3),
            weights: None,
        };
        let obs = design_continuous_modal_observer(&red, &opts).unwrap();
        // 8 model + 1 noise-model + 6 band-pass states; [y; u] → [ŷ_f; u_d].
        assert_eq!(obs.system.states(), 15);
        assert_eq!((obs.system.inputs(), obs.system.outputs()), (2, 2));
        // Theorem 3.2.4: O_yu → 0 at low frequency (∝ s).
        let lo = freq_response_continuous(&obs.system, 2.0 * std::f64::consts::PI * 1e-3).unwrap()
            [(0, 1)]
            .norm();
        let lo10 = freq_response_continuous(&obs.system, 2.0 * std::f64::consts::PI * 1e-2)
            .unwrap()[(0, 1)]
            .norm();
        assert!((lo10 / lo - 10.0).abs() < 0.5, "{lo} {lo10}");
        // Without the noise model O_yu(0) ≠ 0.
        let plain = design_continuous_modal_observer(
            &red,
            &ContinuousObserverOptions {
                q_nu: None,
                ..opts.clone()
            },
        )
        .unwrap();
        let dc = freq_response_continuous(&plain.system, 1e-3).unwrap()[(0, 1)].norm();
        assert!(dc > 1e3 * lo, "{dc} vs {lo}");
        // Bad Q_ν is an error, not a panic.
        for q in [0.0, -1.0, f64::NAN] {
            let bad = ContinuousObserverOptions {
                q_nu: Some(q),
                ..opts.clone()
            };
            assert!(design_continuous_modal_observer(&red, &bad).is_err());
            let mut dopts = ModalObserverOptions::thesis_mc_ad(TS_10KHZ, 3);
            dopts.q_nu = Some(q);
            assert!(design_modal_observer(&red, &dopts).is_err());
        }
    }

    #[test]
    fn noise_model_gives_zero_dc_from_u_to_yflex() {
        // Theorem 3.2.4: with U = B_t, O_yu(1) = 0; without it, not.
        let red = thesis_reduced(5).unwrap();
        let dc = |q_nu: Option<f64>| {
            let opts = ModalObserverOptions {
                ts: TS_10KHZ,
                mc: true,
                damping: None,
                q_nu,
                weights: None,
                extra_delay_samples: 0,
                command_deadline: None,
            };
            let b = design_modal_observer(&red, &opts).unwrap().block.system;
            let n = b.states();
            let x = (DMatrix::identity(n, n) - &b.a).lu().solve(&b.b).unwrap();
            let g = &b.c * x + &b.d;
            g[(0, 1)] // u_a → ŷ_flex
        };
        let with = dc(Some(0.03));
        let without = dc(None);
        assert!(without.abs() > 1e-11, "{without}");
        assert!(with.abs() < 1e-6 * without.abs(), "{with} vs {without}");
    }
}
