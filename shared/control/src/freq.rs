//! Frequency responses of continuous and discrete state spaces, and the
//! SISO loop analysis of control.md §5.4/§6: sensitivities S^I, S^O, the
//! r → e_true transfer, bandwidth as the first 0 dB crossing, peaks, and a
//! bandwidth optimiser under the 6 dB rule.

use crate::continuous::ContinuousStateSpace;
use crate::linalg::LinalgError;
use crate::lti::DiscreteStateSpace;
use nalgebra::{Complex, DMatrix};

type C64 = Complex<f64>;

fn response(
    a: &DMatrix<f64>,
    b: &DMatrix<f64>,
    c: &DMatrix<f64>,
    d: &DMatrix<f64>,
    point: C64,
) -> Result<DMatrix<C64>, LinalgError> {
    let n = a.nrows();
    let to_c = |m: &DMatrix<f64>| m.map(|v| C64::new(v, 0.0));
    let mut out = to_c(d);
    if n > 0 {
        let m = DMatrix::<C64>::identity(n, n) * point - to_c(a);
        let x = m
            .lu()
            .solve(&to_c(b))
            .ok_or(LinalgError::Singular("(sI - A) at a pole"))?;
        out += to_c(c) * x;
    }
    if out.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
        return Err(LinalgError::NonFinite);
    }
    Ok(out)
}

/// G(jω) = C (jωI − A)⁻¹ B + D.
pub fn freq_response_continuous(
    sys: &ContinuousStateSpace,
    w: f64,
) -> Result<DMatrix<C64>, LinalgError> {
    response(&sys.a, &sys.b, &sys.c, &sys.d, C64::new(0.0, w))
}

/// G(e^{jωTs}) = C (zI − A)⁻¹ B + D.
pub fn freq_response_discrete(
    sys: &DiscreteStateSpace,
    w: f64,
) -> Result<DMatrix<C64>, LinalgError> {
    let z = C64::new(0.0, w * sys.ts).exp();
    response(&sys.a, &sys.b, &sys.c, &sys.d, z)
}

/// Logarithmic frequency grid [rad/s] from f_lo to f_hi Hz.
pub fn log_grid_hz(f_lo: f64, f_hi: f64, points: usize) -> Vec<f64> {
    let (l0, l1) = (f_lo.log10(), f_hi.log10());
    let n = points.max(2);
    (0..n)
        .map(|i| {
            2.0 * std::f64::consts::PI * 10f64.powf(l0 + (l1 - l0) * i as f64 / (n - 1) as f64)
        })
        .collect()
}

/// Frequency-domain and stability summary of one SISO loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopMetrics {
    /// First 0 dB crossing of the open loop P_eq C_fb [Hz] (NaN if none).
    pub crossover_hz: f64,
    /// max |S^I| [dB] (r → e_meas).
    pub peak_si_db: f64,
    /// max |S^O| [dB] (output disturbance → measured output).
    pub peak_so_db: f64,
    /// max |T_{r→e_true}| [dB].
    pub peak_re_db: f64,
    /// Closed-loop eigenvalues all stable.
    pub stable: bool,
}

/// The four SISO observer transfers at one frequency (control.md §5):
/// ŷ_flex = O_yy y + O_yu u, u_d = O_uy y + O_uu u.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObserverResponse {
    pub yy: C64,
    pub yu: C64,
    pub uy: C64,
    pub uu: C64,
}

/// S^I, S^O, T_{r→e_true} and the open loop L = P_eq C at one frequency,
/// from the SISO formulas of control.md §5.4. `p` is the plant from the
/// controller output to y (including any loop delay), `o` the observer with
/// its u input referred to the same controller output.
pub fn siso_sensitivities(p: C64, c: C64, o: Option<ObserverResponse>) -> (C64, C64, C64, C64) {
    let one = C64::new(1.0, 0.0);
    let o = o.unwrap_or(ObserverResponse {
        yy: C64::new(0.0, 0.0),
        yu: C64::new(0.0, 0.0),
        uy: C64::new(0.0, 0.0),
        uu: C64::new(0.0, 0.0),
    });
    let p_eq = ((one - o.yy) * p - o.yu) / (one - o.uu - o.uy * p);
    let l = p_eq * c;
    let s_i = one / (one + l);
    let den = one - c * o.yu - o.uu;
    let c_eq = (c * (one - o.yy) - o.uy) / den;
    let s_o = one / (one + p * c_eq);
    let t_re = one - p * c / (den * (one + p * c_eq));
    (s_i, s_o, t_re, l)
}

