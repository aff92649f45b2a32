//! Errors that name where the arrays came from, the array, and the reason.

use std::fmt;
use std::path::PathBuf;

use crate::limits;

/// Where a model's arrays came from, for error messages.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ArraySource {
    /// A `.npz` or `.mat` file.
    File(PathBuf),
    /// A table of the scenario file, e.g. `plant.arrays`.
    Inline { scenario: PathBuf, table: String },
}

impl fmt::Display for ArraySource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ArraySource::File(path) => write!(f, "{}", path.display()),
            ArraySource::Inline { scenario, table } => {
                write!(f, "{}, table `{table}`", scenario.display())
            }
        }
    }
}

/// The file formats a model can come in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FileFormat {
    /// NumPy's `.npz`: a zip archive of `.npy` arrays (`np.savez`, `np.savez_compressed`).
    Npz,
    /// MATLAB's level-5 MAT-file, compressed (v7, MATLAB's default) or not (v6, scipy's default).
    Mat,
}

impl fmt::Display for FileFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FileFormat::Npz => "NumPy .npz archive",
            FileFormat::Mat => "MATLAB level-5 MAT-file",
        })
    }
}

/// Model arrays that cannot be used, and why: `"<source>: array `M`: <reason>"`.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelFileError {
    /// Where the arrays came from.
    pub origin: ArraySource,
    /// The array to blame, if one is.
    pub array: Option<String>,
    pub kind: ModelFileErrorKind,
}

impl ModelFileError {
    pub(crate) fn new(origin: &ArraySource, array: Option<&str>, kind: ModelFileErrorKind) -> Self {
        Self {
            origin: origin.clone(),
            array: array.map(str::to_string),
            kind,
        }
    }
}

impl fmt::Display for ModelFileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.array {
            Some(name) => write!(f, "{}: array `{name}`: {}", self.origin, self.kind),
            None => write!(f, "{}: {}", self.origin, self.kind),
        }
    }
}

impl std::error::Error for ModelFileError {}

/// The instruction given with every MAT-file flexloop cannot read as level 5.
const SAVE_AS_V7: &str =
    "save it with -v7 (save plant.mat A B C D -v7), or from Python with scipy.io.savemat";

/// Why arrays cannot be used.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum ModelFileErrorKind {
    /// The file cannot be read (missing, no permission, ...).
    Io { reason: String },
    /// Not a regular file (a FIFO, a device, a directory, a socket): `found` says what.
    NotARegularFile { found: String },
    /// A file larger than [`MAX_FILE_BYTES`](crate::limits::MAX_FILE_BYTES).
    FileTooLarge { bytes: u64 },
    /// An array whose declared shape exceeds what flexloop takes
    /// ([`limits`](crate::limits)), refused before its data are read.
    ArrayTooLarge { shape: Vec<u64> },
    /// An array whose data take (`Some`: declare) more bytes than
    /// [`MAX_ARRAY_BYTES`](crate::limits::MAX_ARRAY_BYTES), stored or inflated.
    ArrayDataTooLarge { bytes: Option<u64> },
    /// More arrays than [`MAX_ARRAYS`](crate::limits::MAX_ARRAYS) (`None`: counted up to the cap).
    TooManyArrays { count: Option<u64> },
    /// The file name ends in neither `.npz` nor `.mat`.
    UnknownFormat { extension: Option<String> },
    /// A MAT-file of version 7.3, which is HDF5, not level 5.
    MatV73,
    /// A level-4 MAT-file (`save -v4`).
    MatLevel4,
    /// The bytes are not a well-formed file of the format (truncated, damaged, another format).
    Corrupt { format: FileFormat, reason: String },
    /// The array is not there.
    Missing { present: Vec<String> },
    /// Two arrays of the same name.
    Duplicate,
    /// The array has complex entries.
    Complex,
    /// The array is a MATLAB sparse matrix.
    Sparse,
    /// The array holds something other than numbers: `found` says what.
    NotNumeric { found: String },
    /// Numbers of a type that is not read (e.g. NumPy float16 or float128).
    UnsupportedNumberType { dtype: String },
    /// An integer entry too large to be an `f64` exactly.
    InexactInteger { value: String },
    /// More than two dimensions: a model array is a matrix, a vector or a scalar.
    TooManyDimensions { shape: Vec<usize> },
    /// A single number was expected.
    NotAScalar { shape: Vec<usize> },
    /// A NaN or infinite entry, at its (row, column) counted from 0.
    NonFinite {
        row: usize,
        column: usize,
        value: f64,
    },
    /// An inline array entry that is not a number; `at` says where in the array.
    InlineNotANumber { at: String, found: &'static str },
    /// Rows of an inline matrix of different lengths.
    InlineRaggedRows {
        row: usize,
        len: usize,
        first_len: usize,
    },
    /// An inline array with both numbers and rows among its elements.
    InlineMixed,
    /// An inline array nested deeper than rows of numbers.
    InlineTooDeep,
    /// The file cannot be written (the directory, the disk, the name).
    Write { reason: String },
    /// A name the writer does not give an array
    /// (see [`ModelArrays::write_npz`](crate::ModelArrays::write_npz)).
    InvalidName,
}

