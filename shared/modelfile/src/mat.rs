//! MATLAB level-5 MAT-files (`save` by default, `-v7` compressed and `-v6`
//! not; scipy.io.savemat), read by the `matrw` crate. flexloop checks the
//! 128-byte header and the framing of the top-level elements itself, for the
//! messages and the safety the crate does not give:
//! - the header: a v7.3 file (HDF5) or a level-4 file gets the instruction to
//!   save with `-v7`; matrw wants the descriptive text to begin exactly with
//!   `MATLAB 5.0 MAT-file, ` (MATLAB's own), which scipy's does not
//!   (`MATLAB 5.0 MAT-file Platform: posix, ...`), though the MAT-file
//!   format (MathWorks, "MAT-File Format", Level 5 header) leaves that text
//!   free: only the version and the endian indicator are read from it;
//! - the framing: matrw takes an early end of the file for the end of the
//!   variable list, so a truncated file would read as one with fewer arrays
//!   (an optional `D` would silently vanish); each top-level element's byte
//!   count is checked against the file, and matrw reads each element on its
//!   own and must find exactly one variable in it;
//! - the sizes (docs/own-plant.md): at most [`MAX_ARRAYS`] variables; a compressed
//!   variable is inflated here, never beyond [`MAX_ARRAY_BYTES`] whatever it
//!   holds (matrw would inflate all of it), and matrw is handed the
//!   uncompressed element; each variable's array flags, dimensions and name
//!   are read here, the dimensions checked against what flexloop takes
//!   ([`check_shape`]) and the data's byte count against the element, before
//!   matrw allocates anything for them;
//! - the classes: a cell, struct, object, char or sparse array is told by
//!   its class and named, without matrw (which misreads the short struct
//!   field names scipy writes); matrw reads numeric arrays only.

use matrw::{MatVariable, MatlabType, NumericArray};

use crate::array::{Array, check_shape, signed_to_f64, unsigned_to_f64};
use crate::error::{FileFormat, ModelFileErrorKind};
use crate::limits::{MAX_ARRAY_BYTES, MAX_ARRAYS};
use crate::read::{Entry, Fault, NamedArrays, catch};

/// The level-5 header: 116 bytes of text, 8 of subsystem data offset, 2 of
/// version, 2 of endian indicator.
const HEADER_LEN: usize = 128;
const SUBSYSTEM_OFFSET: std::ops::Range<usize> = 116..124;
const VERSION: std::ops::Range<usize> = 124..126;
const ENDIAN: std::ops::Range<usize> = 126..128;
/// The header's version field of a level-5 file, and of a v7.3 (HDF5) one.
const VERSION_5: u16 = 0x0100;
const VERSION_7_3: u16 = 0x0200;
/// A v7.3 file is HDF5 with the MAT-file header in its 512-byte user block.
const HDF5_SIGNATURE: &[u8] = b"\x89HDF\r\n\x1a\n";
const HDF5_SIGNATURE_AT: usize = 512;
/// The data types of a variable at the top level of a level-5 file.
const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;
/// The text matrw requires at the start of the header (see the module doc).
const MATRW_TEXT: &[u8] = b"MATLAB 5.0 MAT-file, ";

#[derive(Debug, Clone, Copy)]
enum Endian {
    Little,
    Big,
}

impl Endian {
    fn u16(self, bytes: [u8; 2]) -> u16 {
        match self {
            Endian::Little => u16::from_le_bytes(bytes),
            Endian::Big => u16::from_be_bytes(bytes),
        }
    }

    fn u32(self, bytes: [u8; 4]) -> u32 {
        match self {
            Endian::Little => u32::from_le_bytes(bytes),
            Endian::Big => u32::from_be_bytes(bytes),
        }
    }

    fn u64(self, bytes: [u8; 8]) -> u64 {
        match self {
            Endian::Little => u64::from_le_bytes(bytes),
            Endian::Big => u64::from_be_bytes(bytes),
        }
    }
}

