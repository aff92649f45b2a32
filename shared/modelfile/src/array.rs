//! One named array as read: its shape and its entries in row-major order,
//! whatever the file's layout, and the conversions of stored numbers to `f64`.

use crate::error::ModelFileErrorKind;
use crate::limits::{MAX_DIMENSION, MAX_ENTRIES};

/// An array of numbers as the file holds it: `shape` as written (`[]` for a
/// single number, `[n]` for a 1-D array, `[rows, columns]` for a matrix) and
/// the entries in row-major (C) order. Entries may be NaN or infinite here:
/// [`ModelArrays::matrix`](crate::ModelArrays::matrix) refuses them, naming the entry.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    shape: Vec<usize>,
    data: Vec<f64>,
}

impl Array {
    /// `None` when the shape does not hold `data.len()` entries.
    pub fn new(shape: Vec<usize>, data: Vec<f64>) -> Option<Self> {
        let count = shape
            .iter()
            .try_fold(1usize, |count, &n| count.checked_mul(n))?;
        (count == data.len()).then_some(Self { shape, data })
    }

    /// An array whose entries are stored in column-major (Fortran, MATLAB) order.
    pub(crate) fn from_column_major(shape: Vec<usize>, data: Vec<f64>) -> Option<Self> {
        let row_major = column_major_to_row_major(&shape, &data)?;
        Self::new(shape, row_major)
    }

    /// A matrix as a 2-D array (`[rows, columns]`, entries row by row), as
    /// [`ModelArrays::matrix`](crate::ModelArrays::matrix) gives it back.
    pub fn from_matrix(matrix: &nalgebra::DMatrix<f64>) -> Self {
        Self {
            shape: vec![matrix.nrows(), matrix.ncols()],
            data: matrix.transpose().as_slice().to_vec(),
        }
    }

    /// A single number (a 0-D array, as `np.savez` writes a Python float).
    pub fn scalar(value: f64) -> Self {
        Self {
            shape: Vec::new(),
            data: vec![value],
        }
    }

    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// The entries in row-major order.
    pub fn data(&self) -> &[f64] {
        &self.data
    }
}

/// How a 1-D array is taken as a matrix: the caller knows (B is a column, C a row).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VectorAs {
    /// n entries make an n×1 matrix.
    Column,
    /// n entries make a 1×n matrix.
    Row,
}

/// `data` (column-major, the first index fastest) reordered so that the last
/// index runs fastest; `None` when the shape does not hold `data.len()` entries.
fn column_major_to_row_major(shape: &[usize], data: &[f64]) -> Option<Vec<f64>> {
    let count = shape
        .iter()
        .try_fold(1usize, |count, &n| count.checked_mul(n))?;
    if count != data.len() {
        return None;
    }
    // The column-major stride of each axis; walking the row-major order with
    // an odometer over the indices keeps this linear in the entries.
    let mut strides = Vec::with_capacity(shape.len());
    let mut stride = 1usize;
    for &n in shape {
        strides.push(stride);
        stride *= n;
    }
    let mut index = vec![0usize; shape.len()];
    let mut out = Vec::with_capacity(count);
    for _ in 0..count {
        let offset: usize = index.iter().zip(&strides).map(|(i, s)| i * s).sum();
        out.push(data[offset]);
        for axis in (0..shape.len()).rev() {
            index[axis] += 1;
            if index[axis] < shape[axis] {
                break;
            }
            index[axis] = 0;
        }
    }
    Some(out)
}

/// The largest magnitude below which every integer is an `f64` exactly (2^53).
const EXACT_INTEGER_LIMIT: u64 = 1 << 53;

/// Signed integers as `f64`, refusing one that would be rounded.
pub(crate) fn signed_to_f64(values: &[i64]) -> Result<Vec<f64>, ModelFileErrorKind> {
    values
        .iter()
        .map(|&v| {
            if v.unsigned_abs() <= EXACT_INTEGER_LIMIT {
                Ok(v as f64)
            } else {
                Err(ModelFileErrorKind::InexactInteger {
                    value: v.to_string(),
                })
            }
        })
        .collect()
}

