//! Continuous → discrete conversion: exact zero-order hold for plants and
//! observer models (docs/control.md §3, (2.20)), Tustin with optional pre-warping
//! for controllers and filters, and pure sample delays.

use crate::continuous::ContinuousStateSpace;
use crate::linalg::{LinalgError, expm, solve};
use crate::lti::{DiscreteStateSpace, StateSpaceError};
use nalgebra::DMatrix;
use std::fmt;

/// Why a discretisation failed.
#[derive(Debug, Clone, PartialEq)]
pub enum DiscretiseError {
    /// Sample period (or pre-warp frequency) not positive and finite.
    InvalidPeriod(f64),
    /// Pre-warp frequency at or above Nyquist, where tan() blows up.
    PrewarpAboveNyquist(f64),
    /// An input switch instant not within the sample period.
    SwitchOutsidePeriod { tau: f64, ts: f64 },
    /// The matrix exponential or the Tustin inverse failed.
    Linalg(LinalgError),
    /// The result is not a valid state space.
    StateSpace(StateSpaceError),
}

impl fmt::Display for DiscretiseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::InvalidPeriod(t) => write!(f, "sample period {t} is not positive and finite"),
            Self::PrewarpAboveNyquist(w) => {
                write!(f, "pre-warp frequency {w} rad/s is at or above Nyquist")
            }
            Self::SwitchOutsidePeriod { tau, ts } => write!(
                f,
                "input switch at {tau} s is not within the sample period [0, {ts}] s"
            ),
            Self::Linalg(e) => write!(f, "discretisation: {e}"),
            Self::StateSpace(e) => write!(f, "discretisation: {e}"),
        }
    }
}

impl std::error::Error for DiscretiseError {}

impl From<LinalgError> for DiscretiseError {
    fn from(e: LinalgError) -> Self {
        Self::Linalg(e)
    }
}
impl From<StateSpaceError> for DiscretiseError {
    fn from(e: StateSpaceError) -> Self {
        Self::StateSpace(e)
    }
}

fn check_ts(ts: f64) -> Result<(), DiscretiseError> {
    if ts.is_finite() && ts > 0.0 {
        Ok(())
    } else {
        Err(DiscretiseError::InvalidPeriod(ts))
    }
}

/// One input held for `h`: (e^{A h}, ∫₀^h e^{As} ds B), from the exponential
/// of the augmented matrix [[A, B], [0, 0]] h.
fn hold(
    sys: &ContinuousStateSpace,
    h: f64,
) -> Result<(DMatrix<f64>, DMatrix<f64>), DiscretiseError> {
    let (n, m) = (sys.states(), sys.inputs());
    let mut aug = DMatrix::zeros(n + m, n + m);
    aug.view_mut((0, 0), (n, n)).copy_from(&(&sys.a * h));
    aug.view_mut((0, n), (n, m)).copy_from(&(&sys.b * h));
    let e = expm(&aug)?;
    Ok((
        e.view((0, 0), (n, n)).into_owned(),
        e.view((0, n), (n, m)).into_owned(),
    ))
}

/// Exact ZOH: A_d = e^{A Ts}, B_d = ∫₀^Ts e^{Aτ}dτ B from the exponential of
/// the augmented matrix [[A, B], [0, 0]] Ts, so a singular A (rigid modes) is
/// fine. C and D (e.g. T_DC) are unchanged (Theorem 2.4.1).
pub fn zoh(sys: &ContinuousStateSpace, ts: f64) -> Result<DiscreteStateSpace, DiscretiseError> {
    check_ts(ts)?;
    let (ad, bd) = hold(sys, ts)?;
    Ok(DiscreteStateSpace::new(
        ad,
        bd,
        sys.c.clone(),
        sys.d.clone(),
        ts,
    )?)
}

/// One sample of a plant whose input changes within it: the previous input
/// u(k−1) held over [t_k, t_k + τ), the new u(k) over [t_k + τ, t_{k+1}),
/// integrated exactly as x(k+1) = Φ x(k) + G_new u(k) + G_old u(k−1) (the
/// command applied on arrival, docs/control.md §10.1).
#[derive(Debug, Clone, PartialEq)]
pub struct SplitHold {
    /// Φ = e^{A Ts}.
    pub phi: DMatrix<f64>,
    /// G_new = ∫₀^{Ts−τ} e^{As} ds B: the input from t_k + τ on.
    pub g_new: DMatrix<f64>,
    /// G_old = e^{A(Ts−τ)} ∫₀^{τ} e^{As} ds B: the input before t_k + τ.
    pub g_old: DMatrix<f64>,
    /// Where in the period the input switches [s].
    pub tau: f64,
}