/// The variables of a level-5 MAT-file, by name.
pub(crate) fn read(bytes: &[u8]) -> Result<NamedArrays, Fault> {
    let endian = check_header(bytes)?;
    let end = variables_end(bytes, endian);
    let elements = elements(&bytes[HEADER_LEN..end], endian)?;

    // Each variable is parsed on its own (a header and its one element), so
    // that a variable matrw cannot parse is told by its place in the file
    // and cannot hide the others.
    let mut header = Vec::with_capacity(HEADER_LEN);
    header.extend_from_slice(MATRW_TEXT);
    header.resize(SUBSYSTEM_OFFSET.start, b' ');
    header.resize(VERSION.start, 0);
    header.extend_from_slice(&bytes[VERSION.start..HEADER_LEN]);

    let mut arrays = NamedArrays::new();
    let mut previous: Option<String> = None;
    for (index, element) in elements.iter().enumerate() {
        let unreadable = |previous: &Option<String>, why: &str| {
            let after = previous
                .as_ref()
                .map(|name| format!(" (the one after `{name}`)"))
                .unwrap_or_default();
            Fault::file(corrupt(format!(
                "variable {} of {}{after} cannot be read: {why}",
                index + 1,
                elements.len()
            )))
        };
        let Some(variable) =
            Variable::read(element, endian).map_err(|why| unreadable(&previous, &why))?
        else {
            continue;
        };
        let Some(entry) = variable.entry(&header, endian) else {
            return Err(unreadable(&previous, DAMAGED));
        };
        let name = variable.name;
        arrays.insert(name.clone(), entry?)?;
        previous = Some(name);
    }
    Ok(arrays)
}

/// Why a variable cannot be read, when flexloop's checks or matrw say so.
const DAMAGED: &str = "its data are damaged, or of a kind the reader does not parse (a model \
                       file holds numeric matrices only)";

/// The classes of a level-5 array (the low byte of its array flags).
const MX_CELL: u32 = 1;
const MX_STRUCT: u32 = 2;
const MX_OBJECT: u32 = 3;
const MX_CHAR: u32 = 4;
const MX_SPARSE: u32 = 5;
const MX_NUMERIC: std::ops::RangeInclusive<u32> = 6..=15;
const MX_FUNCTION: u32 = 16;
const MX_OPAQUE: u32 = 17;
/// The complex bit of the array flags' flag byte.
const COMPLEX: u32 = 0x0800;
/// The sub-element data types of the array flags, dimensions and name.
const MI_INT8: u32 = 1;
const MI_INT32: u32 = 5;
const MI_UINT32: u32 = 6;

/// One variable's `miMATRIX` element, uncompressed (a compressed variable
/// inflated, with a bound), and what flexloop reads of its header itself
/// before matrw sees it: the class, the declared dimensions, the name.
struct Variable<'a> {
    /// The `miMATRIX` element: its tag and its bytes, at most as declared.
    element: std::borrow::Cow<'a, [u8]>,
    /// Inflating stopped at [`MAX_ARRAY_BYTES`] before the stream's end.
    inflated_beyond_cap: bool,
    class: u32,
    complex: bool,
    /// None for an opaque object, whose element carries no dimensions.
    dims: Option<Vec<u64>>,
    name: String,
    /// Where the data sub-elements begin, after the name.
    data_at: usize,
}