/// Unsigned integers as `f64`, refusing one that would be rounded.
pub(crate) fn unsigned_to_f64(values: &[u64]) -> Result<Vec<f64>, ModelFileErrorKind> {
    values
        .iter()
        .map(|&v| {
            if v <= EXACT_INTEGER_LIMIT {
                Ok(v as f64)
            } else {
                Err(ModelFileErrorKind::InexactInteger {
                    value: v.to_string(),
                })
            }
        })
        .collect()
}

/// Whether an array of `shape` (as declared, before anything is read) is
/// within what flexloop takes: every dimension at most [`MAX_DIMENSION`](crate::limits::MAX_DIMENSION) and
/// at most [`MAX_ENTRIES`](crate::limits::MAX_ENTRIES) entries.
pub(crate) fn check_shape(shape: &[u64]) -> Result<(), ModelFileErrorKind> {
    let entries = shape
        .iter()
        .try_fold(1u64, |count, &n| count.checked_mul(n))
        .unwrap_or(u64::MAX);
    if shape.iter().any(|&n| n > MAX_DIMENSION) || entries > MAX_ENTRIES {
        return Err(ModelFileErrorKind::ArrayTooLarge {
            shape: shape.to_vec(),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn column_major_entries_are_put_in_row_major_order() {
        // [[1, 2, 3], [4, 5, 6]] stored column by column.
        let a = Array::from_column_major(vec![2, 3], vec![1.0, 4.0, 2.0, 5.0, 3.0, 6.0]).unwrap();
        assert_eq!(a.data(), &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        // Three dimensions: entry (i, j, k) at i + 2 j + 4 k in column-major order.
        let column_major: Vec<f64> = (0..8).map(f64::from).collect();
        let a = Array::from_column_major(vec![2, 2, 2], column_major).unwrap();
        let expected: Vec<f64> = [0, 4, 2, 6, 1, 5, 3, 7]
            .into_iter()
            .map(f64::from)
            .collect();
        assert_eq!(a.data(), expected.as_slice());
        // Scalars, vectors and empty arrays are unchanged.
        let a = Array::from_column_major(vec![], vec![7.0]).unwrap();
        assert_eq!(a.data(), &[7.0]);
        let a = Array::from_column_major(vec![0, 3], vec![]).unwrap();
        assert_eq!(a.data(), &[] as &[f64]);
    }

    #[test]
    fn a_shape_that_does_not_hold_the_entries_is_refused() {
        assert!(Array::new(vec![2, 2], vec![1.0; 3]).is_none());
        assert!(Array::new(vec![usize::MAX, 3], vec![]).is_none());
        assert!(Array::from_column_major(vec![3], vec![1.0; 2]).is_none());
    }

    #[test]
    fn integers_convert_exactly_or_not_at_all() {
        assert_eq!(
            signed_to_f64(&[-3, 1 << 53]).unwrap(),
            vec![-3.0, 9007199254740992.0]
        );
        assert_eq!(
            signed_to_f64(&[(1 << 53) + 1]),
            Err(ModelFileErrorKind::InexactInteger {
                value: "9007199254740993".into()
            })
        );
        assert!(unsigned_to_f64(&[u64::MAX]).is_err());
        assert_eq!(unsigned_to_f64(&[7]).unwrap(), vec![7.0]);
    }

    #[test]
    fn shapes_up_to_the_loop_s_size_pass() {
        for shape in [
            &[][..],
            &[128],
            &[128, 128],
            &[128, 8],
            &[2, 2, 2],
            &[0, 1 << 40],
        ] {
            // An empty array has no entries, but a dimension beyond the
            // bound is still refused: nothing flexloop takes has one.
            let ok = shape.iter().all(|&n| n <= MAX_DIMENSION);
            assert_eq!(check_shape(shape).is_ok(), ok, "{shape:?}");
        }
        for shape in [
            &[129][..],
            &[129, 129],
            &[64, 64, 64],
            &[u64::MAX, u64::MAX],
        ] {
            assert_eq!(
                check_shape(shape),
                Err(ModelFileErrorKind::ArrayTooLarge {
                    shape: shape.to_vec()
                })
            );
        }
    }
}
