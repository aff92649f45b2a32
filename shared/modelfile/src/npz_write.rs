//! Writing named arrays as a NumPy `.npz`, the same contract the reader
//! ([`crate::npz`]) takes: a zip archive (the `zip` crate) of float64 `.npy`
//! arrays (the `npyz` crate), stored as `np.savez` stores them, in C order.
//!
//! Only what flexloop reads back is written: at most
//! [`MAX_ARRAYS`](crate::limits::MAX_ARRAYS) arrays, each within
//! [`limits`](crate::limits), of finite entries, under a name `np.load` and
//! MATLAB both take. The archive is written to a temporary file in the
//! destination's directory and renamed over the destination, so a reader
//! sees the old file or the whole new one, never half of one, and a failed
//! write leaves nothing behind.

use std::fs::{File, OpenOptions};
use std::io::{Cursor, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use npyz::WriterBuilder;
use zip::write::SimpleFileOptions;

use crate::array::{Array, check_shape};
use crate::error::ModelFileErrorKind;
use crate::limits::MAX_ARRAYS;
use crate::read::Fault;

/// Writes `arrays` (name, array) to `path`, an `.npz` file.
pub(crate) fn write(path: &Path, arrays: &[(&str, Array)]) -> Result<(), Fault> {
    let is_npz = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npz"));
    if !is_npz {
        return Err(Fault::file(write_error(
            "the writer makes NumPy .npz archives: the name must end in .npz".into(),
        )));
    }
    if arrays.len() > MAX_ARRAYS {
        return Err(Fault::file(ModelFileErrorKind::TooManyArrays {
            count: Some(arrays.len() as u64),
        }));
    }
    // Everything is checked and serialised before the file system is touched.
    let mut members = Vec::with_capacity(arrays.len());
    for (index, (name, array)) in arrays.iter().enumerate() {
        check_name(name).map_err(|kind| Fault::array(name, kind))?;
        if arrays[..index].iter().any(|(other, _)| other == name) {
            return Err(Fault::array(name, ModelFileErrorKind::Duplicate));
        }
        let shape: Vec<u64> = array.shape().iter().map(|&n| n as u64).collect();
        check_shape(&shape).map_err(|kind| Fault::array(name, kind))?;
        check_finite(array).map_err(|kind| Fault::array(name, kind))?;
        members.push((format!("{name}.npy"), npy(array, &shape)?));
    }
    let archive = zip_of(&members)?;
    replace(path, &archive).map_err(|e| Fault::file(write_error(e.to_string())))
}

/// A name both `np.load` (a Python identifier, as `np.savez`'s keywords are)
/// and MATLAB (a variable name) take: a letter, then letters, digits and
/// underscores, at most 63 (MATLAB's `namelengthmax`).
fn check_name(name: &str) -> Result<(), ModelFileErrorKind> {
    let mut chars = name.chars();
    let starts_with_letter = chars.next().is_some_and(|c| c.is_ascii_alphabetic());
    let rest_ok = chars.all(|c| c.is_ascii_alphanumeric() || c == '_');
    if starts_with_letter && rest_ok && name.len() <= 63 {
        Ok(())
    } else {
        Err(ModelFileErrorKind::InvalidName)
    }
}

/// The first NaN or infinite entry, by (row, column) of the matrix the
/// reader would make of it (a 1-D array counts as a row here).
fn check_finite(array: &Array) -> Result<(), ModelFileErrorKind> {
    let columns = array.shape().last().copied().unwrap_or(1).max(1);
    match array.data().iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(at) => Err(ModelFileErrorKind::NonFinite {
            row: at / columns,
            column: at % columns,
            value: array.data()[at],
        }),
    }
}

