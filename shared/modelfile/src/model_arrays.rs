//! The named arrays of one model, from a file or the scenario, and how the
//! caller takes each: as a matrix, a vector of known orientation, or a number.

use std::collections::BTreeMap;
use std::path::Path;

use nalgebra::DMatrix;

use crate::array::{Array, VectorAs};
use crate::error::{ArraySource, FileFormat, ModelFileError, ModelFileErrorKind};
use crate::limits::MAX_FILE_BYTES;
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
        let bytes =
            read_regular_file(path).map_err(|kind| ModelFileError::new(&source, None, kind))?;
        Self::from_bytes(source, format, &bytes)
    }

    /// Writes `arrays` (name, array) as a NumPy `.npz` archive at `path`, as
    /// `np.savez` does (float64, C order, stored): what [`ModelArrays::read`]
    /// and `np.load` read back, e.g. `A`, `B`, `C`, `D` of a `state-space`
    /// plant (docs/own-plant.md). Refused, naming the array, before anything
    /// is written: a name other than a letter then letters, digits or
    /// underscores; a name given twice; more arrays, or an array larger, than
    /// flexloop reads ([`limits`](crate::limits)); a NaN or infinite entry.
    /// The archive goes to a temporary file in `path`'s directory, renamed
    /// over `path` once whole: no half-written file is ever at `path`, and a
    /// failed write leaves none beside it.
    pub fn write_npz(path: &Path, arrays: &[(&str, Array)]) -> Result<(), ModelFileError> {
        let source = ArraySource::File(path.to_path_buf());
        crate::npz_write::write(path, arrays).map_err(|fault| fault.at(&source))
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
    /// column, C a row); a single number (0-D) as 1×1. A MAT-file has no 1-D
    /// arrays: MATLAB and scipy.io.savemat write a vector as a 1×n or n×1
    /// matrix (savemat makes a 1-D NumPy array a 1×n row by default), which
    /// comes as written. Which dimensions fit is the caller's to check. An error names the source and the array:
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

    /// The refusal of the arrays present that `what` (e.g. "a `second-order`
    /// model") does not take, naming the source, those arrays and the ones
    /// it takes; None when every array present is taken.
    pub fn not_taken(&self, taken: &[&str], what: &str) -> Option<String> {
        let unused = self.unused(taken);
        if unused.is_empty() {
            return None;
        }
        Some(format!(
            "{}: {} {} not part of {what} (it takes {})",
            self.source,
            unused
                .iter()
                .map(|n| format!("`{n}`"))
                .collect::<Vec<_>>()
                .join(", "),
            if unused.len() == 1 { "is" } else { "are" },
            taken.join(", ")
        ))
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

/// The bytes of the regular file at `path` (a symbolic link is followed),
/// refused before it is read if it is anything else or larger than
/// [`MAX_FILE_BYTES`]. The metadata are checked before the file is opened,
/// and again on the file opened (without blocking, so that a FIFO put in
/// its place meanwhile cannot hold the open), and the read stops at the
/// cap whatever the file does meanwhile.
fn read_regular_file(path: &Path) -> Result<Vec<u8>, ModelFileErrorKind> {
    use std::io::Read;
    use std::os::unix::fs::OpenOptionsExt;

    let io = |e: std::io::Error| ModelFileErrorKind::Io {
        reason: e.to_string(),
    };
    check_metadata(&std::fs::metadata(path).map_err(io)?)?;
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY)
        .open(path)
        .map_err(io)?;
    let metadata = file.metadata().map_err(io)?;
    check_metadata(&metadata)?;
    let mut bytes = Vec::with_capacity(usize::try_from(metadata.len()).unwrap_or(0));
    file.take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(io)?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(ModelFileErrorKind::FileTooLarge {
            bytes: bytes.len() as u64,
        });
    }
    Ok(bytes)
}

