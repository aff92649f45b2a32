//! NumPy `.npz`: a zip archive (the `zip` crate) of `.npy` arrays (the `npyz`
//! crate), as `np.savez` and `np.savez_compressed` write it.

use std::io::{Cursor, Read};

use npyz::{DType, NpyFile, Order, TypeChar};

use crate::array::{Array, signed_to_f64, unsigned_to_f64};
use crate::error::{FileFormat, ModelFileErrorKind};
use crate::read::{Entry, Fault, NamedArrays, catch};

/// The arrays of an `.npz` archive, named as `np.load` names them (the member
/// name without `.npy`).
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