/// One array as a `.npy` (version 1.0, little-endian float64, C order).
fn npy(array: &Array, shape: &[u64]) -> Result<Vec<u8>, Fault> {
    let failed = |e: std::io::Error| Fault::file(write_error(format!("cannot encode .npy: {e}")));
    let mut bytes = Vec::new();
    let mut writer = npyz::WriteOptions::<f64>::new()
        .default_dtype()
        .shape(shape)
        .writer(&mut bytes)
        .begin_nd()
        .map_err(failed)?;
    writer
        .extend(array.data().iter().copied())
        .map_err(failed)?;
    writer.finish().map_err(failed)?;
    Ok(bytes)
}

/// The archive of `members` (file name, bytes), stored uncompressed as
/// `np.savez` stores them (a model is a few KiB).
fn zip_of(members: &[(String, Vec<u8>)]) -> Result<Vec<u8>, Fault> {
    let failed = |e: &dyn std::fmt::Display| {
        Fault::file(write_error(format!("cannot build the archive: {e}")))
    };
    let options = SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
    for (name, bytes) in members {
        zip.start_file(name.as_str(), options)
            .map_err(|e| failed(&e))?;
        zip.write_all(bytes).map_err(|e| failed(&e))?;
    }
    Ok(zip.finish().map_err(|e| failed(&e))?.into_inner())
}

/// Distinguishes the temporary files of writes running at once in one process.
static TEMPORARY: AtomicU64 = AtomicU64::new(0);

/// Writes `bytes` to a new temporary file beside `path`, flushes it to disk,
/// and renames it to `path` (atomic within one file system: readers see the
/// old file or the new one). On any failure the temporary file is removed.
fn replace(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let file_name = path.file_name().ok_or_else(|| {
        std::io::Error::new(std::io::ErrorKind::InvalidInput, "the path names no file")
    })?;
    let temporary = path.with_file_name(format!(
        ".{}.{}.{}.tmp",
        file_name.to_string_lossy(),
        std::process::id(),
        TEMPORARY.fetch_add(1, Ordering::Relaxed)
    ));
    let written = write_new(&temporary, bytes).and_then(|()| std::fs::rename(&temporary, path));
    if written.is_err() {
        // Nothing of a failed write is left; the error to report is the
        // write's, not a failure to remove what may not exist.
        let _ = std::fs::remove_file(&temporary);
        return written;
    }
    // The rename is durable once the directory is; readers are not affected
    // either way, so a directory that cannot be synced (some file systems)
    // is no error.
    if let Some(directory) = parent(path)
        && let Ok(directory) = File::open(directory)
    {
        let _ = directory.sync_all();
    }
    Ok(())
}

fn write_new(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut file = OpenOptions::new().write(true).create_new(true).open(path)?;
    file.write_all(bytes)?;
    file.sync_all()
}

/// The directory `path` is in (`.` for a bare file name).
fn parent(path: &Path) -> Option<PathBuf> {
    match path.parent() {
        Some(p) if p.as_os_str().is_empty() => Some(PathBuf::from(".")),
        Some(p) => Some(p.to_path_buf()),
        None => None,
    }
}

fn write_error(reason: String) -> ModelFileErrorKind {
    ModelFileErrorKind::Write { reason }
}

#[cfg(test)]
mod tests {
    use nalgebra::DMatrix;

    use crate::{Array, ModelArrays, ModelFileErrorKind, VectorAs};