/// A regular file of at most [`MAX_FILE_BYTES`], or why not.
fn check_metadata(metadata: &std::fs::Metadata) -> Result<(), ModelFileErrorKind> {
    use std::os::unix::fs::FileTypeExt;

    let kind = metadata.file_type();
    let found = if kind.is_file() {
        None
    } else if kind.is_dir() {
        Some("a directory")
    } else if kind.is_fifo() {
        Some("a FIFO (named pipe)")
    } else if kind.is_char_device() {
        Some("a character device")
    } else if kind.is_block_device() {
        Some("a block device")
    } else if kind.is_socket() {
        Some("a socket")
    } else {
        Some("not a file")
    };
    if let Some(found) = found {
        return Err(ModelFileErrorKind::NotARegularFile {
            found: found.to_string(),
        });
    }
    if metadata.len() > MAX_FILE_BYTES {
        return Err(ModelFileErrorKind::FileTooLarge {
            bytes: metadata.len(),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inline(text: &str) -> Result<ModelArrays, ModelFileError> {
        let table: toml::Table = text.parse().unwrap();
        ModelArrays::from_toml(Path::new("scenarios/own.toml"), "plant.arrays", &table)
    }

    fn error(result: Result<impl std::fmt::Debug, ModelFileError>) -> String {
        result.unwrap_err().to_string()
    }

    const CHAIN: &str = r#"
        M = [[1.5, 0], [0, 2.5]]
        K = [[3e4, -3e4], [-3e4, 3e4]]
        B = [1, 0]
        C = [0.0, 1.0]
        ts = 1e-4
    "#;

    #[test]
    fn inline_arrays_are_matrices_vectors_and_numbers() {
        let arrays = inline(CHAIN).unwrap();
        assert_eq!(arrays.names(), ["B", "C", "K", "M", "ts"]);
        assert_eq!(
            arrays.matrix("M", VectorAs::Column).unwrap(),
            DMatrix::from_row_slice(2, 2, &[1.5, 0.0, 0.0, 2.5])
        );
        // A 1-D array is the column or the row the caller asks for.
        assert_eq!(
            arrays.matrix("B", VectorAs::Column).unwrap().shape(),
            (2, 1)
        );
        assert_eq!(
            arrays.matrix("C", VectorAs::Row).unwrap(),
            DMatrix::from_row_slice(1, 2, &[0.0, 1.0])
        );
        // A number is a 1×1 matrix, or a scalar.
        assert_eq!(arrays.matrix("ts", VectorAs::Row).unwrap().shape(), (1, 1));
        assert_eq!(arrays.scalar("ts").unwrap(), Some(1e-4));
        assert_eq!(arrays.scalar("dt").unwrap(), None);
        assert_eq!(arrays.optional_matrix("D", VectorAs::Row).unwrap(), None);
        assert!(
            arrays
                .optional_matrix("K", VectorAs::Row)
                .unwrap()
                .is_some()
        );
        assert_eq!(arrays.unused(&["M", "K", "B", "C"]), ["ts"]);
        assert!(arrays.unused(&["M", "K", "B", "C", "ts"]).is_empty());
    }

    #[test]
    fn errors_name_the_scenario_table_the_array_and_the_reason() {
        let arrays = inline(CHAIN).unwrap();
        assert_eq!(
            error(arrays.matrix("D", VectorAs::Row)),
            "scenarios/own.toml, table `plant.arrays`: array `D`: missing (the arrays present: B, C, K, M, ts)"
        );
        assert_eq!(
            error(arrays.scalar("M")),
            "scenarios/own.toml, table `plant.arrays`: array `M`: must be a single number, found 4 entries (2×2)"
        );
        let cases = [
            (
                "M = [[1.0, 2.0], [3.0]]",
                "array `M`: row 2 has length 1 where row 1 has length 2; a matrix is written as rows of equal length",
            ),
            (
                "M = [[1.0, 'x']]",
                "array `M`: row 1, element 2 is a string, not a number",
            ),
            (
                "B = [1.0, true]",
                "array `B`: element 2 is a boolean, not a number",
            ),
            (
                "ts = '1e-4'",
                "array `ts`: the value is a string, not a number",
            ),
            (
                "M = [[[1.0]]]",
                "array `M`: is nested deeper than rows of numbers",
            ),
            ("M = [1.0, [2.0]]", "array `M`: mixes numbers and rows"),
            (
                "K = 9007199254740993",
                "array `K`: has the integer entry 9007199254740993, too large",
            ),
        ];
        for (text, expected) in cases {
            let arrays = inline(text).unwrap();
            let name = arrays.names()[0].to_string();
            let message = error(arrays.matrix(&name, VectorAs::Column));
            assert!(message.contains(expected), "{text}: {message}");
        }
    }

    #[test]
    fn a_non_finite_entry_is_refused_naming_its_place() {
        let arrays = inline("K = [[1.0, 2.0], [3.0, nan]]\nB = [0.0, -inf]\nts = inf").unwrap();
        assert!(matches!(
            arrays.matrix("K", VectorAs::Column).unwrap_err().kind,
            ModelFileErrorKind::NonFinite { row: 1, column: 1, value } if value.is_nan()
        ));
        assert!(
            error(arrays.matrix("K", VectorAs::Column))
                .ends_with("array `K`: the entry at row 2, column 2 (counted from 1) is NaN; entries must be finite")
        );
        // The place is the matrix's: a 1-D array taken as a column.
        assert!(error(arrays.matrix("B", VectorAs::Column)).contains("row 2, column 1"));
        assert!(error(arrays.matrix("B", VectorAs::Row)).contains("row 1, column 2"));
        assert!(error(arrays.scalar("ts")).contains("is inf"));
    }

    #[test]
    fn more_than_two_dimensions_are_refused() {
        let arrays = ModelArrays {
            source: ArraySource::File("plant.npz".into()),
            arrays: [(
                "M".to_string(),
                Ok(Array::new(vec![2, 2, 2], vec![0.0; 8]).unwrap()),
            )]
            .into(),
        };
        assert_eq!(
            error(arrays.matrix("M", VectorAs::Column)),
            "plant.npz: array `M`: has 3 dimensions (2×2×2); a model array is a matrix, a vector or a single number"
        );
    }

    #[test]
    fn files_are_read_by_extension() {
        let dir = std::env::temp_dir();
        assert_eq!(
            error(ModelArrays::read(&dir.join("plant.csv"))),
            format!(
                "{}: unknown model file type `.csv`: expected .npz (NumPy np.savez) or .mat (MATLAB save, level 5)",
                dir.join("plant.csv").display()
            )
        );
        assert!(matches!(
            ModelArrays::read(Path::new("plant")).unwrap_err().kind,
            ModelFileErrorKind::UnknownFormat { extension: None }
        ));
        let missing = dir.join(format!(
            "flexloop-modelfile-{}-missing.MAT",
            std::process::id()
        ));
        let message = error(ModelArrays::read(&missing));
        assert!(
            message.contains("cannot read the file: No such file"),
            "{message}"
        );
    }
}