fn db(v: C64) -> f64 {
    20.0 * v.norm().log10()
}

/// First frequency [Hz] where |L| falls through 1 (log interpolation).
fn first_crossing(grid: &[f64], l_abs: &[f64]) -> f64 {
    for i in 1..grid.len() {
        if l_abs[i - 1] >= 1.0 && l_abs[i] < 1.0 {
            let (a, b) = (l_abs[i - 1].ln(), l_abs[i].ln());
            let frac = a / (a - b);
            let w = (grid[i - 1].ln() + frac * (grid[i].ln() - grid[i - 1].ln())).exp();
            return w / (2.0 * std::f64::consts::PI);
        }
    }
    f64::NAN
}

/// Metrics of a continuous SISO loop P(s), C(s) without observer.
pub fn continuous_loop_metrics(
    plant: &ContinuousStateSpace,
    controller: &ContinuousStateSpace,
    grid: &[f64],
) -> Result<LoopMetrics, crate::design_error::DesignError> {
    let mut l_abs = Vec::with_capacity(grid.len());
    let (mut si, mut so, mut re) = (f64::MIN, f64::MIN, f64::MIN);
    for &w in grid {
        let p = freq_response_continuous(plant, w)?[(0, 0)];
        let c = freq_response_continuous(controller, w)?[(0, 0)];
        let (s_i, s_o, t_re, l) = siso_sensitivities(p, c, None);
        l_abs.push(l.norm());
        si = si.max(db(s_i));
        so = so.max(db(s_o));
        re = re.max(db(t_re));
    }
    // Closed loop (plant D = 0): [[Ap − Bp Dc Cp, Bp Cc], [−Bc Cp, Ac]].
    let (np, nc) = (plant.states(), controller.states());
    let mut a = DMatrix::zeros(np + nc, np + nc);
    a.view_mut((0, 0), (np, np))
        .copy_from(&(&plant.a - &plant.b * &controller.d * &plant.c));
    a.view_mut((0, np), (np, nc))
        .copy_from(&(&plant.b * &controller.c));
    a.view_mut((np, 0), (nc, np))
        .copy_from(&(-(&controller.b * &plant.c)));
    a.view_mut((np, np), (nc, nc)).copy_from(&controller.a);
    let ev = crate::linalg::eigenvalues(&a)?;
    Ok(LoopMetrics {
        crossover_hz: first_crossing(grid, &l_abs),
        peak_si_db: si,
        peak_so_db: so,
        peak_re_db: re,
        stable: ev.iter().all(|s| s.re < 0.0),
    })
}

/// A discrete bandwidth problem: the thesis PID (Table 3.3 tuning on
/// `mass`) on several plant outputs, each with its own optional observer
/// block, a loop delay, and the 6 dB rule. The plant and observer responses
/// do not depend on f_bw and are computed once.
pub struct DiscreteBandwidthProblem {
    pub plants: Vec<DiscreteStateSpace>,
    pub observers: Vec<Option<crate::observer_block::ObserverBlock>>,
    pub loop_delay: usize,
    pub mass: f64,
    /// Peak limit [dB] (thesis: 6).
    pub limit_db: f64,
    /// Also bound |T_{r→e_true}| (the MC constraint).
    pub bound_re: bool,
    grid: Vec<f64>,
    cache: Vec<Vec<(C64, Option<ObserverResponse>)>>,
}