impl fmt::Display for ModelFileErrorKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use ModelFileErrorKind::*;
        match self {
            Io { reason } => write!(f, "cannot read the file: {reason}"),
            NotARegularFile { found } => write!(
                f,
                "is {found}, not a regular file: a model is read from a regular .npz or .mat file"
            ),
            FileTooLarge { bytes } => write!(
                f,
                "the file has {}, more than the {} flexloop reads: the largest model it takes \
                 ({LOOP_SIZE}) fits in well under 1 MiB; reduce the model first (e.g. by modal \
                 truncation)",
                bytes_text(*bytes),
                bytes_text(limits::MAX_FILE_BYTES)
            ),
            ArrayTooLarge { shape } => write!(
                f,
                "declares {} entries, more than any model array flexloop takes: at most {} in \
                 each dimension ({LOOP_SIZE}); it is not read",
                shape_text_u64(shape),
                limits::MAX_DIMENSION
            ),
            ArrayDataTooLarge { bytes } => {
                match bytes {
                    Some(bytes) => write!(f, "its data take {}", bytes_text(*bytes))?,
                    None => write!(
                        f,
                        "its data inflate to more than {} (inflating stopped there)",
                        bytes_text(limits::MAX_ARRAY_BYTES)
                    )?,
                }
                write!(
                    f,
                    "; an array flexloop takes needs at most {} (a 128×128 float64 matrix is \
                     128 KiB), so it is not read",
                    bytes_text(limits::MAX_ARRAY_BYTES)
                )
            }
            TooManyArrays { count } => {
                match count {
                    Some(count) => write!(f, "the file holds {count} arrays")?,
                    None => write!(f, "the file holds more than {} arrays", limits::MAX_ARRAYS)?,
                }
                write!(
                    f,
                    "; a model has at most five, and flexloop reads at most {}",
                    limits::MAX_ARRAYS
                )
            }
            UnknownFormat { extension } => {
                match extension {
                    Some(ext) => write!(f, "unknown model file type `.{ext}`")?,
                    None => write!(f, "the file name has no extension")?,
                }
                write!(
                    f,
                    ": expected .npz (NumPy np.savez) or .mat (MATLAB save, level 5)"
                )
            }
            MatV73 => write!(
                f,
                "a MATLAB v7.3 MAT-file (HDF5), which is not read: {SAVE_AS_V7}"
            ),
            MatLevel4 => write!(
                f,
                "a level-4 MAT-file (save -v4), which is not read: {SAVE_AS_V7}"
            ),
            Corrupt { format, reason } => write!(f, "not a readable {format}: {reason}"),
            Missing { present } if present.is_empty() => write!(f, "missing (there are no arrays)"),
            Missing { present } => {
                write!(f, "missing (the arrays present: {})", present.join(", "))
            }
            Duplicate => write!(f, "is given twice"),
            Complex => write!(f, "has complex entries; a model array must be real"),
            Sparse => write!(
                f,
                "is a sparse matrix, which is not read: save it full (full(K) in MATLAB, K.toarray() in Python)"
            ),
            NotNumeric { found } => write!(f, "is {found}, not numbers"),
            UnsupportedNumberType { dtype } => write!(
                f,
                "holds numbers of type {dtype}, which is not read: save it as float64 (double)"
            ),
            InexactInteger { value } => write!(
                f,
                "has the integer entry {value}, too large to be represented exactly as a double"
            ),
            TooManyDimensions { shape } => write!(
                f,
                "has {} dimensions ({}); a model array is a matrix, a vector or a single number",
                shape.len(),
                shape_text(shape)
            ),
            NotAScalar { shape } => write!(
                f,
                "must be a single number, found {} entries ({})",
                shape.iter().product::<usize>(),
                shape_text(shape)
            ),
            NonFinite { row, column, value } => write!(
                f,
                "the entry at row {}, column {} (counted from 1) is {value}; entries must be finite",
                row + 1,
                column + 1
            ),
            InlineNotANumber { at, found } => write!(f, "{at} is {found}, not a number"),
            InlineRaggedRows {
                row,
                len,
                first_len,
            } => write!(
                f,
                "row {} has length {len} where row 1 has length {first_len}; a matrix is written as rows of equal length",
                row + 1
            ),
            InlineMixed => write!(
                f,
                "mixes numbers and rows; a matrix is written as rows of numbers ([[1.0, 2.0], [3.0, 4.0]])"
            ),
            InlineTooDeep => write!(
                f,
                "is nested deeper than rows of numbers; a model array is a matrix ([[1.0, 2.0], [3.0, 4.0]]), a vector ([1.0, 2.0]) or a number"
            ),
            Write { reason } => write!(f, "cannot write the file: {reason}"),
            InvalidName => write!(
                f,
                "is not a name an array is written under: a letter, then letters, digits or \
                 underscores, at most 63 in all (what np.load and MATLAB both take)"
            ),
        }
    }
}