impl<'a> Variable<'a> {
    /// The variable of a top-level element (framed by [`elements`]); `None`
    /// for an unnamed element, which is not a variable (MATLAB's subsystem
    /// data when the header does not point to it); `Err` saying why it
    /// cannot be read.
    fn read(element: &'a [u8], endian: Endian) -> Result<Option<Self>, String> {
        let (data_type, _) = tag(element, 0, endian).ok_or(DAMAGED)?;
        let (element, inflated_beyond_cap) = if data_type == MI_COMPRESSED {
            let (inflated, beyond) = inflate(&element[8..])?;
            (std::borrow::Cow::Owned(inflated), beyond)
        } else {
            (std::borrow::Cow::Borrowed(element), false)
        };
        let (data_type, size) = tag(&element, 0, endian).ok_or(DAMAGED)?;
        if data_type != MI_MATRIX {
            return Err(format!(
                "it holds data of type {data_type}, not a variable (miMATRIX 14)"
            ));
        }
        let size = usize::try_from(size).unwrap_or(usize::MAX);
        if size > element.len() - 8 && !inflated_beyond_cap {
            return Err(format!(
                "it should have {size} bytes, its compressed data hold {}",
                element.len() - 8
            ));
        }
        // At most the declared bytes (a top-level element may be padded).
        let end = 8 + size.min(element.len() - 8);
        let element = match element {
            std::borrow::Cow::Borrowed(e) => std::borrow::Cow::Borrowed(&e[..end]),
            std::borrow::Cow::Owned(mut e) => {
                e.truncate(end);
                std::borrow::Cow::Owned(e)
            }
        };
        let body = &element[8..];
        let (flags_type, flags, mut at) = sub_element(body, 0, endian).ok_or(DAMAGED)?;
        if flags_type != MI_UINT32 || flags.len() != 8 {
            return Err(DAMAGED.into());
        }
        let flags = endian.u32([flags[0], flags[1], flags[2], flags[3]]);
        let class = flags & 0xff;
        let dims = if class == MX_OPAQUE {
            None
        } else {
            let (dims_type, dims, next) = sub_element(body, at, endian).ok_or(DAMAGED)?;
            if dims_type != MI_INT32 || dims.len() < 8 || dims.len() % 4 != 0 {
                return Err(DAMAGED.into());
            }
            at = next;
            let dims = dims
                .chunks_exact(4)
                .map(|d| u64::try_from(endian.u32([d[0], d[1], d[2], d[3]]) as i32).ok())
                .collect::<Option<Vec<u64>>>()
                .ok_or("it declares a negative dimension")?;
            Some(dims)
        };
        let (name_type, name, data_at) = sub_element(body, at, endian).ok_or(DAMAGED)?;
        if name_type != MI_INT8 {
            return Err(DAMAGED.into());
        }
        let name = String::from_utf8_lossy(name).into_owned();
        if name.is_empty() {
            return Ok(None);
        }
        Ok(Some(Self {
            element,
            inflated_beyond_cap,
            class,
            complex: flags & COMPLEX != 0,
            dims,
            name,
            data_at,
        }))
    }

    /// The variable as an array, or why it is not one; `Err` when the whole
    /// file is refused for it (an array beyond what flexloop takes); `None`
    /// if its data cannot be read (matrw fails or panics).
    fn entry(&self, header: &[u8], endian: Endian) -> Option<Result<Entry, Fault>> {
        let refused = |kind| Some(Ok(Err(kind)));
        match self.class {
            MX_CELL => return refused(not_numeric("a cell array")),
            MX_STRUCT => return refused(not_numeric("a struct")),
            MX_OBJECT | MX_FUNCTION | MX_OPAQUE => {
                return refused(not_numeric("an object or another unsupported MATLAB class"));
            }
            MX_CHAR => return refused(not_numeric("text (a char array)")),
            MX_SPARSE => return refused(ModelFileErrorKind::Sparse),
            class if MX_NUMERIC.contains(&class) => {}
            _ => return None,
        }
        // The declared dimensions first, then what the data take: nothing
        // of an array beyond what flexloop takes reaches matrw.
        let too_large = |kind| Some(Err(Fault::array(&self.name, kind)));
        if let Err(kind) = check_shape(self.dims.as_deref().unwrap_or_default()) {
            return too_large(kind);
        }
        if self.inflated_beyond_cap {
            return too_large(ModelFileErrorKind::ArrayDataTooLarge { bytes: None });
        }
        let stored = self.element.len() as u64 - 8;
        if stored > MAX_ARRAY_BYTES {
            return too_large(ModelFileErrorKind::ArrayDataTooLarge {
                bytes: Some(stored),
            });
        }
        if self.complex {
            return refused(ModelFileErrorKind::Complex);
        }
        // The real part's byte count must lie within the element, so that
        // matrw allocates no more than the file holds.
        sub_element(&self.element[8..], self.data_at, endian)?;
        let (name, variable) = parse_one(header, &self.element)?;
        (name == self.name).then_some(Ok(array_of(variable)))
    }
}

