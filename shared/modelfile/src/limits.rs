//! What flexloop reads of a model file at most (docs/own-plant.md, "What
//! flexloop reads at most"): every size a file declares is checked against
//! these before anything is read, inflated or allocated for it, so that a
//! FIFO, a device, a zip bomb or a header declaring a huge array is refused
//! at once, naming the file, the array and the reason.
//!
//! The bounds follow from what the loop carries: at most 128 states (the
//! estimate, `flexloop_protocol::MAX_STATES`), 8 inputs and 8 outputs. The
//! largest model flexloop takes is a state space of 128 states (A 128×128,
//! B 128×8, C 8×128, D 8×8: 145 KiB as float64) or a second-order model of
//! 64 degrees of freedom (M, K, D 64×64: 96 KiB); the caps below leave
//! room for any number type and writer around that, and nothing for a
//! model flexloop could not run anyway.

/// The largest dimension of any array flexloop takes: the loop's estimate
/// carries at most 128 states (`flexloop_protocol::MAX_STATES`; flexloop-design
/// checks that the two agree), and every model array (A, B, C, D, M, K, and
/// an IO observer's K(z)) has the states, the inputs or the outputs as its
/// dimensions.
pub const MAX_DIMENSION: u64 = 128;

/// The most entries of one array: a 128×128 matrix.
pub const MAX_ENTRIES: u64 = MAX_DIMENSION * MAX_DIMENSION;

/// The largest model file read (16 MiB on disk): more than a hundred times
/// the largest model flexloop takes. A larger file, and anything but a
/// regular file (a FIFO, a device, a directory, a socket), is refused from
/// its metadata before it is opened for reading.
pub const MAX_FILE_BYTES: u64 = 16 << 20;

/// The most bytes one array may take as stored, and so inflate to (an
/// `.npz` member, a `.mat` variable, compressed or not): 1 MiB, eight times
/// a 128×128 float64 matrix with its header. Inflating stops here whatever
/// the archive's header says.
pub const MAX_ARRAY_BYTES: u64 = 1 << 20;

/// The most arrays (`.npz` members, `.mat` variables) a model file may
/// hold: a model has at most five (M, K, D, B, C or A, B, C, D, ts).
pub const MAX_ARRAYS: usize = 64;