impl DiscreteBandwidthProblem {
    /// Prepares the responses on a log grid from 0.5 Hz to Nyquist, refined
    /// around every plant resonance (their peaks are only ~1 % wide).
    pub fn new(
        plants: Vec<DiscreteStateSpace>,
        observers: Vec<Option<crate::observer_block::ObserverBlock>>,
        loop_delay: usize,
        mass: f64,
        limit_db: f64,
        bound_re: bool,
    ) -> Result<Self, crate::design_error::DesignError> {
        use crate::design_error::DesignError;
        if plants.is_empty() || observers.len() != plants.len() {
            return Err(DesignError::InvalidParameter(
                "need one observer entry (or None) per plant".into(),
            ));
        }
        let ts = plants[0].ts;
        let f_nyq = 0.5 / ts;
        let mut grid = log_grid_hz(0.5, 0.999 * f_nyq, 800);
        for p in &plants {
            for z in crate::linalg::eigenvalues(&p.a)? {
                if z.im > 0.0 {
                    let (w, zeta) = crate::linalg::discrete_pole_to_continuous(z, ts);
                    for k in -6..=6 {
                        let wk = w * (1.0 + 0.5 * k as f64 * zeta.max(1e-4));
                        if wk > 0.0 && wk < 2.0 * std::f64::consts::PI * f_nyq {
                            grid.push(wk);
                        }
                    }
                }
            }
        }
        grid.sort_by(|a, b| a.total_cmp(b));
        let mut cache = Vec::with_capacity(plants.len());
        for (p, o) in plants.iter().zip(&observers) {
            let mut row = Vec::with_capacity(grid.len());
            for &w in &grid {
                let z_d = C64::new(0.0, -w * ts * loop_delay as f64).exp();
                let pv = freq_response_discrete(p, w)?[(0, 0)] * z_d;
                let ov = match o {
                    Some(b) => {
                        let h = freq_response_discrete(&b.system, w)?;
                        Some(ObserverResponse {
                            yy: h[(0, 0)],
                            yu: h[(0, 1)] * z_d,
                            uy: h[(1, 0)],
                            uu: h[(1, 1)] * z_d,
                        })
                    }
                    None => None,
                };
                row.push((pv, ov));
            }
            cache.push(row);
        }
        Ok(Self {
            plants,
            observers,
            loop_delay,
            mass,
            limit_db,
            bound_re,
            grid,
            cache,
        })
    }

    /// Metrics of every output at one f_bw.
    pub fn evaluate(
        &self,
        f_bw: f64,
    ) -> Result<Vec<LoopMetrics>, crate::design_error::DesignError> {
        let ts = self.plants[0].ts;
        let pid = crate::pid::PidTuning::single_parameter(self.mass, f_bw)?.discrete(ts)?;
        let cvals: Vec<C64> = self
            .grid
            .iter()
            .map(|&w| freq_response_discrete(&pid, w).map(|h| h[(0, 0)]))
            .collect::<Result<_, _>>()?;
        let mut out = Vec::with_capacity(self.plants.len());
        for (i, plant) in self.plants.iter().enumerate() {
            let (mut si, mut so, mut re) = (f64::MIN, f64::MIN, f64::MIN);
            let mut l_abs = Vec::with_capacity(self.grid.len());
            for (k, &(p, o)) in self.cache[i].iter().enumerate() {
                let (s_i, s_o, t_re, l) = siso_sensitivities(p, cvals[k], o);
                l_abs.push(l.norm());
                si = si.max(db(s_i));
                so = so.max(db(s_o));
                re = re.max(db(t_re));
            }
            let cl = crate::closed_loop::assemble_loop(&crate::closed_loop::LoopSpec {
                plant,
                observer: self.observers[i].as_ref(),
                controller: &pid,
                loop_delay: self.loop_delay,
            })?;
            let stable = crate::linalg::spectral_radius(&cl.a)? < 1.0;
            out.push(LoopMetrics {
                crossover_hz: first_crossing(&self.grid, &l_abs),
                peak_si_db: si,
                peak_so_db: so,
                peak_re_db: re,
                stable,
            });
        }
        Ok(out)
    }