/// The tag at `at` of `bytes`: its data type and byte count (the long form
/// only, as a top-level element's).
fn tag(bytes: &[u8], at: usize, endian: Endian) -> Option<(u32, u32)> {
    let word = |i: usize| -> Option<u32> {
        let w = bytes.get(at + i..at + i + 4)?;
        Some(endian.u32([w[0], w[1], w[2], w[3]]))
    };
    Some((word(0)?, word(4)?))
}

/// The sub-element at `at` of a `miMATRIX` element's body: its data type,
/// its data, and where the next begins (after the padding to 8 bytes);
/// `None` if it does not lie within the body. The small form (a byte count
/// of 1 to 4 in the upper half of the first word, the data in the second)
/// included.
fn sub_element(body: &[u8], at: usize, endian: Endian) -> Option<(u32, &[u8], usize)> {
    let (first, second) = tag(body, at, endian)?;
    if first >> 16 != 0 {
        let len = (first >> 16) as usize;
        if len > 4 {
            return None;
        }
        return Some((first & 0xffff, &body[at + 4..at + 4 + len], at + 8));
    }
    let len = usize::try_from(second).ok()?;
    let start = at + 8;
    let data = body.get(start..start.checked_add(len)?)?;
    let next = (start + len).next_multiple_of(8).min(body.len());
    Some((first, data, next))
}

/// The zlib stream of a compressed variable inflated, at most
/// [`MAX_ARRAY_BYTES`] and one byte: whether it went beyond is the second
/// value (the bytes then begin the variable, enough to name it).
fn inflate(compressed: &[u8]) -> Result<(Vec<u8>, bool), String> {
    use std::io::Read;
    let mut inflated = Vec::new();
    flate2::read::ZlibDecoder::new(compressed)
        .take(MAX_ARRAY_BYTES + 1)
        .read_to_end(&mut inflated)
        .map_err(|e| format!("its compressed data are damaged ({e})"))?;
    let beyond = inflated.len() as u64 > MAX_ARRAY_BYTES;
    if inflated.len() < 8 {
        return Err(format!(
            "its compressed data inflate to {} bytes, too few for a variable",
            inflated.len()
        ));
    }
    Ok((inflated, beyond))
}

/// The one variable of `element` read by matrw after `header`; `None` if
/// matrw fails, panics, or finds other than one variable (it takes an early
/// end of its input for the end of the variable list).
fn parse_one(header: &[u8], element: &[u8]) -> Option<(String, MatVariable)> {
    let mut one = Vec::with_capacity(header.len() + element.len());
    one.extend_from_slice(header);
    one.extend_from_slice(element);
    let file = catch(|| matrw::load_matfile_from_u8(&one))?.ok()?;
    let mut variables = file.into_iter();
    let first = variables.next()?;
    variables.next().is_none().then_some(first)
}

/// The byte order of a level-5 file; any other file is refused, a v7.3 or
/// level-4 MAT-file with the instruction to save it with `-v7`.
fn check_header(bytes: &[u8]) -> Result<Endian, Fault> {
    // MATLAB tells the levels apart by the first four bytes: a level-4 file
    // begins with its first matrix's type, a small integer with zero bytes
    // (MathWorks, "MAT-File Format", Level 5 header).
    if bytes.len() >= 4 && bytes[..4].contains(&0) {
        return Err(Fault::file(ModelFileErrorKind::MatLevel4));
    }
    let hdf5 = bytes
        .get(HDF5_SIGNATURE_AT..HDF5_SIGNATURE_AT + HDF5_SIGNATURE.len())
        .is_some_and(|s| s == HDF5_SIGNATURE);
    if bytes.starts_with(b"MATLAB 7.3 MAT-file") || hdf5 {
        return Err(Fault::file(ModelFileErrorKind::MatV73));
    }
    if bytes.len() < HEADER_LEN {
        return Err(Fault::file(corrupt(format!(
            "{} bytes, shorter than the {HEADER_LEN}-byte header",
            bytes.len()
        ))));
    }
    let endian = match &bytes[ENDIAN] {
        b"IM" => Endian::Little,
        b"MI" => Endian::Big,
        _ => {
            return Err(Fault::file(corrupt(
                "no endian indicator (IM or MI) at byte 126 of the header".into(),
            )));
        }
    };
    match endian.u16([bytes[VERSION.start], bytes[VERSION.start + 1]]) {
        VERSION_5 => Ok(endian),
        VERSION_7_3 => Err(Fault::file(ModelFileErrorKind::MatV73)),
        other => Err(Fault::file(corrupt(format!(
            "header version {other:#06x}, not level 5 (0x0100)"
        )))),
    }
}