/// What the loop carries, as the size errors say it.
const LOOP_SIZE: &str = "the loop carries at most 128 states: a state-space model of 128 states, a \
     second-order one of 64 degrees of freedom, at most 8 inputs and 8 outputs";

/// A declared shape, which may not fit a `usize`.
fn shape_text_u64(shape: &[u64]) -> String {
    let dims: Vec<String> = shape.iter().map(u64::to_string).collect();
    if dims.is_empty() {
        return "a scalar".to_string();
    }
    dims.join("×")
}

/// A byte count as people read it: `512 bytes`, `16 MiB`, `4.0 GiB`.
pub(crate) fn bytes_text(bytes: u64) -> String {
    const UNITS: [(&str, u64); 3] = [("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)];
    for (unit, size) in UNITS {
        if bytes >= size {
            return if bytes.is_multiple_of(size) {
                format!("{} {unit}", bytes / size)
            } else {
                format!("{:.1} {unit}", bytes as f64 / size as f64)
            };
        }
    }
    format!("{bytes} bytes")
}

/// A shape as a reader writes it: `3×4`, `5` (a 1-D array of five), `scalar`.
pub(crate) fn shape_text(shape: &[usize]) -> String {
    if shape.is_empty() {
        return "a scalar".to_string();
    }
    let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
    dims.join("×")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_message_names_the_file_the_array_and_the_reason() {
        let origin = ArraySource::File(PathBuf::from("models/plant.mat"));
        let e = ModelFileError::new(
            &origin,
            Some("K"),
            ModelFileErrorKind::Missing {
                present: vec!["B".into(), "C".into(), "M".into()],
            },
        );
        assert_eq!(
            e.to_string(),
            "models/plant.mat: array `K`: missing (the arrays present: B, C, M)"
        );
        let inline = ArraySource::Inline {
            scenario: PathBuf::from("scenarios/own.toml"),
            table: "plant.arrays".into(),
        };
        let e = ModelFileError::new(&inline, None, ModelFileErrorKind::MatV73);
        assert!(
            e.to_string()
                .starts_with("scenarios/own.toml, table `plant.arrays`: "),
            "{e}"
        );
        assert!(e.to_string().contains("save plant.mat A B C D -v7"), "{e}");
    }

    #[test]
    fn sizes_read_plainly() {
        assert_eq!(bytes_text(100), "100 bytes");
        assert_eq!(bytes_text(16 << 20), "16 MiB");
        assert_eq!(bytes_text((1 << 30) * 4 + (1 << 29)), "4.5 GiB");
        let e = ModelFileErrorKind::ArrayTooLarge {
            shape: vec![100_000, 100_000],
        };
        assert!(
            e.to_string()
                .starts_with("declares 100000×100000 entries, more than any model array"),
            "{e}"
        );
    }

    #[test]
    fn shapes_read_plainly() {
        assert_eq!(shape_text(&[]), "a scalar");
        assert_eq!(shape_text(&[5]), "5");
        assert_eq!(shape_text(&[2, 3, 4]), "2×3×4");
    }
}
