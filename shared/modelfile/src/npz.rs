//! NumPy `.npz`: a zip archive (the `zip` crate) of `.npy` arrays (the `npyz`
//! crate), as `np.savez` and `np.savez_compressed` write it.

use std::io::{Cursor, Read};

use npyz::{DType, NpyFile, Order, TypeChar};

use crate::array::{Array, check_shape, signed_to_f64, unsigned_to_f64};
use crate::error::{FileFormat, ModelFileErrorKind};
use crate::limits::{MAX_ARRAY_BYTES, MAX_ARRAYS};
use crate::read::{Entry, Fault, NamedArrays, catch};

/// The names scipy.io.loadmat adds to the variables of a MAT-file: a model
/// saved with `np.savez(path, **scipy.io.loadmat(mat))` carries them, and
/// they are no arrays of the model (neither MATLAB's save nor savemat writes
/// them into a .mat).
const LOADMAT_METADATA: [&str; 3] = ["__header__", "__version__", "__globals__"];

/// What is inflated of a member declared beyond the cap, for its `.npy`
/// header's shape (NumPy pads the header to 64 bytes; a shape of two
/// dimensions takes about 128).
const NPY_HEADER_PREFIX: u64 = 4096;

/// The arrays of an `.npz` archive, named as `np.load` names them (the member
/// name without `.npy`), less scipy.io.loadmat's metadata.
pub(crate) fn read(bytes: &[u8]) -> Result<NamedArrays, Fault> {
    // The count the archive's end record declares, before the zip crate
    // reads its whole directory (180 000 empty members fit in the file cap,
    // and take it a second and 60 MB to list).
    if let Some(count) = declared_members(bytes)
        && count > MAX_ARRAYS as u64
    {
        return Err(Fault::file(ModelFileErrorKind::TooManyArrays {
            count: Some(count),
        }));
    }
    let mut archive = zip::ZipArchive::new(Cursor::new(bytes))
        .map_err(|e| Fault::file(corrupt(format!("not a zip archive ({e})"))))?;
    if archive.len() > MAX_ARRAYS {
        return Err(Fault::file(ModelFileErrorKind::TooManyArrays {
            count: Some(archive.len() as u64),
        }));
    }
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
        // The size the archive declares, then what the member inflates to
        // whatever it declares (a zip bomb): neither beyond one array's cap.
        // A member declared beyond it is read no further than its header,
        // whose shape tells the user more than a byte count (a model of
        // 1000 degrees of freedom, where flexloop takes 64).
        let declared = member.size();
        let read_at_most = if declared > MAX_ARRAY_BYTES {
            NPY_HEADER_PREFIX
        } else {
            MAX_ARRAY_BYTES + 1
        };
        // The zip crate checks the member's CRC as its last bytes are read: a
        // damaged member fails here rather than giving wrong numbers.
        let mut npy = Vec::new();
        (&mut member)
            .take(read_at_most)
            .read_to_end(&mut npy)
            .map_err(|e| Fault::array(&name, corrupt(format!("cannot extract the array ({e})"))))?;
        let too_large = |kind| Fault::array(&name, kind);
        if let Some(shape) = declared_shape(&npy) {
            check_shape(&shape).map_err(too_large)?;
        }
        if declared > MAX_ARRAY_BYTES {
            return Err(too_large(ModelFileErrorKind::ArrayDataTooLarge {
                bytes: Some(declared),
            }));
        }
        if npy.len() as u64 > MAX_ARRAY_BYTES {
            return Err(too_large(ModelFileErrorKind::ArrayDataTooLarge {
                bytes: None,
            }));
        }
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
    // The header's shape, before npyz multiplies it out (unchecked) or
    // anything is read or allocated for it; again as npyz reads it.
    if let Some(shape) = declared_shape(bytes) {
        check_shape(&shape)?;
    }
    let npy =
        NpyFile::new(bytes).map_err(|e| corrupt(format!("not a readable .npy array ({e})")))?;
    check_shape(npy.shape())?;
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

/// The number of members the end-of-central-directory record of a zip
/// archive declares: the last record whose comment ends the file (APPNOTE
/// 4.3.16), where it is told without the zip crate; `None` for a zip64
/// archive (0xFFFF there) or none found, which the zip crate then reads.
fn declared_members(zip: &[u8]) -> Option<u64> {
    const SIGNATURE: &[u8] = b"PK\x05\x06";
    const RECORD: usize = 22;
    let earliest = zip.len().saturating_sub(RECORD + usize::from(u16::MAX));
    let at = (earliest..=zip.len().checked_sub(RECORD)?)
        .rev()
        .find(|&at| {
            let comment = usize::from(u16::from_le_bytes([zip[at + 20], zip[at + 21]]));
            zip[at..].starts_with(SIGNATURE) && at + RECORD + comment == zip.len()
        })?;
    let field = |i: usize| u16::from_le_bytes([zip[at + i], zip[at + i + 1]]);
    let count = field(8).max(field(10));
    if count != u16::MAX {
        return Some(u64::from(count));
    }
    // Zip64: the locator just before the record points to the zip64 end
    // record, which holds the counts as 64-bit numbers (APPNOTE 4.3.14–15).
    let u64_at = |i: usize| Some(u64::from_le_bytes(zip.get(i..i + 8)?.try_into().ok()?));
    let locator = at.checked_sub(20)?;
    if !zip[locator..].starts_with(b"PK\x06\x07") {
        return None;
    }
    let record = usize::try_from(u64_at(locator + 8)?).ok()?;
    if !zip.get(record..)?.starts_with(b"PK\x06\x06") {
        return None;
    }
    Some(u64_at(record + 24)?.max(u64_at(record + 32)?))
}

/// The shape a `.npy` header declares (its `'shape': (…)` entry, read as
/// plainly as the format writes it), if it can be told without npyz; a
/// number too large for a `u64` is `u64::MAX`.
fn declared_shape(npy: &[u8]) -> Option<Vec<u64>> {
    let rest = npy.strip_prefix(b"\x93NUMPY")?;
    let (&major, rest) = rest.split_first()?;
    let rest = rest.get(1..)?;
    let (len, rest) = match major {
        1 => (
            usize::from(u16::from_le_bytes([*rest.first()?, *rest.get(1)?])),
            rest.get(2..)?,
        ),
        _ => {
            let len: [u8; 4] = rest.get(..4)?.try_into().ok()?;
            (
                usize::try_from(u32::from_le_bytes(len)).ok()?,
                rest.get(4..)?,
            )
        }
    };
    let header = std::str::from_utf8(rest.get(..len)?).ok()?;
    let at = header
        .find("'shape':")
        .or_else(|| header.find("\"shape\":"))?;
    let tuple = header[at..].split_once('(')?.1.split_once(')')?.0;
    tuple
        .split(',')
        .map(str::trim)
        .filter(|n| !n.is_empty())
        .map(|n| match n.parse::<u64>() {
            Ok(n) => Some(n),
            Err(_) if n.bytes().all(|b| b.is_ascii_digit()) => Some(u64::MAX),
            Err(_) => None,
        })
        .collect()
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
    fn declared_shapes_and_member_counts_are_read_before_the_readers() {
        assert_eq!(
            declared_shape(&npy("<f8", false, "(3, 4)", &[])),
            Some(vec![3, 4])
        );
        assert_eq!(declared_shape(&npy("<f8", false, "()", &[])), Some(vec![]));
        assert_eq!(
            declared_shape(&npy("<f8", false, "(99999999999999999999999,)", &[])),
            Some(vec![u64::MAX])
        );
        assert_eq!(declared_shape(b"\x93NUMPY\x01\x00\xff\xff{'shape"), None);
        assert_eq!(declared_shape(b"not an array"), None);
        let members: Vec<(String, Vec<u8>)> = (0..3)
            .map(|i| (format!("x{i}.npy"), npy("<f8", false, "()", &f64s(&[1.0]))))
            .collect();
        let members: Vec<(&str, Vec<u8>)> = members
            .iter()
            .map(|(n, b)| (n.as_str(), b.clone()))
            .collect();
        let file = npz(&members, true);
        assert_eq!(declared_members(&file), Some(3));
        assert_eq!(declared_members(&file[..file.len() - 1]), None);
        assert_eq!(declared_members(b"PK"), None);
        // A shape beyond the bound is refused naming the array, before its data.
        let huge = npz(&[("K.npy", npy("<f8", false, "(129, 129)", &[]))], false);
        assert_eq!(
            message(read(&huge)),
            "t.npz: array `K`: declares 129×129 entries, more than any model array flexloop \
             takes: at most 128 in each dimension (the loop carries at most 128 states: a \
             state-space model of 128 states, a second-order one of 64 degrees of freedom, at \
             most 8 inputs and 8 outputs); it is not read"
        );
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
