//! Modified feedforward for observer loops (thesis App. A, docs/control.md §7).
//!
//! With MC and/or AD the observer reacts to the reference: if the plant
//! followed r exactly, the observer would still output ŷ_f and û_d, the
//! controller would act on ŷ_f, and the total input would no longer be the
//! ideal u0 = P̂⁻¹ r. The fix (Fig. A.2) runs a copy of the observer, fed
//! with the signals it would see in that ideal case (y = r, u = u0), and a
//! copy of C_fb on its ŷ_f, and removes their contributions:
//!
//!   u_ff = u0 − û_d − C_fb ŷ_f,   (ŷ_f, û_d) = O(y = r, u = u0),
//!
//! i.e. (A.7) C_ff = (I − O_uu − C_fb O_yu) P⁻¹ − O_uy − C_fb O_yy.
//!
//! # Timing (one loop tick = one sample)
//! [`modified_feedforward`] returns a block with inputs [u0(k); r(k)] and
//! output u_ff(k), where u0(k) is the input the plant should APPLY over
//! [t_k, t_{k+1}) (e.g. the 4-gain filter (A.1) on the set-point at t_k) and
//! r(k) the reference at t_k. Its observer copy is the real observer block
//! (inputs y(k), u_a(k)); with `loop_delay` = d the controller output of tick k
//! is applied at k + d, so the copy's û_d and C_fb ŷ_f of tick k are
//! subtracted from the input applied at k + d: the block delays them by d.
//! Feed tick k of the loop ([`crate::closed_loop`]'s u_ff input) with the
//! block's output at tick k + d, i.e. run the block d ticks ahead, exactly as
//! the plain feedforward is advanced by the loop delay (docs/control.md §10.1).
//! Then, if u0 inverts the plant exactly, e_true = 0.

use crate::design_error::DesignError;
use crate::lti::DiscreteStateSpace;
use crate::matrix_error::MatrixError;
use crate::observer_block::ObserverBlock;
use nalgebra::DMatrix;

