//! Continuous-time LTI state spaces (design-time only) and their
//! interconnections: series, sum, and transfer-function realisation.
//!
//! The loop runs only discrete systems; continuous ones exist to be designed
//! (plants, PID, filters) and then discretised by [`crate::discretise`].

use crate::linalg::block_diag;
use crate::lti::StateSpaceError;
use crate::matrix_error::MatrixError;
use nalgebra::DMatrix;

/// ẋ = A x + B u, y = C x + D u.
#[derive(Debug, Clone, PartialEq)]
pub struct ContinuousStateSpace {
    pub a: DMatrix<f64>,
    pub b: DMatrix<f64>,
    pub c: DMatrix<f64>,
    pub d: DMatrix<f64>,
}

impl ContinuousStateSpace {
    /// Checks shapes and finiteness (same rules as the discrete type).
    pub fn new(
        a: DMatrix<f64>,
        b: DMatrix<f64>,
        c: DMatrix<f64>,
        d: DMatrix<f64>,
    ) -> Result<Self, StateSpaceError> {
        // Reuse the discrete checker with a dummy period: the rules are identical.
        let s = crate::lti::DiscreteStateSpace::new(a, b, c, d, 1.0)?;
        Ok(Self {
            a: s.a,
            b: s.b,
            c: s.c,
            d: s.d,
        })
    }

    /// A static gain y = D u.
    pub fn gain(d: DMatrix<f64>) -> Self {
        let (p, m) = d.shape();
        Self {
            a: DMatrix::zeros(0, 0),
            b: DMatrix::zeros(0, m),
            c: DMatrix::zeros(p, 0),
            d,
        }
    }

    pub fn states(&self) -> usize {
        self.a.nrows()
    }
    pub fn inputs(&self) -> usize {
        self.b.ncols()
    }
    pub fn outputs(&self) -> usize {
        self.c.nrows()
    }

    /// `second` after `self`: y = second(self(u)).
    pub fn series(&self, second: &Self) -> Result<Self, StateSpaceError> {
        if second.inputs() != self.outputs() {
            return Err(StateSpaceError::Matrix(MatrixError::DimensionMismatch {
                what: "series input",
                expected: (self.outputs(), 1),
                found: (second.inputs(), 1),
            }));
        }
        let (n1, n2) = (self.states(), second.states());
        let mut a = block_diag(&[&self.a, &second.a]);
        a.view_mut((n1, 0), (n2, n1))
            .copy_from(&(&second.b * &self.c));
        let mut b = DMatrix::zeros(n1 + n2, self.inputs());
        b.view_mut((0, 0), (n1, self.inputs())).copy_from(&self.b);
        b.view_mut((n1, 0), (n2, self.inputs()))
            .copy_from(&(&second.b * &self.d));
        let mut c = DMatrix::zeros(second.outputs(), n1 + n2);
        c.view_mut((0, 0), (second.outputs(), n1))
            .copy_from(&(&second.d * &self.c));
        c.view_mut((0, n1), (second.outputs(), n2))
            .copy_from(&second.c);
        let d = &second.d * &self.d;
        Self::new(a, b, c, d)
    }

    /// Proper SISO transfer function num(s)/den(s) (coefficients highest power
    /// first) in observable canonical form.
    pub fn from_transfer_function(num: &[f64], den: &[f64]) -> Result<Self, StateSpaceError> {
        let (a, b, c, d) = tf_to_ss(num, den)?;
        Self::new(a, b, c, d)
    }
}

/// Observable canonical realisation of a proper SISO transfer function;
/// shared by the continuous and discrete constructors.
type Abcd = (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>, DMatrix<f64>);

pub(crate) fn tf_to_ss(num: &[f64], den: &[f64]) -> Result<Abcd, StateSpaceError> {
    let bad = |what| {
        StateSpaceError::Matrix(MatrixError::DimensionMismatch {
            what,
            expected: (den.len().max(1), 1),
            found: (num.len(), 1),
        })
    };
    // Strip leading zeros so that the degree is the true degree.
    let den: Vec<f64> = den.iter().copied().skip_while(|v| *v == 0.0).collect();
    let num: Vec<f64> = num.iter().copied().skip_while(|v| *v == 0.0).collect();
    if den.is_empty() {
        return Err(bad("transfer function denominator"));
    }
    if num.len() > den.len() {
        return Err(bad("transfer function numerator (improper)"));
    }
    if num.iter().chain(den.iter()).any(|v| !v.is_finite()) {
        return Err(StateSpaceError::Matrix(MatrixError::NonFinite(
            "transfer function",
        )));
    }
    let n = den.len() - 1;
    let a0 = den[0];
    let den: Vec<f64> = den.iter().map(|v| v / a0).collect();
    let mut nump = vec![0.0; n + 1];
    for (i, v) in num.iter().enumerate() {
        nump[n + 1 - num.len() + i] = v / a0;
    }
    let d0 = nump[0];
    let mut a = DMatrix::zeros(n, n);
    let mut b = DMatrix::zeros(n, 1);
    let mut c = DMatrix::zeros(1, n);
    for i in 0..n {
        a[(i, 0)] = -den[i + 1];
        if i + 1 < n {
            a[(i, i + 1)] = 1.0;
        }
        b[(i, 0)] = nump[i + 1] - d0 * den[i + 1];
    }
    if n > 0 {
        c[(0, 0)] = 1.0;
    }
    let d = DMatrix::from_element(1, 1, d0);
    Ok((a, b, c, d))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Complex;

    fn eval(sys: &ContinuousStateSpace, s: Complex<f64>) -> Complex<f64> {
        let n = sys.states();
        let a = sys.a.map(|v| Complex::new(v, 0.0));
        let m = DMatrix::<Complex<f64>>::identity(n, n) * s - a;
        let b = sys.b.map(|v| Complex::new(v, 0.0));
        let x = m.lu().solve(&b).unwrap();
        let c = sys.c.map(|v| Complex::new(v, 0.0));
        (c * x)[(0, 0)] + sys.d[(0, 0)]
    }

    #[test]
    fn transfer_function_and_series() {
        // (2s + 3)/(s^2 + 4s + 5) at s = j.
        let g =
            ContinuousStateSpace::from_transfer_function(&[2.0, 3.0], &[1.0, 4.0, 5.0]).unwrap();
        let s = Complex::new(0.0, 1.0);
        let want = (s * 2.0 + 3.0) / (s * s + s * 4.0 + 5.0);
        assert!((eval(&g, s) - want).norm() < 1e-12);
        let h = ContinuousStateSpace::from_transfer_function(&[1.0, 1.0], &[1.0, 10.0]).unwrap();
        let gh = g.series(&h).unwrap();
        let want2 = want * (s + 1.0) / (s + 10.0);
        assert!((eval(&gh, s) - want2).norm() < 1e-12);
        assert!(
            ContinuousStateSpace::from_transfer_function(&[1.0, 0.0, 0.0], &[1.0, 1.0]).is_err()
        );
    }
}