impl SplitHold {
    /// The sampled plant as one state space whose input acts in the same
    /// sample: state [x(k); u(k−1)], input u(k), output y(k) = C x(k) +
    /// D u(k−1) (at t_k the input still applied is u(k−1)). With τ = Ts it
    /// is the plain ZOH behind one sample of delay.
    pub fn plant(
        &self,
        c: &DMatrix<f64>,
        d: &DMatrix<f64>,
        ts: f64,
    ) -> Result<DiscreteStateSpace, DiscretiseError> {
        let (n, m) = (self.phi.nrows(), self.g_new.ncols());
        let p = c.nrows();
        let mut a = DMatrix::zeros(n + m, n + m);
        a.view_mut((0, 0), (n, n)).copy_from(&self.phi);
        a.view_mut((0, n), (n, m)).copy_from(&self.g_old);
        let mut b = DMatrix::zeros(n + m, m);
        b.view_mut((0, 0), (n, m)).copy_from(&self.g_new);
        b.view_mut((n, 0), (m, m)).fill_with_identity();
        let mut c_aug = DMatrix::zeros(p, n + m);
        c_aug.view_mut((0, 0), (p, n)).copy_from(c);
        c_aug.view_mut((0, n), (p, m)).copy_from(d);
        Ok(DiscreteStateSpace::new(
            a,
            b,
            c_aug,
            DMatrix::zeros(p, m),
            ts,
        )?)
    }
}

impl SplitHold {
    /// The sampled plant in the coordinates the loop's blocks use: input
    /// u_a(k), the input present at t_k (held until t_k + τ; u_a(k+1) acts
    /// from then on), state z(k) = x(k) − G_new u_a(k):
    /// z(k+1) = Φ z(k) + (Φ G_new + G_old) u_a(k),
    /// y(k) = C z(k) + (C G_new + D) u_a(k).
    /// Causal in u_a, so a loop, an observer or the emulator runs it exactly
    /// as a plant behind one sample of delay; with τ = Ts (G_new = 0) it is
    /// the plain ZOH (Φ, Γ, C, D).
    pub fn delayed_input_form(
        &self,
        c: &DMatrix<f64>,
        d: &DMatrix<f64>,
        ts: f64,
    ) -> Result<DiscreteStateSpace, DiscretiseError> {
        Ok(DiscreteStateSpace::new(
            self.phi.clone(),
            &self.phi * &self.g_new + &self.g_old,
            c.clone(),
            c * &self.g_new + d,
            ts,
        )?)
    }
}

/// (e^{A h}, ∫₀^h e^{As} ds B) of `sys`: the state moved on by `h` with
/// the input held (for an estimate at an instant inside a sample).
pub fn hold_for(
    sys: &ContinuousStateSpace,
    h: f64,
) -> Result<(DMatrix<f64>, DMatrix<f64>), DiscretiseError> {
    if !(h.is_finite() && h >= 0.0) {
        return Err(DiscretiseError::InvalidPeriod(h));
    }
    hold(sys, h)
}

/// [`SplitHold`] of `sys` at period `ts` with the input switching `tau`
/// after each tick (0 ≤ τ ≤ Ts: τ = 0 is the plain ZOH, τ = Ts one whole
/// sample of delay). Each piece is one exact ZOH (the augmented
/// exponential), so rigid modes are fine.
pub fn zoh_split(
    sys: &ContinuousStateSpace,
    ts: f64,
    tau: f64,
) -> Result<SplitHold, DiscretiseError> {
    check_ts(ts)?;
    if !(tau.is_finite() && (0.0..=ts).contains(&tau)) {
        return Err(DiscretiseError::SwitchOutsidePeriod { tau, ts });
    }
    let (phi_before, gamma_before) = hold(sys, tau)?;
    let (phi_after, gamma_after) = hold(sys, ts - tau)?;
    Ok(SplitHold {
        phi: &phi_after * &phi_before,
        g_new: gamma_after,
        g_old: &phi_after * gamma_before,
        tau,
    })
}

