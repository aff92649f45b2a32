//! NumPy `.npz`: a zip archive (the `zip` crate) of `.npy` arrays (the `npyz`
//! crate), as `np.savez` and `np.savez_compressed` write it.

use std::io::{Cursor, Read};

use npyz::{DType, NpyFile, Order, TypeChar};

use crate::array::{Array, signed_to_f64, unsigned_to_f64};
use crate::error::{FileFormat, ModelFileErrorKind};
use crate::read::{Entry, Fault, NamedArrays, catch};

/// The names scipy.io.loadmat adds to the variables of a MAT-file: a model
/// saved with `np.savez(path, **scipy.io.loadmat(mat))` carries them, and
/// they are no arrays of the model (neither MATLAB's save nor savemat writes
/// them into a .mat).
const LOADMAT_METADATA: [&str; 3] = ["__header__", "__version__", "__globals__"];

/// The arrays of an `.npz` archive, named as `np.load` names them (the member
/// name without `.npy`), less scipy.io.loadmat's metadata.
pub(crate) fn read(bytes: &[u8]) -> Result<NamedArrays, Fault> {
    let mut archive = zip::ZipArchive::new(Cursor::new(bytes))
        .map_err(|e| Fault::file(corrupt(format!("not a zip archive ({e})"))))?;
    let mut arrays = NamedArrays::new();
    for index in 0..archive.len() {
        let mut member = archive
            .by_index(index)
            .map_err(|e| Fault::file(corrupt(format!("member {}: {e}", index + 1))))?;
        let member_name = member
            .name()
            .map_err(|e| Fault::file(corrupt(format!("member {}: {e}", index + 1))))?
            .into_owned();
        if LOADMAT_METADATA
            .iter()
            .any(|m| member_name == format!("{m}.npy"))
        {
            continue;
        }
        let Some(name) = member_name.strip_suffix(".npy").map(str::to_string) else {
            let refused = Err(ModelFileErrorKind::NotNumeric {
                found: "a member of the archive that is not a .npy array".into(),
            });
            arrays.insert(member_name, refused)?;
            continue;
        };
        // The zip crate checks the member's CRC as its last bytes are read: a
        // damaged member fails here rather than giving wrong numbers.
        let mut npy = Vec::new();
        member
            .read_to_end(&mut npy)
            .map_err(|e| Fault::array(&name, corrupt(format!("cannot extract the array ({e})"))))?;
        let entry = catch(|| read_npy(&npy))
            .unwrap_or_else(|| Err(corrupt("the .npy reader stopped on malformed data".into())))
            .map_err(|kind| Fault::array(&name, kind))?;
        arrays.insert(name, entry)?;
    }
    Ok(arrays)
}

/// One `.npy` array (any byte order, C or Fortran order, numbers or
/// booleans), or why it is not one; `Err` if the bytes are not a `.npy` array.
fn read_npy(bytes: &[u8]) -> Result<Entry, ModelFileErrorKind> {
    let npy =
        NpyFile::new(bytes).map_err(|e| corrupt(format!("not a readable .npy array ({e})")))?;
    let shape = npy
        .shape()
        .iter()
        .map(|&n| usize::try_from(n))
        .collect::<Result<Vec<usize>, _>>()
        .map_err(|_| corrupt("an array dimension too large for this machine".into()))?;
    let order = npy.order();
    let type_str = match npy.dtype() {
        DType::Plain(type_str) => type_str,
        DType::Array(..) | DType::Record(_) => {
            return Ok(Err(not_numeric("a structured (record) array".into())));
        }
    };
    let converted = match (type_str.type_char(), type_str.size_field()) {
        (TypeChar::Float, 8) => Ok(values::<f64>(npy)?),
        (TypeChar::Float, 4) => Ok(values::<f32>(npy)?.into_iter().map(f64::from).collect()),
        (TypeChar::Int, 1) => signed(values::<i8>(npy)?),
        (TypeChar::Int, 2) => signed(values::<i16>(npy)?),
        (TypeChar::Int, 4) => signed(values::<i32>(npy)?),
        (TypeChar::Int, 8) => signed_to_f64(&values::<i64>(npy)?),
        (TypeChar::Uint, 1) => unsigned(values::<u8>(npy)?),
        (TypeChar::Uint, 2) => unsigned(values::<u16>(npy)?),
        (TypeChar::Uint, 4) => unsigned(values::<u32>(npy)?),
        (TypeChar::Uint, 8) => unsigned_to_f64(&values::<u64>(npy)?),
        (TypeChar::Bool, 1) => Ok(values::<bool>(npy)?
            .into_iter()
            .map(|b| if b { 1.0 } else { 0.0 })
            .collect()),
        (TypeChar::Complex, _) => Err(ModelFileErrorKind::Complex),
        (TypeChar::Float | TypeChar::Int | TypeChar::Uint | TypeChar::Bool, _) => {
            Err(ModelFileErrorKind::UnsupportedNumberType {
                dtype: type_str.to_string(),
            })
        }
        (TypeChar::ByteStr | TypeChar::UnicodeStr, _) => {
            Err(not_numeric(format!("text (dtype {type_str})")))
        }
        (TypeChar::Object, _) => Err(not_numeric(
            "an array of Python objects (dtype object)".into(),
        )),
        (TypeChar::TimeDelta | TypeChar::DateTime, _) => {
            Err(not_numeric(format!("dates or times (dtype {type_str})")))
        }
        _ => Err(not_numeric(format!("of dtype {type_str}"))),
    };
    let data = match converted {
        Ok(data) => data,
        Err(refused) => return Ok(Err(refused)),
    };
    let array = match order {
        Order::C => Array::new(shape, data),
        Order::Fortran => Array::from_column_major(shape, data),
    };
    array
        .map(Ok)
        .ok_or_else(|| corrupt("the data do not fill the array's shape".into()))
}

