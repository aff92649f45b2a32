//! Assembly of the discrete single-rate loop of docs/control.md §5.4/§10.1 into
//! one closed-loop [`DiscreteStateSpace`], for eigenvalue, frequency-response
//! and simulation checks at design time.
//!
//! Per tick k: y_meas = y + n; the observer block gets [y_meas; u_a] (and
//! u_pending with an extra-delay block); e_meas = r − (y_meas − ŷ_flex);
//! u_fb = C_fb(e_meas); u_c = u_fb + u_d + u_ff; the plant applies
//! u_a(k) = u_c(k − d) (d = `loop_delay` samples, 0 allowed) plus the force
//! disturbance w.
//!
//! Closed-loop inputs: [r (n_y); n (n_y); u_ff (n_u); w (n_u)].
//! Outputs: [e_meas (n_y); y_meas (n_y); e_true = r − y (n_y); u_c (n_u)].
//! So r → e_meas is S^I, n → y_meas is S^O, and r → e_true is T_{r→e_true}.
//!
//! [`assemble_continuous_loop`] builds the same loop in continuous time (no
//! delay; the observer gets the total input u directly), for the continuous
//! design checks of docs/control.md §9.

use crate::continuous::ContinuousStateSpace;
use crate::design_error::DesignError;
use crate::linalg::{LinalgError, solve};
use crate::lti::DiscreteStateSpace;
use crate::matrix_error::MatrixError;
use crate::observer_block::ObserverBlock;
use nalgebra::DMatrix;

/// The pieces of the loop.
#[derive(Debug, Clone, Copy)]
pub struct LoopSpec<'a> {
    /// Plant from applied input (n_u) to true output (n_y).
    pub plant: &'a DiscreteStateSpace,
    /// Observer block, or None (no MC, no AD).
    pub observer: Option<&'a ObserverBlock>,
    /// Feedback controller from e_meas (n_y) to u_fb (n_u).
    pub controller: &'a DiscreteStateSpace,
    /// Samples between computing u_c(k) and applying it (1 = the thesis
    /// 10 kHz reference: u_c(k) is held over [t_{k+1}, t_{k+2})).
    pub loop_delay: usize,
}

/// A linear signal: x · X + w · W + a · u_a.
#[derive(Clone)]
struct Lin {
    x: DMatrix<f64>,
    w: DMatrix<f64>,
    a: DMatrix<f64>,
}

impl Lin {
    fn zeros(rows: usize, nx: usize, nw: usize, na: usize) -> Self {
        Self {
            x: DMatrix::zeros(rows, nx),
            w: DMatrix::zeros(rows, nw),
            a: DMatrix::zeros(rows, na),
        }
    }
    fn add(&self, o: &Lin) -> Lin {
        Lin {
            x: &self.x + &o.x,
            w: &self.w + &o.w,
            a: &self.a + &o.a,
        }
    }
    fn sub(&self, o: &Lin) -> Lin {
        Lin {
            x: &self.x - &o.x,
            w: &self.w - &o.w,
            a: &self.a - &o.a,
        }
    }
    fn mul(m: &DMatrix<f64>, s: &Lin) -> Lin {
        Lin {
            x: m * &s.x,
            w: m * &s.w,
            a: m * &s.a,
        }
    }
    fn stack(parts: &[&Lin]) -> Lin {
        let rows: usize = parts.iter().map(|p| p.x.nrows()).sum();
        let (nx, nw, na) = (parts[0].x.ncols(), parts[0].w.ncols(), parts[0].a.ncols());
        let mut out = Lin::zeros(rows, nx, nw, na);
        let mut r = 0;
        for p in parts {
            let k = p.x.nrows();
            out.x.rows_mut(r, k).copy_from(&p.x);
            out.w.rows_mut(r, k).copy_from(&p.w);
            out.a.rows_mut(r, k).copy_from(&p.a);
            r += k;
        }
        out
    }
    fn rows(&self, start: usize, n: usize) -> Lin {
        Lin {
            x: self.x.rows(start, n).into_owned(),
            w: self.w.rows(start, n).into_owned(),
            a: self.a.rows(start, n).into_owned(),
        }
    }
}