/// Tustin (bilinear) transform s = c (z − 1)/(z + 1), with c = 2/Ts, or with
/// pre-warping c = ω₀ / tan(ω₀ Ts / 2) so that the response at ω₀ is exact
/// (used for the per-mode band-pass filters).
pub fn tustin(
    sys: &ContinuousStateSpace,
    ts: f64,
    prewarp: Option<f64>,
) -> Result<DiscreteStateSpace, DiscretiseError> {
    check_ts(ts)?;
    let c = match prewarp {
        None => 2.0 / ts,
        Some(w) => {
            if !(w.is_finite() && w > 0.0) {
                return Err(DiscretiseError::InvalidPeriod(w));
            }
            if w * ts / 2.0 >= std::f64::consts::FRAC_PI_2 {
                return Err(DiscretiseError::PrewarpAboveNyquist(w));
            }
            w / (w * ts / 2.0).tan()
        }
    };
    let alpha = 1.0 / c;
    let n = sys.states();
    let id = DMatrix::<f64>::identity(n, n);
    let m = &id - &sys.a * alpha;
    let minv = solve(&m, &id, "I - A/c (pole at s = c)")?;
    let ad = &minv * (&id + &sys.a * alpha);
    let k = (2.0 * alpha).sqrt();
    let bd = &minv * &sys.b * k;
    let cd = &sys.c * &minv * k;
    let dd = &sys.d + &sys.c * &minv * &sys.b * alpha;
    Ok(DiscreteStateSpace::new(ad, bd, cd, dd, ts)?)
}

