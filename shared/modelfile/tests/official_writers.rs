//! Model files written by the official writers, NumPy's `np.savez` and
//! SciPy's `scipy.io.savemat` (tests/write_models.py), read back entry for
//! entry: what a user's Python or MATLAB session hands flexloop.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use flexloop_modelfile::{ArraySource, FileFormat, ModelArrays, ModelFileErrorKind, VectorAs};
use nalgebra::DMatrix;

/// The Python with numpy and scipy of `tools/python-requirements.txt`:
/// `FLEXLOOP_PYTHON` (`tools/test` sets it to the venv it makes), else that
/// venv. Without one the test fails, saying how to get it: it never passes
/// without having read the official writers' files.
fn python() -> String {
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let venv = workspace.join("target/test-python/bin/python");
    let python = std::env::var("FLEXLOOP_PYTHON").unwrap_or_else(|_| venv.display().to_string());
    let probe = Command::new(&python)
        .args(["-c", "import numpy, scipy.io"])
        .output();
    match probe {
        Ok(out) if out.status.success() => python,
        Ok(out) => panic!(
            "{python} cannot import numpy and scipy ({}); run the tests with tools/test, which installs tools/python-requirements.txt",
            String::from_utf8_lossy(&out.stderr).trim()
        ),
        Err(e) => panic!(
            "{python}: {e}; run the tests with tools/test (it makes that venv), or set FLEXLOOP_PYTHON to a Python with tools/python-requirements.txt"
        ),
    }
}

/// The directory of the files tests/write_models.py writes, once per run.
fn models() -> &'static Path {
    static MODELS: OnceLock<PathBuf> = OnceLock::new();
    MODELS.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("official-writers-{}", std::process::id()));
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/write_models.py");
        let out = Command::new(python())
            .arg(&script)
            .arg(&dir)
            .output()
            .unwrap_or_else(|e| panic!("{}: {e}", script.display()));
        assert!(
            out.status.success(),
            "{} failed:\n{}",
            script.display(),
            String::from_utf8_lossy(&out.stderr)
        );
        dir
    })
}

fn read(file: &str) -> ModelArrays {
    let path = models().join(file);
    ModelArrays::read(&path).unwrap_or_else(|e| panic!("{e}"))
}

fn matrix(rows: usize, columns: usize, row_major: &[f64]) -> DMatrix<f64> {
    DMatrix::from_row_slice(rows, columns, row_major)
}