/// Builds the closed loop (see the module doc).
pub fn assemble_loop(spec: &LoopSpec) -> Result<DiscreteStateSpace, DesignError> {
    let p = spec.plant;
    let c = spec.controller;
    let (ny, nu) = (p.outputs(), p.inputs());
    let ts = p.ts;
    if c.inputs() != ny || c.outputs() != nu {
        return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
            what: "controller (outputs x inputs)",
            expected: (nu, ny),
            found: (c.outputs(), c.inputs()),
        }));
    }
    let same_ts = |t: f64| (t - ts).abs() <= 1e-12 * ts;
    if !same_ts(c.ts) {
        return Err(DesignError::InvalidParameter(
            "controller sample period differs".into(),
        ));
    }
    if let Some(b) = spec.observer {
        if b.n_y != ny || b.n_u != nu || !same_ts(b.system.ts) {
            return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                what: "observer block (n_y, n_u)",
                expected: (ny, nu),
                found: (b.n_y, b.n_u),
            }));
        }
        if b.extra_delay_samples > 0 && spec.loop_delay < 2 {
            return Err(DesignError::InvalidParameter(
                "an extra-delay observer block needs a loop delay of at least 2".into(),
            ));
        }
    }
    let d = spec.loop_delay;
    let np = p.states();
    let nb = spec.observer.map_or(0, |b| b.system.states());
    let nc = c.states();
    let nr = d * nu;
    let nx = np + nb + nc + nr;
    let nw = 2 * ny + 2 * nu;
    let na = nu;
    let (ox_p, ox_b, ox_c, ox_r) = (0, np, np + nb, np + nb + nc);
    let (ow_r, ow_n, ow_ff, ow_w) = (0, ny, 2 * ny, 2 * ny + nu);
    let state = |off: usize, k: usize| {
        let mut s = Lin::zeros(k, nx, nw, na);
        s.x.view_mut((0, off), (k, k)).fill_with_identity();
        s
    };
    let exog = |off: usize, k: usize| {
        let mut s = Lin::zeros(k, nx, nw, na);
        s.w.view_mut((0, off), (k, k)).fill_with_identity();
        s
    };
    let u_a = if d == 0 {
        let mut s = Lin::zeros(nu, nx, nw, na);
        s.a.fill_with_identity();
        s
    } else {
        state(ox_r + (d - 1) * nu, nu)
    };
    let xp = state(ox_p, np);
    let y = Lin::mul(&p.c, &xp).add(&Lin::mul(&p.d, &u_a));
    let y_meas = y.add(&exog(ow_n, ny));
    let r = exog(ow_r, ny);
    let (yf, ud, block_in) = match spec.observer {
        Some(b) => {
            let mut parts = vec![&y_meas, &u_a];
            let pending;
            if b.extra_delay_samples == 1 {
                pending = state(ox_r + (d - 2) * nu, nu);
                parts.push(&pending);
            }
            let input = Lin::stack(&parts);
            let s = state(ox_b, nb);
            let out = Lin::mul(&b.system.c, &s).add(&Lin::mul(&b.system.d, &input));
            (out.rows(0, ny), out.rows(ny, nu), Some(input))
        }
        None => (Lin::zeros(ny, nx, nw, na), Lin::zeros(nu, nx, nw, na), None),
    };
    let e_meas = r.sub(&y_meas).add(&yf);
    let xc = state(ox_c, nc);
    let u_fb = Lin::mul(&c.c, &xc).add(&Lin::mul(&c.d, &e_meas));
    let u_c = u_fb.add(&ud).add(&exog(ow_ff, nu));
    // Next state.
    let mut next = Lin::zeros(nx, nx, nw, na);
    let plant_in = u_a.add(&exog(ow_w, nu));
    let xp_next = Lin::mul(&p.a, &xp).add(&Lin::mul(&p.b, &plant_in));
    next.x.rows_mut(ox_p, np).copy_from(&xp_next.x);
    next.w.rows_mut(ox_p, np).copy_from(&xp_next.w);
    next.a.rows_mut(ox_p, np).copy_from(&xp_next.a);
    if let (Some(b), Some(input)) = (spec.observer, &block_in) {
        let s = state(ox_b, nb);
        let sn = Lin::mul(&b.system.a, &s).add(&Lin::mul(&b.system.b, input));
        next.x.rows_mut(ox_b, nb).copy_from(&sn.x);
        next.w.rows_mut(ox_b, nb).copy_from(&sn.w);
        next.a.rows_mut(ox_b, nb).copy_from(&sn.a);
    }
    let xcn = Lin::mul(&c.a, &xc).add(&Lin::mul(&c.b, &e_meas));
    next.x.rows_mut(ox_c, nc).copy_from(&xcn.x);
    next.w.rows_mut(ox_c, nc).copy_from(&xcn.w);
    next.a.rows_mut(ox_c, nc).copy_from(&xcn.a);
    if d > 0 {
        next.x.rows_mut(ox_r, nu).copy_from(&u_c.x);
        next.w.rows_mut(ox_r, nu).copy_from(&u_c.w);
        next.a.rows_mut(ox_r, nu).copy_from(&u_c.a);
        for j in 1..d {
            let mut blk = next
                .x
                .view_mut((ox_r + j * nu, ox_r + (j - 1) * nu), (nu, nu));
            blk.fill_with_identity();
        }
    }
    let e_true = r.sub(&y);
    let out = Lin::stack(&[&e_meas, &y_meas, &e_true, &u_c]);
    // Resolve u_a: with d ≥ 1 it is a state (a-coefficients are zero);
    // with d = 0, u_a = u_c is an algebraic loop: (I − U_a) u_a = U_x X + U_w W.
    let (ua_x, ua_w) = if d == 0 {
        let m = DMatrix::<f64>::identity(nu, nu) - &u_c.a;
        (
            solve(&m, &u_c.x, "algebraic loop I − D")?,
            solve(&m, &u_c.w, "algebraic loop I − D")?,
        )
    } else {
        (DMatrix::zeros(nu, nx), DMatrix::zeros(nu, nw))
    };
    let a = &next.x + &next.a * &ua_x;
    let bm = &next.w + &next.a * &ua_w;
    let cm = &out.x + &out.a * &ua_x;
    let dm = &out.w + &out.a * &ua_w;
    if a.iter().any(|v| !v.is_finite()) {
        return Err(LinalgError::NonFinite.into());
    }
    Ok(DiscreteStateSpace::new(a, bm, cm, dm, ts)?)
}