/// The modified feedforward block (module doc): inputs [u0 (n_u); r (n_y)],
/// output u_ff (n_u), for a loop with `loop_delay` samples between computing
/// and applying the controller output. Observer blocks with an extra
/// prediction step (`extra_delay_samples` = 1) are refused: their copy would
/// need u0 one sample ahead as a third input.
pub fn modified_feedforward(
    observer: &ObserverBlock,
    controller: &DiscreteStateSpace,
    loop_delay: usize,
) -> Result<DiscreteStateSpace, DesignError> {
    let o = &observer.system;
    let (ny, nu) = (observer.n_y, observer.n_u);
    if observer.extra_delay_samples != 0 {
        return Err(DesignError::InvalidParameter(format!(
            "modified feedforward needs an observer block without extra prediction \
             (extra_delay_samples = {})",
            observer.extra_delay_samples
        )));
    }
    if o.inputs() != ny + nu || o.outputs() != ny + nu {
        return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
            what: "observer block (outputs x inputs) for n_y, n_u",
            expected: (ny + nu, ny + nu),
            found: (o.outputs(), o.inputs()),
        }));
    }
    if controller.inputs() != ny || controller.outputs() != nu {
        return Err(DesignError::Matrix(MatrixError::DimensionMismatch {
            what: "controller C_fb (outputs x inputs)",
            expected: (nu, ny),
            found: (controller.outputs(), controller.inputs()),
        }));
    }
    if (controller.ts - o.ts).abs() > 1e-12 * o.ts {
        return Err(DesignError::InvalidParameter(format!(
            "controller sample period {} s differs from the observer's {} s",
            controller.ts, o.ts
        )));
    }
    let (nb, nc, d) = (o.states(), controller.states(), loop_delay);
    // Observer copy with y = r, u_a = u0; its inputs reordered to [u0; r].
    let b_u = o.b.columns(ny, nu);
    let b_y = o.b.columns(0, ny);
    let c_f = o.c.rows(0, ny);
    let c_d = o.c.rows(ny, nu);
    let d_fy = o.d.view((0, 0), (ny, ny));
    let d_fu = o.d.view((0, ny), (ny, nu));
    let d_dy = o.d.view((ny, 0), (nu, ny));
    let d_du = o.d.view((ny, ny), (nu, nu));
    let (ac, bc, cc, dc) = (&controller.a, &controller.b, &controller.c, &controller.d);
    // q = û_d + C_fb ŷ_f = Q_x [s; c] + Q_u0 u0 + Q_r r.
    let mut q_x = DMatrix::zeros(nu, nb + nc);
    q_x.columns_mut(0, nb).copy_from(&(c_d + dc * c_f));
    q_x.columns_mut(nb, nc).copy_from(cc);
    let q_u0 = d_du + dc * d_fu;
    let q_r = d_dy + dc * d_fy;
    let n = nb + nc + d * nu;
    let mut a = DMatrix::zeros(n, n);
    let mut b = DMatrix::zeros(n, nu + ny);
    a.view_mut((0, 0), (nb, nb)).copy_from(&o.a);
    b.view_mut((0, 0), (nb, nu)).copy_from(&b_u);
    b.view_mut((0, nu), (nb, ny)).copy_from(&b_y);
    a.view_mut((nb, 0), (nc, nb)).copy_from(&(bc * c_f));
    a.view_mut((nb, nb), (nc, nc)).copy_from(ac);
    b.view_mut((nb, 0), (nc, nu)).copy_from(&(bc * d_fu));
    b.view_mut((nb, nu), (nc, ny)).copy_from(&(bc * d_fy));
    let mut c = DMatrix::zeros(nu, n);
    let mut dm = DMatrix::zeros(nu, nu + ny);
    dm.columns_mut(0, nu).fill_with_identity();
    if d == 0 {
        c.columns_mut(0, nb + nc).copy_from(&(-&q_x));
        dm.columns_mut(0, nu)
            .copy_from(&(DMatrix::identity(nu, nu) - &q_u0));
        dm.columns_mut(nu, ny).copy_from(&(-&q_r));
    } else {
        // Delay line z_1 … z_d of q; u_ff = u0 − z_d.
        let z0 = nb + nc;
        a.view_mut((z0, 0), (nu, nb + nc)).copy_from(&q_x);
        b.view_mut((z0, 0), (nu, nu)).copy_from(&q_u0);
        b.view_mut((z0, nu), (nu, ny)).copy_from(&q_r);
        for j in 1..d {
            a.view_mut((z0 + j * nu, z0 + (j - 1) * nu), (nu, nu))
                .fill_with_identity();
        }
        c.view_mut((0, z0 + (d - 1) * nu), (nu, nu))
            .copy_from(&(-DMatrix::<f64>::identity(nu, nu)));
    }
    Ok(DiscreteStateSpace::new(a, b, c, dm, o.ts)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::closed_loop::{LoopSpec, assemble_loop};
    use crate::discretise::zoh;
    use crate::feedforward::FeedforwardGains;
    use crate::freq::freq_response_discrete;
    use crate::lti::LtiRunner;
    use crate::models::{CHAIN_MASS, TS_10KHZ, thesis_plant};
    use crate::observer_block::thesis_observer_block;
    use crate::pid::thesis_pid;
    use crate::setpoint::{Setpoint, SetpointParams};
    use nalgebra::Complex;

    type C64 = Complex<f64>;

    #[test]
    fn matches_a7_and_cancels_the_observer_in_the_frequency_domain() {
        // Thesis MC+AD loop at y5, 10 kHz, one sample of loop delay.
        let ts = TS_10KHZ;
        let plant = zoh(&thesis_plant(5).unwrap().state_space(), ts).unwrap();
        let obs = thesis_observer_block(5, ts, true, true, Some(1e3), 0).unwrap();
        let pid = thesis_pid(35.5, ts).unwrap();
        let d = 1;
        let cl = assemble_loop(&LoopSpec {
            plant: &plant,
            observer: Some(&obs.block),
            controller: &pid,
            loop_delay: d,
        })
        .unwrap();
        let ff = modified_feedforward(&obs.block, &pid, d).unwrap();
        for f_hz in [2.0, 30.0, 120.0, 470.0, 941.0, 2000.0] {
            let w = 2.0 * std::f64::consts::PI * f_hz;
            let z = C64::new(0.0, w * ts).exp();
            let h = freq_response_discrete(&ff, w).unwrap();
            let (h_u0, h_r) = (h[(0, 0)], h[(0, 1)]);
            // (A.7) from the observer and controller responses, with the
            // subtracted part delayed by the loop delay.
            let o = freq_response_discrete(&obs.block.system, w).unwrap();
            let (o_yy, o_yu, o_uy, o_uu) = (o[(0, 0)], o[(0, 1)], o[(1, 0)], o[(1, 1)]);
            let c = freq_response_discrete(&pid, w).unwrap()[(0, 0)];
            let zd = z.powi(-(d as i32));
            let want_u0 = C64::new(1.0, 0.0) - zd * (o_uu + c * o_yu);
            let want_r = -zd * (o_uy + c * o_yy);
            assert!(
                (h_u0 - want_u0).norm() <= 1e-9 * want_u0.norm(),
                "{f_hz} Hz"
            );
            assert!(
                (h_r - want_r).norm() <= 1e-9 * want_r.norm().max(1e-300),
                "{f_hz} Hz"
            );
            // Closed loop with u0 = P⁻¹ r (exact inverse at this frequency)
            // and the block run d ticks ahead: e_true vanishes; with the plain
            // feedforward u_ff = P⁻¹ r it does not.
            let g = freq_response_discrete(&cl, w).unwrap();
            let (t_r, t_ff) = (g[(2, 0)], g[(2, 2)]);
            let p = freq_response_discrete(&plant, w).unwrap()[(0, 0)];
            let lead = z.powi(d as i32);
            let plain = t_r + t_ff * lead / p;
            let modified = t_r + t_ff * lead * (h_u0 / p + h_r);
            eprintln!(
                "{f_hz:7.1} Hz: |e_true/r| plain {:.3e}, modified {:.3e}",
                plain.norm(),
                modified.norm()
            );
            assert!(modified.norm() < 1e-6 * plain.norm(), "{f_hz} Hz");
        }
    }

    /// Runs the thesis scan (Table 3.6 set-point, y5, 10 kHz, one sample of
    /// loop delay, PID f_bw 35.5) and returns e_true per tick (with r = 0
    /// unless `reference`, which gives −y for the fit). `u_ff(k, t)`
    /// gives the feedforward input of tick k; tick 0 is t = −Ts so that the
    /// feedforward for t = 0 is issued one tick before the motion starts.
    fn scan(
        obs: Option<&ObserverBlock>,
        reference: bool,
        mut u_ff: impl FnMut(usize, &dyn Fn(usize) -> f64) -> f64,
    ) -> Vec<f64> {
        let ts = TS_10KHZ;
        let plant = zoh(&thesis_plant(5).unwrap().state_space(), ts).unwrap();
        let pid = thesis_pid(35.5, ts).unwrap();
        let cl = assemble_loop(&LoopSpec {
            plant: &plant,
            observer: obs,
            controller: &pid,
            loop_delay: 1,
        })
        .unwrap();
        let sp = Setpoint::new(&SetpointParams::thesis()).unwrap();
        let steps = (sp.duration() / ts).round() as usize + 2;
        let time = |k: usize| (k as f64 - 1.0) * ts;
        let mut run = LtiRunner::new(cl);
        (0..steps)
            .map(|k| {
                let u = u_ff(k, &time);
                let r = if reference {
                    sp.evaluate(time(k)).r
                } else {
                    0.0
                };
                run.step(&[r, 0.0, u, 0.0])[2]
            })
            .collect()
    }

    fn scan_rms_nm(e: &[f64]) -> f64 {
        let sp = Setpoint::new(&SetpointParams::thesis()).unwrap();
        let (a, b) = sp.scan_window();
        let win: Vec<f64> = e
            .iter()
            .enumerate()
            .filter(|(k, _)| {
                let t = (*k as f64 - 1.0) * TS_10KHZ;
                t >= a - 1e-12 && t <= b + 1e-12
            })
            .map(|(_, v)| *v)
            .collect();
        (win.iter().map(|v| v * v).sum::<f64>() / win.len() as f64).sqrt() * 1e9
    }

    #[test]
    fn reduces_the_scan_error_of_observer_loops() {
        let sp = Setpoint::new(&SetpointParams::thesis()).unwrap();
        // u0: the 4-gain feedforward (A.1) fitted by least squares on the loop
        // WITHOUT observer (feedforward.rs procedure), advanced by one tick.
        let e0 = scan(None, true, |_, _| 0.0);
        let basis: Vec<Vec<f64>> = (0..4)
            .map(|i| {
                let y_only = scan(None, false, |k, t| {
                    FeedforwardGains::regressor(&sp.evaluate(t(k + 1)))[i]
                });
                // e_true = r − y; with r = 0 the response is −y.
                y_only.iter().map(|v| -v).collect()
            })
            .collect();
        let rows: Vec<[f64; 4]> = (0..e0.len())
            .map(|k| [basis[0][k], basis[1][k], basis[2][k], basis[3][k]])
            .collect();
        let g = crate::feedforward::fit_gains(&rows, &e0).unwrap();
        assert!((g.acc - CHAIN_MASS).abs() < 1e-3, "{g:?}");
        let baseline = scan_rms_nm(&scan(None, true, |k, t| g.apply(&sp.evaluate(t(k + 1)))));
        // docs/control.md §10.1, bold column: 8.46 nm without observer.
        assert!((baseline - 8.46).abs() < 0.05, "{baseline}");
        // Same gains in the observer loops. Measured: MC 71.8 → 10.97 nm,
        // MC+AD 67.4 → 2.51 nm; §10.1 gets 10.98 and 2.47 nm only by
        // re-fitting the gains in each loop, which the modified block makes
        // unnecessary.
        for (name, ad, q_nu, refitted) in [("MC", false, 0.03, 10.98), ("MC+AD", true, 1e3, 2.47)] {
            let obs = thesis_observer_block(5, TS_10KHZ, true, ad, Some(q_nu), 0).unwrap();
            let plain = scan_rms_nm(&scan(Some(&obs.block), true, |k, t| {
                g.apply(&sp.evaluate(t(k + 1)))
            }));
            let pid = thesis_pid(35.5, TS_10KHZ).unwrap();
            let mut ff = LtiRunner::new(modified_feedforward(&obs.block, &pid, 1).unwrap());
            let modified = scan_rms_nm(&scan(Some(&obs.block), true, |k, t| {
                let s = sp.evaluate(t(k + 1));
                ff.step(&[g.apply(&s), s.r])[0]
            }));
            eprintln!(
                "{name}: scan rms without observer {baseline:.3} nm, plain FF {plain:.3} nm, \
                 modified FF {modified:.3} nm"
            );
            assert!(modified < 0.2 * plain, "{name}: {modified} vs {plain}");
            assert!(
                (modified - refitted).abs() < 0.05 * refitted,
                "{name}: {modified}"
            );
        }
    }

    #[test]
    fn refuses_mismatched_blocks() {
        let obs = thesis_observer_block(5, TS_10KHZ, true, false, Some(0.03), 0).unwrap();
        let pid = thesis_pid(35.5, 2e-4).unwrap();
        assert!(matches!(
            modified_feedforward(&obs.block, &pid, 1),
            Err(DesignError::InvalidParameter(s)) if s.contains("sample period")
        ));
        let two = DiscreteStateSpace::gain(DMatrix::zeros(2, 1), TS_10KHZ).unwrap();
        assert!(matches!(
            modified_feedforward(&obs.block, &two, 1),
            Err(DesignError::Matrix(MatrixError::DimensionMismatch { .. }))
        ));
        let extra = thesis_observer_block(5, TS_10KHZ, false, true, None, 1).unwrap();
        let pid = thesis_pid(35.5, TS_10KHZ).unwrap();
        assert!(modified_feedforward(&extra.block, &pid, 2).is_err());
    }
}
