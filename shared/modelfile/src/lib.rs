//! flexloop-modelfile: the named numeric arrays of a model that a user brings
//! (docs/own-plant.md), whatever they were saved with, as one data
//! contract. Turning the arrays into a model is the next crate up.
//!
//! - [`ModelArrays`]: read from a NumPy `.npz` (`np.savez`), a MATLAB level-5
//!   `.mat` (`save`, scipy.io.savemat) or a table of the scenario's TOML, and
//!   taken by name as a matrix, a vector or a number; and written as an
//!   `.npz` ([`ModelArrays::write_npz`]) that it reads back, e.g. a model
//!   fitted to a measurement.
//! - [`Array`], [`VectorAs`]: one array as read, and how a 1-D one is taken.
//! - [`ModelFileError`]: errors naming the file (or scenario table), the array
//!   and the reason.
//! - `npz`, `mat`, `inline`: one reader per source. The file formats are
//!   parsed by crates (`zip` and `npyz`; `matrw`); `mat` adds the header and
//!   framing checks matrw lacks (see there).
//! - [`limits`]: what is read at most. A model file must be a regular file
//!   of at most 16 MiB, and every array it declares fit the loop (at most
//!   128 per dimension), checked before anything is read, inflated or
//!   allocated for it (docs/own-plant.md, "What flexloop reads at most").

mod array;
pub mod error;
mod inline;
pub mod limits;
mod mat;
mod model_arrays;
mod npz;
mod npz_write;
mod read;

pub use array::{Array, VectorAs};
pub use error::{ArraySource, FileFormat, ModelFileError, ModelFileErrorKind};
pub use model_arrays::ModelArrays;