/// The arrays of write_models.py's `second_order()`, computed as NumPy does
/// (each entry one IEEE operation, so equal to the last bit).
fn second_order() -> [(&'static str, DMatrix<f64>); 5] {
    let m = matrix(3, 3, &[1.5, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 2.0]);
    let k = matrix(
        3,
        3,
        &[
            3.0e4, -3.0e4, 0.0, -3.0e4, 5.0e4, -2.0e4, 0.0, -2.0e4, 2.0e4,
        ],
    );
    let d = k.map(|v| 1e-3 * v)
        + DMatrix::from_diagonal(&nalgebra::DVector::from_row_slice(&[0.1, 0.2, 0.3]));
    let b = matrix(3, 1, &[1.0, 0.0, -1.0 / 3.0]);
    let c = matrix(1, 3, &[0.0, 0.1, 1.0 / 7.0]);
    [("M", m), ("K", k), ("D", d), ("B", b), ("C", c)]
}

#[test]
fn second_order_models_read_back_exactly() {
    for file in [
        "second_order.npz",
        "second_order_compressed.npz",
        "second_order_plain.mat",
        "second_order_compressed.mat",
        "via_loadmat.npz",
    ] {
        let arrays = read(file);
        assert_eq!(arrays.names(), ["B", "C", "D", "K", "M"], "{file}");
        for (name, expected) in second_order() {
            let vector = if name == "C" {
                VectorAs::Row
            } else {
                VectorAs::Column
            };
            assert_eq!(
                arrays.matrix(name, vector).unwrap(),
                expected,
                "{file}: {name}"
            );
        }
        assert!(
            arrays.unused(&["M", "K", "D", "B", "C"]).is_empty(),
            "{file}"
        );
    }
}

#[test]
fn state_space_models_read_back_exactly() {
    let a = matrix(2, 2, &[0.0, 1.0, -4.0e3, -0.7]);
    for file in [
        "state_space.npz",
        "state_space_plain.mat",
        "state_space_compressed.mat",
    ] {
        let arrays = read(file);
        assert_eq!(arrays.names(), ["A", "B", "C", "D", "ts"], "{file}");
        assert_eq!(arrays.matrix("A", VectorAs::Column).unwrap(), a, "{file}");
        assert_eq!(
            arrays.matrix("D", VectorAs::Column).unwrap(),
            matrix(1, 1, &[0.0])
        );
        assert_eq!(arrays.scalar("ts").unwrap(), Some(1e-4), "{file}");
        assert_eq!(
            arrays.matrix("C", VectorAs::Row).unwrap(),
            matrix(1, 2, &[1.0, 1e-300]),
            "{file}"
        );
        // The 1-D B: .npz keeps it 1-D, taken as the column asked for;
        // savemat writes a 1-D array as a 1×n row (its oned_as='row'), a
        // matrix the caller gets as written.
        let b = arrays.matrix("B", VectorAs::Column).unwrap();
        if file.ends_with(".npz") {
            assert_eq!(b, matrix(2, 1, &[0.0, 2.5]));
        } else {
            assert_eq!(b, matrix(1, 2, &[0.0, 2.5]));
        }
    }
}

#[test]
fn fortran_order_integers_booleans_and_singles_read_as_numbers() {
    let arrays = read("layouts.npz");
    let f: Vec<f64> = (0..12).map(|i| f64::from(i) + 0.5).collect();
    assert_eq!(arrays.array("F").unwrap().shape(), &[3, 4]);
    assert_eq!(
        arrays.matrix("F", VectorAs::Column).unwrap(),
        matrix(3, 4, &f)
    );
    for file in ["layouts.npz", "layouts.mat"] {
        let arrays = read(file);
        assert_eq!(
            arrays.matrix("I", VectorAs::Column).unwrap(),
            matrix(2, 3, &[1.0, -2.0, 3.0, 4.0, 5.0, -6.0]),
            "{file}"
        );
        assert_eq!(
            arrays.matrix("U", VectorAs::Row).unwrap(),
            matrix(1, 2, &[7.0, 8.0])
        );
        assert_eq!(
            arrays.matrix("L", VectorAs::Row).unwrap(),
            matrix(1, 3, &[1.0, 0.0, 1.0]),
            "{file}"
        );
        assert_eq!(arrays.scalar("S").unwrap(), Some(0.25), "{file}");
    }
}

#[test]
fn arrays_that_are_not_real_numbers_are_refused_naming_them() {
    let cases = [
        ("complex.npz", "Z", "has complex entries"),
        ("text.npz", "T", "is text (dtype <U1), not numbers"),
        ("complex.mat", "Z", "has complex entries"),
        ("sparse.mat", "K", "is a sparse matrix"),
        ("text.mat", "T", "is text (a char array), not numbers"),
        ("cell.mat", "X", "is a cell array, not numbers"),
    ];
    for (file, name, reason) in cases {
        let message = read(file)
            .matrix(name, VectorAs::Column)
            .unwrap_err()
            .to_string();
        let expected = format!(
            "{}: array `{name}`: {reason}",
            models().join(file).display()
        );
        assert!(message.starts_with(&expected), "{message}");
    }
    // matrw 0.1.4 misreads the short field names scipy writes in a struct
    // (MATLAB writes them long); flexloop tells a struct by its class
    // before matrw sees it, so the struct is named as any other entry.
    let message = read("struct.mat")
        .matrix("P", VectorAs::Column)
        .unwrap_err()
        .to_string();
    assert!(
        message.ends_with("array `P`: is a struct, not numbers"),
        "{message}"
    );
}

#[test]
fn a_level_4_file_gets_the_instruction_to_save_with_v7() {
    let error = ModelArrays::read(&models().join("level4.mat")).unwrap_err();
    assert_eq!(error.kind, ModelFileErrorKind::MatLevel4);
    assert!(
        error.to_string().contains("save plant.mat A B C D -v7"),
        "{error}"
    );
}

/// Every truncation of every official file: an error from flexloop's checks
/// (never a panic, never a reader's failure), or, a MAT-file cut exactly
/// between variables, the variables before the cut.
#[test]
fn truncated_files_are_errors() {
    let mut files: Vec<PathBuf> = std::fs::read_dir(models())
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| !path.ends_with("struct.mat") && !path.ends_with("level4.mat"))
        .collect();
    files.sort();
    assert_eq!(files.len(), 16, "{files:?}");
    for file in files {
        let bytes = std::fs::read(&file).unwrap();
        let whole = ModelArrays::read(&file).unwrap();
        let format = if file.extension().unwrap() == "mat" {
            FileFormat::Mat
        } else {
            FileFormat::Npz
        };
        for len in 0..bytes.len() {
            let source = ArraySource::File(file.clone());
            match ModelArrays::from_bytes(source, format, &bytes[..len]) {
                Ok(part) => {
                    assert!(
                        format == FileFormat::Mat
                            && part.names().len() < whole.names().len()
                            && part.names().iter().all(|n| whole.names().contains(n)),
                        "{} cut at {len}: {:?}",
                        file.display(),
                        part.names()
                    );
                }
                Err(e) => {
                    let message = e.to_string();
                    assert!(
                        !message.contains("cannot be read:") && !message.contains("stopped on"),
                        "{} cut at {len}: {message}",
                        file.display()
                    );
                }
            }
        }
    }
}