/// Where the variables end: at the subsystem data (MATLAB's class
/// definitions for objects, not a variable) when the header points to it
/// within the file, else at the end of the file. All zeros or all spaces
/// mean there is none.
fn variables_end(bytes: &[u8], endian: Endian) -> usize {
    let field = &bytes[SUBSYSTEM_OFFSET];
    if field.iter().all(|&b| b == 0) || field.iter().all(|&b| b == b' ') {
        return bytes.len();
    }
    let mut offset = [0u8; 8];
    offset.copy_from_slice(field);
    match usize::try_from(endian.u64(offset)) {
        Ok(at) if (HEADER_LEN..=bytes.len()).contains(&at) => at,
        _ => bytes.len(),
    }
}

/// The top-level elements (variables) after the header, each checked to lie
/// within the file, with its tag.
fn elements(body: &[u8], endian: Endian) -> Result<Vec<&[u8]>, Fault> {
    let mut elements = Vec::new();
    let mut at = 0;
    while at < body.len() {
        let left = body.len() - at;
        let number = elements.len() + 1;
        if elements.len() == MAX_ARRAYS {
            return Err(Fault::file(ModelFileErrorKind::TooManyArrays {
                count: None,
            }));
        }
        if left < 8 {
            return Err(Fault::file(corrupt(format!(
                "truncated: {left} bytes after variable {}, too few for another",
                number - 1
            ))));
        }
        let word = |i: usize| {
            let mut w = [0u8; 4];
            w.copy_from_slice(&body[at + i..at + i + 4]);
            endian.u32(w)
        };
        let (data_type, size) = (word(0), word(4));
        if data_type != MI_MATRIX && data_type != MI_COMPRESSED {
            return Err(Fault::file(corrupt(format!(
                "element {number} has data type {data_type}, not a variable (miMATRIX 14 or miCOMPRESSED 15)"
            ))));
        }
        let size = usize::try_from(size).unwrap_or(usize::MAX);
        if size > left - 8 {
            return Err(Fault::file(corrupt(format!(
                "truncated: variable {number} should have {size} bytes, the file ends after {}",
                left - 8
            ))));
        }
        // Uncompressed elements are padded to 8 bytes (their sizes are
        // multiples of 8 as MATLAB writes them); compressed ones follow each
        // other directly.
        let padded = if data_type == MI_MATRIX {
            size.next_multiple_of(8).min(left - 8)
        } else {
            size
        };
        elements.push(&body[at..at + 8 + padded]);
        at += 8 + padded;
    }
    Ok(elements)
}

/// A MATLAB variable as an array of `f64`, or why it is not one.
fn array_of(variable: MatVariable) -> Entry {
    let numeric = match variable {
        MatVariable::NumericArray(numeric) => numeric,
        MatVariable::SparseArray(_) => return Err(ModelFileErrorKind::Sparse),
        MatVariable::CellArray(_) => return Err(not_numeric("a cell array")),
        MatVariable::Structure(_) | MatVariable::StructureArray(_) => {
            return Err(not_numeric("a struct"));
        }
        _ => return Err(not_numeric("an object or another unsupported MATLAB class")),
    };
    let NumericArray {
        dim,
        value,
        value_cmp,
    } = numeric;
    if value_cmp.is_some() {
        return Err(ModelFileErrorKind::Complex);
    }
    let data = match value {
        MatlabType::F64(v) => v,
        MatlabType::F32(v) => v.into_iter().map(f64::from).collect(),
        MatlabType::I8(v) => signed_to_f64(&v.into_iter().map(i64::from).collect::<Vec<_>>())?,
        MatlabType::I16(v) => signed_to_f64(&v.into_iter().map(i64::from).collect::<Vec<_>>())?,
        MatlabType::I32(v) => signed_to_f64(&v.into_iter().map(i64::from).collect::<Vec<_>>())?,
        MatlabType::I64(v) => signed_to_f64(&v)?,
        MatlabType::U8(v) => unsigned_to_f64(&v.into_iter().map(u64::from).collect::<Vec<_>>())?,
        MatlabType::U16(v) => unsigned_to_f64(&v.into_iter().map(u64::from).collect::<Vec<_>>())?,
        MatlabType::U32(v) => unsigned_to_f64(&v.into_iter().map(u64::from).collect::<Vec<_>>())?,
        MatlabType::U64(v) => unsigned_to_f64(&v)?,
        MatlabType::BOOL(v) => v.into_iter().map(|b| if b { 1.0 } else { 0.0 }).collect(),
        MatlabType::UTF8(_) | MatlabType::UTF16(_) => {
            return Err(not_numeric("text (a char array)"));
        }
    };
    Array::from_column_major(dim, data)
        .ok_or_else(|| corrupt("the dimensions do not match the number of entries".into()))
}