    /// Whether every output meets the constraints at f_bw.
    pub fn feasible(&self, f_bw: f64) -> Result<bool, crate::design_error::DesignError> {
        Ok(self.evaluate(f_bw)?.iter().all(|m| {
            m.stable
                && m.peak_si_db <= self.limit_db
                && m.peak_so_db <= self.limit_db
                && (!self.bound_re || m.peak_re_db <= self.limit_db)
        }))
    }

    /// Largest f_bw on the grid f_start, f_start + step, … ≤ f_stop such that
    /// it and every smaller grid value are feasible; None if f_start fails.
    pub fn max_bandwidth(
        &self,
        f_start: f64,
        f_stop: f64,
        step: f64,
    ) -> Result<Option<f64>, crate::design_error::DesignError> {
        if !(step > 0.0 && f_start > 0.0 && f_stop >= f_start) {
            return Err(crate::design_error::DesignError::InvalidParameter(
                "bandwidth scan range".into(),
            ));
        }
        let n = ((f_stop - f_start) / step).floor() as usize;
        let mut best = None;
        for k in 0..=n {
            let f = f_start + k as f64 * step;
            if self.feasible(f)? {
                best = Some(f);
            } else {
                break;
            }
        }
        Ok(best)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::discretise::zoh;
    use crate::models::{CHAIN_MASS, TS_10KHZ, thesis_plant};
    use crate::pid::PidTuning;

    #[test]
    fn continuous_baseline_crossover_and_peak() {
        let grid = log_grid_hz(1.0, 5000.0, 3000);
        let pid = PidTuning::single_parameter(CHAIN_MASS, 35.5)
            .unwrap()
            .continuous()
            .unwrap();
        let mut worst = f64::MIN;
        for out in 1..=7 {
            let p = thesis_plant(out).unwrap().state_space();
            let m = continuous_loop_metrics(&p, &pid, &grid).unwrap();
            assert!(m.stable, "y{out}");
            if out == 5 {
                // Flexible modes shift the y5 crossover slightly above 37.3.
                assert!((m.crossover_hz - 37.3).abs() < 0.3, "{m:?}");
            }
            worst = worst.max(m.peak_si_db);
        }
        // The 6 dB rule is met at 35.5 (nominal rigid peak 5.4 dB).
        assert!(worst <= 6.0 && worst > 5.3, "{worst}");
        // Rigid-body plant alone: peak 5.4 dB.
        let rigid = thesis_plant(5)
            .unwrap()
            .select_modes(&[0])
            .unwrap()
            .state_space();
        let m = continuous_loop_metrics(&rigid, &pid, &grid).unwrap();
        assert!((m.peak_si_db - 5.4).abs() < 0.06, "{m:?}");
        // Crossover = 1.0498 f_bw = 37.27 Hz on the rigid plant.
        assert!((m.crossover_hz - 1.0498 * 35.5).abs() < 0.02, "{m:?}");
    }

    #[test]
    fn discrete_baseline_bandwidth_versus_loop_delay() {
        let plants: Vec<_> = (1..=7)
            .map(|i| zoh(&thesis_plant(i).unwrap().state_space(), TS_10KHZ).unwrap())
            .collect();
        // §10: 1 sample → 35.5 (crossover ≈ 37 Hz); 2 samples → 24.5.
        let one =
            DiscreteBandwidthProblem::new(plants.clone(), vec![None; 7], 1, CHAIN_MASS, 6.0, false)
                .unwrap();
        assert_eq!(one.max_bandwidth(34.0, 40.0, 0.5).unwrap(), Some(35.5));
        let cross = one.evaluate(35.5).unwrap()[4].crossover_hz;
        assert!((cross - 37.3).abs() < 0.5, "{cross}");
        let two = DiscreteBandwidthProblem::new(plants, vec![None; 7], 2, CHAIN_MASS, 6.0, false)
            .unwrap();
        assert_eq!(two.max_bandwidth(23.0, 30.0, 0.5).unwrap(), Some(24.5));
    }
}