    /// A fresh directory of this test's own, removed by the caller.
    fn directory(test: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!(
            "flexloop-modelfile-write-{}-{test}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn entries(dir: &std::path::Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn a_written_state_space_reads_back_equal() {
        let dir = directory("round-trip");
        let path = dir.join("plant.npz");
        let a = DMatrix::from_row_slice(3, 3, &[0.0, 1.0, 0.0, -4e6, -80.0, 0.0, 0.0, 0.0, -1.5]);
        let b = DMatrix::from_row_slice(3, 1, &[0.0, 0.31, -2.0e-3]);
        let c = DMatrix::from_row_slice(1, 3, &[0.31, 0.0, 1.0 / 3.0]);
        let d = DMatrix::zeros(1, 1);
        let vector = Array::new(vec![2], vec![f64::MIN_POSITIVE, -f64::MAX]).unwrap();
        let arrays = [
            ("A", Array::from_matrix(&a)),
            ("B", Array::from_matrix(&b)),
            ("C", Array::from_matrix(&c)),
            ("D", Array::from_matrix(&d)),
            ("ts", Array::scalar(1e-4)),
            ("v_1", vector.clone()),
        ];
        ModelArrays::write_npz(&path, &arrays).unwrap();
        let read = ModelArrays::read(&path).unwrap();
        assert_eq!(read.names(), ["A", "B", "C", "D", "ts", "v_1"]);
        for (name, array) in &arrays {
            assert_eq!(read.array(name).unwrap(), array, "{name}");
        }
        assert_eq!(read.matrix("A", VectorAs::Column).unwrap(), a);
        assert_eq!(read.matrix("B", VectorAs::Column).unwrap(), b);
        assert_eq!(read.matrix("C", VectorAs::Row).unwrap(), c);
        assert_eq!(read.optional_matrix("D", VectorAs::Row).unwrap(), Some(d));
        assert_eq!(read.scalar("ts").unwrap(), Some(1e-4));
        // Written again over itself: replaced whole, nothing left beside it.
        ModelArrays::write_npz(&path, &arrays[..3]).unwrap();
        assert_eq!(ModelArrays::read(&path).unwrap().names(), ["A", "B", "C"]);
        assert_eq!(entries(&dir), ["plant.npz"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn what_flexloop_would_not_read_is_not_written() {
        let dir = directory("refused");
        let path = dir.join("plant.npz");
        let one = || Array::scalar(1.0);
        let kind = |arrays: &[(&str, Array)]| ModelArrays::write_npz(&path, arrays).unwrap_err();
        for name in ["", "1A", "A.B", "A/B", "Ä", &"x".repeat(64)] {
            let e = kind(&[(name, one())]);
            assert_eq!(e.kind, ModelFileErrorKind::InvalidName, "{name:?}");
        }
        assert_eq!(
            kind(&[("A", one()), ("A", one())]).to_string(),
            format!("{}: array `A`: is given twice", path.display())
        );
        let nan = Array::new(vec![2, 2], vec![0.0, 1.0, f64::NAN, 0.0]).unwrap();
        assert!(matches!(
            kind(&[("A", nan)]).kind,
            ModelFileErrorKind::NonFinite {
                row: 1,
                column: 0,
                ..
            }
        ));
        let large = Array::new(vec![129, 1], vec![0.0; 129]).unwrap();
        assert!(matches!(
            kind(&[("B", large)]).kind,
            ModelFileErrorKind::ArrayTooLarge { .. }
        ));
        let many: Vec<(String, Array)> = (0..65).map(|i| (format!("x{i}"), one())).collect();
        let many: Vec<(&str, Array)> = many.iter().map(|(n, a)| (n.as_str(), a.clone())).collect();
        assert!(matches!(
            kind(&many).kind,
            ModelFileErrorKind::TooManyArrays { count: Some(65) }
        ));
        let e = ModelArrays::write_npz(&dir.join("plant.mat"), &[("A", one())]).unwrap_err();
        assert!(e.to_string().contains("must end in .npz"), "{e}");
        assert!(entries(&dir).is_empty(), "{:?}", entries(&dir));
        // A directory where the file should go: the rename fails, and the
        // temporary file is removed.
        std::fs::create_dir(&path).unwrap();
        let e = ModelArrays::write_npz(&path, &[("A", one())]).unwrap_err();
        assert!(
            e.to_string()
                .starts_with(&format!("{}: cannot write the file: ", path.display())),
            "{e}"
        );
        assert_eq!(entries(&dir), ["plant.npz"]);
        assert!(path.is_dir());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