/// Every entry of `npy` as `T` (the caller matched the dtype to `T`); `Err`
/// if the data are shorter than the shape or not of the dtype.
fn values<T: npyz::Deserialize>(npy: NpyFile<&[u8]>) -> Result<Vec<T>, ModelFileErrorKind> {
    npy.into_vec::<T>()
        .map_err(|e| corrupt(format!("cannot read the array's data ({e})")))
}

fn signed<T: Into<i64>>(values: Vec<T>) -> Result<Vec<f64>, ModelFileErrorKind> {
    let wide: Vec<i64> = values.into_iter().map(Into::into).collect();
    signed_to_f64(&wide)
}

fn unsigned<T: Into<u64>>(values: Vec<T>) -> Result<Vec<f64>, ModelFileErrorKind> {
    let wide: Vec<u64> = values.into_iter().map(Into::into).collect();
    unsigned_to_f64(&wide)
}

fn not_numeric(found: String) -> ModelFileErrorKind {
    ModelFileErrorKind::NotNumeric { found }
}

fn corrupt(reason: String) -> ModelFileErrorKind {
    ModelFileErrorKind::Corrupt {
        format: FileFormat::Npz,
        reason,
    }
}

#[cfg(test)]
mod tests {
    use std::io::Write;

    use zip::write::SimpleFileOptions;

    use super::*;
    use crate::error::ArraySource;

    /// A `.npy` array as the format's specification lays it out (version 1.0:
    /// magic, header length, the header dict padded to 64 bytes, the data),
    /// made here so that the reader is checked against the format, not
    /// against npyz's own writer.
    fn npy(descr: &str, fortran_order: bool, shape: &str, data: &[u8]) -> Vec<u8> {
        let order = if fortran_order { "True" } else { "False" };
        let mut dict =
            format!("{{'descr': '{descr}', 'fortran_order': {order}, 'shape': {shape}, }}");
        while (10 + dict.len() + 1) % 64 != 0 {
            dict.push(' ');
        }
        dict.push('\n');
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend_from_slice(&u16::try_from(dict.len()).unwrap().to_le_bytes());
        bytes.extend_from_slice(dict.as_bytes());
        bytes.extend_from_slice(data);
        bytes
    }

