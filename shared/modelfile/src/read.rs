//! What the readers of each source share: the arrays read so far, each an
//! array or the reason it is not one, and a fault that names the array to
//! blame before the source is known.

use std::collections::BTreeMap;

use crate::array::Array;
use crate::error::{ArraySource, ModelFileError, ModelFileErrorKind};

/// One named entry of a source: an array of numbers, or why it is not one
/// (complex, text, a struct, ...). The refusal is given when the array is
/// asked for, or listed among the unused names, so that each array's own
/// reason reaches the user.
pub(crate) type Entry = Result<Array, ModelFileErrorKind>;

/// A reader's error before it is tied to its source: the whole source is
/// unusable (damaged, truncated, another format).
#[derive(Debug)]
pub(crate) struct Fault {
    array: Option<String>,
    kind: ModelFileErrorKind,
}

impl Fault {
    /// A fault of the whole file.
    pub(crate) fn file(kind: ModelFileErrorKind) -> Self {
        Self { array: None, kind }
    }

    /// A fault of the file found in one array (its data cannot be extracted).
    pub(crate) fn array(name: &str, kind: ModelFileErrorKind) -> Self {
        Self {
            array: Some(name.to_string()),
            kind,
        }
    }

    pub(crate) fn at(self, origin: &ArraySource) -> ModelFileError {
        ModelFileError::new(origin, self.array.as_deref(), self.kind)
    }
}

/// Entries by name; a name given twice is an error.
#[derive(Debug, Default)]
pub(crate) struct NamedArrays(pub(crate) BTreeMap<String, Entry>);

impl NamedArrays {
    pub(crate) fn new() -> Self {
        Self::default()
    }

    pub(crate) fn insert(&mut self, name: String, entry: Entry) -> Result<(), Fault> {
        if self.0.contains_key(&name) {
            return Err(Fault::array(&name, ModelFileErrorKind::Duplicate));
        }
        self.0.insert(name, entry);
        Ok(())
    }

    pub(crate) fn into_map(self) -> BTreeMap<String, Entry> {
        self.0
    }
}

/// Runs a third-party reader on untrusted bytes; `None` if it panicked.
/// flexloop's own checks come first and the tests show that no truncation of
/// a valid file gets this far, but both readers still hold an `unwrap` or an
/// unchecked product for some malformed inputs (matrw 0.1.4: zlib data,
/// struct field names written in the short form scipy uses; npyz 0.9: the
/// product of a header's shape): a damaged file must be an error naming it,
/// never a crash of the tool. (The default panic hook still prints the
/// panic on stderr; a library must not replace the process's hook.)
pub(crate) fn catch<T>(read: impl FnOnce() -> T + std::panic::UnwindSafe) -> Option<T> {
    std::panic::catch_unwind(read).ok()
}
