//! What a replacement instance needs to continue where another one left off:
//! a fingerprint of the design (state is copied only between identical
//! designs) and, for a different design, the state shift that makes its
//! output continue the old one (bumpless transfer).

use flexloop_control::lti::DiscreteStateSpace;
use nalgebra::DMatrix;

/// FNV-1a over the bit patterns of every matrix entry and the shapes: the
/// same design in two processes gives the same value.
#[derive(Debug, Clone, Copy)]
pub struct Fingerprint(u64);

impl Default for Fingerprint {
    fn default() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
}

impl Fingerprint {
    pub fn bytes(mut self, bytes: &[u8]) -> Self {
        for b in bytes {
            self.0 ^= u64::from(*b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
        self
    }

    pub fn number(self, v: f64) -> Self {
        self.bytes(&v.to_bits().to_le_bytes())
    }

    pub fn matrix(self, m: &DMatrix<f64>) -> Self {
        let shaped = self
            .bytes(&(m.nrows() as u64).to_le_bytes())
            .bytes(&(m.ncols() as u64).to_le_bytes());
        m.iter().fold(shaped, |f, v| f.number(*v))
    }

    pub fn system(self, sys: &DiscreteStateSpace) -> Self {
        self.matrix(&sys.a)
            .matrix(&sys.b)
            .matrix(&sys.c)
            .matrix(&sys.d)
            .number(sys.ts)
    }

    pub fn value(self) -> u64 {
        self.0
    }
}

/// The state shift δx = S Δu that moves the output of `sys` by Δu and that
/// the free dynamics keep: δx in the eigenspace of eigenvalue 1 (the
/// integrator of a PID). A filter without an integrator gets the
/// least-norm shift, which its dynamics then let decay.
pub fn bumpless_shift(sys: &DiscreteStateSpace) -> DMatrix<f64> {
    let n = sys.states();
    let p = sys.outputs();
    if n == 0 {
        return DMatrix::zeros(0, p);
    }
    let least_norm = || {
        sys.c
            .clone()
            .pseudo_inverse(1e-12)
            .unwrap_or_else(|_| DMatrix::zeros(n, p))
    };
    let shifted = &sys.a - DMatrix::identity(n, n);
    let svd = shifted.svd(false, true);
    let Some(v_t) = svd.v_t else {
        return least_norm();
    };
    let scale = sys.a.norm().max(1.0);
    let kept: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&i| svd.singular_values[i] < 1e-9 * scale)
        .collect();
    if kept.is_empty() {
        return least_norm();
    }
    let mut basis = DMatrix::zeros(n, kept.len());
    for (col, &i) in kept.iter().enumerate() {
        basis.set_column(col, &v_t.row(i).transpose());
    }
    let seen = &sys.c * &basis;
    if seen.norm() < 1e-12 {
        return least_norm();
    }
    match seen.pseudo_inverse(1e-12) {
        Ok(inverse) => basis * inverse,
        Err(_) => least_norm(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_control::lti::LtiRunner;

    #[test]
    fn integrator_shift_moves_the_output_for_good() {
        // x(k+1) = x(k) + e(k), u = 0.5 x + 2 e: a PI controller.
        let pi = DiscreteStateSpace::new(
            DMatrix::from_element(1, 1, 1.0),
            DMatrix::from_element(1, 1, 1.0),
            DMatrix::from_element(1, 1, 0.5),
            DMatrix::from_element(1, 1, 2.0),
            1e-4,
        )
        .unwrap();
        let shift = bumpless_shift(&pi);
        let mut runner = LtiRunner::new(pi);
        runner.step(&[0.3]);
        let before = runner.output(&[0.0])[0];
        let delta = 1.25;
        let x = runner.state()[0] + shift[(0, 0)] * delta;
        runner.set_state(&[x]);
        assert!((runner.output(&[0.0])[0] - before - delta).abs() < 1e-12);
        runner.step(&[0.0]);
        assert!((runner.output(&[0.0])[0] - before - delta).abs() < 1e-12);
    }

    #[test]
    fn fingerprints_tell_designs_apart() {
        let a = DMatrix::from_element(2, 2, 0.5);
        let mut b = a.clone();
        b[(1, 1)] = 0.5000000001;
        let f = |m: &DMatrix<f64>| Fingerprint::default().matrix(m).value();
        assert_eq!(f(&a), f(&a.clone()));
        assert_ne!(f(&a), f(&b));
    }
}