    fn f64s(values: &[f64]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    /// An archive of `members` (name, bytes), stored or deflated.
    fn npz(members: &[(&str, Vec<u8>)], deflated: bool) -> Vec<u8> {
        let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
        let method = if deflated {
            zip::CompressionMethod::Deflated
        } else {
            zip::CompressionMethod::Stored
        };
        for (name, bytes) in members {
            zip.start_file(
                *name,
                SimpleFileOptions::default().compression_method(method),
            )
            .unwrap();
            zip.write_all(bytes).unwrap();
        }
        zip.finish().unwrap().into_inner()
    }

    fn entry(arrays: &NamedArrays, name: &str) -> Entry {
        arrays
            .0
            .get(name)
            .cloned()
            .unwrap_or_else(|| panic!("no {name}"))
    }

    fn message(result: Result<NamedArrays, Fault>) -> String {
        match result {
            Ok(arrays) => panic!("read: {:?}", arrays.0.keys()),
            Err(fault) => fault.at(&ArraySource::File("t.npz".into())).to_string(),
        }
    }

    #[test]
    fn orders_byte_orders_and_number_types_read_as_row_major_f64() {
        // [[1, 2, 3], [4, 5, 6]] stored column by column.
        let fortran = npy(
            "<f8",
            true,
            "(2, 3)",
            &f64s(&[1.0, 4.0, 2.0, 5.0, 3.0, 6.0]),
        );
        let c = npy(
            "<f8",
            false,
            "(2, 3)",
            &f64s(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
        );
        let big: Vec<u8> = [1.5f64, -2.0]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let ints: Vec<u8> = [-7i32, 9].iter().flat_map(|v| v.to_le_bytes()).collect();
        let bools = vec![1u8, 0, 1];
        let single = 0.25f32.to_le_bytes().to_vec();
        let file = npz(
            &[
                ("F.npy", fortran),
                ("C.npy", c),
                ("big.npy", npy(">f8", false, "(2,)", &big)),
                ("ints.npy", npy("<i4", false, "(2,)", &ints)),
                ("bools.npy", npy("|b1", false, "(3,)", &bools)),
                ("single.npy", npy("<f4", false, "()", &single)),
            ],
            true,
        );
        let arrays = read(&file).unwrap();
        let six = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        assert_eq!(
            entry(&arrays, "F").unwrap(),
            Array::new(vec![2, 3], six.to_vec()).unwrap()
        );
        assert_eq!(
            entry(&arrays, "C").unwrap(),
            Array::new(vec![2, 3], six.to_vec()).unwrap()
        );
        assert_eq!(entry(&arrays, "big").unwrap().data(), &[1.5, -2.0]);
        assert_eq!(entry(&arrays, "ints").unwrap().data(), &[-7.0, 9.0]);
        assert_eq!(entry(&arrays, "bools").unwrap().data(), &[1.0, 0.0, 1.0]);
        let single = entry(&arrays, "single").unwrap();
        assert_eq!((single.shape(), single.data()), (&[][..], &[0.25][..]));
    }

    #[test]
    fn arrays_that_are_not_real_numbers_are_refused_each_with_its_reason() {
        let huge: Vec<u8> = [(1i64 << 53) + 1]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let file = npz(
            &[
                ("Z.npy", npy("<c16", false, "(1,)", &f64s(&[1.0, 2.0]))),
                ("T.npy", npy("<U1", false, "(1,)", &[b'M', 0, 0, 0])),
                ("O.npy", npy("|O", false, "(1,)", b"\x80\x02N.")),
                ("H.npy", npy("<f2", false, "(1,)", &[0, 0x3c])),
                ("N.npy", npy("<i8", false, "(1,)", &huge)),
                ("notes.txt", b"a model".to_vec()),
                ("__header__.npy", npy("|S5", false, "()", b"MATLA")),
            ],
            false,
        );
        let arrays = read(&file).unwrap();
        assert_eq!(
            arrays.0.len(),
            6,
            "loadmat's __header__ is no array of the model"
        );
        assert_eq!(entry(&arrays, "Z"), Err(ModelFileErrorKind::Complex));
        assert_eq!(
            entry(&arrays, "T"),
            Err(not_numeric("text (dtype <U1)".into()))
        );
        assert_eq!(
            entry(&arrays, "O"),
            Err(not_numeric(
                "an array of Python objects (dtype object)".into()
            ))
        );
        assert_eq!(
            entry(&arrays, "H"),
            Err(ModelFileErrorKind::UnsupportedNumberType {
                dtype: "<f2".into()
            })
        );
        assert_eq!(
            entry(&arrays, "N"),
            Err(ModelFileErrorKind::InexactInteger {
                value: "9007199254740993".into()
            })
        );
        assert!(matches!(
            entry(&arrays, "notes.txt"),
            Err(ModelFileErrorKind::NotNumeric { .. })
        ));
    }

    #[test]
    fn a_damaged_or_foreign_file_is_an_error_naming_it() {
        let short = npz(
            &[("M.npy", npy("<f8", false, "(2, 2)", &f64s(&[1.0; 3])))],
            false,
        );
        assert!(
            message(read(&short)).starts_with(
                "t.npz: array `M`: not a readable NumPy .npz archive: cannot read the array's data"
            ),
            "{}",
            message(read(&short))
        );
        // The zip crate refuses two members of one name; `M.npy` and `M`
        // are two names for `np.load`'s one.
        let twice = npz(
            &[
                ("M.npy", npy("<f8", false, "()", &f64s(&[1.0]))),
                ("M", b"M again".to_vec()),
            ],
            false,
        );
        assert_eq!(message(read(&twice)), "t.npz: array `M`: is given twice");
        assert!(message(read(b"MATLAB 5.0 MAT-file")).contains("not a zip archive"));
    }

    #[test]
    fn truncated_archives_are_errors() {
        for deflated in [false, true] {
            let file = npz(
                &[
                    (
                        "M.npy",
                        npy("<f8", true, "(2, 2)", &f64s(&[1.0, 0.0, 0.0, 2.0])),
                    ),
                    ("B.npy", npy("<f8", false, "(2,)", &f64s(&[0.0, 1.0]))),
                ],
                deflated,
            );
            assert_eq!(read(&file).unwrap().0.len(), 2);
            for len in 0..file.len() {
                let text = message(read(&file[..len]));
                assert!(
                    !text.contains("stopped on malformed data"),
                    "cut at {len}: {text}"
                );
            }
        }
    }
}