/// A delay of `samples` samples on `signals` channels: y(k) = u(k − samples).
pub fn delay(
    signals: usize,
    samples: usize,
    ts: f64,
) -> Result<DiscreteStateSpace, DiscretiseError> {
    check_ts(ts)?;
    let n = signals * samples;
    if samples == 0 {
        return Ok(DiscreteStateSpace::gain(
            DMatrix::identity(signals, signals),
            ts,
        )?);
    }
    // Shift register: state block j holds u(k − 1 − j).
    let mut a = DMatrix::zeros(n, n);
    for j in 1..samples {
        a.view_mut((j * signals, (j - 1) * signals), (signals, signals))
            .fill_with_identity();
    }
    let mut b = DMatrix::zeros(n, signals);
    b.view_mut((0, 0), (signals, signals)).fill_with_identity();
    let mut c = DMatrix::zeros(signals, n);
    c.view_mut((0, (samples - 1) * signals), (signals, signals))
        .fill_with_identity();
    Ok(DiscreteStateSpace::new(
        a,
        b,
        c,
        DMatrix::zeros(signals, signals),
        ts,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::freq::{freq_response_continuous, freq_response_discrete};
    use crate::lti::LtiRunner;
    use crate::models::{TS_10KHZ, thesis_chain_modal, thesis_plant};
    use nalgebra::DVector;

    #[test]
    fn a_split_hold_is_the_plain_zoh_at_its_ends_and_refuses_a_switch_outside() {
        let sys = thesis_chain_modal().unwrap().state_space();
        let ts = TS_10KHZ;
        let d = zoh(&sys, ts).unwrap();
        let close =
            |a: &DMatrix<f64>, b: &DMatrix<f64>| (a - b).amax() <= 1e-12 * b.amax().max(1e-300);
        let at_arrival = zoh_split(&sys, ts, 0.0).unwrap();
        assert!(close(&at_arrival.phi, &d.a) && close(&at_arrival.g_new, &d.b));
        assert_eq!(at_arrival.g_old.amax(), 0.0);
        let one_sample = zoh_split(&sys, ts, ts).unwrap();
        assert!(close(&one_sample.phi, &d.a) && close(&one_sample.g_old, &d.b));
        assert_eq!(one_sample.g_new.amax(), 0.0);
        for tau in [-1e-6, 1.5 * ts, f64::NAN] {
            assert!(matches!(
                zoh_split(&sys, ts, tau),
                Err(DiscretiseError::SwitchOutsidePeriod { .. })
            ));
        }
    }

    /// The two-piece sample against a fine-step simulation of the same
    /// continuous model (each fine step an exact ZOH of 1/1000 of the
    /// period, the input switching on the fine grid at τ).
    #[test]
    fn a_split_hold_matches_a_fine_step_simulation() {
        let sys = thesis_chain_modal().unwrap().state_space();
        let ts = TS_10KHZ;
        let steps = 1000;
        let fine = zoh(&sys, ts / steps as f64).unwrap();
        let (n, m) = (sys.states(), sys.inputs());
        let x0 = DVector::from_fn(n, |i, _| 1e-6 * (i as f64 + 1.0).sin());
        let (u_old, u_new) = (
            DVector::from_element(m, 3.0),
            DVector::from_element(m, -5.0),
        );
        for switch_at in [0, 300, 700, 1000] {
            let tau = ts * switch_at as f64 / steps as f64;
            let split = zoh_split(&sys, ts, tau).unwrap();
            let exact = &split.phi * &x0 + &split.g_new * &u_new + &split.g_old * &u_old;
            let mut x = x0.clone();
            for step in 0..steps {
                let u = if step < switch_at { &u_old } else { &u_new };
                x = &fine.a * &x + &fine.b * u;
            }
            let error = (&x - &exact).amax();
            assert!(
                error <= 1e-9 * exact.amax(),
                "τ = {tau}: {error:e} against {:e}",
                exact.amax()
            );
        }
    }

    /// The delayed-input form driven by u_a(k) gives the outputs of the
    /// two-piece plant, and the moved-on state by `hold_for` is the split's
    /// first piece.
    #[test]
    fn the_delayed_input_form_runs_the_split_plant() {
        let sys = thesis_plant(5).unwrap().state_space();
        let ts = TS_10KHZ;
        let tau = 30e-6;
        let split = zoh_split(&sys, ts, tau).unwrap();
        let form = split.delayed_input_form(&sys.c, &sys.d, ts).unwrap();
        let u_a: Vec<f64> = (0..400).map(|k| (0.37 * k as f64).sin() * 40.0).collect();
        let mut x = DVector::zeros(sys.states());
        let mut z = LtiRunner::new(form);
        for k in 0..u_a.len() - 1 {
            let y_split = (&sys.c * &x)[0] + sys.d[(0, 0)] * u_a[k];
            let y_form = z.output(&[u_a[k]])[0];
            assert!(
                (y_split - y_form).abs() <= 1e-9 * y_split.abs().max(1e-12),
                "k = {k}: {y_split:e} vs {y_form:e}"
            );
            z.advance(&[u_a[k]]);
            x = &split.phi * &x
                + &split.g_old * DVector::from_element(1, u_a[k])
                + &split.g_new * DVector::from_element(1, u_a[k + 1]);
        }
        let (e_tau, gamma_tau) = hold_for(&sys, tau).unwrap();
        let (e_rest, _) = hold_for(&sys, ts - tau).unwrap();
        let close = (&e_rest * &gamma_tau - &split.g_old).amax() <= 1e-12 * split.g_old.amax();
        assert!(close && (&e_rest * &e_tau - &split.phi).amax() <= 1e-12);
        assert!(hold_for(&sys, -1.0).is_err());
    }

    #[test]
    fn zoh_matches_closed_form_per_mode() {
        let m = thesis_chain_modal().unwrap();
        let ts = TS_10KHZ;
        let d = zoh(&m.state_space(), ts).unwrap();
        // Rigid mode: [[1, Ts], [0, 1]], B = φ_a [Ts²/2; Ts].
        assert!((d.a[(0, 1)] - ts).abs() < 1e-18);
        assert!((d.b[(0, 0)] - m.phi_a[(0, 0)] * ts * ts / 2.0).abs() < 1e-20);
        for i in 1..8 {
            let (w, z) = (m.omega[i], m.zeta[i]);
            let wd = w * (1.0 - z * z).sqrt();
            let e = (-z * w * ts).exp();
            let (s, c) = (wd * ts).sin_cos();
            let r = z / (1.0 - z * z).sqrt();
            // (2.31)
            let want = [
                e * (c + r * s),
                e * s / wd,
                -e * w / (1.0 - z * z).sqrt() * s,
                e * (c - r * s),
            ];
            let blk = d.a.view((2 * i, 2 * i), (2, 2));
            let got = [blk[(0, 0)], blk[(0, 1)], blk[(1, 0)], blk[(1, 1)]];
            for (g, w_) in got.iter().zip(want) {
                assert!(
                    (g - w_).abs() <= 1e-12 * w_.abs().max(1e-9),
                    "mode {i}: {g} vs {w_}"
                );
            }
            // Exact B = A⁻¹ (A_d − I) [0; φ_a] for a non-singular mode block.
            let a_c = DMatrix::from_row_slice(2, 2, &[0.0, 1.0, -w * w, -2.0 * z * w]);
            let ad = DMatrix::from_row_slice(2, 2, &want);
            let rhs = (ad - DMatrix::identity(2, 2))
                * DMatrix::from_column_slice(2, 1, &[0.0, m.phi_a[(i, 0)]]);
            let bd = a_c.lu().solve(&rhs).unwrap();
            for r in 0..2 {
                let g = d.b[(2 * i + r, 0)];
                assert!(
                    (g - bd[(r, 0)]).abs() <= 1e-10 * bd[(r, 0)].abs(),
                    "mode {i} B row {r}"
                );
            }
        }
    }

    #[test]
    fn t_dc_is_unchanged_by_discretisation() {
        // Discretise the discarded modes 4–6 of y5 and take their DC gain
        // C_d (I − A_d)⁻¹ B_d: it must equal T_DC (Theorem 2.4.1).
        let p = thesis_plant(5).unwrap();
        let disc = p.select_modes(&[4, 5, 6]).unwrap();
        let d = zoh(&disc.state_space(), TS_10KHZ).unwrap();
        let n = d.states();
        let dc = &d.c * (DMatrix::identity(n, n) - &d.a).lu().solve(&d.b).unwrap();
        let t_dc = p.compliance(&[4, 5, 6]).unwrap();
        assert!(
            (dc[(0, 0)] - t_dc[(0, 0)]).abs() < 1e-9 * t_dc[(0, 0)].abs(),
            "{dc} vs {t_dc}"
        );
        assert!((t_dc[(0, 0)] + 3.28e-10).abs() < 0.006e-10);
        // And the reduced model keeps T_DC as its D matrix.
        let red = crate::models::thesis_reduced(5).unwrap();
        let rd = zoh(&red.state_space(), TS_10KHZ).unwrap();
        assert_eq!(rd.d, red.t_dc);
    }

    #[test]
    fn tustin_matches_continuous_at_prewarp_frequency() {
        // Band-pass (ω/Q) s / (s² + (ω/Q) s + ω²) at 1396 Hz, Q = 2.
        let w = 2.0 * std::f64::consts::PI * 1396.06;
        let q = 2.0;
        let bp = ContinuousStateSpace::from_transfer_function(&[w / q, 0.0], &[1.0, w / q, w * w])
            .unwrap();
        let d = tustin(&bp, TS_10KHZ, Some(w)).unwrap();
        let h = freq_response_discrete(&d, w).unwrap()[(0, 0)];
        assert!((h.re - 1.0).abs() < 1e-9 && h.im.abs() < 1e-9, "{h}");
        // Without pre-warping, low frequencies still match closely.
        let d2 = tustin(&bp, TS_10KHZ, None).unwrap();
        let wl = 2.0 * std::f64::consts::PI * 50.0;
        let hd = freq_response_discrete(&d2, wl).unwrap()[(0, 0)];
        let hc = freq_response_continuous(&bp, wl).unwrap()[(0, 0)];
        assert!((hd - hc).norm() < 1e-3 * hc.norm());
        assert!(matches!(
            tustin(&bp, TS_10KHZ, Some(4e4)),
            Err(DiscretiseError::PrewarpAboveNyquist(_))
        ));
        assert!(zoh(&bp, 0.0).is_err());
    }

    #[test]
    fn delay_shifts_samples() {
        let mut r = LtiRunner::new(delay(1, 2, 1.0).unwrap());
        let out: Vec<f64> = [1.0, 2.0, 3.0, 4.0]
            .iter()
            .map(|u| r.step(&[*u])[0])
            .collect();
        assert_eq!(out, vec![0.0, 0.0, 1.0, 2.0]);
    }
}