/// The loop of the module doc in continuous time: plant P (D may be
/// non-zero), an optional observer with inputs [y (n_y); u (n_u)] and
/// outputs [ŷ_flex (n_y); u_d (n_u)] (e.g.
/// [`crate::observer_block::ContinuousModalObserver::system`]), controller
/// e_meas → u_fb, and u = u_fb + u_d + u_ff applied without delay. Same
/// inputs and outputs as [`assemble_loop`]; algebraic loops through direct
/// feedthroughs are resolved (an error if I − D_loop is singular).
pub fn assemble_continuous_loop(
    plant: &ContinuousStateSpace,
    observer: Option<&ContinuousStateSpace>,
    controller: &ContinuousStateSpace,
) -> Result<ContinuousStateSpace, DesignError> {
    // The interconnection algebra is the same as for a discrete loop without
    // delay (ẋ instead of x(k+1)), so reuse it on unit-period copies.
    let unit = |s: &ContinuousStateSpace| {
        DiscreteStateSpace::new(s.a.clone(), s.b.clone(), s.c.clone(), s.d.clone(), 1.0)
    };
    let p = unit(plant)?;
    let c = unit(controller)?;
    let block = match observer {
        Some(o) => {
            let (ny, nu) = (plant.outputs(), plant.inputs());
            if o.inputs() != ny + nu || o.outputs() != ny + nu {
                return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
                    what: "continuous observer (outputs x inputs)",
                    expected: (ny + nu, ny + nu),
                    found: (o.outputs(), o.inputs()),
                }));
            }
            Some(ObserverBlock {
                system: unit(o)?,
                estimate_map: DMatrix::zeros(0, o.states()),
                model: None,
                n_y: ny,
                n_u: nu,
                extra_delay_samples: 0,
            })
        }
        None => None,
    };
    let cl = assemble_loop(&LoopSpec {
        plant: &p,
        observer: block.as_ref(),
        controller: &c,
        loop_delay: 0,
    })?;
    Ok(ContinuousStateSpace::new(cl.a, cl.b, cl.c, cl.d)?)
}

/// Closed-loop poles as (frequency [Hz], damping), upper half-plane only.
pub fn closed_loop_modes(sys: &DiscreteStateSpace) -> Result<Vec<(f64, f64)>, DesignError> {
    discrete_modes(&sys.a, sys.ts)
}

/// Poles of a discrete system matrix as continuous-equivalent (frequency
/// [Hz], damping), upper half-plane only.
pub fn discrete_modes(a: &DMatrix<f64>, ts: f64) -> Result<Vec<(f64, f64)>, DesignError> {
    let ev = crate::linalg::eigenvalues(a)?;
    Ok(ev
        .iter()
        .filter(|z| z.im > 0.0)
        .map(|z| {
            let (w, zeta) = crate::linalg::discrete_pole_to_continuous(*z, ts);
            (w / (2.0 * std::f64::consts::PI), zeta)
        })
        .collect())
}

/// Continuous closed-loop poles as (frequency [Hz], damping), upper
/// half-plane only.
pub fn continuous_closed_loop_modes(
    sys: &ContinuousStateSpace,
) -> Result<Vec<(f64, f64)>, DesignError> {
    let ev = crate::linalg::eigenvalues(&sys.a)?;
    Ok(ev
        .iter()
        .filter(|s| s.im > 0.0)
        .map(|s| (s.norm() / (2.0 * std::f64::consts::PI), -s.re / s.norm()))
        .collect())
}