fn not_numeric(found: &str) -> ModelFileErrorKind {
    ModelFileErrorKind::NotNumeric {
        found: found.to_string(),
    }
}

fn corrupt(reason: String) -> ModelFileErrorKind {
    ModelFileErrorKind::Corrupt {
        format: FileFormat::Mat,
        reason,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Written by MATLAB (see tests/data/README.md).
    const MATLAB_V7: &[u8] = include_bytes!("../tests/data/matlab_v7.mat");
    const MATLAB_V7_3: &[u8] = include_bytes!("../tests/data/matlab_v7.3.mat");

    fn kind(result: Result<NamedArrays, Fault>) -> ModelFileErrorKind {
        match result {
            Ok(arrays) => panic!("read: {:?}", arrays.into_map().keys()),
            Err(fault) => fault.at(&crate::ArraySource::File("t.mat".into())).kind,
        }
    }

    fn entry(arrays: &NamedArrays, name: &str) -> Entry {
        arrays
            .0
            .get(name)
            .cloned()
            .unwrap_or_else(|| panic!("no {name}"))
    }

    #[test]
    fn a_file_written_by_matlab_reads_each_variable_or_its_reason() {
        let arrays = read(MATLAB_V7).unwrap();
        let names: Vec<&String> = arrays.0.keys().collect();
        assert_eq!(names, ["A", "S", "a", "ans", "b", "c", "d", "s"]);
        assert_eq!(entry(&arrays, "a").unwrap().data(), &[42.0]);
        assert_eq!(entry(&arrays, "b").unwrap().data(), &[std::f64::consts::PI]);
        // A(:, :, 1) = [1 2 3; 4 5 6; 7 8 9], A(:, :, 2) = A(:, :, 1) + 9: row-major now.
        let a = entry(&arrays, "A").unwrap();
        assert_eq!(a.shape(), &[3, 3, 2]);
        assert_eq!(&a.data()[..4], &[1.0, 10.0, 2.0, 11.0]);
        assert_eq!(entry(&arrays, "c"), Err(ModelFileErrorKind::Complex));
        assert_eq!(entry(&arrays, "d"), Err(not_numeric("text (a char array)")));
        assert_eq!(entry(&arrays, "s"), Err(not_numeric("a struct")));
        assert_eq!(entry(&arrays, "S"), Err(not_numeric("a struct")));
    }

    #[test]
    fn a_v7_3_file_is_refused_with_the_instruction_to_save_with_v7() {
        assert_eq!(kind(read(MATLAB_V7_3)), ModelFileErrorKind::MatV73);
        // The same from a constructed header (the 128-byte text header, then
        // the HDF5 signature at byte 512): flexloop cannot write HDF5, and
        // each sign alone suffices.
        let mut header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan 13 2025 HDF5 schema 1.00 .".to_vec();
        header.resize(116, b' ');
        header.extend_from_slice(&[0; 8]);
        header.extend_from_slice(&[0x00, 0x02, b'I', b'M']);
        assert_eq!(kind(read(&header)), ModelFileErrorKind::MatV73);
        let mut hdf5_only = vec![b'x'; 512];
        hdf5_only.extend_from_slice(HDF5_SIGNATURE);
        assert_eq!(kind(read(&hdf5_only)), ModelFileErrorKind::MatV73);
        let mut version_only = MATLAB_V7.to_vec();
        version_only[VERSION].copy_from_slice(&[0x00, 0x02]);
        assert_eq!(kind(read(&version_only)), ModelFileErrorKind::MatV73);
        let message = ModelFileErrorKind::MatV73.to_string();
        assert!(
            message.contains("save it with -v7 (save plant.mat A B C D -v7), or from Python with scipy.io.savemat"),
            "{message}"
        );
    }

    #[test]
    fn a_level_4_file_is_refused() {
        // A level-4 matrix header: type 0 (double, little endian), 2 rows, 2
        // columns, no imaginary part, name length 2 ("A\0").
        let mut level4 = Vec::new();
        for word in [0u32, 2, 2, 0, 2] {
            level4.extend_from_slice(&word.to_le_bytes());
        }
        level4.extend_from_slice(b"A\0");
        level4.extend_from_slice(&[0; 32]);
        assert_eq!(kind(read(&level4)), ModelFileErrorKind::MatLevel4);
    }

    #[test]
    fn other_files_are_not_mat_files() {
        for bytes in [&b""[..], b"MATLAB 5.0 MAT-file", &[b'#'; 300]] {
            let kind = kind(read(bytes));
            assert!(
                matches!(
                    kind,
                    ModelFileErrorKind::Corrupt {
                        format: FileFormat::Mat,
                        ..
                    }
                ),
                "{kind}"
            );
        }
    }

    #[test]
    fn a_variable_of_a_kind_matrw_cannot_parse_is_told_by_its_place() {
        // The second variable's class byte set to an unknown class (99).
        let mut damaged = MATLAB_V7.to_vec();
        let second = HEADER_LEN + 8 + 0x50;
        damaged[second + 16] = 99;
        let message = kind(read(&damaged)).to_string();
        assert!(
            message.starts_with("not a readable MATLAB level-5 MAT-file: variable 2 of 8 (the one after `A`) cannot be read"),
            "{message}"
        );
    }

    /// Every truncation of a valid file is an error from flexloop's own
    /// checks (never a panic, never matrw's failure), or, cut exactly between
    /// variables, a file of the variables before the cut.
    pub(crate) fn assert_truncations_are_caught(bytes: &[u8]) {
        let whole: Vec<String> = read(bytes).unwrap().0.into_keys().collect();
        for len in 0..bytes.len() {
            match read(&bytes[..len]) {
                Ok(arrays) => {
                    let names: Vec<String> = arrays.0.into_keys().collect();
                    assert!(
                        names.len() < whole.len() && names.iter().all(|n| whole.contains(n)),
                        "cut at {len}: {names:?}"
                    );
                }
                Err(fault) => {
                    let message = fault
                        .at(&crate::ArraySource::File("t.mat".into()))
                        .to_string();
                    assert!(
                        !message.contains("cannot be read"),
                        "cut at {len}: {message}"
                    );
                }
            }
        }
    }

    #[test]
    fn truncated_files_are_errors() {
        assert_truncations_are_caught(MATLAB_V7);
        // Compressed elements, as MATLAB's default save writes them, by
        // matrw's writer (flexloop's own test of scipy's is in tests/).
        let path = std::env::temp_dir().join(format!(
            "flexloop-modelfile-{}-compressed.mat",
            std::process::id()
        ));
        let mut file = matrw::MatFile::new();
        file.insert("M", matrw::matvar!([[1.0, 2.0], [3.0, 4.0]]));
        file.insert("ts", matrw::matvar!(1e-4));
        matrw::save_matfile_v7(path.to_str().unwrap(), file, true).unwrap();
        let compressed = std::fs::read(&path).unwrap();
        std::fs::remove_file(&path).unwrap();
        assert_eq!(compressed[HEADER_LEN], MI_COMPRESSED as u8);
        let arrays = read(&compressed).unwrap();
        assert_eq!(entry(&arrays, "M").unwrap().data(), &[1.0, 2.0, 3.0, 4.0]);
        assert_truncations_are_caught(&compressed);
    }
}
