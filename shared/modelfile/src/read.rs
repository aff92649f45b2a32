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
/// flexloop's own checks come first (the framing, every declared size) and
/// the tests show that no truncation of a valid file gets this far, but
/// both readers still hold an `unwrap` or an unchecked product for some
/// malformed inputs (matrw 0.1.4: mismatched real and imaginary types;
/// npyz 0.9: the product of a header's shape): a damaged file must be an
/// error naming it, never a crash of the tool, and never a panic message
/// and backtrace before that error. The panic is silenced on this thread
/// only, for this call only ([`quiet_panics`]).
pub(crate) fn catch<T>(read: impl FnOnce() -> T + std::panic::UnwindSafe) -> Option<T> {
    quiet_panics::run(read)
}

/// A process-wide panic hook installed once, around the hook there was:
/// it passes every panic on to that hook except one on a thread inside
/// [`catch`]. Swapping the hook around each call (`take_hook`, `set_hook`)
/// would race with other threads (the tests read files in parallel) and
/// silence their panics, or restore a hook another thread had just
/// replaced; the wrapper never changes what any other panic prints.
mod quiet_panics {
    use std::cell::Cell;
    use std::sync::Once;

    thread_local! {
        /// Whether this thread is inside [`run`].
        static QUIET: Cell<bool> = const { Cell::new(false) };
    }

    static INSTALL: Once = Once::new();

    fn install() {
        INSTALL.call_once(|| {
            let previous = std::panic::take_hook();
            std::panic::set_hook(Box::new(move |info| {
                if !QUIET.with(Cell::get) {
                    previous(info);
                }
            }));
        });
    }

    pub(super) fn run<T>(read: impl FnOnce() -> T + std::panic::UnwindSafe) -> Option<T> {
        install();
        let was = QUIET.with(|q| q.replace(true));
        let result = std::panic::catch_unwind(read);
        QUIET.with(|q| q.set(was));
        result.ok()
    }

    #[cfg(test)]
    mod tests {
        #[test]
        fn a_caught_panic_is_silent_and_others_are_not() {
            assert_eq!(super::run(|| 7), Some(7));
            let none: Option<()> = super::run(|| panic!("a reader's unwrap"));
            assert_eq!(none, None);
            // Nested, and the flag is back after each.
            assert_eq!(super::run(|| super::run(|| -> u8 { panic!() })), Some(None));
            assert!(!super::QUIET.with(std::cell::Cell::get));
        }
    }
}
