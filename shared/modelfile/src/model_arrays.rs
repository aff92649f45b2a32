//! The named arrays of one model, from a file or the scenario, and how the
//! caller takes each: as a matrix, a vector of known orientation, or a number.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::DMatrix;

use crate::array::{Array, VectorAs};
use crate::error::{ArraySource, FileFormat, ModelFileError, ModelFileErrorKind};
use crate::read::{Entry, NamedArrays};
use crate::{inline, mat, npz};

/// The named numeric arrays of a model file or of a scenario's inline table.
///
/// Numbers of any stored type are read as `f64`: floats of 32 or 64 bits;
/// integers of 8 to 64 bits, signed or not (one beyond 2^53 in magnitude,
/// which an `f64` cannot hold exactly, is refused); booleans as 0 and 1.
/// An entry that is not an array of real numbers (complex, sparse, text,
/// a cell array, a struct, an object, NumPy float16, ...) is refused, naming
/// it, when it is asked for or listed by [`ModelArrays::unused`].
#[derive(Debug, Clone)]
pub struct ModelArrays {
    source: ArraySource,
    arrays: BTreeMap<String, Entry>,
}

impl ModelArrays {
    /// Reads a model file by its extension: `.npz` (NumPy `np.savez` or
    /// `np.savez_compressed`) or `.mat` (MATLAB level 5: `save`'s default
    /// `-v7`, `-v6`, scipy.io.savemat). A v7.3 or level-4 MAT-file, another
    /// extension, a missing, truncated or damaged file: an error naming it.
    pub fn read(path: &Path) -> Result<Self, ModelFileError> {
        let source = ArraySource::File(path.to_path_buf());
        let extension = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        let format = match extension.as_deref() {
            Some("npz") => FileFormat::Npz,
            Some("mat") => FileFormat::Mat,
            _ => {
                let kind = ModelFileErrorKind::UnknownFormat { extension };
                return Err(ModelFileError::new(&source, None, kind));
            }
        };
        let bytes = std::fs::read(path).map_err(|e| {
            let kind = ModelFileErrorKind::Io {
                reason: e.to_string(),
            };
            ModelFileError::new(&source, None, kind)
        })?;
        Self::from_bytes(source, format, &bytes)
    }

    /// Reads the bytes of a model file of `format`; `source` names it in errors.
    pub fn from_bytes(
        source: ArraySource,
        format: FileFormat,
        bytes: &[u8],
    ) -> Result<Self, ModelFileError> {
        let read = match format {
            FileFormat::Npz => npz::read(bytes),
            FileFormat::Mat => mat::read(bytes),
        };
        Self::from_read(source, read)
    }

    /// The arrays of the scenario's table `table` (e.g. `plant.arrays`): each
    /// name a number, an array of numbers (1-D), or an array of rows of
    /// numbers of equal length (2-D, row by row). Integers are read as `f64`.
    pub fn from_toml(
        scenario: &Path,
        table: &str,
        value: &toml::Table,
    ) -> Result<Self, ModelFileError> {
        let source = ArraySource::Inline {
            scenario: scenario.to_path_buf(),
            table: table.to_string(),
        };
        Self::from_read(source, inline::read(value))
    }

    fn from_read(
        source: ArraySource,
        read: Result<NamedArrays, crate::read::Fault>,
    ) -> Result<Self, ModelFileError> {
        match read {
            Ok(arrays) => Ok(Self {
                source,
                arrays: arrays.into_map(),
            }),
            Err(fault) => Err(fault.at(&source)),
        }
    }

    /// Where the arrays came from.
    pub fn source(&self) -> &ArraySource {
        &self.source
    }

    /// The names present, in sorted order, arrays and refused entries alike.
    pub fn names(&self) -> Vec<&str> {
        self.arrays.keys().map(String::as_str).collect()
    }

    /// The array `name` as read; an error if it is missing or not an array
    /// of real numbers.
    pub fn array(&self, name: &str) -> Result<&Array, ModelFileError> {
        match self.arrays.get(name) {
            Some(Ok(array)) => Ok(array),
            Some(Err(kind)) => Err(self.error(name, kind.clone())),
            None => Err(self.error(
                name,
                ModelFileErrorKind::Missing {
                    present: self.arrays.keys().cloned().collect(),
                },
            )),
        }
    }

    /// The array `name` as a matrix: a 2-D array as it is; a 1-D array of n
    /// as an n×1 column or a 1×n row, per `vector` (the caller knows: B is a
    /// column, C a row); a single number (0-D) as 1×1. Which dimensions fit
    /// is the caller's to check. An error names the source and the array:
    /// missing (listing the names present), more than two dimensions, a NaN
    /// or infinite entry (which one), or not real numbers.
    pub fn matrix(&self, name: &str, vector: VectorAs) -> Result<DMatrix<f64>, ModelFileError> {
        let array = self.array(name)?;
        let (rows, columns) = match *array.shape() {
            [] => (1, 1),
            [n] => match vector {
                VectorAs::Column => (n, 1),
                VectorAs::Row => (1, n),
            },
            [rows, columns] => (rows, columns),
            _ => {
                let shape = array.shape().to_vec();
                return Err(self.error(name, ModelFileErrorKind::TooManyDimensions { shape }));
            }
        };
        self.check_finite(name, array, columns)?;
        Ok(DMatrix::from_row_slice(rows, columns, array.data()))
    }

    /// [`ModelArrays::matrix`] for an array the model may leave out (e.g. `D`).
    pub fn optional_matrix(
        &self,
        name: &str,
        vector: VectorAs,
    ) -> Result<Option<DMatrix<f64>>, ModelFileError> {
        if self.arrays.contains_key(name) {
            self.matrix(name, vector).map(Some)
        } else {
            Ok(None)
        }
    }

    /// The single number `name` (e.g. the sample time `ts`), `None` if absent:
    /// a 0-D array or any array of one entry (MATLAB's 1×1).
    pub fn scalar(&self, name: &str) -> Result<Option<f64>, ModelFileError> {
        if !self.arrays.contains_key(name) {
            return Ok(None);
        }
        let array = self.array(name)?;
        if array.data().len() != 1 {
            let shape = array.shape().to_vec();
            return Err(self.error(name, ModelFileErrorKind::NotAScalar { shape }));
        }
        self.check_finite(name, array, 1)?;
        Ok(Some(array.data()[0]))
    }

    /// The names present that are not in `used`, sorted: the caller refuses
    /// them, as a field that does not apply is an error.
    pub fn unused(&self, used: &[&str]) -> Vec<String> {
        self.arrays
            .keys()
            .filter(|name| !used.contains(&name.as_str()))
            .cloned()
            .collect()
    }

    /// The first NaN or infinite entry, by row and column in a matrix of
    /// `columns` columns.
    fn check_finite(
        &self,
        name: &str,
        array: &Array,
        columns: usize,
    ) -> Result<(), ModelFileError> {
        match array.data().iter().position(|v| !v.is_finite()) {
            None => Ok(()),
            Some(at) => Err(self.error(
                name,
                ModelFileErrorKind::NonFinite {
                    row: at / columns,
                    column: at % columns,
                    value: array.data()[at],
                },
            )),
        }
    }

    fn error(&self, name: &str, kind: ModelFileErrorKind) -> ModelFileError {
        ModelFileError::new(&self.source, Some(name), kind)
    }
}
